"""Speed of the testbed as ratios against references measured in the same run.

Usage::

    python scripts/benchmark.py --json runs/benchmark.json

Measured (median of ``--repeats`` timed blocks, after a warm-up):

- ``raw_steps_per_s``: bare ``mujoco.mj_step(model, data, nstep=frame_skip)`` calls per
  second on the helicopter model (one control period of physics each);
- ``env_steps_per_s``: ``Helicopter2DOFEnv.step`` per second (same physics, plus action
  checks, sensors, reward, info); ``env_overhead_ratio`` = env step time / bare step time
  (target <= 2.0);
- ``env_kf_steps_per_s``: ``FilterInLoop.step`` with the discrete Kalman filter;
- ``kf_step_us`` / ``filterpy_step_us``: one predict + update of our ``KalmanFilter`` and of
  ``filterpy.kalman.KalmanFilter`` on the same 4-state, 2-measurement model;
  ``kf_vs_filterpy`` = their ratio (target <= 1.0);
- ``mshinf_step_us``: one step of the mean-square H-infinity filter (Basin et al.'s example,
  4 states, one RK4 substep) and ``mshinf_vs_kf`` its ratio to ``kf_step_us`` (target <= 2);
- ``inverted_pendulum_v5_steps_per_s``: Gymnasium's ``InvertedPendulum-v5`` for reference;
- Monte Carlo (``scripts/bench_mc.py``): ``raw_rollout_traj_steps_per_s``,
  ``mc_traj_steps_per_s``, ``mc_mshinf_traj_steps_per_s``, ``mc_vs_raw`` (target >= 0.4),
  ``mc_peak_rss_mb`` (target <= 500), ``scaling``, ``mc_1000x80s_wall_s`` (the papers'
  scale: 1000 runs of 80 s with the Kalman filter) and ``sweep_ray_speedup`` (a 16-point
  sweep on local Ray, 2 workers vs 1; target >= 1.6). ``--quick`` skips the two long ones;
- LMI (``scripts/bench_lmi.py``): ``lmi_solve_s`` (median solve of Zhang et al.'s LMI (48) for
  Example 5.2; target < 0.1 s) and ``gamma_bisection_s`` (target < 2 s).

Never used as a timed test: numbers depend on the machine; ratios much less so.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from testbed.envs.helicopter import Helicopter2DOFEnv  # noqa: E402
from testbed.experiment import build_helicopter  # noqa: E402

from filters import KalmanFilter, LinearSystem, MeanSquareHInfFilter  # noqa: E402
from testbed.io import write_json  # noqa: E402
from testbed.rigs.helicopter import gravity_voltage, paper_model  # noqa: E402


def time_per_call(fn: Callable[[], object], calls: int, repeats: int) -> float:
    """Median over ``repeats`` blocks of the time per call of ``fn``, in seconds."""
    for _ in range(max(calls // 10, 1)):
        fn()
    blocks = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        blocks.append((time.perf_counter() - start) / calls)
    return statistics.median(blocks)


def bench_physics(calls: int, repeats: int) -> dict[str, float]:
    env = Helicopter2DOFEnv()
    env.reset(seed=0, options={"x0": np.zeros(4)})
    u = gravity_voltage(env.nominal_params, 0.0)
    model, data = env.rig.model, env.rig.data
    data.ctrl[:] = u
    raw = time_per_call(lambda: mujoco.mj_step(model, data, nstep=env.frame_skip), calls,
                        repeats)
    env.reset(seed=0, options={"x0": np.zeros(4)})
    env_step = time_per_call(lambda: env.step(u), calls, repeats)

    exp = build_helicopter("kalman", "open-loop")
    exp.env.reset(seed=0, options={"x0": np.zeros(4)})
    kf_loop = time_per_call(lambda: exp.env.step(u), calls, repeats)
    return {
        "raw_steps_per_s": 1.0 / raw,
        "env_steps_per_s": 1.0 / env_step,
        "env_overhead_ratio": env_step / raw,
        "env_kf_steps_per_s": 1.0 / kf_loop,
    }


def bench_kalman(calls: int, repeats: int) -> dict[str, float]:
    from filterpy.kalman import KalmanFilter as FilterpyKF

    pm = paper_model()
    dt = 0.01
    sysd = LinearSystem(A=pm.A, B=pm.B, C=pm.C1, Q=pm.b @ pm.b.T, R=np.eye(2) * 1e-4
                        ).discretize(dt)
    x0, P0 = np.zeros(4), np.eye(4)
    rng = np.random.default_rng(0)
    ys = rng.normal(size=(1024, 2)) * 0.01
    u = np.array([0.1, -0.2])

    ours = KalmanFilter(sysd, x0, P0)
    counter = {"i": 0}

    def ours_step() -> None:
        counter["i"] = (counter["i"] + 1) & 1023
        ours.predict(u)
        ours.update(ys[counter["i"]])

    ref = FilterpyKF(dim_x=4, dim_z=2, dim_u=2)
    ref.F, ref.B, ref.H = sysd.F.copy(), sysd.B.copy(), sysd.H.copy()
    ref.Q, ref.R, ref.x, ref.P = sysd.Q.copy(), sysd.R.copy(), x0.copy(), P0.copy()

    def filterpy_step() -> None:
        counter["i"] = (counter["i"] + 1) & 1023
        ref.predict(u=u)
        ref.update(ys[counter["i"]])

    hinf = MeanSquareHInfFilter(pm.A, pm.B, pm.C1, pm.h, pm.C2, pm.H, pm.G, pm.b, pm.L, 1.1,
                                np.eye(4), x0, P0, dt)
    ys4 = rng.normal(size=(1024, 4)) * 0.01

    def hinf_step() -> None:
        counter["i"] = (counter["i"] + 1) & 1023
        hinf.step(ys4[counter["i"]], u)

    ours_s = time_per_call(ours_step, calls, repeats)
    ref_s = time_per_call(filterpy_step, calls, repeats)
    hinf_s = time_per_call(hinf_step, calls, repeats)
    return {"kf_step_us": ours_s * 1e6, "filterpy_step_us": ref_s * 1e6,
            "kf_vs_filterpy": ours_s / ref_s, "mshinf_step_us": hinf_s * 1e6,
            "mshinf_vs_kf": hinf_s / ours_s}


def bench_reference_env(calls: int, repeats: int) -> dict[str, float]:
    import gymnasium as gym

    try:
        env = gym.make("InvertedPendulum-v5")
    except Exception as exc:  # noqa: BLE001 - optional reference, reported not hidden
        return {"inverted_pendulum_v5_error": repr(exc)}
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape)
    step = time_per_call(lambda: env.step(action), calls, repeats)
    return {"inverted_pendulum_v5_steps_per_s": 1.0 / step}


def bench_scale(quick: bool) -> dict[str, object]:
    """Monte-Carlo throughput, memory, scaling, the papers' scale and the Ray sweep speedup."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_mc import bench_monte_carlo
    from testbed.batch import monte_carlo

    out: dict[str, object] = dict(bench_monte_carlo())
    mshinf = monte_carlo("ms-hinf", runs=256, duration_s=20.0, seed=0, progress=False,
                         disturbance="basin-helicopter")
    out["mc_mshinf_traj_steps_per_s"] = mshinf["traj_steps_per_s"]
    if quick:
        return out
    big = monte_carlo("kalman", runs=1000, duration_s=80.0, seed=0, progress=False)
    out["mc_1000x80s_wall_s"] = big["wall_s"]
    out.update(bench_ray_sweep())
    return out


