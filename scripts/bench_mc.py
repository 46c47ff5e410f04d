"""Speed and memory of the batched Monte Carlo (:func:`testbed.batch.monte_carlo`).

Usage::

    python scripts/bench_mc.py --json runs/bench_mc.json

:func:`bench_monte_carlo` returns (all measured in the same run, never a timed test):

- ``raw_rollout_traj_steps_per_s``: bare ``mujoco.rollout`` of the helicopter model (same
  threads, constant hover voltage, no sensors, estimator or controller), in trajectory
  control steps (``frame_skip`` physics steps each) per second;
- ``mc_traj_steps_per_s``: ``monte_carlo`` with the Kalman filter and the LQR in the loop,
  same trajectories and steps; ``mc_vs_raw`` their ratio (target >= 0.4);
- ``mc_peak_rss_mb``: peak resident memory of a fresh process running a streaming
  ``monte_carlo`` of ``rss_runs`` trajectories (target <= 500 MB), and ``import_rss_mb`` of
  one that only imports it;
- ``scaling``: wall time per trajectory-step (setup included) for each batch size and
  horizon.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from testbed.batch import limit_blas_threads, monte_carlo  # noqa: E402
from testbed.envs.helicopter_vector import default_num_threads  # noqa: E402

from testbed.rigs.helicopter import HelicopterRig  # noqa: E402

# VmHWM (peak RSS of this process image), not ru_maxrss: Linux carries ru_maxrss over fork and
# exec, so a child would report at least its parent's size.
_RSS_SNIPPET = """
import resource, sys
from testbed.batch import monte_carlo
runs, steps = int(sys.argv[1]), int(sys.argv[2])
if runs:
    monte_carlo(runs=runs, duration_s=steps * 0.01, progress=False)
try:
    with open("/proc/self/status") as f:
        peak_kb = next(int(l.split()[1]) for l in f if l.startswith("VmHWM:"))
except (OSError, StopIteration):
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(peak_kb)
"""


def raw_rollout_traj_steps_per_s(runs: int, steps: int, num_threads: int,
                                 frame_skip: int = 10, chunk: int = 100) -> float:
    """Trajectory control steps per second of a bare ``mujoco.rollout`` (chunks of steps)."""
    rig = HelicopterRig()
    model = rig.model
    rig.set_state(np.zeros(4))
    spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state0 = np.zeros((runs, mujoco.mj_stateSize(model, spec)))
    mujoco.mj_getState(model, rig.data, state0[0], spec)
    state0[:] = state0[0]
    control = np.tile(rig.gravity_voltage(0.0), (runs, 1, 1))
    chunk = min(chunk, steps)
    out = np.empty((runs, chunk * frame_skip, state0.shape[1]))
    datas = [mujoco.MjData(model) for _ in range(num_threads)]
    with rollout.Rollout(nthread=num_threads if num_threads > 1 else 0) as pool:
        pool.rollout(model, datas, state0, control, nstep=frame_skip, state=out[:, :frame_skip])
        start = time.perf_counter()
        for _ in range(steps // chunk):
            pool.rollout(model, datas, state0, control, state=out)
            state0 = out[:, -1].copy()
        elapsed = time.perf_counter() - start
    return runs * (steps // chunk) * chunk / elapsed


def peak_rss_mb(runs: int, steps: int) -> float:
    """Peak RSS (MB) of a fresh Python process running ``monte_carlo(runs, steps)``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
    out = subprocess.run([sys.executable, "-c", _RSS_SNIPPET, str(runs), str(steps)],
                         capture_output=True, text=True, check=True, env=env)
    return int(out.stdout.strip().splitlines()[-1]) / 1024.0


def bench_monte_carlo(runs: int = 256, steps: int = 2000, rss_runs: int = 1000,
                      rss_steps: int = 2000, scaling_runs: Sequence[int] = (10, 100, 1000),
                      scaling_steps: Sequence[int] = (200, 2000), filter_name: str = "kalman",
                      num_threads: int | None = None) -> dict[str, object]:
    """Measure the batched Monte Carlo against a bare ``mujoco.rollout``.

    Parameters
    ----------
    runs, steps : int
        Trajectories and control steps of the speed comparison (10 ms per step).
    rss_runs, rss_steps : int
        Size of the streaming run whose peak memory is measured (in a subprocess).
    scaling_runs, scaling_steps : sequence of int
        Batch sizes and horizons of the ``scaling`` table.
    filter_name : str
        Estimator in the loop.
    num_threads : int, optional
        Physics threads for both (default: the CPUs available).

    Returns
    -------
    dict
        ``raw_rollout_traj_steps_per_s``, ``mc_traj_steps_per_s``, ``mc_vs_raw``,
        ``mc_peak_rss_mb``, ``import_rss_mb``, ``scaling`` (``"N=..,steps=.."`` ->
        ``{"us_per_traj_step", "traj_steps_per_s"}``), ``threads``, ``runs``, ``steps``.
    """
    threads = num_threads or default_num_threads()
    with limit_blas_threads(1):
        raw = raw_rollout_traj_steps_per_s(runs, steps, threads)
    mc = monte_carlo(filter_name, runs=runs, duration_s=steps * 0.01, progress=False,
                     num_threads=threads)
    scaling: dict[str, dict[str, float]] = {}
    for n in scaling_runs:
        for horizon in scaling_steps:
            start = time.perf_counter()
            monte_carlo(filter_name, runs=n, duration_s=horizon * 0.01, progress=False,
                        num_threads=threads)
            wall = time.perf_counter() - start
            scaling[f"N={n},steps={horizon}"] = {"us_per_traj_step": wall / (n * horizon) * 1e6,
                                                 "traj_steps_per_s": n * horizon / wall}
    return {
        "raw_rollout_traj_steps_per_s": raw,
        "mc_traj_steps_per_s": mc["traj_steps_per_s"],
        "mc_vs_raw": mc["traj_steps_per_s"] / raw,
        "mc_peak_rss_mb": peak_rss_mb(rss_runs, rss_steps),
        "import_rss_mb": peak_rss_mb(0, 0),
        "scaling": scaling,
        "threads": threads,
        "runs": runs,
        "steps": steps,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the results here (atomically)")
    parser.add_argument("--runs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    args = parser.parse_args(argv)
    kwargs: dict[str, object] = {"runs": args.runs, "steps": args.steps}
    if args.quick:
        kwargs.update(runs=32, steps=200, rss_runs=100, rss_steps=200, scaling_runs=(10, 100),
                      scaling_steps=(50, 200))
    results = bench_monte_carlo(**kwargs)  # type: ignore[arg-type]
    print(json.dumps(results, indent=2))
    if args.json:
        from testbed.io import write_json

        write_json(args.json, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
