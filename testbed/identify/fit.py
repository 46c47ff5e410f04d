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
    it leaves (the bandwidth by Sokal's automatic window), recoloured (:func:`_hac_inflation`;
    a test checks it against the closed-form covariance of a regression with AR(1) noise).
    A parameter whose 95 % interval is wider than its value, or whose
    correlation with another exceeds :data:`MAX_CORRELATION`, is not determined by the
    recording: the least determined of them is held at nominal and the rest refitted, until
    none is left.

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

from testbed.identify.channels import IdentificationError
from testbed.identify.sensor_model import (
    noise_level,
    still_segment,
    still_statistics,
)
from testbed.identify.simulate import RecordingModel, sensor_vectors
from testbed.io.recording import Recording
from testbed.rigs.base import Params, Rig

METHODS = ("auto", "output-error", "multiple-shooting")
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
#: Relative forward-difference step of the Jacobian (scale factors).
FD_STEP = 1e-5
#: Residual (in noise levels) given to a diverged prediction.
DIVERGED_RESIDUAL = 1e3
#: Largest singular value of the scores' prewhitening VAR(1) (Andrews and Monahan 1992
#: cap theirs at 0.97).
MAX_PREWHITEN_EIGENVALUE = 0.97


def _sysid():
    """:mod:`mujoco.sysid`, which needs the ``mujoco[sysid]`` extra."""
    import mujoco.sysid as sysid

    if not hasattr(sysid, "calculate_intervals"):
        raise ImportError("testbed identify needs mujoco.sysid: pip install 'mujoco[sysid]'")
    return sysid


@dataclasses.dataclass
class ParameterEstimate:
    """One free parameter's result.

    Attributes
    ----------
    name : str
    value : float
        Absolute value (the nominal one when not identifiable).
    ci95 : tuple of float or None
        95 % interval, absolute (None when not identifiable).
    nominal : float
    scale : float
        ``value / nominal``.
    identifiable : bool
        False: the recording does not determine it; held at nominal (``reason`` says why).
    reason : str
    """

    name: str
    value: float
    ci95: tuple[float, float] | None
    nominal: float
    scale: float
    identifiable: bool
    reason: str = ""

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"value": self.value, "ci95": None if self.ci95 is None else list(self.ci95),
                "nominal": self.nominal, "identifiable": self.identifiable,
                "scale": self.scale, **({"reason": self.reason} if self.reason else {})}


