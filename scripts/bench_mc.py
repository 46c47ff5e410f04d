"""Speed and memory of the batched Monte Carlo (:func:`testbed.experiment.runner.monte_carlo`).

Usage::

    python scripts/bench_mc.py --json runs/bench_mc.json [--quick]

:func:`bench_monte_carlo` returns (all measured in the same run, never a timed test):

- ``raw_rollout_traj_steps_per_s`` / ``raw_rollout_vehicle_traj_steps_per_s``: bare
  ``mujoco.rollout`` of the rig's MJCF (nominal parameters, the same physics threads, from
  the state 0 with the rig's operating input held: the helicopter hovering on its gravity
  voltage, the vehicle at rest; no sensors, estimator or controller), in trajectory control
  steps (``frame_skip`` physics steps each) per second;
- ``mc_traj_steps_per_s`` / ``mc_vehicle_traj_steps_per_s``: ``monte_carlo`` of the rig's
  default scenario with the Kalman filter (helicopter: LQR tracking the default setpoints;
  vehicle roll: the double-lane-change manoeuvre open loop, with its per-step damping noise),
  same trajectories and steps and threads (``monte_carlo`` runs them in lanes, one Python and
  one physics thread each), set-up included (``traj_steps_per_s`` of the result);
  ``mc_vs_raw`` / ``mc_vehicle_vs_raw`` their ratios (target >= 0.7 each);
- ``raw_batch_traj_steps_per_s`` / ``raw_batch_vehicle_traj_steps_per_s``: bare
  ``mujoco.batch`` stepping of the same MJCF (what the simulator runs its members on), and
  ``mc_vs_raw_batch`` / ``mc_vehicle_vs_raw_batch`` the Monte Carlo against it;
- ``mc_hardware_traj_steps_per_s``: the helicopter's Monte Carlo in the ``hardware`` profile
  and ``mc_hardware_vs_paper`` its ratio to the ``paper`` profile's (interleaved);
- ``mc_vs_raw_1thread`` / ``mc_vehicle_vs_raw_1thread``: the same ratios with one physics
  thread for both (a quarter of the steps), which a busy second core does not distort: the
  testbed's own cost per step without the threading;
- ``mc_mshinf_traj_steps_per_s``: the helicopter with Basin et al.'s mean-square
  H-infinity filter and disturbance (``ms-hinf``, ``basin-helicopter``);
- ``mc_peak_rss_mb``: peak resident memory of a fresh process running a streaming
  ``monte_carlo`` of ``rss_runs`` helicopter trajectories (target <= 500 MB), and
  ``import_rss_mb`` of one that only imports it;
- ``scaling``: wall time per trajectory-step (set-up included) for each batch size and
  horizon (helicopter, Kalman filter).

The machine may be shared: raw and Monte-Carlo blocks are interleaved ``repeats`` times and
the best (least disturbed) throughput of each is used; ``*_pairs`` keep every pair's ratio.
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
from typing import Any

import mujoco
import mujoco.batch
import numpy as np
from mujoco import rollout
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from testbed.experiment.runner import monte_carlo  # noqa: E402
from testbed.experiment.scenario import Scenario  # noqa: E402
from testbed.rigs import resolve_rig  # noqa: E402
from testbed.sim.simulator import default_num_threads  # noqa: E402

#: Rig name -> (key prefix of its metrics, its Monte-Carlo scenario).
RIG_SCENARIOS: dict[str, tuple[str, Scenario]] = {
    "helicopter": ("", Scenario(rig="helicopter", estimator="kalman", seed=0)),
    "vehicle-roll": ("vehicle_", Scenario(rig="vehicle-roll", estimator="kalman", seed=0)),
}

# VmHWM (peak RSS of this process image), not ru_maxrss: Linux carries ru_maxrss over fork and
# exec, so a child would report at least its parent's size.
_RSS_SNIPPET = """
import resource, sys
from testbed.experiment.runner import monte_carlo
from testbed.experiment.scenario import Scenario
runs, steps = int(sys.argv[1]), int(sys.argv[2])
if runs:
    monte_carlo(Scenario(rig="helicopter", estimator="kalman", duration_s=steps * 0.01),
                runs, progress=False)
