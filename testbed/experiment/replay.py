"""Estimators over a recording: the estimator stage of the closed loop with a recording in
place of the simulator (``testbed replay``).

A :class:`~testbed.io.recording.Recording` holds time, the rig's inputs and its sensor
channels, no truth. :func:`replay` builds the estimator exactly as a run does
(:func:`testbed.experiment.runner.build`: the designer's rig with nominal parameters, or
the given ones of a twin, the sensor preset, the design model, :func:`testbed.estimators.build`,
:class:`~testbed.experiment.loop.EstimatorStage`) and feeds the stage the recording's
samples instead of the simulator's. The designer never sees the recording: the design comes
from the rig, its profile, the preset and the parameters given here.

Sample convention (what a rig's log holds, and what :func:`recording_from_result` writes):
row ``k`` has the time ``t_k``, the channels sampled at ``t_k`` and the input **held over**
``[t_k, t_k+1)`` (the command the controller sent at ``t_k``). The estimator stage's step
``j`` (``j = 1..K``) gets the channels of sample ``j`` and the input of sample ``j - 1`` (the
input applied over the interval that ended at sample ``j``); the stage is reset (and primed)
on sample 0. The input of the last row is never used.

Another period: ``period_s = k * dt`` (a whole multiple of the recording's period) uses
every ``k``-th sample (rows ``0, k, 2k, ...``; the rows between are dropped, not averaged)
and holds the input of each used row over its ``k`` recording periods (a zero-order hold of
the sub-sampled command: exact where the command itself was held that long). The sensors
and the design are built at ``period_s``.

Multi-rate channels: a channel without a new sample at a row (a 100 Hz IMU in a 1 kHz log)
holds its last value, as :class:`~testbed.sensors.SampleAndHold` gives it to the estimator
in a run; a recording has a value in every row of every channel (no NaN).

With no truth, consistency comes from the innovations (the estimator's ``innovation`` and
``innovation_cov`` after each step): the normalized innovation squared ``NIS_k = nu_k^T
S_k^-1 nu_k`` with ``m`` degrees of freedom. A consistent linear-Gaussian filter's
innovations are white (Bar-Shalom, Li & Kirubarajan 2001, ch. 5.4), so the time average of
one run's ``K`` values (ANIS) times ``K`` is ``chi2(K m)``: its two-sided band is
:func:`testbed.score.stats.chi2_bounds` ``(K, m)``, and ANIS above it says
``overconfident`` (``S`` too small), below it ``underconfident``. The per-step band fraction
is the fraction of steps whose NIS lies outside the ``chi2(m)`` band (expected ``1 - level``;
Clopper-Pearson interval), and the whiteness test is ``testbed score``'s
(:func:`testbed.score.consistency.whiteness_test` on the whitened innovations of the one
run).

``reference=CHANNEL`` holds a channel out of the estimator (the design and the estimator see
a suite whose linear model leaves it out) and reports the RMSE of its prediction from the
estimate, ``C_j x_hat + D_j u`` (the channel's linear model; for an encoder ``pitch`` the
pitch estimate itself), against the recorded channel.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from filters import KalmanFilter
from testbed import estimators
from testbed.design import DesignModel, channel_effects
from testbed.experiment.loop import EstimatorStage, LoopResult, Tape, check_estimate, sensor_taps
from testbed.experiment.trajectory import Trajectory
from testbed.io.recording import Recording
from testbed.rigs import resolve_rig
from testbed.rigs.base import build_rig
from testbed.sensors import Sensor, SensorModel, Suite
from testbed.stats import (
    CONSISTENT,
    LEVEL,
    OVERCONFIDENT,
    UNDERCONFIDENT,
    chi2_bounds,
    clopper_pearson,
    whiten,
    whiteness_test,
)

#: How the rows of a recording pair inputs and channels (in the recording's ``meta``).
INPUT_CONVENTION = "inputs[k] held over [t_k, t_k+1); channels[k] sampled at t_k"
#: Scenario fields a simulated recording's ``meta`` keeps (never the simulated unit's
#: parameters or its states).
_SCENARIO_META = ("rig", "profile", "sensors", "sensor_options", "physics_dt_s", "frame_skip",
                  "duration_s", "seed", "controller", "estimator", "estimator_options",
                  "design_profile", "design_options", "disturbance", "process_noise",
                  "ambient_noise", "manoeuvre")
#: Relative tolerance of a uniform sample period and of ``period_s`` as a whole multiple.
_PERIOD_TOLERANCE = 1e-6


# ---------------------------------------------------------------------- from a simulation
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
    it (no step follows it; :func:`replay` and ``identify`` never use it).

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


def _meta(run_meta: dict[str, Any], rig: Any, sensors: Sensor | None,
          seed: Any) -> dict[str, Any]:
    """A recording's ``meta`` from a run's: settings, no truth."""
    scenario = {k: v for k, v in (run_meta.get("scenario") or {}).items()
                if k in _SCENARIO_META}
    meta: dict[str, Any] = {
        "rig": run_meta.get("rig", getattr(rig, "name", None)),
        "profile": getattr(rig, "profile", scenario.get("profile", "paper")),
        "options": dict(getattr(rig, "options", {}) or {}),
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


# ---------------------------------------------------------------------- the replay
class _HeldOut(Suite):
    """A suite whose linear model leaves some channels out of every design (they are marked
    as channels an input is computed from, not measurements: ``SensorModel.inputs``), so
    the design and the estimator do not use them; the channels stay in ``y``."""

    def __init__(self, sensors: Sensor, held: Sequence[int]):
        super().__init__(*(sensors.sensors if isinstance(sensors, Suite) else (sensors,)))
        self.held = np.asarray(sorted(set(int(i) for i in held)), dtype=int)

    def linear_model(self) -> SensorModel:
        """The suite's model with the held-out channels neither stochastic nor deterministic
        measurements."""
        model = super().linear_model()
        stochastic, inputs = model.stochastic.copy(), model.inputs.copy()
        stochastic[self.held], inputs[self.held] = False, True
        return dataclasses.replace(model, stochastic=stochastic, inputs=inputs)

    def describe(self) -> str:
        """The suite's description and the held-out channels."""
        held = ", ".join(self.names[i] for i in self.held)
        return f"{super().describe()} (held out: {held})"