@dataclasses.dataclass
class Identification:
    """What :func:`identify` found (see :meth:`to_json` for the file form).

    Attributes
    ----------
    rig, profile : str
    options : dict
    parameters : dict of str to ParameterEstimate
        The free parameters, fitted or held at nominal.
    correlation : ndarray, shape (q, q)
        Correlations of the fitted (identifiable) parameters, order ``correlation_names``.
    correlation_names : tuple of str
    sensors : dict of str to dict
        Per channel: ``bias``, ``scale``, ``delay_samples``, ``noise_std``,
        ``noise_density``, ``quantization_step``, ``still_bias`` (None without a still
        segment), ``initial_state_bias`` (what the initial states were read with).
    fit_percent, holdout_fit_percent, free_run_fit_percent : dict of str to float
        NRMSE fit per channel ``100 (1 - |y - y_hat| / |y - mean(y)|)``: the method's
        prediction over the fitted part and over the held-out end (empty without one); the
        whole fitted part simulated from its first sample (for information).
    method : str
        ``"output-error"`` or ``"multiple-shooting"``.
    method_reason : str
    segment_s : float
    still_segment_s : tuple or None
    recording_sha256, recording_source : str
    dt_s : float
    n_fit : int
        Samples fitted (the rest is held out).
    timings : dict
    time_s, measured, predicted : ndarray
        The recording's times (N,), its channels (N, m) and their prediction (N, m).
    channels, units : tuple of str
    holdout : float
        The held-out fraction.
    sensor_preset : str
        The sensor preset the channels were read with (``""``: the profile's default;
        ``"<custom>"``: a sensor object the caller passed).
    """

    rig: str
    profile: str
    options: dict[str, Any]
    parameters: dict[str, ParameterEstimate]
    correlation: np.ndarray
    correlation_names: tuple[str, ...]
    sensors: dict[str, dict[str, Any]]
    fit_percent: dict[str, float]
    holdout_fit_percent: dict[str, float]
    free_run_fit_percent: dict[str, float]
    method: str
    method_reason: str
    segment_s: float
    still_segment_s: tuple[float, float] | None
    recording_sha256: str
    recording_source: str
    dt_s: float
    n_fit: int
    timings: dict[str, float]
    time_s: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    channels: tuple[str, ...]
    units: tuple[str, ...]
    holdout: float = 0.0
    sensor_preset: str = ""

    def holdout_signal_to_noise(self) -> dict[str, float]:
        """Per channel, the held-out part's spread over the channel's noise level
        (``std(y_holdout) / sqrt(noise_std^2 + q^2 / 12)`` with ``q`` the quantization step;
        empty without a held-out part). Near 1 the held-out part has no excitation: its NRMSE
        fit compares the prediction with the noise and says nothing of the model (a still
        end of the recording fits near 0 %)."""
        if self.n_fit >= len(self.time_s):
            return {}
        out = {}
        for c, name in enumerate(self.channels):
            sensor = self.sensors.get(name, {})
            noise = math.hypot(float(sensor.get("noise_std") or 0.0),
                               float(sensor.get("quantization_step") or 0.0) / math.sqrt(12))
            spread = float(np.std(self.measured[self.n_fit:, c]))
            out[name] = spread / noise if noise > 0 else float("inf")
        return out

    def params_scales(self) -> dict[str, float]:
        """Scale factors of the fitted parameters relative to nominal (held ones omitted)."""
        return {n: p.scale for n, p in self.parameters.items() if p.identifiable}

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict: ``parameters``, ``correlation``, ``sensors``, ``fit_percent``,
        ``holdout_fit_percent``, ``method``, ``recording_sha256``, ``timings``..."""
        return {
            "rig": self.rig, "profile": self.profile, "options": dict(self.options),
            "parameters": {n: p.to_json() for n, p in self.parameters.items()},
            "unidentifiable": [n for n, p in self.parameters.items() if not p.identifiable],
            "correlation": {"names": list(self.correlation_names),
                            "matrix": np.round(self.correlation, 6).tolist()},
            "sensors": self.sensors, "fit_percent": self.fit_percent,
            "holdout_fit_percent": self.holdout_fit_percent,
            "holdout_signal_to_noise": self.holdout_signal_to_noise(),
            "free_run_fit_percent": self.free_run_fit_percent,
            "method": self.method, "method_reason": self.method_reason,
            "segment_s": self.segment_s,
            "still_segment_s": None if self.still_segment_s is None
            else list(self.still_segment_s),
            "recording_sha256": self.recording_sha256,
            "recording_source": self.recording_source, "dt_s": self.dt_s,
            "n_samples": len(self.time_s), "n_fit": self.n_fit, "holdout": self.holdout,
            "sensor_preset": self.sensor_preset, "channels": list(self.channels),
            "timings": self.timings,
        }


def fit_percent(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    """NRMSE fit per column: ``100 (1 - |y - y_hat| / |y - mean(y)|)``, shape (m,)
    (``-inf`` for a constant channel predicted wrong, 100 predicted right)."""
    err = np.linalg.norm(y - y_hat, axis=0)
    spread = np.linalg.norm(y - y.mean(axis=0), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 100.0 * (1.0 - err / spread)
    out[(spread == 0) & (err == 0)] = 100.0
    return np.where(np.isnan(out), -np.inf, out)


def segment_starts(start: int, stop: int, length: int) -> np.ndarray:
    """First samples of the segments tiling ``[start, stop)``."""
    return np.arange(start, stop, max(int(length), 2))


def predict_channels(model: RecordingModel, params: list[Params], bias: np.ndarray,
                     scale: np.ndarray, delay: np.ndarray, method: str, segment_len: int,
                     start: int, stop: int, x0_bias: np.ndarray | None = None) -> np.ndarray:
    """Predicted channels over samples ``[start, stop)`` of P parameter sets (one batch).

    ``output-error``: one simulation from the measured state at ``start``;
    ``multiple-shooting``: segments of ``segment_len`` samples, each from its measured state.
    The actuator states (MuJoCo ``act``: the hardware profile's rotor lag) are not measured:
    a segment starting after the first sample takes them from a free run at nominal
    parameters (:meth:`RecordingModel.actuator_track`).
    ``x0_bias`` (default: ``bias`` on the channels with a declared bias,
    :attr:`RecordingModel.x0_bias_mask`) is the bias the initial states are read with: a
    quantized position's fitted offset is its zero known to a step, not a sensor bias.

    Returns
    -------
    ndarray, shape (P, stop - start, m)
    """
    raw = predict_raw(model, params, delay, method, segment_len, start, stop,
                      bias * model.x0_bias_mask if x0_bias is None else x0_bias)
    return bias + (1.0 + scale) * raw


def predict_raw(model: RecordingModel, params: list[Params], delay: np.ndarray, method: str,
                segment_len: int, start: int, stop: int, x0_bias: np.ndarray) -> np.ndarray:
    """:func:`predict_channels` before the bias and scale: (P, stop - start, m)."""
    if method == "output-error":
        starts, length = np.array([start]), stop - start
    else:
        starts, length = segment_starts(start, stop, segment_len), int(segment_len)
    x0 = model.initial_states(starts, x0_bias, delay)
    act0 = model.actuator_track()[starts] if (model.na and method != "output-error"
                                              or (model.na and start > 0)) else None
    if model.reads_act:  # a channel reads the actuator states (the Aero's rotor speeds)
        states, u_prev, act = model.rollout(params, x0, starts, length, act0=act0,
                                            with_act=True)
        h = model.measure(states, u_prev, delay, act)  # (P, S, L, m)
    else:
        states, u_prev = model.rollout(params, x0, starts, length, act0=act0)
        h = model.measure(states, u_prev, delay)  # (P, S, L, m)
    P, S, L, m = h.shape
    return h.reshape(P, S * L, m)[:, :stop - start]


def _project(h: np.ndarray, y: np.ndarray, fit_bias: np.ndarray, fit_scale: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares bias and scale per set and channel for ``y ~ b + (1 + s) h``:
    ``(bias, scale)`` each (P, m)."""
    P, _, m = h.shape
    bias, scale = np.zeros((P, m)), np.zeros((P, m))
    for c in range(m):
        yc = y[:, c]
        for p in range(P):
            hc = h[p, :, c]
            if not np.all(np.isfinite(hc)):
                continue
            if fit_scale[c]:
                cols = [hc] + ([np.ones_like(hc)] if fit_bias[c] else [])
                coef, *_ = np.linalg.lstsq(np.column_stack(cols), yc, rcond=None)
                scale[p, c] = coef[0] - 1.0
                bias[p, c] = coef[1] if fit_bias[c] else 0.0
            elif fit_bias[c]:
                bias[p, c] = float(np.mean(yc - hc))
    return bias, scale


class _Problem:
    """The least-squares problem of one fit round: free scale factors -> weighted residual."""

    def __init__(self, model: RecordingModel, free: list[str], held: dict[str, float],
                 method: str, segment_len: int, n_fit: int, sigma: np.ndarray,
                 fit_bias: np.ndarray, fit_scale: np.ndarray, delay: np.ndarray,
                 x0_bias: np.ndarray):
        self.model, self.free, self.held = model, free, held
        self.method, self.segment_len, self.n_fit = method, segment_len, n_fit
        self.sigma, self.fit_bias, self.fit_scale = sigma, fit_bias, fit_scale
        self.delay, self.x0_bias = delay, x0_bias
        self.y = model.y[:n_fit]
        self.evaluations = 0

    def params(self, s: np.ndarray) -> Params | None:
        scales = {**self.held, **dict(zip(self.free, np.asarray(s, float).tolist(),
                                          strict=True))}
        try:
            return self.model.nominal.scaled(scales)
        except ValueError:
            return None  # unphysical: penalized

    def residuals(self, sets: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Weighted residuals (P, T * m), and the projected bias and scale (P, m)."""
        params = [self.params(s) for s in sets]
        valid = [p for p in params if p is not None]
        T, m = self.y.shape
        r = np.full((len(sets), T, m), DIVERGED_RESIDUAL)
        bias, scale = np.zeros((len(sets), m)), np.zeros((len(sets), m))
        if valid:
            h = predict_raw(self.model, valid, self.delay, self.method, self.segment_len, 0,
                            self.n_fit, self.x0_bias)
            b, s = _project(h, self.y, self.fit_bias, self.fit_scale)
            self.evaluations += len(valid)
            j = 0
            for i, p in enumerate(params):
                if p is None:
                    continue
                pred = b[j] + (1.0 + s[j]) * h[j]
                ri = (self.y - pred) / self.sigma
                r[i] = np.where(np.isfinite(ri), ri, DIVERGED_RESIDUAL)
                bias[i], scale[i] = b[j], s[j]
                j += 1
        return r.reshape(len(sets), -1), bias, scale

    def fun(self, s: np.ndarray) -> np.ndarray:
        return self.residuals([s])[0][0]

    def jac(self, s: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Forward differences of the residual: one batch of ``1 + p`` parameter sets."""
        s = np.asarray(s, float)
        steps = FD_STEP * np.maximum(np.abs(s), 1.0)
        steps = np.where(s + steps > hi, -steps, steps)
        steps = np.where(s + steps < lo, np.abs(steps), steps)
        sets = [s] + [s + steps[i] * np.eye(len(s))[i] for i in range(len(s))]
        r, _, _ = self.residuals(sets)
        return ((r[1:] - r[0]) / steps[:, None]).T


def _sokal_bandwidth(g: np.ndarray) -> int:
    """Sokal's (1997) automatic window of each column's integrated autocorrelation time
    (the smallest M with M >= 5 tau(M)), the largest over the columns, at most T / 4."""
    T, p = g.shape
    bandwidth = 1
    for i in range(p):
        x = g[:, i] - g[:, i].mean()
        denom = float(x @ x)
        if denom <= 0:
            continue
        f = np.fft.rfft(x, 2 * T)
        acf = np.fft.irfft(f * np.conj(f))[:T] / denom
        tau = 1.0 + 2.0 * np.cumsum(acf[1:])
        window = np.flatnonzero(np.arange(1, T) >= 5.0 * tau)
        bandwidth = max(bandwidth, int(window[0]) + 1 if len(window) else T // 4)
    return int(min(bandwidth, max(T // 4, 1)))


def _bartlett(g: np.ndarray, bandwidth: int) -> np.ndarray:
    """``sum_l w_l Gamma_l`` with Bartlett weights ``1 - |l| / (L + 1)``, (p, p)."""
    T, p = g.shape
    G = np.fft.rfft(g, 2 * T, axis=0)
    S = np.zeros((p, p))
    weights = 1.0 - np.arange(bandwidth + 1) / (bandwidth + 1.0)
    for i in range(p):
        for k in range(i, p):
            cc = np.fft.irfft(G[:, i] * np.conj(G[:, k]), 2 * T)  # sum_t g_i[t+l] g_k[t]
            pos = cc[:bandwidth + 1]  # lags 0..L
            neg = cc[::-1][:bandwidth]  # lags -1..-L
            S[i, k] = S[k, i] = weights[0] * pos[0] + np.sum(weights[1:] * (pos[1:] + neg))
    return S


def _hac_inflation(J: np.ndarray, r: np.ndarray, T: int, m: int
                   ) -> tuple[np.ndarray, int, np.ndarray]:
    """Autocorrelation-consistent over white-noise variance ratios per parameter (>= 1), the
    bandwidth and the autocorrelation-consistent covariance.

    The sandwich ``H^-1 S H^-1`` (``H = J'J``) with the long-run covariance ``S`` of the
    per-sample scores ``g_t = J_t' r_t`` prewhitened (Andrews and Monahan 1992): a VAR(1)
    ``g_t = A g_(t-1) + u_t`` fitted by least squares (its eigenvalues held within
    :data:`MAX_PREWHITEN_EIGENVALUE`), the Newey and West (1987) Bartlett estimate of the
    whitened ``u``'s (the bandwidth by Sokal's window on them), recoloured
    ``S = (I - A)^-1 S_u (I - A)^-T``. Without the prewhitening a Bartlett window at the
    bandwidth of an AR(1) of ``rho = 0.8`` falls 20 % short of the long-run variance.

    ``J`` (T m, p), ``r`` (T m,) ordered sample-major.
    """
    p = J.shape[1]
    g = (J.reshape(T, m, p) * r.reshape(T, m, 1)).sum(axis=1)  # (T, p) scores per sample
    A = np.zeros((p, p))
    if T > 4 * p + 4:
        past, now = g[:-1], g[1:]
        A = np.linalg.lstsq(past, now, rcond=None)[0].T  # g_t ~ A g_(t-1)
        # Andrews and Monahan's adjustment: singular values capped (a near-unit root makes
        # (I - A)^-1 explode)
        U, sv, Vt = np.linalg.svd(A)
        A = U @ np.diag(np.minimum(sv, MAX_PREWHITEN_EIGENVALUE)) @ Vt
        u = np.vstack([g[:1], now - past @ A.T])
    else:
        u = g
    bandwidth = _sokal_bandwidth(u)
    S_u = _bartlett(u, bandwidth)
    recolour = np.linalg.inv(np.eye(p) - A)
    S = recolour @ S_u @ recolour.T
    H = J.T @ J
    Hinv = np.linalg.pinv(H)
    hac = Hinv @ S @ Hinv
    dof = max(J.shape[0] - p, 1)
    white = float(r @ r) / dof * np.diag(Hinv)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(white > 0, np.diag(hac) / white, 1.0)
    return np.maximum(ratio, 1.0), bandwidth, hac


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
    if not (isinstance(rig_cls, type) and issubclass(rig_cls, Rig)):
        raise IdentificationError(f"rig must be a testbed Rig subclass, got {rig_cls!r}")
    declared = dict(rig_cls.identifiable)
    if not declared:
        raise IdentificationError(f"rig {rig_cls.name!r} declares no identifiable parameters")
    if free is None:
        free = list(declared)
    elif isinstance(free, str) or not all(isinstance(f, str) for f in free):
        raise IdentificationError(f"free must be a list of parameter names, got {free!r}")
    free = list(dict.fromkeys(free))
    for name in free:
        if name not in declared:
            raise IdentificationError(f"unknown free parameter {name!r} for rig "
                                      f"{rig_cls.name!r}; expected one of {list(declared)}")
    if not free:
        raise IdentificationError("free must name at least one parameter")
    if not (isinstance(holdout, int | float) and not isinstance(holdout, bool)
            and 0.0 <= holdout < 0.9):
        raise IdentificationError(f"holdout must be a fraction in [0, 0.9), got {holdout!r}")
    if fit_scale not in (True, False, "declared"):
        raise IdentificationError(f"fit_scale must be True, False or 'declared', got "
                                  f"{fit_scale!r}")
    if method not in METHODS:
        raise IdentificationError(f"method must be one of {METHODS}, got {method!r}")
    if not (isinstance(segment_s, int | float) and np.isfinite(segment_s) and segment_s > 0):
        raise IdentificationError(f"segment_s must be a positive time in s, got {segment_s!r}")
    if max_delay is not None and (isinstance(max_delay, bool) or not isinstance(max_delay, int)
                                  or max_delay < 0):
        raise IdentificationError(f"max_delay must be whole samples >= 0, got {max_delay!r}")
    sysid = _sysid()

    model = RecordingModel(rig_cls, recording, profile=profile, options=options,
                           sensors=sensors, channels=channels)
    N, m = model.y.shape
    n_fit = int(math.floor(N * (1.0 - holdout)))
    segment_len = max(int(round(segment_s / model.dt_s)), 10)
    if n_fit < max(20, 2 * min(segment_len, n_fit)) and n_fit < 20:
        raise IdentificationError(f"recording {recording.source}: {n_fit} samples to fit; "
                                  "need at least 20")
    infos = model.infos
    steps = model.steps
    # a quantized position of a joint without limits (a yaw encoder) is known to a step: its
    # offset is fitted (a free joint's offset changes no dynamics); on a limited joint the
    # position against the stop is physics and stays as measured
    limited = {i for i, _, _ in model._ranges}
    fit_bias = np.array([i.bias or (steps[c] > 0 and i.direct_state is not None
                                    and i.direct_state < model.j
                                    and i.direct_state not in limited)
                         for c, i in enumerate(infos)])
    if fit_scale == "declared":  # the sensors' declared sensitivity errors
        fit_scale_v = np.array([i.scale for i in infos])
    else:
        fit_scale_v = np.full(m, bool(fit_scale)) & np.array([i.direct_state is None
                                                              for i in infos])
    max_delays = np.array([i.max_delay if max_delay is None else max_delay for i in infos])

    # sensor model from a still segment
    still = still_segment(model.u, model.y, model.dt_s, steps, n_fit)
    sigma = np.array([noise_level(model.y[:n_fit, c], steps[c]) for c in range(m)])
    still_bias = np.full(m, np.nan)
    still_std = np.full(m, np.nan)
    if still is not None:
        a, b = still
        x_rest = model.initial_states(np.array([a]), np.zeros(m), np.zeros(m, int))[0]
        x_rest[model.j:] = 0.0
        from testbed.identify.channels import measure_noise_free

        rest = measure_noise_free(infos, x_rest[None], model.u_prev[a:a + 1], np.zeros(1))[0]
        still_bias, still_std, _ = still_statistics(model.y[a:b], rest, model.dt_s)
        still_bias = np.where(fit_bias, still_bias, 0.0)
        sigma = np.maximum(sigma, np.maximum(still_std, steps / np.sqrt(12.0)))
    x0_bias = np.where(np.isfinite(still_bias) & model.x0_bias_mask, still_bias, 0.0)
    # with a still segment the initial states are read with its biases, fixed: the fit's
    # own bias and the states read with it could feed each other (a wrong roll from a
    # wrongly biased accelerometer); without one they follow the fit's rounds
    x0_fixed = still is not None
    # a quantized channel's error is a function of the signal between level changes (no new
    # information while it stays on a level): its samples count as many as its changes
    for c in np.flatnonzero(steps > 0):
        changes = int(np.count_nonzero(np.diff(model.y[:n_fit, c])))
        sigma[c] *= math.sqrt(n_fit / max(changes, 1))

    bounds = {n: declared[n] for n in free}
    pdict = sysid.ParameterDict()
    for name in free:
        lo, hi = bounds[name]
        pdict.add(sysid.Parameter(name, 1.0, lo, hi))

    def choose_delays(s_vec: np.ndarray, meth: str, x0b: np.ndarray) -> np.ndarray:
        """Each channel's delay: the candidate with the least projected residual."""
        delay = np.zeros(m, int)
        if not np.any(max_delays > 0):
            return delay
        problem = _Problem(model, list(pdict.get_non_frozen_parameter_names()), held, meth,
                           segment_len, n_fit, sigma, fit_bias, fit_scale_v, delay, x0b)
        params = problem.params(s_vec)
        h0 = predict_raw(model, [params], np.zeros(m, int), meth, segment_len, 0, n_fit, x0b)[0]
        y = model.y[:n_fit]
        for c in np.flatnonzero(max_delays > 0):
            best = None
            for d in range(int(max_delays[c]) + 1):
                hd = np.concatenate([np.full(d, h0[0, c]), h0[:n_fit - d, c]])
                b, s = _project(hd[None, :, None], y[:, c:c + 1], fit_bias[c:c + 1],
                                fit_scale_v[c:c + 1])
                err = float(np.sum((y[:, c] - b[0, 0] - (1 + s[0, 0]) * hd) ** 2))
                if best is None or err < best[0]:
                    best = (err, d)
            delay[c] = best[1]
        return delay

    held: dict[str, float] = {}
    timings: dict[str, float] = {}

    # one rollout of the fitted part (the unit of the timings)
    t0 = time.perf_counter()
    nominal_set = [model.nominal]
    predict_raw(model, nominal_set, np.zeros(m, int), "output-error", segment_len, 0,
                           n_fit, x0_bias)
    timings["rollout_s"] = time.perf_counter() - t0

    # the method
    # the declared delays to start with; searched again at each round's estimate
    delay = np.minimum([i.delay for i in infos], max_delays).astype(int)
    declared_delay = delay.copy()

    def rms(h: np.ndarray) -> float:
        if not np.all(np.isfinite(h)):
            return math.inf
        b, s = _project(h, model.y[:n_fit], fit_bias, fit_scale_v)
        return float(np.sqrt(np.mean(((model.y[:n_fit] - b[0] - (1 + s[0]) * h[0])
                                      / sigma) ** 2)))

    def drift_ratio(params: Params) -> float:
        """The free run's residual over the multiple-shooting one (one batch each)."""
        ms = predict_raw(model, [params], delay, "multiple-shooting", segment_len, 0, n_fit,
                         x0_bias)
        oe = predict_raw(model, [params], delay, "output-error", segment_len, 0, n_fit,
                         x0_bias)
        return rms(oe) / max(rms(ms), 1e-300)

    polish = nominal_follows = False
    if method == "auto":
        # multiple shooting first (its short segments keep the fit out of the free run's
        # local minima: a frequency far off, a drift), then output error from its estimate,
        # kept where its free run follows the recording (no errors in variables)
        ratio = drift_ratio(model.nominal)
        chosen, polish = "multiple-shooting", True
        nominal_follows = ratio <= DRIFT_RATIO
        reason = (f"auto: the nominal free run's residual is {ratio:.3g} times the "
                  f"{segment_s:g}-s multiple-shooting residual "
                  f"({'the free run drifts' if ratio > DRIFT_RATIO else 'no drift'}); fitted "
                  "by multiple shooting")
    else:
        chosen, reason = method, "chosen by the caller"

    # fit rounds, then hold the undetermined parameters at nominal and refit
    s_vec = np.ones(len(free))
    flagged: dict[str, str] = {}
    t0 = time.perf_counter()
    rounds = 0
    while True:
        names = [n for n in free if n not in flagged]
        if not names:
            break
        s_cur = np.array([s_vec[free.index(n)] for n in names])
        lo = np.array([bounds[n][0] for n in names])
        hi = np.array([bounds[n][1] for n in names])
        s_cur = np.clip(s_cur, lo + 1e-9, hi - 1e-9)
        s_start = s_cur.copy()
        while True:
            for _ in range(3):  # rounds: delays and the initial states' bias follow the fit
                rounds += 1
                problem = _Problem(model, names, held, chosen, segment_len, n_fit, sigma,
                                   fit_bias, fit_scale_v, delay, x0_bias)
                sol = scipy.optimize.least_squares(
                    problem.fun, s_cur, jac=lambda s, p=problem, a=lo, b=hi: p.jac(s, a, b),
                    bounds=(lo, hi), method="trf", x_scale=1.0, max_nfev=max_iterations,
                    xtol=1e-10, ftol=1e-12, gtol=1e-10)
                s_cur = sol.x
                last = (sol, chosen, delay, x0_bias)
                _, bias_now, _ = problem.residuals([s_cur])
                new_delay = (choose_delays(s_cur, chosen, x0_bias) if np.any(max_delays)
                             else delay)
                new_x0_bias = (x0_bias if x0_fixed
                               else np.where(model.x0_bias_mask, bias_now[0], 0.0))
                moved = np.max(np.abs(new_x0_bias - x0_bias) / sigma)
                if np.array_equal(new_delay, delay) and moved < 0.05:
                    break  # (the solve's own delays and bias kept: its Jacobian is final)
                delay, x0_bias = new_delay, new_x0_bias
            if not polish:
                break
            # multiple shooting's initial states carry the measurement noise into the fit
            # (errors in variables): output error from its estimate is consistent where the
            # free run then follows the recording as well as the segments do
            polish = False
            ms_rms = rms(predict_raw(model, [problem.params(s_cur)], delay, chosen,
                                     segment_len, 0, n_fit, x0_bias))
            trial = _Problem(model, names, held, "output-error", segment_len, n_fit, sigma,
                             fit_bias, fit_scale_v, delay, x0_bias)
            sol = scipy.optimize.least_squares(
                trial.fun, s_cur, jac=lambda s, p=trial, a=lo, b=hi: p.jac(s, a, b),
                bounds=(lo, hi), method="trf", x_scale=1.0, max_nfev=max_iterations,
                xtol=1e-10, ftol=1e-12, gtol=1e-10)
            start_note, polish_delay = "its estimate", delay
            if nominal_follows:  # the free run from the start may find a better minimum
                # (from the declared delays: the segments' rounds may have moved them to a
                # local minimum)
                start = _Problem(model, names, held, "output-error", segment_len, n_fit, sigma,
                                 fit_bias, fit_scale_v, declared_delay, x0_bias)
                other = scipy.optimize.least_squares(
                    start.fun, s_start, jac=lambda s, p=start, a=lo, b=hi: p.jac(s, a, b),
                    bounds=(lo, hi), method="trf", x_scale=1.0, max_nfev=max_iterations,
                    xtol=1e-10, ftol=1e-12, gtol=1e-10)
                if other.cost < sol.cost:
                    sol, start_note = other, "nominal (a lower residual than from its estimate)"
                    polish_delay = declared_delay
            oe_rms = float(np.sqrt(np.mean(sol.fun ** 2)))
            after = oe_rms / max(ms_rms, 1e-300)
            if after <= POLISH_RATIO:
                chosen, s_cur, delay = "output-error", sol.x, polish_delay
                last = (sol, chosen, delay, x0_bias)
                reason += (f", then output error from {start_note} (its residual "
                           f"{after:.3g} times the segments', within {POLISH_RATIO:g}: used, "
                           "no errors in variables)")
                # its rounds again where the delays (searched at the multiple-shooting
                # estimate) or the initial states' bias can follow the output-error fit (a
                # vehicle unit kept a roll-rate delay one sample short, its estimates 18 %
                # off)
                if np.any(max_delays > 0) or not x0_fixed:
                    continue
                break
            reason += (f"; output error from its estimate does not follow the recording "
                       f"(residual {after:.3g} times the segments', above "
                       f"{POLISH_RATIO:g}): not used")
            break
        for n, v in zip(names, s_cur, strict=True):
            s_vec[free.index(n)] = v
        problem = _Problem(model, names, held, chosen, segment_len, n_fit, sigma, fit_bias,
                           fit_scale_v, delay, x0_bias)
        sol_last, method_last, delay_last, bias_last = last
        if (method_last == chosen and delay_last is delay and bias_last is x0_bias
                and np.array_equal(sol_last.x, s_cur)):
            r_star, J = sol_last.fun, sol_last.jac  # the solve's own, at its solution
        else:
            r_star, J = problem.fun(s_cur), problem.jac(s_cur, lo, hi)
        _, half = sysid.calculate_intervals([r_star], J)
        inflation, bandwidth, hac = _hac_inflation(J, r_star, n_fit, m)
        half = np.asarray(half, float) * np.sqrt(inflation)
        with np.errstate(divide="ignore", invalid="ignore"):
            sd = np.sqrt(np.diag(hac))
            corr = hac / np.outer(sd, sd)
        corr = np.where(np.isfinite(corr), corr, 0.0)
        np.fill_diagonal(corr, 1.0)
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
        if not candidates:
            break
        rel = {n: (half[names.index(n)] / abs(s_cur[names.index(n)])
                   if np.isfinite(half[names.index(n)]) else math.inf) for n in candidates}
        worst_name = max(rel, key=lambda n: (rel[n], n))
        flagged[worst_name] = candidates[worst_name]
        held[worst_name] = 1.0
        s_vec[free.index(worst_name)] = 1.0
        pdict[worst_name].frozen = True
    timings["fit_s"] = time.perf_counter() - t0
    names = [n for n in free if n not in flagged]

    # results
    final_scales = {**held, **{n: float(s_vec[free.index(n)]) for n in names}}
    params = model.nominal.scaled(final_scales)
    if names:
        problem = _Problem(model, names, held, chosen, segment_len, n_fit, sigma, fit_bias,
                           fit_scale_v, delay, x0_bias)
        _, bias_fit, scale_fit = problem.residuals([np.array([final_scales[n]
                                                              for n in names])])
        bias_fit, scale_fit = bias_fit[0], scale_fit[0]
    else:
        bias_fit, scale_fit = np.where(fit_bias, x0_bias, 0.0), np.zeros(m)
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

    estimates: dict[str, ParameterEstimate] = {}
    names_index = {n: i for i, n in enumerate(names)}
    for name in free:
        nominal = float(getattr(model.nominal, name))
        if name in flagged:
            estimates[name] = ParameterEstimate(name, nominal, None, nominal, 1.0, False,
                                                flagged[name])
            continue
        i = names_index[name]
        s = float(s_vec[free.index(name)])
        lo_hi = sorted(((s - half[i]) * nominal, (s + half[i]) * nominal))
        estimates[name] = ParameterEstimate(name, s * nominal, (float(lo_hi[0]),
                                                                float(lo_hi[1])),
                                            nominal, s, True)
    residual_std = np.nanstd(model.y[:n_fit] - pred_fit, axis=0)
    sensors_out = {}
    for c, info in enumerate(infos):
        noise_std = float(still_std[c]) if np.isfinite(still_std[c]) else float(residual_std[c])
        sensors_out[info.name] = {
            "unit": info.unit, "bias": float(bias_fit[c]), "bias_fitted": bool(fit_bias[c]),
            "scale": float(scale_fit[c]), "scale_fitted": bool(fit_scale_v[c]),
            "delay_samples": int(delay[c]), "delay_s": float(delay[c] * model.dt_s),
            "initial_state_bias": float(x0_bias[c]),
            "noise_std": noise_std, "noise_density": noise_std * math.sqrt(model.dt_s),
            "noise_from": "still segment" if np.isfinite(still_std[c]) else "fit residual",
            "quantization_step": float(steps[c]),
            "still_bias": None if not np.isfinite(still_bias[c]) else float(still_bias[c]),
        }
    timings["total_s"] = time.perf_counter() - t_start
    timings["ratio_to_rollout"] = timings["total_s"] / max(timings["rollout_s"], 1e-12)
    timings["member_steps"] = float(model.rollouts)
    timings["rounds"] = float(rounds)
    timings["hac_bandwidth_samples"] = float(bandwidth) if names else 0.0
    still_s = None if still is None else (float(model.recording.time_s[still[0]]),
                                          float(model.recording.time_s[still[1] - 1]))
    return Identification(
        rig=rig_cls.name, profile=profile, options=dict(model.options), parameters=estimates,
        correlation=corr if names else np.zeros((0, 0)), correlation_names=tuple(names),
        sensors=sensors_out, fit_percent=fits, holdout_fit_percent=holdout_fit,
        free_run_fit_percent=free_fits, method=chosen, method_reason=reason,
        segment_s=segment_len * model.dt_s, still_segment_s=still_s,
        recording_sha256=recording.sha256, recording_source=recording.source,
        dt_s=model.dt_s, n_fit=n_fit, timings=timings, time_s=np.asarray(recording.time_s),
        measured=model.y, predicted=predicted, channels=model.names,
        units=tuple(i.unit for i in infos), holdout=float(holdout),
        sensor_preset=sensors if isinstance(sensors, str) else
        ("" if sensors is None else "<custom>"))


def sensor_model_of(identification: Identification, names: tuple[str, ...]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(bias, scale, delay)`` vectors of ``names`` from an identification's sensors."""
    sensors = identification.sensors
    return sensor_vectors(names, {n: sensors[n]["bias"] for n in names if n in sensors},
                          {n: sensors[n]["scale"] for n in names if n in sensors},
                          {n: sensors[n]["delay_samples"] for n in names if n in sensors})
