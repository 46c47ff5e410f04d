"""Speed of the testbed as ratios against references measured in the same run.

Usage::

    python scripts/benchmark.py --json runs/benchmark.json          # everything (~20 min)
    python scripts/benchmark.py --quick --json runs/benchmark.json  # without the two long ones
    python scripts/benchmark.py --only-replay                        # the replay metrics
    python scripts/benchmark.py --markdown runs/b1.json runs/b2.json [--doc docs/performance.md]

Measured (the median of ``--repeats`` timed blocks of ``--calls`` calls after a warm-up; the
blocks of the quantities compared in a ratio are interleaved, because the machine may be
shared):

- ``raw_steps_per_s``: bare ``mujoco.mj_step(model, data, nstep=frame_skip)`` calls per
  second on the helicopter's MJCF (one control period of physics each, hovering on the
  gravity voltage); ``env_steps_per_s``: :class:`testbed.envs.RigEnv` ``step`` per second
  (same physics: the rig's ambient disturbance off; plus action checks, sensors, reward,
  info); ``env_overhead_ratio`` = env step time / bare step time (target <= 1.5);
  ``env_vehicle_overhead_ratio``: the same for the vehicle roll rig (at rest, zero action;
  target <= 3);
- ``env_kf_steps_per_s``: :class:`testbed.envs.wrappers.FilterInLoop` ``step`` with the Kalman
  filter built by :func:`testbed.estimators.build` from the rig's design model;
- ``kf_step_us`` / ``filterpy_step_us``: one predict + update of our ``KalmanFilter`` and of
  ``filterpy.kalman.KalmanFilter`` on the same 4-state, 2-measurement model (Basin et al.'s
  helicopter); ``kf_vs_filterpy`` = their ratio (target <= 1.0);
- ``mshinf_step_us``: one step of the mean-square H-infinity filter (Basin et al.'s example,
  4 states, one RK4 substep) and ``mshinf_vs_kf`` its ratio to ``kf_step_us`` (target <= 2);
- ``poly_step_us``: one public ``step`` of the polynomial H-infinity filter on Basin, Shi &
  Calderon-Alvarez's cubic example (the printed filter (26): 2 states, time-varying cubic
  term, dt 0.1 ms, restarted every 0.5 s of filter time because (26) escapes at 1.02 s;
  target <= 50 us) and ``poly_batch64_member_step_us``: one ``step`` of a batch of 64
  filters (leading batch axis) divided by 64;
- ``kalman_hw_vs_paper``: the hardware helicopter's Kalman filter (matched design, 10 states)
  per step / the paper profile's (4 states), target <= 2. The Kalman filter of these metrics
  is the one the ekf and ukf are compared with: the same design and noise model, the
  sensitivity errors as white noise (``kalman`` with ``constants="white"``); the built-in
  ``kalman``'s default on this design, a Schmidt-Kalman filter carrying them as consider
  constants, is ``kalman_consider_hw_step_us`` (diagnostic);
- ``kalman_hw_step_us``, ``ekf_hw_step_us``, ``ukf_hw_step_us``: one ``step`` of a single
  filter (as :func:`testbed.estimators.build` makes it, with its input and channel
  wrappers) on the hardware helicopter's matched design (10 states: rig, rotors, gyro
  biases, IMU delay), hovering at level pitch; ``ekf_vs_kalman`` (target <= 20) and
  ``ukf_vs_kalman`` (target <= 40) their ratios; ``*_batch32_vs_kalman`` the same ratios
  for one batched filter of 32 members (targets <= 30 and <= 50, issue 42: the MuJoCo
  rollouts of the nonlinear filters grow with the batch, the Kalman filter's matrix products
  hardly); ``ekf_physics_fraction`` (target >= 0.8) and ``ukf_physics_fraction``: the share
  of those batched steps spent inside ``mujoco.rollout.rollout`` (the distance to the
  physics limit); the ``ukf`` is the built-in's default, Julier's ``n + 2`` spherical simplex
  sigma points; ``ukf_scaled_*`` the same for the ukf with the ``2n + 1`` scaled points
  (``sigma_points="scaled"``, diagnostic); ``--only-nonlinear`` runs
  these alone;
- ``inverted_pendulum_v5_steps_per_s``: Gymnasium's ``InvertedPendulum-v5`` for reference;
- Monte Carlo (``scripts/bench_mc.py``, both rigs): ``raw_rollout_traj_steps_per_s``,
  ``mc_traj_steps_per_s``, ``mc_vs_raw`` (target >= 0.9), their ``vehicle`` counterparts
  with ``mc_vehicle_vs_raw`` (target >= 0.9), the bare ``mujoco.batch`` reference
  (``raw_batch_*``, ``mc_*vs_raw_batch``), the hardware profile's Monte Carlo
  (``mc_hardware_traj_steps_per_s``, ``mc_hardware_vs_paper``), the ratios with one thread
  (``*_1thread``, diagnostic), ``mc_mshinf_traj_steps_per_s``,
  ``mc_peak_rss_mb`` (target <= 500), ``scaling``, ``mc_1000x80s_wall_s`` (the papers'
  scale: 1000 helicopter runs of 80 s with the Kalman filter), ``sweep_ray_speedup`` (a
  16-point sweep on local Ray, 2 workers vs 1; target >= 1.6) and ``mc_ray_speedup``
  (``mc --backend ray`` of 1000 helicopter runs of 10 s, 2 local workers vs 1, one physics
  thread each; target >= 1.6). ``--quick`` skips the three long ones;
- ``score_replay_vs_simulate``: ``testbed score`` simulates each entry's episodes once and
  replays every further estimator on them (truth feedback): one Monte Carlo of the Kalman
  filter on the helicopter (16 runs x 2 s) replayed / simulated (target <= 0.5);
- LMI (``scripts/bench_lmi.py``): ``lmi_solve_s`` (median solve of Zhang et al.'s LMI (48) for
  Example 5.2; target < 0.1 s) and ``gamma_bisection_s`` (target < 2 s).

The JSON lists every metric with its unit, meaning, target and whether it is met, and the
machine: Python, the processor's architecture and model name, numpy's BLAS, the kernel it
chose and ``OPENBLAS_CORETYPE``. Never used as a timed test: numbers depend on the machine;
ratios much less so.
"""