try:
    with open("/proc/self/status") as f:
        peak_kb = next(int(l.split()[1]) for l in f if l.startswith("VmHWM:"))
except (OSError, StopIteration):
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(peak_kb)
"""


def raw_rollout_traj_steps_per_s(rig_name: str, runs: int, steps: int, num_threads: int,
                                 frame_skip: int = 10, chunk: int = 100) -> float:
    """Trajectory control steps per second of a bare ``mujoco.rollout`` of a rig's MJCF.

    Parameters
    ----------
    rig_name : str
        Registered rig; its model with nominal parameters is stepped from the state 0 with
        the rig's operating input (``Rig.operating_input`` through ``Rig.actuation``: ctrl
        and/or ``xfrc_applied``) held.
    runs, steps : int
        Trajectories and control steps.
    num_threads : int
        Rollout threads (1: the calling thread).
    frame_skip : int
        Physics steps per control step.
    chunk : int
        Control steps per ``rollout`` call (its state output is ``chunk * frame_skip`` rows).

    Returns
    -------
    float
        ``runs * steps / wall time`` (warm-up call excluded).
    """
    rig = resolve_rig(rig_name)()
    model, data = rig.model, rig.data
    x0 = np.zeros(rig.n_states)
    rig.set_state(x0)
    inputs = rig.actuation(rig.operating_input(rig.params, x0[None]),
                           rig.member_constants(rig.params)[None])
    if "ctrl" in inputs:
        data.ctrl[:] = inputs["ctrl"][0]
    if "xfrc" in inputs:
        data.xfrc_applied[:] = inputs["xfrc"][0]
    user = int(mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED)
    control = np.zeros((1, 1, mujoco.mj_stateSize(model, user)))
    mujoco.mj_getState(model, data, control[0, 0], user)
    spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state0 = np.zeros((runs, mujoco.mj_stateSize(model, spec)))
    mujoco.mj_getState(model, data, state0[0], spec)
    state0[:] = state0[0]
    chunk = min(chunk, steps)
    out = np.empty((runs, chunk * frame_skip, state0.shape[1]))
    datas = [mujoco.MjData(model) for _ in range(num_threads)]
    with threadpool_limits(1), rollout.Rollout(nthread=num_threads if num_threads > 1 else 0
                                               ) as pool:
        pool.rollout(model, datas, state0, control, control_spec=user, nstep=frame_skip,
                     state=out[:, :frame_skip])
        start = time.perf_counter()
        for _ in range(steps // chunk):
            pool.rollout(model, datas, state0, control, control_spec=user, state=out)
            state0 = out[:, -1].copy()
        elapsed = time.perf_counter() - start
    return runs * (steps // chunk) * chunk / elapsed


def raw_batch_traj_steps_per_s(rig_name: str, runs: int, steps: int, num_threads: int,
                               frame_skip: int = 10, profile: str = "paper") -> float:
    """Trajectory control steps per second of bare ``mujoco.batch`` stepping of a rig's MJCF.

    ``Batch(model, runs, nthread).step(nstep=frame_skip)`` once per control step, from the
    state 0 with the rig's operating input held (as :func:`raw_rollout_traj_steps_per_s`):
    the physics the simulator runs, without anything else.
    """
    rig = resolve_rig(rig_name)(profile=profile)
    model = rig.model
    x0 = np.zeros(rig.n_states)
    inputs = rig.actuation(rig.operating_input(rig.params, x0[None]),
                           rig.member_constants(rig.params)[None])
    batch = mujoco.batch.Batch(model, runs, nthread=num_threads)
    batch.reset()
    if "ctrl" in inputs:
        batch.bind("ctrl")[:] = inputs["ctrl"][0]
    if "xfrc" in inputs:
        batch.bind("xfrc_applied")[:] = inputs["xfrc"][0]
    with threadpool_limits(1):
        batch.step(None, frame_skip)
        start = time.perf_counter()
        for _ in range(steps):
            batch.step(None, frame_skip)
        elapsed = time.perf_counter() - start
    return runs * steps / elapsed


def mc_traj_steps_per_s(scenario: Scenario, runs: int, steps: int, num_threads: int) -> float:
    """``traj_steps_per_s`` of ``monte_carlo(scenario, runs)`` over ``steps`` control steps
    (10 ms each; set-up included)."""
    result = monte_carlo(scenario.replace(duration_s=steps * 0.01), runs, progress=False,
                         num_threads=num_threads)
    return float(result["traj_steps_per_s"])


def peak_rss_mb(runs: int, steps: int) -> float:
    """Peak RSS (MB) of a fresh Python process running a helicopter ``monte_carlo``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
    out = subprocess.run([sys.executable, "-c", _RSS_SNIPPET, str(runs), str(steps)],
                         capture_output=True, text=True, check=True, env=env)
    return int(out.stdout.strip().splitlines()[-1]) / 1024.0