class _NoTruth:
    """The stage's metrics without a truth: counts the steps (the time in error messages)."""

    def __init__(self, dt_s: float):
        self.dt_s, self.count = float(dt_s), 0

    def reset(self, x_true: Any) -> None:
        """A new episode."""
        self.count = 0

    def update(self, x_true: Any, x_hat: Any, P: Any, y: Any, w: Any) -> None:
        """One step."""
        self.count += 1


def _innermost(est: Any) -> Any:
    """The :class:`filters.KalmanFilter` inside wrappers that change none of ``x``, ``P`` and
    the innovations (:class:`~testbed.estimators.ChannelSelect` and the plain
    :class:`~testbed.estimators.EstimatorWrapper`), else ``est`` itself."""
    inner = est
    while type(inner) in (estimators.EstimatorWrapper, estimators.ChannelSelect):
        inner = inner.inner
    return inner if isinstance(inner, KalmanFilter) else est


class _Collect:
    """The replay's steps and their record: the physical estimate, its variances and the
    innovations, into arrays allocated once, a block of steps at a time.

    A :class:`filters.KalmanFilter` (possibly behind a channel selection) is read through
    its batch of one's shared members (``shared_P``, ``shared_innovation_cov``): each step's
    arrays are kept by reference (the filter replaces them, never writes them) and copied
    into the record once per block; any other estimator is read after each step through
    ``P``, ``innovation`` and ``innovation_cov``.

    Parameters
    ----------
    stage : EstimatorStage
    inner : estimator
        What the innovations are read from (:func:`_innermost`, or a per-member
        estimator's one instance).
    has_P : bool
        Whether the estimator reports a covariance.
    Y, U : ndarray, shape (K+1, 1, m) and (K+1, 1, nu)
        The channels and inputs of the samples used, as the stage takes them.
    taps : list of (Tap, list of int)
        The sensors' taps and the channels they hold.
    """

    #: Steps per block.
    BLOCK = 1024

    def __init__(self, stage: EstimatorStage, inner: Any, has_P: bool, Y: np.ndarray,
                 U: np.ndarray, taps: Sequence[tuple[Any, Sequence[int]]]):
        self.stage, self.inner, self.Y, self.U, self.taps = stage, inner, Y, U, taps
        self.K = K = len(Y) - 1
        n = len(stage.prior[0]) if stage.physical_index is None else len(stage.physical_index)
        self.x_hat = np.empty((K + 1, n))
        self.P_diag = np.empty((K + 1, n)) if has_P else None
        self.nu: np.ndarray | None = None
        self.S: np.ndarray | None = None
        self.has_innovation = True
        self._kalman_filter = isinstance(inner, KalmanFilter) and has_P

    def block(self, j0: int, j1: int) -> None:
        """Steps ``j0..j1-1`` (rows ``j0..j1-1`` of the record)."""
        if self._kalman_filter and self.inner.shared_P is not None:  # a batch of one
            self._kalman(j0, j1)
        else:
            self._generic(j0, j1)

    def restore_taps(self, j: int) -> None:
        """Set each tap's latest values to the recorded channels of row ``j``."""
        for tap, cols in self.taps:
            tap.last[:] = self.Y[j][:, cols]

    def first(self) -> None:
        """Row 0: the estimate after the stage's reset."""
        self.x_hat[0] = self.stage.x[0]
        if self.P_diag is not None:
            self.P_diag[0] = self.stage.P[0].diagonal()

    def _allocate(self, nu: Any) -> None:
        p = np.shape(nu)[-1]
        self.nu, self.S = np.empty((self.K, p)), np.empty((self.K, p, p))

    def _kalman(self, j0: int, j1: int) -> None:
        """Steps ``j0..j1-1`` of a Kalman filter's batch of one."""
        step, inner, Y, U, taps = self.stage.step, self.inner, self.Y, self.U, self.taps
        xs, nus, Ss, Ps = [], [], [], []
        for j in range(j0, j1):
            if taps:
                self.restore_taps(j)
            xs.append(step(Y[j], U[j - 1], None, None))
            nus.append(inner.innovation)
            Ss.append(inner.shared_innovation_cov)
            Ps.append(inner.shared_P)
        self.x_hat[j0:j1] = np.concatenate(xs)
        if self.nu is None:
            self._allocate(nus[0])
        self.nu[j0 - 1:j1 - 1] = np.concatenate(nus)  # type: ignore[index]
        self.S[j0 - 1:j1 - 1] = Ss  # type: ignore[index]
        self.P_diag[j0:j1] = np.diagonal(  # type: ignore[index]
            self.stage._physical_block(np.stack(Ps)), axis1=-2, axis2=-1)

    def _generic(self, j0: int, j1: int) -> None:
        """Steps ``j0..j1-1`` of any estimator."""
        step, stage, inner, Y, U = self.stage.step, self.stage, self.inner, self.Y, self.U
        for j in range(j0, j1):
            if self.taps:
                self.restore_taps(j)
            self.x_hat[j] = step(Y[j], U[j - 1], None, None)[0]
            if self.P_diag is not None:
                self.P_diag[j] = stage.P[0].diagonal()
            if not self.has_innovation:
                continue
            nu = getattr(inner, "innovation", None)
            S = getattr(inner, "innovation_cov", None)
            if self.nu is None and nu is not None and S is not None:
                self._allocate(nu)
            try:
                # (N, p) and (N, p, p), or one member's (p,) and (p, p)
                self.nu[j - 1] = nu[0 if np.ndim(nu) == 2 else ()]  # type: ignore[index]
                self.S[j - 1] = S[0 if np.ndim(S) == 3 else ()]  # type: ignore[index]
            except (TypeError, ValueError, IndexError):  # none, or not (N, p) and (N, p, p)
                self.has_innovation = False

    def arrays(self) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None,
                              np.ndarray | None, bool]:
        """``x_hat`` (K+1, n), ``P_diag`` (K+1, n) or None, the innovations (K, p) and
        their covariances (K, p, p) (None: none exposed), and whether there were any."""
        return (self.x_hat, self.P_diag, self.nu, self.S,
                self.has_innovation and self.nu is not None)