from __future__ import annotations

import argparse
import json
import operator
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from filters import (  # noqa: E402
    KalmanFilter,
    LinearSystem,
    MeanSquareHInfFilter,
    PolynomialHInfFilter,
)
from testbed import estimators  # noqa: E402
from testbed.envs import RigEnv  # noqa: E402
from testbed.envs.wrappers import FilterInLoop  # noqa: E402
from testbed.io import atomic_path, write_json  # noqa: E402

#: metric -> (unit, meaning). Every key the benchmark can report.
METRICS: dict[str, tuple[str, str]] = {
    "raw_steps_per_s": ("1/s", "bare mj_step(nstep=10), helicopter MJCF"),
    "env_steps_per_s": ("1/s", "RigEnv('helicopter').step"),
    "env_overhead_ratio": ("", "RigEnv step time / bare mj_step time, helicopter"),
    "env_vehicle_overhead_ratio": ("", "the same for the vehicle roll rig"),
    "env_kf_steps_per_s": ("1/s", "FilterInLoop(RigEnv, Kalman filter).step"),
    "kf_step_us": ("us", "our KalmanFilter predict + update (4 states, 2 outputs)"),
    "filterpy_step_us": ("us", "filterpy KalmanFilter predict + update, same model"),
    "kf_vs_filterpy": ("", "kf_step_us / filterpy_step_us"),
    "mshinf_step_us": ("us", "mean-square H-infinity step (4 states, 1 RK4 substep)"),
    "mshinf_vs_kf": ("", "mshinf_step_us / kf_step_us"),
    "poly_step_us": ("us", "polynomial H-infinity step, one filter (2 states)"),
    "poly_batch64_member_step_us": ("us", "polynomial H-infinity step of a batch of 64, / 64"),
    "kalman_hw_step_us": ("us", "kalman step, hardware helicopter (matched design, 10 states; "
                                "constants white, as the ekf and ukf)"),
    "kalman_consider_hw_step_us": ("us", "the default kalman there: Schmidt-Kalman filter "
                                         "with the consider constants"),
    "ekf_hw_step_us": ("us", "ekf step, same design, nominal MuJoCo model"),
    "ukf_hw_step_us": ("us", "ukf step, same design, nominal MuJoCo model"),
    "kalman_hw_vs_paper": ("", "kalman step, hardware matched design (10 states) / paper "
                           "design (4 states), both built by estimators.build"),
    "ekf_vs_kalman": ("", "ekf_hw_step_us / kalman_hw_step_us"),
    "ukf_vs_kalman": ("", "ukf_hw_step_us / kalman_hw_step_us"),
    "ekf_batch32_vs_kalman": ("", "the same ratio for batches of 32 filters"),
    "ukf_batch32_vs_kalman": ("", "the same ratio for batches of 32 filters"),
    "ekf_physics_fraction": ("", "share of the batch-32 ekf step spent in mujoco.rollout"),
    "ukf_physics_fraction": ("", "share of the batch-32 ukf step spent in mujoco.rollout"),
    "ukf_scaled_vs_kalman": ("", "ukf with the 2n + 1 scaled sigma points / kalman step"),
    "ukf_scaled_batch32_vs_kalman": ("", "the same ratio for batches of 32 filters"),
    "ukf_scaled_physics_fraction": ("", "share of the batch-32 scaled-set ukf step in "
                                        "mujoco.rollout"),
    "inverted_pendulum_v5_steps_per_s": ("1/s", "Gymnasium InvertedPendulum-v5 (reference)"),
    "raw_rollout_traj_steps_per_s": ("1/s", "bare mujoco.rollout, helicopter (N x steps)"),
    "mc_traj_steps_per_s": ("1/s", "monte_carlo helicopter, Kalman + LQR, same size"),
    "mc_vs_raw": ("", "mc_traj_steps_per_s / raw_rollout_traj_steps_per_s"),
    "raw_rollout_vehicle_traj_steps_per_s": ("1/s", "bare mujoco.rollout, vehicle roll"),
    "mc_vehicle_traj_steps_per_s": ("1/s", "monte_carlo vehicle roll, Kalman, manoeuvre"),
    "mc_vehicle_vs_raw": ("", "mc_vehicle_traj_steps_per_s / raw_rollout_vehicle_..."),
    "raw_batch_traj_steps_per_s": ("1/s", "bare mujoco.batch stepping, helicopter (N x steps)"),
    "mc_vs_raw_batch": ("", "mc_traj_steps_per_s / raw_batch_traj_steps_per_s"),
    "raw_batch_vehicle_traj_steps_per_s": ("1/s", "bare mujoco.batch stepping, vehicle roll"),
    "mc_vehicle_vs_raw_batch": ("", "mc_vehicle_traj_steps_per_s / raw_batch_vehicle_..."),
    "mc_hardware_traj_steps_per_s": ("1/s", "monte_carlo helicopter, hardware profile"),
    "mc_hardware_vs_paper": ("", "mc_hardware_traj_steps_per_s / the paper profile's"),
    "mc_vs_raw_1thread": ("", "mc_vs_raw with one physics thread for both (diagnostic)"),
    "mc_vehicle_vs_raw_1thread": ("", "mc_vehicle_vs_raw with one thread (diagnostic)"),
    "mc_vehicle_vs_raw_4xruns": ("", "mc_vehicle_vs_raw with 4x the runs, 1/4 the steps "
                                 "(diagnostic: 4x the members per lane)"),
    "mc_vs_raw_batch_1thread": ("", "mc_vs_raw_batch with one thread (diagnostic)"),
    "mc_vehicle_vs_raw_batch_1thread": ("", "mc_vehicle_vs_raw_batch with one thread"),
    "mc_mshinf_traj_steps_per_s": ("1/s", "monte_carlo helicopter, mean-square H-infinity"),
    "mc_peak_rss_mb": ("MB", "peak RSS, streaming monte_carlo (N = 1000 x 2000 steps)"),
    "import_rss_mb": ("MB", "peak RSS of a process that only imports the runner"),
    "scaling": ("us", "wall time per trajectory-step by batch size N"),
    "mc_1000x80s_wall_s": ("s", "the papers' scale: 1000 helicopter runs of 80 s, Kalman"),
    "sweep_ray_wall_s": ("s", "16-point sweep on local Ray, by number of workers"),
    "sweep_ray_speedup": ("", "sweep wall time 1 worker / 2 workers"),
    "mc_ray_wall_s": ("s", "mc --backend ray, 1000 helicopter runs of 10 s, by workers"),
    "mc_ray_speedup": ("", "mc --backend ray wall time 1 worker / 2 workers"),
    "score_replay_vs_simulate": ("", "testbed score: a Monte Carlo replayed on recorded "
                                 "episodes / simulated (helicopter, Kalman, 16 x 2 s)"),
    "version_vs_python": ("", "wall time of `testbed --version` / `python -c pass` (start-up; "
                          "median of interleaved runs)"),
    "identify_wall_s": ("s", "testbed identify: 30 s helicopter recording at 1 kHz, hardware "
                        "profile, 6 free parameters (scripts/bench_identify.py)"),
    "identify_vs_rollout": ("", "identify_wall_s / one rollout of the same recording"),
    "replay_real_time_factor": ("", "testbed replay: kalman over a 30 s, 1 kHz helicopter "
                                "recording, simulated seconds per wall second"),
    "replay_cpu_real_time_factor": ("", "the same, simulated seconds per CPU second of the "
                                    "loop (the wall figure of an idle machine)"),
    "replay_aero_hardware_real_time_factor": (
        "", "the same for the yaw-locked Aero, hardware profile (6-state matched design whose "
        "covariance does not settle in 30 s: its recursion runs every step)"),
    "replay_aero_hardware_cpu_real_time_factor": (
        "", "the same, simulated seconds per CPU second of the loop"),
    "lmi_solve_s": ("s", "LMI (48) solve, Zhang, Deng & Zhang (2018) Example 5.2 (median)"),
    "gamma_bisection_s": ("s", "gamma bisection on the same LMI (median)"),
}
#: metric -> (comparison, bound): the targets the issues set.
TARGETS: dict[str, tuple[str, float]] = {
    "env_overhead_ratio": ("<=", 1.5),
    "env_vehicle_overhead_ratio": ("<=", 3.0),
    "kf_vs_filterpy": ("<=", 1.0),
    "mshinf_vs_kf": ("<=", 2.0),
    "kalman_hw_vs_paper": ("<=", 2.0),
    "ekf_vs_kalman": ("<=", 20.0),
    "ukf_vs_kalman": ("<=", 40.0),
    "ekf_batch32_vs_kalman": ("<=", 30.0),
    "ukf_batch32_vs_kalman": ("<=", 50.0),
    "ekf_physics_fraction": (">=", 0.8),
    "poly_step_us": ("<=", 50.0),
    "mc_vs_raw": (">=", 0.9),
    "mc_vehicle_vs_raw": (">=", 0.9),
    "mc_hardware_vs_paper": (">=", 0.7),
    "mc_peak_rss_mb": ("<=", 500.0),
    "sweep_ray_speedup": (">=", 1.6),
    "mc_ray_speedup": (">=", 1.6),
    "score_replay_vs_simulate": ("<=", 0.5),
    "version_vs_python": ("<=", 5.0),
    "identify_wall_s": ("<=", 60.0),
    "replay_real_time_factor": (">=", 100.0),
    "lmi_solve_s": ("<", 0.1),
    "gamma_bisection_s": ("<", 2.0),
}
_COMPARE = {"<=": operator.le, ">=": operator.ge, "<": operator.lt, ">": operator.gt}
#: Settings of ``--smoke``: seconds of work, numbers without meaning (tests the script).
SMOKE_CALLS, SMOKE_REPEATS = 5, 1


