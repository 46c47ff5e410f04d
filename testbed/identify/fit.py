"""Identification: a rig's declared identifiable parameters and its sensor model from a recording.

Residual
    The recorded channels minus the predicted ones, each divided by its noise level
    (:func:`~testbed.identify.sensor_model.noise_level`, the still segment's where there is
    one). A quantized channel's (an encoder's) error is a function of the signal between
    its level changes: its level is ``q / sqrt(12)`` times ``sqrt(N / changes)``, its
    samples counting as many as its level changes. A prediction is the rig simulated with
    the recorded inputs through the project's simulator
    (:class:`~testbed.identify.simulate.RecordingModel`), measured noise-free by the sensors'
    core channels, then ``bias + (1 + scale) y(t - delay)`` per channel.

Least squares
    :func:`scipy.optimize.least_squares` (trust-region reflective, the declared bounds
    :attr:`Rig.identifiable` as box bounds) over the free parameters' scale factors. Bias
    and scale are linear in the prediction: they are eliminated in closed form for every
    parameter set (variable projection, Golub and Pereyra 1973), so the optimizer sees the
    physical parameters only. The Jacobian is a forward difference computed as one batched
    simulation of the ``1 + p`` parameter sets (the base and one perturbation per
    parameter; times the segments in multiple shooting), not a loop of rollouts. Whole-sample
    delays are chosen between rounds of the fit by the residual of each candidate (no
    rollout: the prediction shifted).

Output error or multiple shooting
    Output error simulates the fitted part of the recording from its first sample. A rig
    that is not open-loop stable (the helicopter's yaw integrates, its pitch rests on
    stops) or a closed-loop recording drifts away from the recording over a long free
    run, and the fit follows the drift; a lightly damped rig far from nominal has local
    minima (a frequency off). Multiple shooting cuts the recording into segments of
    ``segment_s``, each re-initialised from the measured state (positions from the channels
    measuring them, rates from their smoothed slope or a gyro,
    :func:`~testbed.identify.channels.initial_state`; the actuator states from a nominal
    free run), with output error inside each segment (Bock and Plitt 1984, without the
    continuity unknowns); the measured initial states carry the sensor noise into the fit
    (errors in variables). ``method="auto"`` measures the nominal free run's drift (its
    residual over the segments', above :data:`DRIFT_RATIO`: it drifts), fits by multiple
    shooting, then refits by output error from that estimate (and, where the nominal free
    run does not drift, from nominal too with the declared delays, the lower residual kept)
    and keeps the output error fit where it follows the recording: its residual at most
    :data:`POLISH_RATIO` times the segments' (without process noise it is the sensors' noise
    alone), then runs its rounds again (delays and the initial states' bias re-searched at
    the output-error estimate). The result says which method was used and why.

Intervals
    ``s^2 (J'J)^-1`` at the optimum (:func:`mujoco.sysid.calculate_intervals`, Student-t,
    infinite along directions the data do not see). Residuals of a fitted dynamic model are
    correlated in time (unmodelled dynamics, held or delayed sensors), and the white-noise
    formula is then too narrow; each variance is inflated by the ratio of the
    autocorrelation-consistent sandwich ``H^-1 S H^-1`` to the white one, never deflated:
    ``S`` the long-run covariance of the per-sample scores ``J_t' r_t``, prewhitened by a
    VAR(1) (Andrews and Monahan 1992), the Newey and West (1987) Bartlett estimate of what
    it leaves (the bandwidth by Sokal's automatic window), recoloured
    (:func:`~testbed.identify.hac.hac_inflation`; a test checks it against the closed-form
    covariance of a regression with AR(1) noise). A parameter whose 95 % interval is wider
    than its value, or whose correlation with another exceeds :data:`MAX_CORRELATION`, is not
    determined by the recording: the least determined of them is held at nominal and the rest
    refitted, until none is left.

Where :mod:`mujoco.sysid` fits and where it does not
    Used: :class:`mujoco.sysid.Parameter` / :class:`~mujoco.sysid.ParameterDict` keep the
    free parameters (scale factors, their bounds; ``frozen`` for those held at nominal)
    and :func:`mujoco.sysid.calculate_intervals` gives the white-noise intervals.
    Not used: ``build_residual_fn`` / ``sysid_rollout`` / ``ModelSequences`` roll out a bare
    ``MjModel`` through ``mujoco.rollout``, with parameters written by ``MjSpec`` modifiers
    and recompiled: that bypasses the project's simulator (the only MuJoCo reset/step), so
    the hardware profile's deadband and per-physics-step current limit
    (:meth:`Rig.substep_ctrl`), :meth:`Rig.physics_inputs` and :meth:`Rig.apply_params`
    would be a second implementation; its sensors are MJCF sensors, not the project's
    channels (the helicopter's IMU, the vehicle's accelerometer). ``optimize``'s scipy
    backend differences the residual one parameter at a time (a loop of rollouts) and its
    MuJoCo backend has no box-bounded variable projection; the signal modifiers
    (``apply_bias``, ``apply_gain``, ``apply_delay``) act on ``TimeSeries`` of MJCF sensors
    with a delay in seconds (resampled), where here bias and scale are eliminated in closed
    form and delays are whole samples of the recording.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np
import scipy.optimize
import scipy.special

from testbed.identify.hac import hac_inflation
from testbed.identify.predict import Problem, predict_channels, predict_raw, project
from testbed.identify.result import (
    Identification,
    ParameterEstimate,
    fit_percent,
    sensor_model_of,
)
from testbed.identify.setup import (
    METHODS,
    FitSetup,
    check_arguments,
    checked_free,
    prepare,
)
from testbed.io.recording import Recording
from testbed.records import field_values
from testbed.rigs.base import Params, Rig

# (Identification, ParameterEstimate and fit_percent are testbed.identify.result's, imported
# here for the fit; the package re-exports them from there: one canonical page each)
__all__ = ["DRIFT_RATIO", "MAX_CORRELATION", "METHODS", "POLISH_RATIO", "identify",
           "predict_channels", "sensor_model_of"]

#: ``auto``: the nominal free run drifts when its residual exceeds the multiple-shooting
#: residual by this factor.
DRIFT_RATIO = 2.0
#: ``auto``: the output-error refit from the multiple-shooting estimate is kept when its
#: residual is at most this factor times the segments' (its free run follows the recording:
#: without process noise its residual is the sensors' noise, below the segments', whose
#: initial states carry that noise; 0.01 to 0.9 on the test units).
POLISH_RATIO = 1.25
#: Correlation above which two parameters are not separately determined. (0.99 flags the
#: vehicle's damping and centre-of-mass height from 10 s of random steps, both within 2 %
#: and inside their intervals; a pair seen only as a product or ratio correlates to 1 - 1e-6.)
MAX_CORRELATION = 0.999


def _sysid():
    """:mod:`mujoco.sysid`, which needs the ``mujoco[sysid]`` extra."""
    import mujoco.sysid as sysid

    if not hasattr(sysid, "calculate_intervals"):
        raise ImportError("testbed identify needs mujoco.sysid: pip install 'mujoco[sysid]'")
    return sysid


def identify(rig_cls: type[Rig], recording: Recording, *, profile: str = "hardware",
             options: dict[str, Any] | None = None, free: Any = None, holdout: float = 0.0,
             method: str = "auto", channels: Any = None, sensors: Any = None,
             fit_scale: bool | str = False, max_delay: int | None = None, segment_s: float = 1.0,
             max_iterations: int = 40) -> Identification:
    """Fit a rig's identifiable parameters and its sensor model to a recording.

    Parameters
    ----------
    rig_cls : type
        A :class:`~testbed.rigs.base.Rig` subclass declaring :attr:`Rig.identifiable`.
    recording : Recording
    profile : str
        The rig's profile the unit is simulated in (its actuator model).
    options : dict, optional
        The rig's construction options.
    free : list of str, optional
        Parameters to fit (default: every declared identifiable one).
    holdout : float
        Fraction of the recording at its end held out of the fit, in ``[0, 0.9)``.
    method : {"auto", "output-error", "multiple-shooting"}
    channels : list of str, optional
        Channels to fit (default: every recorded state channel of the rig's sensors).
    sensors : Sensor or str, optional
        The sensor suite or preset that made the recording (default: the profile's).
    fit_scale : bool or "declared"
        Fit a scale factor per channel (besides the bias): True every channel but a direct
        state, ``"declared"`` the channels whose sensors declare a sensitivity error
        (:class:`~testbed.sensors.ScaleFactor`), False (default) none. A scale trades
        against the physical gains (the vehicle's centre-of-mass height against its
        accelerometer's sensitivity): free it when the recording separates them.
    max_delay : int, optional
        Largest whole-sample delay searched per channel (default: from the sensors'
        declared delays and holds; 0 for channels without).
    segment_s : float
        Multiple-shooting segment length, s.
    max_iterations : int
        Largest number of residual evaluations per least-squares round.

    Returns
    -------
    Identification

    Raises
    ------
    IdentificationError
        A bad argument (one line, named) before any simulation.
    """
    t_start = time.perf_counter()
    declared, free = checked_free(rig_cls, free)
    check_arguments(holdout, fit_scale, method, segment_s, max_delay)
    sysid = _sysid()
    setup = prepare(rig_cls, recording, declared, free, sysid, profile=profile,
                     options=options, sensors=sensors, channels=channels, holdout=holdout,
                     fit_scale=fit_scale, max_delay=max_delay, segment_s=segment_s,
                     max_iterations=max_iterations)
    timings: dict[str, float] = {"rollout_s": _time_one_rollout(setup)}
    state = _start_method(setup, method, segment_s)
    t0 = time.perf_counter()
    fitted = _fit(setup, state, sysid)
    timings["fit_s"] = time.perf_counter() - t0
    return _results(setup, state, fitted, timings, t_start, rig_cls=rig_cls,
                    recording=recording, profile=profile, holdout=holdout, sensors=sensors)


def _time_one_rollout(setup: FitSetup) -> float:
    """Wall time of one rollout of the fitted part at nominal (the unit of the timings), s."""
    t0 = time.perf_counter()
    predict_raw(setup.model, [setup.model.nominal], np.zeros(setup.m, int), "output-error",
                setup.segment_len, 0, setup.n_fit, setup.x0_bias)
    return time.perf_counter() - t0


def _choose_delays(setup: FitSetup, s_vec: np.ndarray, meth: str, x0b: np.ndarray) -> np.ndarray:
    """Each channel's delay: the candidate with the least projected residual."""
    m, n_fit, max_delays = setup.m, setup.n_fit, setup.max_delays
    delay = np.zeros(m, int)
    if not np.any(max_delays > 0):
        return delay
    problem = setup.problem(list(setup.pdict.get_non_frozen_parameter_names()), meth, delay,
                            x0b)
    params = problem.params(s_vec)
    h0 = predict_raw(setup.model, [params], np.zeros(m, int), meth, setup.segment_len, 0,
                     n_fit, x0b)[0]
    y = setup.model.y[:n_fit]
    for c in np.flatnonzero(max_delays > 0):
        best = None
        for d in range(int(max_delays[c]) + 1):
            hd = np.concatenate([np.full(d, h0[0, c]), h0[:n_fit - d, c]])
            b, s = project(hd[None, :, None], y[:, c:c + 1], setup.fit_bias[c:c + 1],
                           setup.fit_scale[c:c + 1])
            err = float(np.sum((y[:, c] - b[0, 0] - (1 + s[0, 0]) * hd) ** 2))
            if best is None or err < best[0]:
                best = (err, d)
        delay[c] = best[1]
    return delay


def _rms(setup: FitSetup, h: np.ndarray) -> float:
    """RMS of the weighted residual of a raw prediction (1, n_fit, m) after projection."""
    if not np.all(np.isfinite(h)):
        return math.inf
    y = setup.model.y[:setup.n_fit]
    b, s = project(h, y, setup.fit_bias, setup.fit_scale)
    return float(np.sqrt(np.mean(((y - b[0] - (1 + s[0]) * h[0]) / setup.sigma) ** 2)))


@dataclasses.dataclass
class _Rounds:
    """The fit's state across its rounds: the method, why, the delays and initial states'
    bias, and the last solve (whose residual and Jacobian the intervals reuse)."""

    chosen: str
    reason: str
    delay: np.ndarray
    declared_delay: np.ndarray
    x0_bias: np.ndarray
    polish: bool = False
    nominal_follows: bool = False
    rounds: int = 0
    last: tuple[Any, str, np.ndarray, np.ndarray] | None = None


def _start_method(setup: FitSetup, method: str, segment_s: float) -> _Rounds:
    """The method to start with and why (``auto``: by the nominal free run's drift)."""
    # the declared delays to start with; searched again at each round's estimate
    delay = np.minimum([i.delay for i in setup.model.infos], setup.max_delays).astype(int)
    state = _Rounds(chosen=method, reason="chosen by the caller", delay=delay,
                    declared_delay=delay.copy(), x0_bias=setup.x0_bias)
    if method == "auto":
        # multiple shooting first (its short segments keep the fit out of the free run's
        # local minima: a frequency far off, a drift), then output error from its estimate,
        # kept where its free run follows the recording (no errors in variables)
        model, args = setup.model, (setup.segment_len, 0, setup.n_fit, state.x0_bias)
        ms = predict_raw(model, [model.nominal], delay, "multiple-shooting", *args)
        oe = predict_raw(model, [model.nominal], delay, "output-error", *args)
        # the free run's residual over the multiple-shooting one (one batch each)
        ratio = _rms(setup, oe) / max(_rms(setup, ms), 1e-300)
        state.chosen, state.polish = "multiple-shooting", True
        state.nominal_follows = ratio <= DRIFT_RATIO
        state.reason = (f"auto: the nominal free run's residual is {ratio:.3g} times the "
                        f"{segment_s:g}-s multiple-shooting residual "
                        f"({'the free run drifts' if ratio > DRIFT_RATIO else 'no drift'}); "
                        "fitted by multiple shooting")
    return state


def _least_squares(problem: Problem, s0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   max_iterations: int) -> Any:
    """One trust-region reflective solve of ``problem`` from ``s0`` within the bounds."""
    return scipy.optimize.least_squares(
        problem.fun, s0, jac=lambda s, p=problem, a=lo, b=hi: p.jac(s, a, b),
        bounds=(lo, hi), method="trf", x_scale=1.0, max_nfev=max_iterations,
        xtol=1e-10, ftol=1e-12, gtol=1e-10)


def _solve_rounds(setup: FitSetup, state: _Rounds, names: list[str], s_cur: np.ndarray,
                  lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, Problem]:
    """Up to three solves, the delays and the initial states' bias re-searched after each,
    until they stay: the estimate and the last round's problem."""
    for _ in range(3):  # rounds: delays and the initial states' bias follow the fit
        state.rounds += 1
        problem = setup.problem(names, state.chosen, state.delay, state.x0_bias)
        sol = _least_squares(problem, s_cur, lo, hi, setup.max_iterations)
        s_cur = sol.x
        state.last = (sol, state.chosen, state.delay, state.x0_bias)
        _, bias_now, _ = problem.residuals([s_cur])
        new_delay = (_choose_delays(setup, s_cur, state.chosen, state.x0_bias)
                     if np.any(setup.max_delays) else state.delay)
        new_x0_bias = (state.x0_bias if setup.x0_fixed
                       else np.where(setup.model.x0_bias_mask, bias_now[0], 0.0))
        moved = np.max(np.abs(new_x0_bias - state.x0_bias) / setup.sigma)
        if np.array_equal(new_delay, state.delay) and moved < 0.05:
            break  # (the solve's own delays and bias kept: its Jacobian is final)
        state.delay, state.x0_bias = new_delay, new_x0_bias
    return s_cur, problem


def _polish(setup: FitSetup, state: _Rounds, names: list[str], s_cur: np.ndarray,
            s_start: np.ndarray, lo: np.ndarray, hi: np.ndarray, problem: Problem
            ) -> tuple[np.ndarray, bool]:
    """Output error from the multiple-shooting estimate, kept where its free run follows the
    recording: the estimate, and whether the rounds run again at it."""
    # multiple shooting's initial states carry the measurement noise into the fit
    # (errors in variables): output error from its estimate is consistent where the
    # free run then follows the recording as well as the segments do
    state.polish = False
    ms_rms = _rms(setup, predict_raw(setup.model, [problem.params(s_cur)], state.delay,
                                     state.chosen, setup.segment_len, 0, setup.n_fit,
                                     state.x0_bias))
    trial = setup.problem(names, "output-error", state.delay, state.x0_bias)
    sol = _least_squares(trial, s_cur, lo, hi, setup.max_iterations)
    start_note, polish_delay = "its estimate", state.delay
    if state.nominal_follows:  # the free run from the start may find a better minimum
        # (from the declared delays: the segments' rounds may have moved them to a
        # local minimum)
        start = setup.problem(names, "output-error", state.declared_delay, state.x0_bias)
        other = _least_squares(start, s_start, lo, hi, setup.max_iterations)
        if other.cost < sol.cost:
            sol, start_note = other, "nominal (a lower residual than from its estimate)"
            polish_delay = state.declared_delay
    oe_rms = float(np.sqrt(np.mean(sol.fun ** 2)))
    after = oe_rms / max(ms_rms, 1e-300)
    if after <= POLISH_RATIO:
        state.chosen, s_cur, state.delay = "output-error", sol.x, polish_delay
        state.last = (sol, state.chosen, state.delay, state.x0_bias)
        state.reason += (f", then output error from {start_note} (its residual "
                         f"{after:.3g} times the segments', within {POLISH_RATIO:g}: used, "
                         "no errors in variables)")
        # its rounds again where the delays (searched at the multiple-shooting
        # estimate) or the initial states' bias can follow the output-error fit (a
        # vehicle unit kept a roll-rate delay one sample short, its estimates 18 %
        # off)
        return s_cur, bool(np.any(setup.max_delays > 0) or not setup.x0_fixed)
    state.reason += (f"; output error from its estimate does not follow the recording "
                     f"(residual {after:.3g} times the segments', above "
                     f"{POLISH_RATIO:g}): not used")
    return s_cur, False


@dataclasses.dataclass
class _Fitted:
    """The fit's outcome: the scale factors (over ``setup.free``), the parameters held at
    nominal and why, and the intervals of the fitted ones."""

    s_vec: np.ndarray
    flagged: dict[str, str]
    names: list[str]
    half: np.ndarray | None = None
    corr: np.ndarray | None = None
    bandwidth: int = 0


def _fit(setup: FitSetup, state: _Rounds, sysid: Any) -> _Fitted:
    """Fit rounds, then hold the undetermined parameters at nominal and refit."""
    free = setup.free
    out = _Fitted(s_vec=np.ones(len(free)), flagged={}, names=list(free))
    while True:
        names = [n for n in free if n not in out.flagged]
        if not names:
            break
        s_cur = np.array([out.s_vec[free.index(n)] for n in names])
        lo = np.array([setup.bounds[n][0] for n in names])
        hi = np.array([setup.bounds[n][1] for n in names])
        s_cur = np.clip(s_cur, lo + 1e-9, hi - 1e-9)
        s_start = s_cur.copy()
        while True:
            s_cur, problem = _solve_rounds(setup, state, names, s_cur, lo, hi)
            if not state.polish:
                break
            s_cur, again = _polish(setup, state, names, s_cur, s_start, lo, hi, problem)
            if not again:
                break
        for n, v in zip(names, s_cur, strict=True):
            out.s_vec[free.index(n)] = v
        out.half, out.corr, out.bandwidth = _intervals(setup, state, names, s_cur, lo, hi,
                                                       sysid)
        candidates = _undetermined(names, s_cur, out.half, out.corr)
        if not candidates:
            break
        rel = {n: (out.half[names.index(n)] / abs(s_cur[names.index(n)])
                   if np.isfinite(out.half[names.index(n)]) else math.inf) for n in candidates}
        worst_name = max(rel, key=lambda n: (rel[n], n))
        out.flagged[worst_name] = candidates[worst_name]
        setup.held[worst_name] = 1.0
        out.s_vec[free.index(worst_name)] = 1.0
        setup.pdict[worst_name].frozen = True
    out.names = [n for n in free if n not in out.flagged]
    return out


def _intervals(setup: FitSetup, state: _Rounds, names: list[str], s_cur: np.ndarray,
               lo: np.ndarray, hi: np.ndarray, sysid: Any
               ) -> tuple[np.ndarray, np.ndarray, int]:
    """95 % half-widths of the scale factors (white-noise intervals inflated by the HAC
    ratio), their correlations (from the HAC covariance) and the HAC bandwidth."""
    problem = setup.problem(names, state.chosen, state.delay, state.x0_bias)
    sol_last, method_last, delay_last, bias_last = state.last
    if (method_last == state.chosen and delay_last is state.delay
            and bias_last is state.x0_bias and np.array_equal(sol_last.x, s_cur)):
        r_star, J = sol_last.fun, sol_last.jac  # the solve's own, at its solution
    else:
        r_star, J = problem.fun(s_cur), problem.jac(s_cur, lo, hi)
    _, half = sysid.calculate_intervals([r_star], J)
    inflation, bandwidth, hac = hac_inflation(J, r_star, setup.n_fit, setup.m)
    half = np.asarray(half, float) * np.sqrt(inflation)
    with np.errstate(divide="ignore", invalid="ignore"):
        sd = np.sqrt(np.diag(hac))
        corr = hac / np.outer(sd, sd)
    corr = np.where(np.isfinite(corr), corr, 0.0)
    np.fill_diagonal(corr, 1.0)
    return half, corr, bandwidth


def _undetermined(names: list[str], s_cur: np.ndarray, half: np.ndarray, corr: np.ndarray
                  ) -> dict[str, str]:
    """The parameters the recording does not determine, each with why."""
    candidates: dict[str, str] = {}
    for i, n in enumerate(names):
        if not np.isfinite(half[i]):
            candidates[n] = "the recording does not determine it (singular J'J)"
        elif 2 * half[i] > abs(s_cur[i]):
            candidates[n] = (f"its 95 % interval ({2 * half[i] / abs(s_cur[i]):.3g} of its "
                             "value) is wider than its value")
        else:
            others = [(abs(corr[i, k]), names[k]) for k in range(len(names)) if k != i]
            worst = max(others, default=(0.0, ""))
            if worst[0] > MAX_CORRELATION:
                candidates[n] = f"correlation {worst[0]:.4f} with {worst[1]}"
    return candidates


def _results(setup: FitSetup, state: _Rounds, fitted: _Fitted, timings: dict[str, float],
             t_start: float, *, rig_cls: type[Rig], recording: Recording, profile: str,
             holdout: float, sensors: Any) -> Identification:
    """The :class:`Identification`: estimates, the sensor model, the fits and the timings."""
    model, n_fit, m = setup.model, setup.n_fit, setup.m
    names, delay, x0_bias = fitted.names, state.delay, state.x0_bias
    final_scales = {**setup.held, **{n: float(fitted.s_vec[setup.free.index(n)])
                                     for n in names}}
    params = model.nominal.scaled(final_scales)
    if names:
        problem = setup.problem(names, state.chosen, delay, x0_bias)
        _, bias_fit, scale_fit = problem.residuals([np.array([final_scales[n]
                                                              for n in names])])
        bias_fit, scale_fit = bias_fit[0], scale_fit[0]
    else:
        bias_fit, scale_fit = np.where(setup.fit_bias, x0_bias, 0.0), np.zeros(m)
    predicted, pred_fit, fits, holdout_fit, free_fits = _predictions(
        setup, state.chosen, params, bias_fit, scale_fit, delay, x0_bias)
    estimates = _estimates(setup, fitted)
    residual_std = np.nanstd(model.y[:n_fit] - pred_fit, axis=0)
    sensors_out = _sensors_out(setup, bias_fit, scale_fit, delay, x0_bias, residual_std)
    timings["total_s"] = time.perf_counter() - t_start
    timings["ratio_to_rollout"] = timings["total_s"] / max(timings["rollout_s"], 1e-12)
    timings["member_steps"] = float(model.rollouts)
    timings["rounds"] = float(state.rounds)
    timings["hac_bandwidth_samples"] = float(fitted.bandwidth) if names else 0.0
    still = setup.still
    still_s = None if still is None else (float(model.recording.time_s[still[0]]),
                                          float(model.recording.time_s[still[1] - 1]))
    return Identification(
        rig=rig_cls.name, profile=profile, options=dict(model.options), parameters=estimates,
        correlation=fitted.corr if names else np.zeros((0, 0)),
        correlation_names=tuple(names),
        sensors=sensors_out, fit_percent=fits, holdout_fit_percent=holdout_fit,
        free_run_fit_percent=free_fits, method=state.chosen, method_reason=state.reason,
        segment_s=setup.segment_len * model.dt_s, still_segment_s=still_s,
        recording_sha256=recording.sha256, recording_source=recording.source,
        dt_s=model.dt_s, n_fit=n_fit, timings=timings, time_s=np.asarray(recording.time_s),
        measured=model.y, predicted=predicted, channels=model.names,
        units=tuple(i.unit for i in model.infos), holdout=float(holdout),
        sensor_preset=sensors if isinstance(sensors, str) else
        ("" if sensors is None else "<custom>"))


def _predictions(setup: FitSetup, chosen: str, params: Params, bias_fit: np.ndarray,
                 scale_fit: np.ndarray, delay: np.ndarray, x0_bias: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, dict[str, float], dict[str, float],
                            dict[str, float]]:
    """The prediction over the whole recording (N, m), over the fitted part (n_fit, m), and
    the fits per channel: the fitted part, the held-out end, the free run."""
    model, n_fit, segment_len = setup.model, setup.n_fit, setup.segment_len
    N = model.y.shape[0]
    pred_fit = predict_channels(model, [params], bias_fit, scale_fit, delay, chosen,
                                segment_len, 0, n_fit, x0_bias)[0]
    predicted = np.full_like(model.y, np.nan)
    predicted[:n_fit] = pred_fit
    holdout_fit: dict[str, float] = {}
    if n_fit < N:
        pred_hold = predict_channels(model, [params], bias_fit, scale_fit, delay, chosen,
                                     segment_len, n_fit, N, x0_bias)[0]
        predicted[n_fit:] = pred_hold
        holdout_fit = dict(zip(model.names, fit_percent(model.y[n_fit:], pred_hold).tolist(),
                               strict=True))
    free_pred = pred_fit if chosen == "output-error" else predict_channels(
        model, [params], bias_fit, scale_fit, delay, "output-error", segment_len, 0, n_fit,
        x0_bias)[0]
    fits = dict(zip(model.names, fit_percent(model.y[:n_fit], pred_fit).tolist(), strict=True))
    free_fits = dict(zip(model.names, fit_percent(model.y[:n_fit], free_pred).tolist(),
                         strict=True))
    return predicted, pred_fit, fits, holdout_fit, free_fits


def _estimates(setup: FitSetup, fitted: _Fitted) -> dict[str, ParameterEstimate]:
    """Each free parameter's estimate, absolute, with its interval (or held at nominal)."""
    estimates: dict[str, ParameterEstimate] = {}
    names_index = {n: i for i, n in enumerate(fitted.names)}
    nominal_values = field_values(setup.model.nominal)
    for name in setup.free:
        nominal = float(nominal_values[name])
        if name in fitted.flagged:
            estimates[name] = ParameterEstimate(name, nominal, None, nominal, 1.0, False,
                                                fitted.flagged[name])
            continue
        i = names_index[name]
        s = float(fitted.s_vec[setup.free.index(name)])
        lo_hi = sorted(((s - fitted.half[i]) * nominal, (s + fitted.half[i]) * nominal))
        estimates[name] = ParameterEstimate(name, s * nominal, (float(lo_hi[0]),
                                                                float(lo_hi[1])),
                                            nominal, s, True)
    return estimates


def _sensors_out(setup: FitSetup, bias_fit: np.ndarray, scale_fit: np.ndarray,
                 delay: np.ndarray, x0_bias: np.ndarray, residual_std: np.ndarray
                 ) -> dict[str, dict[str, Any]]:
    """The sensor model per channel (the ``sensors`` of an :class:`Identification`)."""
    model, still_std, still_bias = setup.model, setup.still_std, setup.still_bias
    sensors_out = {}
    for c, info in enumerate(model.infos):
        noise_std = float(still_std[c]) if np.isfinite(still_std[c]) else float(residual_std[c])
        sensors_out[info.name] = {
            "unit": info.unit, "bias": float(bias_fit[c]), "bias_fitted": bool(setup.fit_bias[c]),
            "scale": float(scale_fit[c]), "scale_fitted": bool(setup.fit_scale[c]),
            "delay_samples": int(delay[c]), "delay_s": float(delay[c] * model.dt_s),
            "initial_state_bias": float(x0_bias[c]),
            "noise_std": noise_std, "noise_density": noise_std * math.sqrt(model.dt_s),
            "noise_from": "still segment" if np.isfinite(still_std[c]) else "fit residual",
            "quantization_step": float(model.steps[c]),
            "still_bias": None if not np.isfinite(still_bias[c]) else float(still_bias[c]),
        }
    return sensors_out