@dataclass
class ReplayResult:
    """An estimator run over a recording.

    Attributes
    ----------
    source, sha256 : str
        The recording's.
    rig, profile, estimator, sensors : str
        What was replayed (``sensors``: the suite's description).
    period_s : float
        The estimator's period (a whole multiple ``every`` of the recording's).
    every : int
    time_s : ndarray, shape (K+1,)
        Times of the samples used (row 0: the reset).
    state_names, state_units : list of str
        The rig's physical states.
    x_hat : ndarray, shape (K+1, n)
        The estimate of the physical states after the reset and after each step.
    P_diag : ndarray, shape (K+1, n) or None
        Its variances (None: the estimator reports no covariance).
    measurement_names, measurement_units : list of str
        The channels of the estimator's sensor suite.
    measurement : ndarray, shape (K+1, m)
        The channels at the samples used (held-out ones included; a channel the estimator
        does not use and the recording lacks is NaN).
    innovation_names : list of str
        The channels of the innovation.
    innovations, innovation_var : ndarray, shape (K, p) or None
        The innovation ``nu_k`` and the diagonal of ``S_k`` after each step (None: the
        estimator exposes none).
    innovation_cov : ndarray, shape (K, p, p) or None
        ``S_k``.
    nis : ndarray, shape (K,) or None
    consistency : dict or None
        ANIS and its band and verdict, the per-step band fraction, the whiteness test
        (see the module docstring); None without innovations.
    reference : dict or None
        ``channel``, ``state`` (the state it measures, or None), ``unit``, ``rmse`` (SI),
        ``samples``; and the arrays ``reference_measured`` / ``reference_predicted`` (K+1,).
    measured_state : list of int or None
        The state each channel measures directly (the sensors' ``measured_state``).
    notes : list of str
    wall_s : float
        Seconds of the estimator loop.
    design_meta : dict
    """

    source: str
    sha256: str
    rig: str
    profile: str
    estimator: str
    sensors: str
    period_s: float
    every: int
    time_s: np.ndarray
    state_names: list[str]
    state_units: list[str]
    x_hat: np.ndarray
    P_diag: np.ndarray | None
    measurement_names: list[str]
    measurement_units: list[str]
    measurement: np.ndarray
    innovation_names: list[str]
    innovations: np.ndarray | None
    innovation_var: np.ndarray | None
    innovation_cov: np.ndarray | None
    nis: np.ndarray | None
    consistency: dict[str, Any] | None
    reference: dict[str, Any] | None
    reference_measured: np.ndarray | None = None
    reference_predicted: np.ndarray | None = None
    measured_state: list[int | None] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    design_meta: dict[str, Any] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        """Estimator steps ``K``."""
        return len(self.time_s) - 1

    @property
    def real_time_factor(self) -> float:
        """Recorded seconds replayed per wall-clock second."""
        span = float(self.time_s[-1] - self.time_s[0])
        return span / self.wall_s if self.wall_s > 0 else math.inf

    def estimates_summary(self) -> dict[str, Any]:
        """Per state: the final estimate, its final standard deviation and the mean one."""
        out: dict[str, Any] = {}
        for i, name in enumerate(self.state_names):
            row: dict[str, Any] = {"final": float(self.x_hat[-1, i]),
                                   "min": float(np.min(self.x_hat[:, i])),
                                   "max": float(np.max(self.x_hat[:, i]))}
            if self.P_diag is not None:
                std = np.sqrt(np.maximum(self.P_diag[:, i], 0.0))
                row["std_final"], row["std_mean"] = float(std[-1]), float(np.mean(std[1:]))
            out[name] = row
        return out

    def to_json(self) -> dict[str, Any]:
        """The JSON-ready summary (no per-step arrays)."""
        units = dict(zip(self.state_names, self.state_units, strict=True))
        units.update({f"measurement:{n}": u for n, u in
                      zip(self.measurement_names, self.measurement_units, strict=True)})
        return {
            "recording": {"source": self.source, "sha256": self.sha256},
            "rig": self.rig, "profile": self.profile, "estimator": self.estimator,
            "sensors": self.sensors, "n_samples": self.steps + 1, "steps": self.steps,
            "period_s": self.period_s, "every": self.every,
            "duration_s": float(self.time_s[-1] - self.time_s[0]),
            "innovation_channels": list(self.innovation_names),
            "consistency": self.consistency, "reference": self.reference,
            "estimates": self.estimates_summary(), "design": self.design_meta,
            "notes": list(self.notes), "units": units,
            "wall_s": self.wall_s, "real_time_factor": self.real_time_factor,
        }


