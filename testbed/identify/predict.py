"""The prediction of a recording's channels and the least-squares problem of one fit round.

:func:`predict_channels` simulates P parameter sets with the recording's inputs (output error
or multiple shooting) and applies each channel's bias and scale; :func:`project` eliminates
bias and scale in closed form (variable projection); :class:`Problem` maps the free scale
factors to the weighted residual and its forward-difference Jacobian (one batch).
"""

from __future__ import annotations

import numpy as np

from testbed.identify.simulate import RecordingModel
from testbed.rigs.base import Params

#: Relative forward-difference step of the Jacobian (scale factors).
FD_STEP = 1e-5
#: Residual (in noise levels) given to a diverged prediction.
DIVERGED_RESIDUAL = 1e3


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


def project(h: np.ndarray, y: np.ndarray, fit_bias: np.ndarray, fit_scale: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares bias and scale per set and channel for ``y ~ b + (1 + s) h``.

    Parameters
    ----------
    h : ndarray, shape (P, T, m)
        Raw predictions of P parameter sets (:func:`predict_raw`).
    y : ndarray, shape (T, m)
        The recorded channels.
    fit_bias, fit_scale : ndarray of bool, shape (m,)
        The channels whose bias, scale are fitted (0 elsewhere).

    Returns
    -------
    bias, scale : ndarray, shape (P, m)
        In the channels' units; ``scale`` a relative error (a set whose prediction is not
        finite keeps zeros).
    """
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


class Problem:
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
            b, s = project(h, self.y, self.fit_bias, self.fit_scale)
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