def bench_rig(rig_name: str, runs: int, steps: int, threads: int,
              repeats: int) -> dict[str, Any]:
    """Raw rollout and Monte Carlo of one rig, interleaved ``repeats`` times.

    Returns
    -------
    dict
        ``raw_rollout_<p>traj_steps_per_s``, ``mc_<p>traj_steps_per_s`` (best of the
        repeats), ``mc_<p>vs_raw`` (their ratio) and ``mc_<p>vs_raw_pairs`` (each pair's
        ratio), with ``<p>`` empty for the helicopter and ``vehicle_`` for the vehicle roll.
    """
    prefix, scenario = RIG_SCENARIOS[rig_name]
    raws, batches, mcs = [], [], []
    for _ in range(repeats):
        raws.append(raw_rollout_traj_steps_per_s(rig_name, runs, steps, threads))
        batches.append(raw_batch_traj_steps_per_s(rig_name, runs, steps, threads))
        mcs.append(mc_traj_steps_per_s(scenario, runs, steps, threads))
    return {
        f"raw_rollout_{prefix}traj_steps_per_s": max(raws),
        f"raw_batch_{prefix}traj_steps_per_s": max(batches),
        f"mc_{prefix}traj_steps_per_s": max(mcs),
        f"mc_{prefix}vs_raw": max(mcs) / max(raws),
        f"mc_{prefix}vs_raw_batch": max(mcs) / max(batches),
        f"mc_{prefix}vs_raw_pairs": [m / r for m, r in zip(mcs, raws, strict=True)],
    }


def bench_hardware(runs: int, steps: int, threads: int, repeats: int) -> dict[str, Any]:
    """The helicopter's Monte Carlo under the ``hardware`` profile (rotor lag, current limit
    every physics step, deadband, IMU) against the ``paper`` profile, interleaved."""
    scenario = RIG_SCENARIOS["helicopter"][1]
    papers, hardwares = [], []
    for _ in range(repeats):
        papers.append(mc_traj_steps_per_s(scenario, runs, steps, threads))
        hardwares.append(mc_traj_steps_per_s(scenario.replace(profile="hardware"), runs, steps,
                                             threads))
    return {"mc_hardware_traj_steps_per_s": max(hardwares),
            "mc_hardware_vs_paper": max(hardwares) / max(papers),
            "mc_hardware_vs_paper_pairs": [h / p for h, p in zip(hardwares, papers,
                                                                 strict=True)]}