def _check_recording(recording: Any) -> float:
    """The recording's period; ``ValueError`` (one line) for what cannot be replayed."""
    if not isinstance(recording, Recording):
        raise ValueError(f"recording must be a testbed.io.Recording, got "
                         f"{type(recording).__name__}")
    t = np.asarray(recording.time_s, float)
    n = recording.n_samples
    if t.ndim != 1 or n < 2 or not np.all(np.isfinite(t)):
        raise ValueError(f"{recording.source}: time_s must be finite with shape (N,), N >= 2, "
                         f"got shape {t.shape}")
    dt = np.diff(t)
    # the period to 12 significant digits: time stamps k dt carry rounding (a diff of
    # 0.010000000000000009 s for 0.01 s), which the design's discretization would see
    dt_s = float(f"{float(np.median(dt)):.12g}")
    bad = np.flatnonzero(~(np.abs(dt - dt_s) <= _PERIOD_TOLERANCE * dt_s))
    if not dt_s > 0 or len(bad):
        row = int(bad[0]) + 1 if len(bad) else 1
        raise ValueError(f"{recording.source}: time_s must increase at a uniform rate "
                         f"({dt_s:g} s), not at row {row}")
    for kind, table in (("input", recording.inputs), ("channel", recording.channels)):
        for name, values in table.items():
            v = np.asarray(values)
            if v.shape != (n,) or not np.all(np.isfinite(v)):
                raise ValueError(f"{recording.source}: {kind} {name!r} must be finite with "
                                 f"shape ({n},), got shape {v.shape}")
    return dt_s


