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
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from testbed import estimators
from testbed.design import DesignModel
from testbed.estimators import optional
from testbed.experiment.loop import EstimatorStage, check_estimate, sensor_taps
from testbed.experiment.replay_collect import Collector, innermost
from testbed.experiment.replay_result import (
    ReplayResult,
    innovation_consistency,
    reference_error,
)
from testbed.experiment.sim_recording import (
    INPUT_CONVENTION,
    episode_recording,
    recording_from_result,
    simulate_recording,
)
from testbed.io.recording import Recording
from testbed.plugins import factory_name
from testbed.rigs import resolve_rig
from testbed.rigs.base import build_rig
from testbed.sensors import Sensor, SensorModel, Suite
from testbed.stats import LEVEL, whiten

__all__ = ["INPUT_CONVENTION", "ReplayResult", "episode_recording", "innovation_consistency",
           "recording_from_result", "replay", "simulate_recording"]

#: Relative tolerance of a uniform sample period and of ``period_s`` as a whole multiple.
_PERIOD_TOLERANCE = 1e-6


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


def _suite(unit: Any, sensors: Any, sensor_options: dict[str, Any] | None, period: float,
           reference: str | None, exclude: Sequence[str], recording: Recording) -> Sensor:
    """The estimator's sensors: the preset (or the suite) at ``period``, with the reference
    and the excluded channels held out (:class:`_HeldOut`), checked against the
    recording."""
    source = recording.source
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
    return suite


def _consistency(nu_arr: np.ndarray | None, S_arr: np.ndarray | None, names: Sequence[str],
                 used: np.ndarray, name: str, level: float, notes: list[str]
                 ) -> tuple[list[str], np.ndarray | None, dict[str, Any] | None]:
    """The innovations' channel names, NIS and :func:`innovation_consistency` (None, with a
    note, without innovations or with an innovation covariance that is not positive
    definite)."""
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
    return innovation_names, nis, consistency


def _design_meta(est: Any, matched: bool, fallback: str | None) -> dict[str, Any]:
    """The estimator's ``design_meta`` and, for a matched design, the design profile."""
    design_meta = dict(optional.design_facts(est) or {})
    if isinstance(est, estimators.PerMember):
        design_meta = dict(optional.design_facts(est.instances[0]) or {})
    if matched:
        design_meta.setdefault("design_profile", "paper (fallback)" if fallback else "matched")
    return design_meta


def _samples(recording: Recording, names: Sequence[str], action_names: Sequence[str],
             every: int, period: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows used (every ``every``-th), the channels (K+1, m; NaN for a channel the
    recording lacks, which the estimator does not use) and the inputs (K+1, nu)."""
    source = recording.source
    rows = np.arange(0, recording.n_samples, every)
    K = len(rows) - 1
    if K < 1:
        raise ValueError(f"{source}: {recording.n_samples} samples give no step at period "
                         f"{period:g} s")
    Y = np.column_stack([np.asarray(recording.channels[n], float)[rows]
                         if n in recording.channels else np.full(K + 1, np.nan)
                         for n in names])
    U = np.column_stack([np.asarray(recording.inputs[n], float)[rows]
                         for n in action_names])
    return rows, Y, U


def _checked(recording: Recording, rig: Any, profile: str, design_profile: str,
             period_s: float | None) -> tuple[type, int, float]:
    """:func:`replay`'s checks of the recording, the rig and its profiles: the rig class,
    every how many samples the estimator steps and its period, s."""
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
    return cls, every, period


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
    cls, every, period = _checked(recording, rig, profile, design_profile, period_s)
    source = recording.source
    nominal = _params(cls, params)
    unit = _rig(cls, nominal, physics_dt_s, profile, options)
    matched = design_profile == "matched" and profile != cls.profiles[0]
    design_rig = unit if matched else _rig(cls, nominal, physics_dt_s, cls.profiles[0], options)
    suite = _suite(unit, sensors, sensor_options, period, reference, exclude, recording)
    names = tuple(suite.names)
    disturbance_model = unit.disturbance(disturbance, process_noise, ambient_noise)
    known = disturbance_model if disturbance_model is not None and (
        disturbance_model.active or disturbance_model.has_signal) else None
    # the design and the estimator, as the runner builds them
    design: DesignModel = design_rig.design_model(suite, period, known, **(design_options or {}))
    name = factory_name(estimator)
    design, fallback = estimators.design_for(estimator, design)
    est = estimators.build(estimator, design, **(estimator_options or {}))
    check_estimate(name, est.x, optional.covariance(est), design.n, "after the factory")
    batched = optional.is_batched(est)
    if not batched:
        est = estimators.PerMember([est])
    # one member (a Kalman filter's batch of one shares its covariance with itself: its
    # recursion is computed once, ahead, and reused where it has settled; filters.KalmanFilter)
    P = optional.covariance(est)
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
    rows, Y, U = _samples(recording, names, cls.action_names, every, period)
    K = len(rows) - 1
    # row j as the (1, m) and (1, nu) the stage takes: views of contiguous rows
    Yb = np.ascontiguousarray(np.nan_to_num(Y)[:, None, :])
    Ub = np.ascontiguousarray(U[:, None, :])
    tap_columns = [(tap, [names.index(n) for n in tap.names]) for tap in taps]
    suite.allocate(1)
    x0_hat, P0 = stage.priors(1, [None])
    inner = est.instances[0] if isinstance(est, estimators.PerMember) else innermost(est)
    loop = Collector(stage, inner, P is not None, Yb, Ub, tap_columns)
    bar = tqdm(total=K, desc=f"replay {cls.name}", unit="step", disable=not progress,
               leave=False)
    start, start_cpu = time.perf_counter(), time.process_time()
    with bar, threadpool_limits(1):
        loop.run(x0_hat, P0, bar.update)
    x_hat, P_diag, nu_arr, S_arr, has_innovation = loop.arrays()
    wall, cpu = time.perf_counter() - start, time.process_time() - start_cpu

    notes: list[str] = []
    if fallback:
        notes.append(f"designed from the paper model ({fallback})")
    if not has_innovation:
        nu_arr = S_arr = None
    innovation_names, nis, consistency = _consistency(nu_arr, S_arr, names, used, name,
                                                      level, notes)
    ref = ref_measured = ref_predicted = None
    if reference is not None:
        ref, ref_measured, ref_predicted = reference_error(
            suite, names.index(reference), reference, Y, U, x_hat, list(unit.state_names))
    design_meta = _design_meta(est, matched, fallback)
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
        notes=notes, wall_s=wall, cpu_s=cpu, design_meta=design_meta)