def bench_monte_carlo(runs: int = 256, steps: int = 2000, rss_runs: int = 1000,
                      rss_steps: int = 2000, scaling_runs: Sequence[int] = (10, 100, 1000),
                      scaling_steps: Sequence[int] = (200, 2000), repeats: int = 2,
                      num_threads: int | None = None) -> dict[str, Any]:
    """Measure the batched Monte Carlo of both rigs against bare ``mujoco.rollout``.

    Parameters
    ----------
    runs, steps : int
        Trajectories and control steps of the speed comparisons (10 ms per step).
    rss_runs, rss_steps : int
        Size of the streaming run whose peak memory is measured (in a subprocess).
    scaling_runs, scaling_steps : sequence of int
        Batch sizes and horizons of the ``scaling`` table.
    repeats : int
        Interleaved raw / Monte-Carlo pairs per rig (best of each taken).
    num_threads : int, optional
        Physics threads for both (default: the CPUs available).

    Returns
    -------
    dict
        The keys of :func:`bench_rig` for both rigs, their ``mc_*vs_raw*`` keys with one
        thread (suffix ``_1thread``, when ``threads > 1``), ``mc_mshinf_traj_steps_per_s``,
        ``mc_vehicle_vs_raw_4xruns`` (4x the runs, 1/4 the steps), ``mc_peak_rss_mb``,
        ``import_rss_mb``, ``scaling`` (``"N=..,steps=.."`` ->
        ``{"us_per_traj_step", "traj_steps_per_s"}``), ``threads``, ``runs``, ``steps``.
    """
    threads = num_threads or default_num_threads()
    out: dict[str, Any] = {}
    for rig_name in RIG_SCENARIOS:
        out.update(bench_rig(rig_name, runs, steps, threads, repeats))
    out.update(bench_hardware(runs, steps, threads, repeats))
    # diagnostic: the vehicle with 4x the runs and 1/4 the steps (the same trajectory-steps,
    # 4x the members per lane: the per-step Python that does not grow with the members is
    # spread over more of them)
    big = bench_rig("vehicle-roll", 4 * runs, max(steps // 4, 1), threads, repeats)
    out["mc_vehicle_vs_raw_4xruns"] = big["mc_vehicle_vs_raw"]
    if threads > 1:  # diagnostic: the same without threads (insensitive to a busy core)
        for rig_name in RIG_SCENARIOS:
            single = bench_rig(rig_name, runs, max(steps // 4, 1), 1, repeats)
            out.update({f"{k}_1thread": v for k, v in single.items()
                        if k.startswith("mc_") and k.endswith(("vs_raw", "vs_raw_batch"))})
    mshinf = Scenario(rig="helicopter", estimator="ms-hinf", disturbance="basin-helicopter")
    out["mc_mshinf_traj_steps_per_s"] = mc_traj_steps_per_s(mshinf, runs, steps, threads)
    scenario = RIG_SCENARIOS["helicopter"][1]
    scaling: dict[str, dict[str, float]] = {}
    for n in scaling_runs:
        for horizon in scaling_steps:
            start = time.perf_counter()
            monte_carlo(scenario.replace(duration_s=horizon * 0.01), n, progress=False,
                        num_threads=threads)
            wall = time.perf_counter() - start
            scaling[f"N={n},steps={horizon}"] = {"us_per_traj_step": wall / (n * horizon) * 1e6,
                                                 "traj_steps_per_s": n * horizon / wall}
    out.update({
        "mc_peak_rss_mb": peak_rss_mb(rss_runs, rss_steps),
        "import_rss_mb": peak_rss_mb(0, 0),
        "scaling": scaling,
        "threads": threads,
        "runs": runs,
        "steps": steps,
    })
    return out


#: Keyword arguments of :func:`bench_monte_carlo` for ``--quick`` (small sizes).
QUICK = {"runs": 32, "steps": 200, "rss_runs": 100, "rss_steps": 200, "scaling_runs": (10, 100),
         "scaling_steps": (50, 200), "repeats": 1}
#: Keyword arguments for a smoke test (seconds; the numbers mean nothing).
SMOKE = {"runs": 4, "steps": 20, "rss_runs": 4, "rss_steps": 20, "scaling_runs": (2,),
         "scaling_steps": (10,), "repeats": 1}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the results here (atomically)")
    parser.add_argument("--runs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    args = parser.parse_args(argv)
    kwargs: dict[str, Any] = {"runs": args.runs, "steps": args.steps, "repeats": args.repeats}
    if args.quick:
        kwargs.update(QUICK)
    results = bench_monte_carlo(**kwargs)
    print(json.dumps(results, indent=2))
    if args.json:
        from testbed.io import write_json

        write_json(args.json, results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