def _every(period_s: float | None, dt_s: float, source: str) -> int:
    if period_s is None:
        return 1
    try:
        period = float(period_s)
    except (TypeError, ValueError):
        raise ValueError(f"period_s must be a number of seconds, got {period_s!r}") from None
    k = round(period / dt_s) if np.isfinite(period) and period > 0 else 0
    if k < 1 or abs(k * dt_s - period) > _PERIOD_TOLERANCE * period:
        raise ValueError(f"period_s must be a whole multiple of the recording's period "
                         f"{dt_s:g} s ({source}), got {period_s!r}")
    return int(k)


def _params(cls: type, params: Any) -> Any:
    if params is None or isinstance(params, cls.params_type):
        return params
    if isinstance(params, dict):
        try:
            return dataclasses.replace(cls.params_type(), **params)
        except TypeError as err:
            raise ValueError(f"params: {err}") from None
    raise ValueError(f"params must be a {cls.params_type.__name__} or a dict of its fields, "
                     f"got {type(params).__name__}")


def _rig(cls: type, params: Any, physics_dt_s: float, profile: str,
         options: dict[str, Any] | None) -> Any:
    """The designer's rig (:func:`testbed.rigs.base.build_rig`), its options checked."""
    try:
        return build_rig(cls, params, physics_dt_s=physics_dt_s, profile=profile,
                         options=cls.resolve_options(options))
    except TypeError as err:
        raise ValueError(f"rig {cls.name!r}: {err}") from None