# ------------------------------------------------------------------------------- timing
def time_interleaved(fns: dict[str, Callable[[], object]], calls: int,
                     repeats: int) -> dict[str, float]:
    """Median time per call of each function, in seconds, over ``repeats`` rounds.

    Each round times one block of ``calls`` calls of every function in turn, so a slow
    phase of a shared machine hits all of them (after a warm-up of ``calls // 10`` calls).
    """
    for fn in fns.values():
        for _ in range(max(calls // 10, 1)):
            fn()
    blocks: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):
        for key, fn in fns.items():
            start = time.perf_counter()
            for _ in range(calls):
                fn()
            blocks[key].append((time.perf_counter() - start) / calls)
    return {k: statistics.median(v) for k, v in blocks.items()}


# ------------------------------------------------------------------------------- physics
def _raw_step(env: RigEnv, x0: np.ndarray, u: np.ndarray) -> Callable[[], None]:
    """``mj_step(nstep=frame_skip)`` on a fresh ``MjData`` of the env's member model, at
    ``x0`` with the MuJoCo inputs of action ``u`` held."""
    physics = env.sim.physics
    model = physics.models[0]
    data = mujoco.MjData(model)
    env.rig.set_state(x0, data, model)
    inputs = env.rig.actuation(u[None], physics.constants[:1])
    if "ctrl" in inputs:
        data.ctrl[:] = inputs["ctrl"][0]
    if "xfrc" in inputs:
        data.xfrc_applied[:] = inputs["xfrc"][0]
    nstep = env.frame_skip
    return lambda: mujoco.mj_step(model, data, nstep=nstep)


def bench_physics(calls: int, repeats: int) -> dict[str, float]:
    """Bare physics, ``RigEnv.step`` and ``FilterInLoop.step`` (see the module docstring)."""
    # the same physics as the bare reference: the rig's ambient disturbance off (it makes
    # the hovering rig drift onto its pitch stop, where MuJoCo solves a joint limit each
    # step: slower physics, not overhead); x0 is given, so no reset noise either
    env = RigEnv("helicopter", ambient_noise=0.0)
    x0 = np.zeros(4)
    u = env.rig.operating_input(env.nominal_params, x0[None])[0]  # hover at level pitch
    env.reset(seed=0, options={"x0": x0})

    kf_env = RigEnv("helicopter", ambient_noise=0.0)
    design = kf_env.rig.design_model(kf_env.sensors, kf_env.dt_s, kf_env.disturbance)

    def transform(u_applied: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
        return design.input_transform(u_applied[None], np.asarray(x_hat)[None])[0]

    looped = FilterInLoop(kf_env, estimators.build("kalman", design), input_transform=transform)
    looped.reset(seed=0, options={"x0": x0})

    vehicle = RigEnv("vehicle-roll", ambient_noise=0.0)
    v_x0, v_u = np.zeros(2), np.zeros(1)
    vehicle.reset(seed=0, options={"x0": v_x0})
    t = time_interleaved({"raw": _raw_step(env, x0, u), "env": lambda: env.step(u),
                          "kf": lambda: looped.step(u),
                          "vraw": _raw_step(vehicle, v_x0, v_u),
                          "venv": lambda: vehicle.step(v_u)}, calls, repeats)
    for e in (env, looped, vehicle):
        e.close()
    return {
        "raw_steps_per_s": 1.0 / t["raw"],
        "env_steps_per_s": 1.0 / t["env"],
        "env_overhead_ratio": t["env"] / t["raw"],
        "env_vehicle_overhead_ratio": t["venv"] / t["vraw"],
        "env_kf_steps_per_s": 1.0 / t["kf"],
    }


# ------------------------------------------------------------------------------- filters
def bench_filters(calls: int, repeats: int) -> dict[str, float]:
    """Kalman (ours and filterpy's), mean-square and polynomial H-infinity steps."""
    from filterpy.kalman import KalmanFilter as FilterpyKF

    from testbed.reproductions.basin_polynomial.scenario import PolynomialHinfScenario
    from testbed.reproductions.basin_polynomial.scenario import paper_model as paper_poly_model
    from testbed.rigs.helicopter import paper_model

    pm = paper_model()
    dt = 0.01
    sysd = LinearSystem(A=pm.A, B=pm.B, C=pm.C1, Q=pm.b @ pm.b.T, R=np.eye(2) * 1e-4
                        ).discretize(dt)
    x0, P0 = np.zeros(4), np.eye(4)
    rng = np.random.default_rng(0)
    ys = rng.normal(size=(1024, 2)) * 0.01
    ys4 = rng.normal(size=(1024, 4)) * 0.01
    u = np.array([0.1, -0.2])
    counter = {"i": 0}

    def row(table: np.ndarray) -> np.ndarray:
        counter["i"] = (counter["i"] + 1) & 1023
        return table[counter["i"]]

    ours = KalmanFilter(sysd, x0, P0)

    def ours_step() -> None:
        ours.predict(u)
        ours.update(row(ys))

    ref = FilterpyKF(dim_x=4, dim_z=2, dim_u=2)
    ref.F, ref.B, ref.H = sysd.F.copy(), sysd.B.copy(), sysd.H.copy()
    ref.Q, ref.R, ref.x, ref.P = sysd.Q.copy(), sysd.R.copy(), x0.copy(), P0.copy()

    def filterpy_step() -> None:
        ref.predict(u=u)
        ref.update(row(ys))

    hinf = MeanSquareHInfFilter(pm.A, pm.B, pm.C1, pm.h, pm.C2, pm.H, pm.G, pm.b, pm.L, 1.1,
                                np.eye(4), x0, P0, dt)

    s = PolynomialHinfScenario()
    model = paper_poly_model(L=s.printed_gain_L)  # the printed filter (26)
    poly_dt = 1e-4  # the reproduction's default sample interval
    batch = 64
    poly = PolynomialHInfFilter(model, s.gamma, s.R, poly_dt, s.xf0)
    poly_batch = PolynomialHInfFilter(model, s.gamma, s.R, poly_dt, np.zeros((batch, model.n)))
    y_poly = rng.normal(size=(1024, batch, model.m)) * 0.01

    def poly_step(filt: PolynomialHInfFilter, y: np.ndarray) -> None:
        # (26) escapes at t = 1.02 s: restart every 0.5 s of filter time (amortized: once
        # per 5000 steps)
        if filt.t_s >= 0.5:
            filt.reset(np.zeros_like(filt.x), filt.P0)
        filt.step(y)

    t = time_interleaved({
        "kf": ours_step, "filterpy": filterpy_step,
        "mshinf": lambda: hinf.step(row(ys4), u),
        "poly": lambda: poly_step(poly, row(y_poly)[0]),
        "poly_batch": lambda: poly_step(poly_batch, row(y_poly)),
    }, calls, repeats)
    return {"kf_step_us": t["kf"] * 1e6, "filterpy_step_us": t["filterpy"] * 1e6,
            "kf_vs_filterpy": t["kf"] / t["filterpy"], "mshinf_step_us": t["mshinf"] * 1e6,
            "mshinf_vs_kf": t["mshinf"] / t["kf"], "poly_step_us": t["poly"] * 1e6,
            "poly_batch64_member_step_us": t["poly_batch"] / batch * 1e6}


def bench_nonlinear(calls: int, repeats: int) -> dict[str, float]:
    """``kalman``, ``ekf`` and ``ukf`` steps on the hardware helicopter's matched design."""
    from testbed.rigs.helicopter.rig import HelicopterRig

    rig = HelicopterRig(profile="hardware")
    design = rig.design_model(rig.sensors(dt_s=0.01), 0.01)
    x_hover = np.array(design.x0, float)
    x_hover[:4] = 0.0   # level pitch, at rest
    x_hover[4:6] = 0.0  # rotors at the gravity-compensating voltage
    x_hover[6:] = 0.0   # no gyro bias, delayed rates zero
    rng = np.random.default_rng(0)
    m = len(design.measurement_index)
    u = np.zeros(len(design.input_names))
    out: dict[str, float] = {}
    for batch in (1, 32):
        ys = (design.discrete.H @ x_hover + 1e-3 * rng.standard_normal((1024, batch, m)))
        filters = {}
        for name, options in (("kalman", {"constants": "white"}), ("kalman_consider", {}),
                              ("ekf", {}), ("ukf", {}),
                              ("ukf_scaled", {"sigma_points": "scaled"})):
            est = estimators.build(name.partition("_")[0], design, **options)
            est.reset(np.tile(x_hover, (batch, 1)), design.P0)
            filters[name] = est
        counter = {"i": 0}
        u_batch = np.tile(u, (batch, 1))

        def stepper(est, ys=ys, ub=u_batch, counter=counter):
            def step() -> None:
                counter["i"] = (counter["i"] + 1) & 1023
                est.step(ys[counter["i"]], ub)
            return step

        steppers = {k: stepper(e) for k, e in filters.items()}
        if batch == 1:  # the paper profile's Kalman filter (4 states), the same path
            paper_rig = HelicopterRig()
            paper = paper_rig.design_model(paper_rig.sensors(dt_s=0.01), 0.01)
            est = estimators.build("kalman", paper)
            est.reset(np.zeros((1, paper.n)), paper.P0)
            ys_paper = 1e-3 * rng.standard_normal((1024, 1, len(paper.measurement_index)))
            steppers["kalman_paper"] = stepper(est, ys=ys_paper,
                                               ub=np.zeros((1, len(paper.input_names))))
        n_calls = max(calls // (10 if batch > 1 else 4), 1)
        t = time_interleaved(steppers, n_calls, repeats)
        if batch == 1:
            out.update({"kalman_hw_vs_paper": t["kalman"] / t["kalman_paper"],
                        "kalman_hw_step_us": t["kalman"] * 1e6,
                        "kalman_consider_hw_step_us": t["kalman_consider"] * 1e6,
                        "ekf_hw_step_us": t["ekf"] * 1e6, "ukf_hw_step_us": t["ukf"] * 1e6,
                        "ekf_vs_kalman": t["ekf"] / t["kalman"],
                        "ukf_vs_kalman": t["ukf"] / t["kalman"],
                        "ukf_scaled_vs_kalman": t["ukf_scaled"] / t["kalman"]})
        else:
            out.update({"ekf_batch32_vs_kalman": t["ekf"] / t["kalman"],
                        "ukf_batch32_vs_kalman": t["ukf"] / t["kalman"],
                        "ukf_scaled_batch32_vs_kalman": t["ukf_scaled"] / t["kalman"]})
            for name in ("ekf", "ukf", "ukf_scaled"):
                out[f"{name}_physics_fraction"] = physics_fraction(steppers[name], n_calls,
                                                                   repeats)
    return out


def physics_fraction(step: Callable[[], None], calls: int, repeats: int) -> float:
    """The median share of ``step``'s time spent inside MuJoCo's rollouts
    (:meth:`mujoco.rollout.Rollout.rollout`, which :func:`mujoco.rollout.rollout` calls too,
    timed around each call; the distance of a nonlinear filter to its physics)."""
    import mujoco.rollout

    inner = mujoco.rollout.Rollout.rollout
    spent = [0.0]

    def timed(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            spent[0] += time.perf_counter() - start

    shares = []
    mujoco.rollout.Rollout.rollout = timed  # type: ignore[method-assign]
    try:
        for _ in range(max(repeats, 1)):
            spent[0] = 0.0
            start = time.perf_counter()
            for _ in range(calls):
                step()
            shares.append(spent[0] / (time.perf_counter() - start))
    finally:
        mujoco.rollout.Rollout.rollout = inner  # type: ignore[method-assign]
    return statistics.median(shares)


def bench_score(repeats: int, runs: int = 16, duration_s: float = 2.0) -> dict[str, float]:
    """``testbed score``'s Monte Carlo of one estimator on the helicopter: simulated (with its
    tape kept) and replayed on the tape (what every estimator after the first of an entry
    costs, :meth:`ClosedLoop.replay`), interleaved."""
    from testbed.experiment import runner
    from testbed.experiment.scenario import Scenario

    experiment = runner.build(Scenario(rig="helicopter", estimator="kalman",
                                       duration_s=duration_s), runs, num_threads=1)
    loop = experiment.loop
    loop.truth_feedback = True
    seeds = np.arange(runs)
    tape = loop.run(seeds, duration_s, record=True, tape=True).tape
    t = time_interleaved({"simulate": lambda: loop.run(seeds, duration_s, record=True,
                                                       tape=True),
                          "replay": lambda: loop.replay(tape, record=True)}, 1, repeats)
    experiment.close()
    return {"score_replay_vs_simulate": t["replay"] / t["simulate"]}


def bench_reference_env(calls: int, repeats: int) -> dict[str, Any]:
    """Gymnasium's ``InvertedPendulum-v5`` (an error string when it cannot be made)."""
    import gymnasium as gym

    try:
        env = gym.make("InvertedPendulum-v5")
    except Exception as exc:  # noqa: BLE001 - optional reference, reported not hidden
        return {"inverted_pendulum_v5_error": repr(exc)}
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape)
    t = time_interleaved({"step": lambda: env.step(action)}, calls, repeats)
    env.close()
    return {"inverted_pendulum_v5_steps_per_s": 1.0 / t["step"]}


# ------------------------------------------------------------------------------- scale
def bench_scale(mode: str) -> dict[str, Any]:
    """Monte-Carlo throughput of both rigs, memory, scaling; with ``mode == "full"`` also the
    papers' scale and the Ray sweep speedup."""
    import bench_mc

    from testbed.experiment.runner import monte_carlo
    from testbed.experiment.scenario import Scenario

    sizes = {"full": {}, "quick": bench_mc.QUICK, "smoke": bench_mc.SMOKE}[mode]
    out: dict[str, Any] = dict(bench_mc.bench_monte_carlo(**sizes))
    if mode != "full":
        return out
    big = monte_carlo(Scenario(rig="helicopter", estimator="kalman", duration_s=80.0), 1000,
                      progress=False)
    out["mc_1000x80s_wall_s"] = big["wall_s"]
    out.update(bench_ray_sweep())
    out.update(bench_ray_mc())
    return out


def bench_ray_sweep(runs: int = 32, duration_s: float = 10.0) -> dict[str, Any]:
    """16-point helicopter sweep on a local Ray instance with 1 and 2 workers (started and
    warmed up outside the timed region: the sweep's own cost, not Ray's start-up)."""
    import ray

    from testbed.experiment.runner import sweep
    from testbed.experiment.scenario import Scenario

    scenario = Scenario(rig="helicopter", estimator="kalman", seed=0)
    grid = {"process_noise": [0.0, 0.1, 0.2, 0.3], "params.mass_kg": [0.9, 1.0, 1.1, 1.2]}
    walls: dict[int, float] = {}
    for workers in (1, 2):
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        try:
            sweep(scenario.replace(duration_s=0.1), {"process_noise": [0.0] * workers},
                  runs=2, backend="ray", workers=workers, progress=False)  # warm the workers
            start = time.perf_counter()
            sweep(scenario.replace(duration_s=duration_s), grid, runs=runs, backend="ray",
                  workers=workers, progress=False)
            walls[workers] = time.perf_counter() - start
        finally:
            ray.shutdown()
    return {"sweep_ray_wall_s": walls, "sweep_ray_speedup": walls[1] / walls[2]}


def bench_ray_mc(runs: int = 1000, duration_s: float = 10.0,
                 repeats: int = 2) -> dict[str, Any]:
    """``monte_carlo(..., backend="ray")`` of the helicopter (Kalman filter) with 1 and 2
    workers (one physics thread each) on one local Ray instance of 2 CPUs, started and warmed
    up outside the timed region; the two are interleaved ``repeats`` times and the shortest
    wall time of each kept (the machine may be shared)."""
    import ray

    from testbed.experiment.runner import monte_carlo
    from testbed.experiment.scenario import Scenario

    scenario = Scenario(rig="helicopter", estimator="kalman", seed=0)
    walls: dict[int, float] = {1: np.inf, 2: np.inf}
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        monte_carlo(scenario.replace(duration_s=0.1), 4, backend="ray", workers=2)  # warm up
        for _ in range(repeats):
            for workers in walls:
                start = time.perf_counter()
                monte_carlo(scenario.replace(duration_s=duration_s), runs, backend="ray",
                            workers=workers)
                walls[workers] = min(walls[workers], time.perf_counter() - start)
    finally:
        ray.shutdown()
    return {"mc_ray_wall_s": walls, "mc_ray_speedup": walls[1] / walls[2]}


# ------------------------------------------------------------------------------- report
def assess(values: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Each measured metric with its unit, meaning, target (or None) and whether it is met."""
    out = {}
    for key, value in values.items():
        unit, what = METRICS.get(key, ("", ""))
        entry: dict[str, Any] = {"value": value, "unit": unit, "what": what,
                                 "target": None, "met": None}
        if key in TARGETS:
            op, bound = TARGETS[key]
            entry["target"] = f"{op} {bound:g}"
            entry["met"] = bool(_COMPARE[op](value, bound))
        out[key] = entry
    return out


def _fmt(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, float | int | np.floating):
        v = float(value)
        if abs(v) >= 100:
            return f"{v:,.0f}"
        if abs(v) >= 10:
            return f"{v:.1f}"
        if abs(v) >= 1:
            return f"{v:.2f}"
        return f"{v:.3g}"
    if isinstance(value, dict) and value and all(isinstance(v, dict) for v in value.values()):
        horizon = max(int(k.split("steps=")[1]) for k in value)  # scaling at its longest
        return " / ".join(f"{k.split(',')[0]}: {_fmt(v['us_per_traj_step'])}"
                          for k, v in value.items() if k.endswith(f"steps={horizon}"))
    if isinstance(value, dict):
        return " / ".join(f"{k}: {_fmt(v)}" for k, v in value.items())
    if isinstance(value, list):
        return ", ".join(_fmt(v) for v in value)
    return str(value)


def print_table(metrics: dict[str, dict[str, Any]]) -> None:
    """The metrics as a plain-text table (key, value, unit, target, met)."""
    width = max(len(k) for k in metrics)
    for key, m in metrics.items():
        target = ""
        if m["target"] is not None:
            target = f"{m['target']:>8}  {'met' if m['met'] else 'MISSED'}"
        print(f"{key:<{width}}  {_fmt(m['value']):>24} {m['unit']:<4} {target}")


def _median_tree(values: list[Any]) -> Any:
    """Element-wise median of equally shaped dicts of numbers (or of such dicts)."""
    if isinstance(values[0], dict):
        return {k: _median_tree([v[k] for v in values]) for k in values[0]}
    return statistics.median(values)


def markdown(results: list[dict[str, Any]]) -> str:
    """A Markdown table of one or more benchmark JSONs: the median (element-wise for the
    tables), and with several runs the range ``(min-max)`` and how many runs met each
    target."""
    keys = [k for k in METRICS if any(k in r["metrics"] for r in results)]
    lines = ["| metric | value | target | met |", "|---|---|---|---|"]
    for key in keys:
        entries = [r["metrics"][key] for r in results if key in r["metrics"]]
        values = [e["value"] for e in entries]
        if all(isinstance(v, int | float) for v in values):
            text = _fmt(statistics.median(values))
            if len(values) > 1:
                text += f" ({_fmt(min(values))}-{_fmt(max(values))})"
        else:
            text = _fmt(_median_tree(values))
        unit = entries[0]["unit"]
        if unit and unit != "1/s":
            text += f" {unit}"
        target = entries[0]["target"] or ""
        met = "" if entries[0]["met"] is None else \
            f"{sum(bool(e['met']) for e in entries)}/{len(entries)}"
        lines.append(f"| `{key}`: {METRICS[key][1]} | {text} | {target} | {met} |")
    return "\n".join(lines)


def cpu_model() -> str:
    """The processor's model name (``/proc/cpuinfo``; ``platform.processor()`` elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def blas_kernel() -> dict[str, str]:
    """numpy's BLAS (threadpoolctl): ``blas`` (its library and version), ``blas_kernel``
    (the kernel it chose, e.g. OpenBLAS's ``SkylakeX``) and ``openblas_coretype`` (the
    variable that forces it, or ``unset``)."""
    import os

    from threadpoolctl import threadpool_info

    info = [i for i in threadpool_info() if i.get("user_api") == "blas"]
    first = info[0] if info else {}
    return {"blas": f"{first.get('internal_api', 'unknown')} {first.get('version', '')}".strip(),
            "blas_kernel": str(first.get("architecture", "unknown")),
            "openblas_coretype": os.environ.get("OPENBLAS_CORETYPE", "unset")}


def provenance(results: list[dict[str, Any]]) -> str:
    """One sentence saying which runs a generated table summarizes."""
    modes = sorted({r["settings"]["mode"] for r in results})
    machine = results[0]["machine"]
    threads = sorted({r["settings"].get("mc_threads") for r in results} - {None})
    return (f"Generated by `python scripts/benchmark.py --markdown` from {len(results)} "
            f"{'/'.join(modes)} run(s) (Python {machine['python']}, MuJoCo {machine['mujoco']}, "
            f"numpy {machine['numpy']}"
            + (f"; {machine['cpu_model']}, BLAS kernel {machine['blas_kernel']} "
               f"(OPENBLAS_CORETYPE {machine['openblas_coretype']})"
               if "cpu_model" in machine else "")
            + (f", {'/'.join(map(str, threads))} physics threads" if threads else "") + "): "
            + ("median (min-max) over the runs, element-wise for the tables; `met`: runs that "
               "met the target." if len(results) > 1 else "one run."))


#: The markers of the table in docs/performance.md (``--doc``).
TABLE_START, TABLE_END = "<!-- benchmark-table:start -->", "<!-- benchmark-table:end -->"
#: Where the repository keeps the table.
PERFORMANCE_DOC = Path(__file__).resolve().parents[1] / "docs" / "performance.md"


def update_doc(path: Path, table: str, note: str) -> None:
    """Replace the text between the benchmark-table markers of ``path`` (atomically)."""
    text = path.read_text()
    start, end = text.find(TABLE_START), text.find(TABLE_END)
    if start < 0 or end < start:
        raise ValueError(f"{path} has no {TABLE_START} ... {TABLE_END} markers")
    new = f"{text[:start]}{TABLE_START}\n{note}\n\n{table}\n{text[end:]}"
    with atomic_path(path) as tmp:
        Path(tmp).write_text(new)


# ------------------------------------------------------------------------------- start-up
def bench_startup(repeats: int) -> dict[str, float]:
    """``testbed --version`` against a bare interpreter, as whole processes (each the median
    of ``repeats`` interleaved runs, at least 3)."""
    import subprocess

    testbed_cmd = [str(Path(sys.executable).with_name("testbed")), "--version"]
    if not Path(testbed_cmd[0]).exists():
        testbed_cmd = [sys.executable, "-m", "testbed", "--version"]
    python_cmd = [sys.executable, "-c", "pass"]
    times: dict[str, list[float]] = {"testbed": [], "python": []}
    for _ in range(max(3, repeats)):
        for name, cmd in (("testbed", testbed_cmd), ("python", python_cmd)):
            start = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times[name].append(time.perf_counter() - start)
    return {"version_vs_python": float(np.median(times["testbed"]) / np.median(times["python"]))}


# ------------------------------------------------------------------------------- twins
def bench_twin(duration_s: float, identify: bool = True) -> dict[str, float]:
    """``identify`` of a 1 kHz recording against one rollout of it
    (:func:`bench_identify.identify_vs_rollout`), and ``replay`` of a 1 kHz recording with
    ``kalman`` as a real-time factor (best of three; the helicopter's paper profile and the
    yaw-locked Aero's hardware profile), of the loop's wall time and of its CPU time (the
    machine's load does not change the second); ``identify=False``: the replays only."""
    from bench_identify import identify_vs_rollout

    from testbed.experiment.replay import replay, simulate_recording
    from testbed.experiment.scenario import Scenario

    ident = identify_vs_rollout(duration_s) if identify else {}
    recording = simulate_recording(Scenario(rig="helicopter", duration_s=duration_s,
                                            frame_skip=1))
    heli = [replay(recording, rig="helicopter") for _ in range(3)]
    aero = {"rig": "aero", "profile": "hardware", "options": {"yaw_locked": True}}
    recording = simulate_recording(Scenario(rig="aero", profile="hardware",
                                            rig_options={"yaw_locked": True},
                                            duration_s=duration_s, frame_skip=1))
    aeros = [replay(recording, **aero) for _ in range(3)]
    return {**{k: ident[k] for k in ("identify_wall_s", "identify_vs_rollout") if k in ident},
            "replay_real_time_factor": max(r.real_time_factor for r in heli),
            "replay_cpu_real_time_factor": max(r.cpu_real_time_factor for r in heli),
            "replay_aero_hardware_real_time_factor": max(r.real_time_factor for r in aeros),
            "replay_aero_hardware_cpu_real_time_factor": max(r.cpu_real_time_factor
                                                             for r in aeros)}


# ------------------------------------------------------------------------------- main
def run(calls: int, repeats: int, mode: str, mc: bool) -> dict[str, Any]:
    """Every benchmark; ``mode`` is ``"full"``, ``"quick"`` or ``"smoke"``."""
    from bench_lmi import bench_lmi

    values: dict[str, Any] = {}
    values.update(bench_physics(calls, repeats))
    values.update(bench_filters(calls, repeats))
    values.update(bench_nonlinear(calls, repeats))
    values.update(bench_reference_env(calls, repeats))
    values.update(bench_score(repeats, duration_s=0.2 if mode == "smoke" else 2.0))
    values.update(bench_lmi(**({"repeats": 1, "bisections": 1} if mode == "smoke" else {})))
    values.update(bench_startup(repeats))
    values.update(bench_twin(2.0 if mode == "smoke" else 30.0))
    settings: dict[str, Any] = {"calls": calls, "repeats": repeats, "mode": mode}
    if mc:
        scale = bench_scale(mode)
        for key in ("threads", "runs", "steps"):
            settings[f"mc_{key}"] = scale.pop(key)
        for key in [k for k in scale if k.endswith("_pairs")]:
            settings[key] = scale.pop(key)
        values.update(scale)
    metrics = assess(values)
    return {
        "machine": {"python": platform.python_version(), "processor": platform.machine(),
                    "cpu_model": cpu_model(), **blas_kernel(),
                    "mujoco": mujoco.__version__, "numpy": np.__version__},
        "settings": settings,
        "metrics": metrics,
        "targets_missed": [k for k, m in metrics.items() if m["met"] is False],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the results here (atomically)")
    parser.add_argument("--calls", type=int, default=2000, help="calls per timed block")
    parser.add_argument("--repeats", type=int, default=7, help="timed blocks (median taken)")
    parser.add_argument("--quick", action="store_true",
                        help="small Monte Carlo; skip the 1000 x 80 s Monte Carlo and the Ray "
                             "sweep and Monte Carlo")
    parser.add_argument("--smoke", action="store_true",
                        help="tiny sizes everywhere (checks that the script runs)")
    parser.add_argument("--no-mc", action="store_true", help="skip the Monte-Carlo section")
    parser.add_argument("--only-replay", action="store_true",
                        help="only the replay metrics (30 s recordings; --smoke: 2 s)")
    parser.add_argument("--only-nonlinear", action="store_true",
                        help="only the kalman/ekf/ukf step metrics of the hardware helicopter")
    parser.add_argument("--markdown", nargs="+", metavar="JSON",
                        help="print the Markdown table of these results and exit")
    parser.add_argument("--doc", "--readme", dest="doc", metavar="PATH",
                        help="with --markdown: write the table into this file between its "
                             "benchmark-table markers (the repository's: docs/performance.md)")
    args = parser.parse_args(argv)
    if args.markdown:
        results = [json.loads(Path(p).read_text()) for p in args.markdown]
        table = markdown(results)
        print(table)
        if args.doc:
            update_doc(Path(args.doc), table, provenance(results))
        return 0
    if args.doc:
        parser.error("--doc needs --markdown")
    if args.smoke:
        calls, repeats, mode = SMOKE_CALLS, SMOKE_REPEATS, "smoke"
    else:
        calls, repeats, mode = args.calls, args.repeats, "quick" if args.quick else "full"
    if calls < 1 or repeats < 1:
        parser.error(f"--calls and --repeats must be >= 1, got {calls} and {repeats}")
    if args.only_replay or args.only_nonlinear:
        only = "replay" if args.only_replay else "nonlinear"
        values = bench_twin(2.0 if mode == "smoke" else 30.0, identify=False) \
            if args.only_replay else bench_nonlinear(calls, repeats)
        results = {"machine": {"python": platform.python_version(),
                               "processor": platform.machine(), "mujoco": mujoco.__version__,
                               "numpy": np.__version__},
                   "settings": {"mode": mode, "only": only}, "metrics": assess(values)}
        results["targets_missed"] = [k for k, m in results["metrics"].items()
                                     if m["met"] is False]
    else:
        results = run(calls, repeats, mode, not args.no_mc)
    print_table(results["metrics"])
    if args.json:
        write_json(args.json, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