def bench_ray_sweep() -> dict[str, object]:
    """16-point sweep on a local Ray instance with 1 and 2 workers (started and warmed up
    outside the timed region: the sweep's own cost, not Ray's start-up)."""
    import ray
    from testbed.sweep import sweep

    grid = {"process_noise_scale": [0.0, 0.1, 0.2, 0.3], "params.mass_kg": [0.9, 1.0, 1.1, 1.2]}
    walls = {}
    for workers in (1, 2):
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        try:
            sweep({"process_noise_scale": [0.0] * workers}, runs=2, duration_s=0.1,
                  backend="ray", workers=workers, progress=False)  # warm the workers
            start = time.perf_counter()
            sweep(grid, runs=32, duration_s=10.0, seed=0, backend="ray", workers=workers,
                  progress=False)
            walls[workers] = time.perf_counter() - start
        finally:
            ray.shutdown()
    return {"sweep_ray_wall_s": walls, "sweep_ray_speedup": walls[1] / walls[2]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the results here (atomically)")
    parser.add_argument("--calls", type=int, default=2000, help="calls per timed block")
    parser.add_argument("--repeats", type=int, default=7, help="timed blocks (median taken)")
    parser.add_argument("--quick", action="store_true",
                        help="skip the 1000 x 80 s Monte Carlo and the Ray sweep")
    parser.add_argument("--no-mc", action="store_true", help="skip the Monte-Carlo section")
    args = parser.parse_args(argv)

    results: dict[str, object] = {
        "machine": {"python": platform.python_version(), "processor": platform.machine(),
                    "mujoco": mujoco.__version__, "numpy": np.__version__},
        "calls": args.calls,
        "repeats": args.repeats,
    }
    results.update(bench_physics(args.calls, args.repeats))
    results.update(bench_kalman(args.calls, args.repeats))
    results.update(bench_reference_env(args.calls, args.repeats))
    targets = {"env_overhead_ratio <= 2.0": results["env_overhead_ratio"] <= 2.0,
               "kf_vs_filterpy <= 1.0": results["kf_vs_filterpy"] <= 1.0,
               "mshinf_vs_kf <= 2.0": results["mshinf_vs_kf"] <= 2.0}
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_lmi import bench_lmi

    results.update(bench_lmi())
    targets["lmi_solve_s < 0.1"] = results["lmi_solve_s"] < 0.1
    targets["gamma_bisection_s < 2"] = results["gamma_bisection_s"] < 2.0
    if not args.no_mc:
        results.update(bench_scale(args.quick))
        targets["mc_vs_raw >= 0.4"] = results["mc_vs_raw"] >= 0.4
        targets["mc_peak_rss_mb <= 500"] = results["mc_peak_rss_mb"] <= 500
        if "sweep_ray_speedup" in results:
            targets["sweep_ray_speedup >= 1.6"] = results["sweep_ray_speedup"] >= 1.6
    results["targets"] = targets
    width = max(len(k) for k in results)
    for key, value in results.items():
        if isinstance(value, float):
            print(f"{key:<{width}}  {value:,.3f}")
        else:
            print(f"{key:<{width}}  {value}")
    if args.json:
        write_json(args.json, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
