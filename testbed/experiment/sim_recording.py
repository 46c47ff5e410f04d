"""Recordings of simulated runs: what ``testbed run --save-log`` and the Gymnasium wrapper
:class:`~testbed.envs.recording.RecordLog` write, in the convention a rig's log has
(:data:`INPUT_CONVENTION`), without truth.

Row ``k`` has the time ``t_k``, the channels sampled at ``t_k`` and the input **held over**
``[t_k, t_k+1)`` (the command the controller sent at ``t_k``); :func:`testbed.experiment.
replay.replay` of such a recording gives the run's estimates bitwise.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from testbed.design import channel_effects
from testbed.experiment.loop import LoopResult, Tape
from testbed.experiment.trajectory import Trajectory
from testbed.io.recording import Recording
from testbed.sensors import Sensor

if TYPE_CHECKING:
    from testbed.rigs.base import Rig

#: How the rows of a recording pair inputs and channels (in the recording's ``meta``).
INPUT_CONVENTION = "inputs[k] held over [t_k, t_k+1); channels[k] sampled at t_k"
#: Scenario fields a simulated recording's ``meta`` keeps (never the simulated unit's
#: parameters or its states).
_SCENARIO_META = ("rig", "profile", "sensors", "sensor_options", "physics_dt_s", "frame_skip",
                  "duration_s", "seed", "controller", "estimator", "estimator_options",
                  "design_profile", "design_options", "disturbance", "process_noise",
                  "ambient_noise", "manoeuvre")


def recording_from_result(result: Any, *, experiment: Any = None, member: int = 0,
                          source: str = "<simulation>") -> Recording:
    """A :class:`Recording` (no truth) of a simulated run, at the control period.

    Parameters
    ----------
    result : Trajectory, (Trajectory, summary), LoopResult or Tape
        What :func:`testbed.experiment.runner.run` returns (``record=True``; every row
        kept: a run longer than :data:`~testbed.experiment.runner.RECORD_MAX_ROWS` rows keeps
        every k-th one and is refused here), or :meth:`ClosedLoop.run`'s
        :class:`~testbed.experiment.loop.LoopResult` (``record=True``) or its
        :class:`~testbed.experiment.loop.Tape` (``tape=True``).
    experiment : testbed.experiment.runner.Experiment, optional
        The built scenario of a ``LoopResult`` or a ``Tape`` (names, period and meta);
        a trajectory carries its own.
    member : int
        The batch member of a ``LoopResult`` or a ``Tape``.
    source : str
        The recording's ``source``.

    Returns
    -------
    Recording
        ``time_s`` (T+1,) = ``k dt``; ``inputs`` by the rig's action names: the applied
        (clipped) input held over ``[t_k, t_k+1)`` (:data:`INPUT_CONVENTION`; the last row
        repeats the one before: no step follows it); ``channels`` by the sensor suite's
        names: what the estimator stage received at ``t_k`` (a held multi-rate channel
        holds its value); ``meta``: rig, profile, options, seed, sensors, periods, the
        scenario's settings (not its parameters) and the design's facts, never a state.

    Raises
    ------
    ValueError
        An unknown result type, a decimated trajectory, a missing ``experiment`` or a bad
        ``member`` (one line).
    """
    if isinstance(result, tuple) and len(result) == 2 and isinstance(result[0], Trajectory):
        result = result[0]
    if isinstance(result, Trajectory):
        return _from_trajectory(result, source)
    if not isinstance(result, LoopResult | Tape):
        raise ValueError(f"result must be a Trajectory, (Trajectory, summary), LoopResult or "
                         f"Tape, got {type(result).__name__}")
    if experiment is None:
        raise ValueError(f"a {type(result).__name__} needs experiment= (the built scenario: "
                         "names, period and meta)")
    if isinstance(result, LoopResult):
        if result.tape is not None:
            result = result.tape
        elif result.trajectory is None:
            raise ValueError("the LoopResult has neither a trajectory nor a tape: run with "
                             "record=True or tape=True")
    if isinstance(result, Tape):
        n = result.measurement.shape[1]
        y, a = result.measurement, result.action
        pick = (slice(None), member)
    else:
        n = result.trajectory["measurement"].shape[0]
        y, a = result.trajectory["measurement"], result.trajectory["action"]
        pick = (member, slice(None))
    if isinstance(member, bool) or not isinstance(member, int | np.integer) \
            or not 0 <= member < n:
        raise ValueError(f"member must be an integer in [0, {n}), got {member!r}")
    sim = experiment.loop.sim
    seed = int(np.asarray(result.seeds)[member])
    return _recording(np.asarray(y[pick], float), np.asarray(a[pick], float),
                      result.dt_s, tuple(sim.rig.action_names), tuple(sim.sensors.names),
                      _meta(experiment.meta, sim.rig, sim.sensors, seed), source)


def simulate_recording(scenario: Any, *, source: str = "<simulation>") -> Recording:
    """One simulated episode of ``scenario`` (seed ``scenario.seed``) as a :class:`Recording`,
    every step kept whatever the duration (through the loop's tape, without body poses).

    The same episode as :func:`testbed.experiment.runner.run` of the scenario (the same
    samples, bitwise): for runs longer than its
    :data:`~testbed.experiment.runner.RECORD_MAX_ROWS` recorded rows.

    Parameters
    ----------
    scenario : Scenario
    source : str

    Returns
    -------
    Recording
    """
    from testbed.experiment import runner

    experiment = runner.build(scenario, 1, num_threads=1)
    try:
        result = experiment.loop.run(np.array([scenario.seed]), scenario.duration_s, tape=True)
    finally:
        experiment.close()
    return recording_from_result(result, experiment=experiment, source=source)


def _from_trajectory(traj: Trajectory, source: str) -> Recording:
    every = int(traj.meta.get("recorded_every_steps", 1) or 1)
    if every != 1:
        raise ValueError(f"the trajectory keeps every {every}th step only (a run of more than "
                         "RECORD_MAX_ROWS rows): a recording needs every step; use "
                         "simulate_recording(scenario) or pass ClosedLoop.run's LoopResult")
    rig = traj.rig
    if rig is None:
        raise ValueError("the trajectory has no rig (Trajectory.rig): its action names are "
                         "unknown")
    t = np.asarray(traj.t_s, float)
    dt_s = float(traj.meta.get("control_dt_s") or (t[1] - t[0] if len(t) > 1 else 0.0))
    if not dt_s > 0:
        raise ValueError("the trajectory's control period (meta['control_dt_s']) is unknown")
    seed = traj.meta.get("seed")
    sensors = dict(traj.meta)
    return _recording(np.asarray(traj.measurement, float), np.asarray(traj.action, float),
                      dt_s, tuple(rig.action_names), tuple(traj.measurement_names),
                      _meta(sensors, rig, None, seed), source)


def _recording(y: np.ndarray, applied: np.ndarray, dt_s: float, action_names: tuple[str, ...],
               channel_names: tuple[str, ...], meta: dict[str, Any], source: str) -> Recording:
    """The arrays in the loop's convention (``applied[k + 1]`` over step ``k``) as a
    recording (:func:`episode_recording`)."""
    if len(y) < 2:
        raise ValueError(f"a recording needs at least 2 samples, the run has {len(y)}")
    return episode_recording(y, applied[1:], dt_s, action_names=action_names,
                             channel_names=channel_names, meta=meta, source=source)


def episode_recording(measurement: np.ndarray, applied: np.ndarray, dt_s: float, *,
                      action_names: Sequence[str], channel_names: Sequence[str],
                      meta: dict[str, Any] | None = None,
                      source: str = "<simulation>") -> Recording:
    """What a recording of a simulated episode holds: the one definition, used by
    :func:`recording_from_result` (``testbed run --save-log``) and by the Gymnasium wrapper
    :class:`~testbed.envs.recording.RecordLog`.

    An episode of ``T`` steps gives ``T + 1`` samples: row ``k`` has the time ``k dt_s``, the
    measurement after the reset (``k = 0``) or after step ``k``, and the input applied over
    step ``k + 1`` (:data:`INPUT_CONVENTION`); the last row's input repeats the one before
    it (no step follows it; :func:`testbed.experiment.replay.replay` and ``identify`` never
    use it).

    Parameters
    ----------
    measurement : ndarray, shape (T+1, m)
        What the sensors gave after the reset and after each step.
    applied : ndarray, shape (T, nu)
        The input applied over each step (after clipping).
    dt_s : float
        The control period, s.
    action_names, channel_names : sequence of str
        The rig's inputs and the sensors' channels (the columns).
    meta : dict, optional
        The recording's ``meta`` (``control_dt_s`` and ``input_convention`` are set).
    source : str

    Returns
    -------
    Recording

    Raises
    ------
    ValueError
        Shapes that do not match (``T >= 1`` steps, ``T + 1`` measurements, the names'
        lengths) or a period that is not positive (one line).
    """
    y = np.asarray(measurement, float)
    u = np.asarray(applied, float)
    if y.ndim != 2 or y.shape[1] != len(channel_names) or len(y) < 2:
        raise ValueError(f"measurement must have shape (T+1, {len(channel_names)}) with T >= 1,"
                         f" got {y.shape}")
    if u.shape != (len(y) - 1, len(action_names)):
        raise ValueError(f"applied must have shape ({len(y) - 1}, {len(action_names)}) (one "
                         f"row per step), got {u.shape}")
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be a positive period in s, got {dt_s!r}")
    held = np.concatenate([u, u[-1:]], axis=0)  # row k: over [t_k, t_k+1)
    time_s = np.arange(len(y)) * float(dt_s)
    return Recording(time_s=time_s,
                     inputs={n: held[:, i].copy() for i, n in enumerate(action_names)},
                     channels={n: y[:, j].copy() for j, n in enumerate(channel_names)},
                     source=source, sha256="",
                     meta=dict(meta or {}, control_dt_s=float(dt_s),
                               input_convention=INPUT_CONVENTION))


def _meta(run_meta: dict[str, Any], rig: Rig | None, sensors: Sensor | None,
          seed: Any) -> dict[str, Any]:
    """A recording's ``meta`` from a run's: settings, no truth (the rig's name, profile and
    options when there is a rig)."""
    scenario = {k: v for k, v in (run_meta.get("scenario") or {}).items()
                if k in _SCENARIO_META}
    meta: dict[str, Any] = {
        "rig": run_meta.get("rig", None if rig is None else rig.name),
        "profile": scenario.get("profile", "paper") if rig is None else rig.profile,
        "options": {} if rig is None else dict(rig.options),
        "seed": None if seed is None else int(seed),
        "sensors": scenario.get("sensors"),
        "sensors_description": run_meta.get("sensors"),
        "physics_dt_s": float(rig.model.opt.timestep) if rig is not None else None,
        "scenario": scenario,
        "simulated": True,
        "input_convention": INPUT_CONVENTION,
        "units": {k: v for k, v in (run_meta.get("units") or {}).items()},
    }
    if sensors is not None:
        meta["hold_samples"] = {n: e.hold for n, e in zip(sensors.names,
                                                          channel_effects(sensors), strict=True)
                                if e.hold > 1}
    for key in ("design", "design_profile", "design_states"):
        if key in run_meta:
            meta[key] = run_meta[key]
    return meta

