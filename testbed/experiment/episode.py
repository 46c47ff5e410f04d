"""One closed-loop episode of a scenario (:func:`run`), with its trajectory kept for plots,
the 3D view and a live viewer (long runs decimated, :data:`RECORD_MAX_ROWS`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from tqdm import tqdm

from testbed.experiment.build import Experiment, build
from testbed.experiment.scenario import Scenario
from testbed.experiment.trajectory import Trajectory

#: Most rows :func:`run` records; longer runs keep every k-th step (and the last one), so
#: the memory of ``--plot``/``--rrd`` does not grow with the duration (20,000 rows of the
#: helicopter with body poses: about 10 MB).
RECORD_MAX_ROWS = 20_000


class _DecimatedRows:
    """A recording array ``(N, T, ...)`` for :meth:`ClosedLoop.run` keeping only some rows.

    Keeps rows ``0, every, 2 every, ...`` and the last row written; the loop writes row ``k``
    with ``rows[:, k] = value`` (or into ``rows[:, k]``) and truncates with ``rows[:, :T]``.
    """

    def __init__(self, shape: tuple[int, ...], every: int):
        self.shape, self.every = shape, every
        kept = (shape[1] - 1) // every + 1
        self.data = np.zeros((shape[0], kept + 1, *shape[2:]))  # + the last row written
        self.last = -1

    def _slot(self, key: Any) -> int:
        rows, k = key
        if rows != slice(None) or not isinstance(k, int | np.integer):
            raise IndexError(f"decimated recording supports [:, k] only, got {key!r}")
        self.last = int(k)
        return int(k) // self.every if k % self.every == 0 else -1

    def __setitem__(self, key: Any, value: Any) -> None:
        slot = self._slot(key)
        self.data[:, slot] = value
        if slot != -1:
            self.data[:, -1] = value

    def __getitem__(self, key: Any) -> Any:
        if isinstance(key, tuple) and isinstance(key[1], slice):
            return self  # truncation at an early end: rows are kept by index
        return self.data[:, self._slot(key)]

    def rows(self) -> np.ndarray:
        """Step indices of :meth:`values`, shape (R,)."""
        kept = np.arange(0, self.last + 1, self.every)
        return kept if kept[-1] == self.last else np.append(kept, self.last)

    def values(self) -> np.ndarray:
        """The kept rows, shape (N, R, ...)."""
        n = self.last // self.every + 1
        if self.last % self.every == 0:
            return self.data[:, :n]
        return np.concatenate([self.data[:, :n], self.data[:, -1:]], axis=1)


def run(scenario: Scenario, *, record: bool = True, progress: bool | None = False,
        observe: Callable[[Experiment], Callable[[int, dict[str, Any]], None]] | None = None,
        every_step: bool = False) -> tuple[Trajectory | None, dict[str, Any]]:
    """One closed-loop episode of ``scenario`` (seed ``scenario.seed``).

    Parameters
    ----------
    scenario : Scenario
    record : bool
        Keep the trajectory (with body poses, for the 3D view).
    progress : bool or None
        Progress bar on stderr: False (default) none, True always, None only when the run
        takes more than two seconds (the CLI's choice on a terminal).
    observe : callable, optional
        Called once with the built :class:`Experiment` before the episode starts; returns
        the per-step observer ``on_step(k, row)`` of :meth:`ClosedLoop.run` (e.g.
        :meth:`testbed.outputs.live.LiveView.attach`, logging to a live viewer). Body poses are
        recorded
        for it. The run is the same with or without it.

    every_step : bool
        Keep every step however long the run (``testbed run --save-log``: a recording has
        every sample), instead of at most :data:`RECORD_MAX_ROWS` rows.

    Returns
    -------
    trajectory : Trajectory or None
        With ``record`` (body poses included, for the 3D view). At most
        :data:`RECORD_MAX_ROWS` rows: a longer run keeps every k-th step and the last one
        (``t_s`` gives the time of each row). Without ``record`` nothing per step is kept,
        so memory does not grow with the duration.
    summary : dict
        ``steps``, ``rmse``, ``measurement_rmse``, ``nees_mean``, ``T_final``,
        ``clipped_fraction``, ``units``, ``meta`` (metrics over every step).
    """
    experiment = build(scenario, 1, num_threads=1)
    loop = experiment.loop
    n_steps = int(round(scenario.duration_s / loop.sim.dt_s))
    every = 1 if every_step else -(-(n_steps + 1) // RECORD_MAX_ROWS)  # ceil
    recorder: Any = record
    if record and every > 1:
        shapes = loop.trajectory_shapes(n_steps, poses=True)
        recorder = {k: _DecimatedRows(shape, every) for k, shape in shapes.items()}
    bar = tqdm(total=n_steps, desc=experiment.meta["rig"], unit="step",
               disable=progress is False, delay=0 if progress else 2.0, leave=False)
    try:
        on_step = observe(experiment) if observe is not None else None
        with bar:
            result = loop.run(np.array([scenario.seed]), scenario.duration_s, record=recorder,
                              poses=record or on_step is not None, bar=bar, on_step=on_step)
    finally:
        experiment.close()
    summary = result.summary(0)
    summary["units"] = experiment.meta["units"]
    summary["meta"] = experiment.meta
    traj = None
    if record:
        rec = result.trajectory
        if isinstance(recorder, dict):
            rows = recorder["state"].rows()
            rec = {k: v.values() for k, v in recorder.items()}
            rec["t_s"] = rows * result.dt_s
        sim = loop.sim
        traj = Trajectory(
            t_s=rec["t_s"], state=rec["state"][0], state_names=list(sim.rig.state_names),
            measurement=rec["measurement"][0], measurement_names=list(sim.sensors.names),
            measured_state_index=list(sim.sensors.measured_state),
            action=rec["action"][0],
            action_names=[f"{n} [{u}]" for n, u in zip(sim.rig.action_names,
                                                        sim.rig.action_units, strict=True)],
            estimate=rec["estimate"][0],
            covariance=rec["covariance"][0] if "covariance" in rec else None,
            setpoint=rec["setpoint"][0], body_pos=rec["body_pos"][0],
            body_quat_wxyz=rec["body_quat_wxyz"][0],
            meta=dict(experiment.meta, seed=scenario.seed, duration_s=result.steps * result.dt_s,
                      setpoint_names=list(sim.rig.tracked_states), recorded_every_steps=every),
            rig=sim.rig)
    return traj, summary
