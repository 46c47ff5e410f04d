"""The sensor model from a recording: a still segment's bias and noise, quantization steps,
and each channel's noise level for weighting the residuals.

A still segment is the longest stretch where every input is constant and every channel is
still: its spread is no more than three times its sample-to-sample noise (a moving signal
spreads far more than it jitters) plus one quantization step. Its first
:data:`SETTLE_S` is dropped (the rig settling after the last input change). There:

- ``still_bias``: the channel's mean less its noise-free value at the resting state (the
  positions from the channels measuring them, rates zero): a gyro's offset, an
  accelerometer's offset at a known angle; 0 for a channel that defines its state (an
  encoder);
- ``noise_std``: the standard deviation about a straight line, channel units per sample;
  ``noise_density = noise_std sqrt(dt)``, units/sqrt(Hz);
- the quantization step is read from the whole recording: the smallest difference between
  distinct recorded values, kept when every other difference is a whole multiple of it
  (the greatest common step) and the grid is coarse for the signal (values repeat, or the
  median change per sample is a few steps: a fine encoder on a fast axis), else 0 (not
  quantized).
"""

from __future__ import annotations

import numpy as np

#: Shortest still segment used, s.
MIN_STILL_S = 0.2
#: Start of a still segment dropped as settling, s.
SETTLE_S = 0.1
#: Largest departure of a value difference from a whole number of steps (in steps) on a grid.
MAX_GRID_TOLERANCE = 0.05
#: A channel whose values are mostly distinct is still quantized when its median change
#: per sample is at most this many steps (a fine encoder on a fast axis: the helicopter's
#: 8192-count yaw encoder changes level at 70 % of its samples).
MAX_STEPS_PER_SAMPLE = 8.0


def quantization_step(y: np.ndarray, rel_tol: float = 1e-6) -> float:
    """The quantization step of a channel (0 when its values are not on a grid).

    Parameters
    ----------
    y : ndarray, shape (N,)

    Returns
    -------
    float
        The greatest common step of the distinct values, or 0.
    """
    values = np.unique(np.asarray(y, float))
    if len(values) < 3:
        return 0.0
    steps = np.diff(values)
    scale = max(float(np.max(np.abs(values))), 1e-300)
    steps = steps[steps > rel_tol * scale]
    if not len(steps):
        return 0.0
    q = float(np.min(steps))
    ratio = steps / q
    tol = min(max(1e-3, 1e3 * rel_tol * scale / q), MAX_GRID_TOLERANCE)
    on_grid = bool(np.all(np.abs(ratio - np.round(ratio)) < tol))
    moves = np.abs(np.diff(np.asarray(y, float)))
    moves = moves[moves > rel_tol * scale]
    # a grid read often (values repeat), or a fine encoder moving a few steps per sample
    # (most values distinct, yet every sample-to-sample change a small multiple of the step)
    coarse = len(values) < 0.5 * len(y) or (
        len(values) < len(y) and len(moves) > 0
        and float(np.median(moves)) <= MAX_STEPS_PER_SAMPLE * q)
    if on_grid and coarse:
        # the grid's step: refine from the spread of all values (rounding in the file)
        span = values - values[0]
        counts = np.round(span / q)
        if counts[-1] > 0:
            q = float(np.sum(span * counts) / np.sum(counts * counts))
        return q
    return 0.0


def noise_level(y: np.ndarray, step: float) -> float:
    """White-noise standard deviation of a moving channel from its second differences
    (``var(d2 y) = 6 sigma^2`` for white noise), at least the quantization's
    ``step / sqrt(12)``; a floor of ``1e-9 (1 + max|y|)``."""
    d2 = np.diff(np.asarray(y, float), 2)
    sigma = float(np.std(d2) / np.sqrt(6.0)) if len(d2) else 0.0
    return max(sigma, step / np.sqrt(12.0), 1e-9 * (1.0 + float(np.max(np.abs(y)))))


def still_segment(u: np.ndarray, y: np.ndarray, dt_s: float, steps: np.ndarray,
                  stop: int) -> tuple[int, int] | None:
    """The longest still segment ``(start, stop)`` in samples ``[0, stop)``, or None.

    Parameters
    ----------
    u : ndarray, shape (N, nu)
    y : ndarray, shape (N, m)
    dt_s : float
    steps : ndarray, shape (m,)
        Quantization steps per channel (0: none).
    stop : int
        Only samples before it are searched (the fitted part).
    """
    constant = np.all(np.diff(u[:stop], axis=0) == 0.0, axis=1)  # u[k+1] == u[k]
    settle = int(round(SETTLE_S / dt_s))
    need = max(int(round(MIN_STILL_S / dt_s)), 10)
    best = None
    k = 0
    while k < len(constant):
        if not constant[k]:
            k += 1
            continue
        j = k
        while j < len(constant) and constant[j]:
            j += 1
        a, b = k + 1 + settle, j + 1  # the samples after the change, past settling
        if b - a >= need and (best is None or b - a > best[1] - best[0]):
            if _is_still(y[a:b], steps):
                best = (a, b)
        k = j
    return best


def still_start(u: np.ndarray, y: np.ndarray, steps: np.ndarray) -> tuple[int, int] | None:
    """``(0, stop)`` when the recording starts at rest: its inputs constant until ``stop``
    (at least 10 samples) and its channels still there (:func:`still_segment`'s test);
    else None."""
    changed = np.flatnonzero(np.any(np.diff(u, axis=0) != 0.0, axis=1))
    stop = int(changed[0]) + 1 if len(changed) else len(u)
    if stop < 10 or not _is_still(y[:stop], steps):
        return None
    return (0, stop)


def _is_still(seg: np.ndarray, steps: np.ndarray) -> bool:
    jitter = np.std(np.diff(seg, axis=0), axis=0) / np.sqrt(2.0)
    spread = np.std(seg, axis=0)
    return bool(np.all(spread <= 3.0 * jitter + steps + 1e-12))


def still_statistics(seg: np.ndarray, rest: np.ndarray, dt_s: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(still_bias, noise_std, noise_density)`` per channel of a still segment.

    Parameters
    ----------
    seg : ndarray, shape (L, m)
    rest : ndarray, shape (m,)
        The channels' noise-free values at the resting state.
    dt_s : float
    """
    t = np.arange(len(seg), dtype=float)
    V = np.column_stack([np.ones_like(t), t - t.mean()])
    coef, *_ = np.linalg.lstsq(V, seg, rcond=None)
    resid = seg - V @ coef
    std = np.sqrt(np.sum(resid**2, axis=0) / max(len(seg) - 2, 1))
    return seg.mean(axis=0) - rest, std, std * np.sqrt(dt_s)