def replay(recording: Recording, *, rig: Any, profile: str = "paper",
           options: dict[str, Any] | None = None, params: Any = None,
           estimator: Any = "kalman", estimator_options: dict[str, Any] | None = None,
           sensors: Any = None, sensor_options: dict[str, Any] | None = None,
           design_options: dict[str, Any] | None = None, design_profile: str = "matched",
           disturbance: Any = None, process_noise: float = 0.0, ambient_noise: float = 1.0,
           physics_dt_s: float = 0.001, reference: str | None = None,
           exclude: Sequence[str] = (), period_s: float | None = None,
           level: float = LEVEL, progress: bool = False) -> ReplayResult:
    """Run an estimator over a recording's inputs and channels (see the module docstring).

    Parameters
    ----------
    recording : Recording
    rig : str or Rig subclass
        A registered name, ``module:Class`` or the class.
    profile : str
        The rig's profile (its sensors and, with ``design_profile="matched"``, its design).
    options : dict, optional
        The rig's construction options (:attr:`~testbed.rigs.base.Rig.rig_options`).
    params : Params or dict, optional
        The designer's parameters (default the rig's nominal ones; e.g. a twin's).
    estimator : str or callable
        A built-in name, ``package.module:factory`` or a factory
        (:func:`testbed.estimators.resolve`).
    estimator_options, design_options : dict, optional
        As in a scenario.
    sensors : str or Sensor, optional
        The sensor preset (default: the profile's) or a suite; built at the estimator's
        period with ``sensor_options``.
    design_profile : {"matched", "paper"}
        As in a scenario.
    disturbance, process_noise, ambient_noise
        What the designer is told about the disturbance (as in a scenario: a named signal,
        and the scales of the process and ambient noise whose intensities enter ``Q``).
    physics_dt_s : float
        The designer's MuJoCo step (the nonlinear filters' model), s.
    reference : str, optional
        A channel held out of the estimator; its RMSE against its prediction from the
        estimate is reported.
    exclude : sequence of str
        Further channels held out (not reported).
    period_s : float, optional
        The estimator's period, a whole multiple of the recording's (default: the
        recording's).
    level : float
        Confidence level of the bands.
    progress : bool
        A progress bar on stderr.

    Returns
    -------
    ReplayResult

    Raises
    ------
    ValueError
        One line, before any estimator step: a bad recording, an input of the rig or a
        channel the estimator needs missing from it, ``period_s`` not a whole multiple of
        its period, a reference or excluded channel not in the suite or the recording, a
        bad option (named by the estimator's factory or the rig).
    """
    dt_rec = _check_recording(recording)
    source = recording.source
    every = _every(period_s, dt_rec, source)
    period = dt_rec * every if period_s is None else float(period_s)
    cls = resolve_rig(rig)
    if profile not in cls.profiles:
        raise ValueError(f"unknown profile {profile!r} for rig {cls.name!r}; expected one of "
                         f"{cls.profiles}")
    from testbed.design import DESIGN_PROFILES

    if design_profile not in DESIGN_PROFILES:
        raise ValueError(f"design_profile must be one of {DESIGN_PROFILES}, got "
                         f"{design_profile!r}")
    missing = [n for n in cls.action_names if n not in recording.inputs]
    if missing:
        raise ValueError(f"{source}: the recording has no input {missing[0]!r} (rig "
                         f"{cls.name!r} needs {list(cls.action_names)}; it has "
                         f"{sorted(recording.inputs)})")
    nominal = _params(cls, params)
    unit = _rig(cls, nominal, physics_dt_s, profile, options)
    matched = design_profile == "matched" and profile != cls.profiles[0]
    design_rig = unit if matched else _rig(cls, nominal, physics_dt_s, cls.profiles[0], options)
    # the sensors
    if sensors is None or isinstance(sensors, str):
        suite = unit.sensors(sensors, dt_s=period, **(sensor_options or {}))
    elif isinstance(sensors, Sensor):
        if sensor_options:
            raise ValueError("sensor_options is only used with a sensor preset name")
        suite = sensors
    else:
        raise ValueError(f"sensors must be a preset name or a Sensor, got {sensors!r}")
    names = tuple(suite.names)
    held_names = ([] if reference is None else [reference]) + list(exclude)
    for name in held_names:
        what = "reference" if name == reference else "exclude"
        if name not in names:
            raise ValueError(f"{what} channel {name!r} is not a channel of the sensors "
                             f"{list(names)}")
        if name not in recording.channels:
            raise ValueError(f"{source}: the recording has no channel {name!r} ({what}); it "
                             f"has {sorted(recording.channels)}")
    if held_names:
        suite = _HeldOut(suite, [names.index(n) for n in held_names])
    disturbance_model = unit.disturbance(disturbance, process_noise, ambient_noise)
    known = disturbance_model if disturbance_model is not None and (
        disturbance_model.active or disturbance_model.has_signal) else None
    # the design and the estimator, as the runner builds them
    design: DesignModel = design_rig.design_model(suite, period, known, **(design_options or {}))
    name = estimator if isinstance(estimator, str) else \
        getattr(estimator, "__name__", repr(estimator))
    design, fallback = estimators.design_for(estimator, design)
    est = estimators.build(estimator, design, **(estimator_options or {}))
    check_estimate(name, est.x, getattr(est, "P", None), design.n, "after the factory")
    batched = bool(getattr(est, "batched", False))
    if not batched:
        est = estimators.PerMember([est])
    # one member (a Kalman filter's batch of one shares its covariance with itself: its
    # recursion is computed once, ahead, and reused where it has settled; filters.KalmanFilter)
    P = getattr(est, "P", None)
    prior = (np.array(design.x0, copy=True), None if P is None else np.array(design.P0))
    stage = EstimatorStage(est, design.input_transform, _NoTruth(period), prior,
                           channels=estimators.channels_for(est, design),
                           physical_index=design.physical, name=name)
    used = np.arange(len(names)) if stage.channels is None else stage.channels
    taps = sensor_taps(suite)
    needed = {names[int(i)] for i in used} | {n for tap in taps for n in tap.names}
    lacking = sorted(needed - set(recording.channels), key=names.index)
    if lacking:
        raise ValueError(f"{source}: the recording has no channel {lacking[0]!r}, which "
                         f"filter {name!r} needs (it has {sorted(recording.channels)})")
    # the samples
    rows = np.arange(0, recording.n_samples, every)
    K = len(rows) - 1
    if K < 1:
        raise ValueError(f"{source}: {recording.n_samples} samples give no step at period "
                         f"{period:g} s")
    Y = np.column_stack([np.asarray(recording.channels[n], float)[rows]
                         if n in recording.channels else np.full(K + 1, np.nan)
                         for n in names])
    U = np.column_stack([np.asarray(recording.inputs[n], float)[rows]
                         for n in cls.action_names])
    # row j as the (1, m) and (1, nu) the stage takes: views of contiguous rows
    Yb = np.ascontiguousarray(np.nan_to_num(Y)[:, None, :])
    Ub = np.ascontiguousarray(U[:, None, :])
    tap_columns = [(tap, [names.index(n) for n in tap.names]) for tap in taps]
    suite.allocate(1)
    x0_hat, P0 = stage.priors(1, [None])
    inner = est.instances[0] if isinstance(est, estimators.PerMember) else _innermost(est)
    loop = _Collect(stage, inner, P is not None, Yb, Ub, tap_columns)
    bar = tqdm(total=K, desc=f"replay {cls.name}", unit="step", disable=not progress,
               leave=False)
    start = time.perf_counter()
    with bar, threadpool_limits(1):
        loop.restore_taps(0)
        stage.reset(Yb[0].copy(), None, x0_hat, P0)
        loop.first()
        for j0 in range(1, K + 1, loop.BLOCK):
            j1 = min(K + 1, j0 + loop.BLOCK)
            loop.block(j0, j1)
            bar.update(j1 - j0)
    x_hat, P_diag, nu_arr, S_arr, has_innovation = loop.arrays()
    wall = time.perf_counter() - start

    notes: list[str] = []
    if fallback:
        notes.append(f"designed from the paper model ({fallback})")
    if not has_innovation:
        nu_arr = S_arr = None
    nis = None
    consistency = None
    innovation_names: list[str] = []
    if nu_arr is not None:
        p = nu_arr.shape[1]
        innovation_names = ([names[int(i)] for i in used] if len(used) == p
                            else [f"innovation_{i}" for i in range(p)])
        try:
            z = whiten(nu_arr, S_arr)
        except np.linalg.LinAlgError:
            notes.append("an innovation covariance is not positive definite: no consistency")
        else:
            nis = np.sum(z * z, axis=1)
            consistency = innovation_consistency(nis, z, p, level)
    else:
        notes.append(f"filter {name!r} exposes no innovation and innovation_cov: no "
                     "consistency statistics")
    ref = ref_measured = ref_predicted = None
    if reference is not None:
        ref, ref_measured, ref_predicted = _reference(suite, names.index(reference), reference,
                                                      Y, U, x_hat, list(unit.state_names))
    design_meta = dict(getattr(getattr(est, "inner", est), "design_meta", None) or {})
    if isinstance(est, estimators.PerMember):
        design_meta = dict(getattr(est.instances[0], "design_meta", None) or {})
    if matched:
        design_meta.setdefault("design_profile", "paper (fallback)" if fallback else "matched")
    return ReplayResult(
        source=source, sha256=recording.sha256, rig=cls.name, profile=profile,
        estimator=name, sensors=suite.describe(), period_s=float(period), every=every,
        time_s=np.asarray(recording.time_s, float)[rows], state_names=list(unit.state_names),
        state_units=list(unit.state_units), x_hat=x_hat,
        P_diag=None if P_diag is None else np.maximum(P_diag, 0.0),
        measurement_names=list(names), measurement_units=list(suite.units), measurement=Y,
        innovation_names=innovation_names, innovations=nu_arr,
        innovation_var=None if S_arr is None else np.diagonal(S_arr, axis1=1, axis2=2).copy(),
        innovation_cov=S_arr,
        nis=nis, consistency=consistency, reference=ref, reference_measured=ref_measured,
        reference_predicted=ref_predicted, measured_state=list(suite.measured_state),
        notes=notes, wall_s=wall, design_meta=design_meta)


def innovation_consistency(nis: np.ndarray, z: np.ndarray, dim: int,
                           level: float = LEVEL) -> dict[str, Any]:
    """ANIS of one run with its band and verdict, the per-step band fraction and the
    whiteness test (see the module docstring).

    Parameters
    ----------
    nis : ndarray, shape (K,)
        NIS of each step.
    z : ndarray, shape (K, dim)
        The whitened innovations ``L^-1 nu`` (``S = L L^T``).
    dim : int
        Innovation dimension.
    level : float

    Returns
    -------
    dict
        ``dim``, ``steps``, ``anis``, ``band`` (the K-step average's), ``verdict``;
        ``step_band`` (one step's chi2(dim) band), ``steps_above``, ``steps_below``,
        ``band_fraction`` (outside), ``band_fraction_ci`` (Clopper-Pearson),
        ``band_fraction_expected`` (``1 - level``); ``whiteness`` (lags, z, p, verdict, or
        None when the run is too short).
    """
    K = len(nis)
    anis = float(np.mean(nis))
    lo, hi = chi2_bounds(K, dim, level)
    verdict = OVERCONFIDENT if anis > hi else UNDERCONFIDENT if anis < lo else CONSISTENT
    step_lo, step_hi = chi2_bounds(1, dim, level)
    above, below = int(np.sum(nis > step_hi)), int(np.sum(nis < step_lo))
    white = whiteness_test(z[None], level=level)
    return {"dim": int(dim), "steps": K, "level": level, "anis": anis, "band": [lo, hi],
            "verdict": verdict, "step_band": [step_lo, step_hi], "steps_above": above,
            "steps_below": below, "band_fraction": (above + below) / K,
            "band_fraction_ci": list(clopper_pearson(above + below, K, level)),
            "band_fraction_expected": 1.0 - level,
            "whiteness": None if white is None else
            {k: white[k] for k in ("lags", "autocorrelation", "z", "statistic", "p",
                                   "verdict")}}


def _reference(suite: Sensor, j: int, name: str, Y: np.ndarray, U: np.ndarray,
               x_hat: np.ndarray, state_names: list[str]
               ) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """The held-out channel ``j`` against ``C_j x_hat + D_j u`` (its linear model; ``u`` the
    input over the interval that ended at the sample), over steps ``1..K``."""
    model = suite.linear_model()
    C, D = np.asarray(model.C[j], float), np.asarray(model.D[j], float)
    predicted = x_hat @ C
    if np.any(D):
        predicted[1:] += U[:-1] @ D
    measured = Y[:, j]
    error = measured[1:] - predicted[1:]
    nonzero = np.flatnonzero(C)
    state = None
    if len(nonzero) == 1 and C[nonzero[0]] == 1.0 and not np.any(D):
        state = state_names[int(nonzero[0])]
    unit = suite.units[j]
    return ({"channel": name, "state": state, "unit": unit,
             "rmse": float(np.sqrt(np.mean(error**2))), "samples": int(len(error)),
             "prediction": "C x_hat" + (" + D u" if np.any(D) else "")},
            measured.copy(), predicted)
