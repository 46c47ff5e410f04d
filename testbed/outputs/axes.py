"""Default ranges of the error axes, shared by the PNG plots and the Rerun layout.

An estimation error usually has a transient (a large initial covariance, a filter
converging) and a steady state that is orders of magnitude smaller; an axis fitted to the
whole run shows the steady state as a flat line at zero. The default range therefore
fits the **second half of the run**; the transient stays reachable by zooming out
(Rerun) and is marked where it leaves the axis (PNG).
"""

from __future__ import annotations

import numpy as np

#: Fraction of the run, from its start, left out of the steady-state range.
TRANSIENT_FRACTION = 0.5


def steady_state_limit(t_s: np.ndarray, error: np.ndarray,
                       bound: np.ndarray | None = None) -> float:
    """Half-height of a symmetric axis showing the error's steady state.

    ``1.15 * max(99.5th percentile of |error|, 95th percentile of bound)`` over the samples
    with ``t >= t0 + TRANSIENT_FRACTION * (t_end - t0)``: percentiles, so that one
    outlier does not flatten the rest either.

    Parameters
    ----------
    t_s : ndarray, shape (T,)
        Sample times.
    error : ndarray, shape (T,)
        Estimation error (NaN samples are ignored).
    bound : ndarray, shape (T,), optional
        The filter's 3-sigma bound.

    Returns
    -------
    float
        A positive, finite limit (1.0 when there is nothing finite to fit).
    """
    t = np.asarray(t_s, dtype=float)
    if t.size == 0:
        return 1.0
    late = t >= t[0] + TRANSIENT_FRACTION * (t[-1] - t[0])
    candidates = []
    err = np.abs(np.asarray(error, dtype=float)[late])
    if np.any(np.isfinite(err)):
        candidates.append(np.nanpercentile(err, 99.5))
    if bound is not None:
        b = np.asarray(bound, dtype=float)[late]
        if np.any(np.isfinite(b)):
            candidates.append(np.nanpercentile(b, 95.0))
    lim = 1.15 * max(candidates, default=1.0)
    return float(lim) if np.isfinite(lim) and lim > 0.0 else 1.0


def nice_limit(value: float) -> float:
    """The smallest of 1, 2, 2.5, 5 times a power of ten that is ``>= value`` (> 0), so
    that an axis ``[-limit, limit]`` ends on a round number (a readable scale)."""
    value = float(value)
    if not (np.isfinite(value) and value > 0.0):
        return 1.0
    power = 10.0 ** np.floor(np.log10(value))
    for step in (1.0, 2.0, 2.5, 5.0, 10.0):
        if step * power >= value * (1.0 - 1e-12):
            return float(step * power)
    return float(10.0 * power)  # pragma: no cover - the loop ends at 10


#: An error view spans ``+-ERROR_AXIS_MARGIN * nice_limit(...)``: its end ticks (the round
#: limit) then sit inside the view, where the viewer prints their labels.
ERROR_AXIS_MARGIN = 1.1


def held_setpoint(setpoint: np.ndarray) -> np.ndarray:
    """The reference in force over each interval ``[t_k, t_k+1)``: row ``T-1`` (used by no
    control step: when the run ends on a switching time it is the NEXT setpoint) replaced
    by row ``T-2``. Plots draw it with ``drawstyle="steps-post"``; recordings log it so, so
    that no sample shows a reference past the run's end."""
    held = np.array(setpoint, dtype=float, copy=True)
    if len(held) >= 2:
        held[-1] = held[-2]
    return held


#: Legend corners of a Rerun time-series view, in order of preference.
CORNERS = ("RightBottom", "RightTop", "LeftTop", "LeftBottom")
#: Fraction of a view's width and height a legend covers, per entry (height): measured on
#: the web viewer's 2-column grid at 1800 x 1100 px (a view about 130 px high, an entry
#: 18 px), rounded up.
LEGEND_WIDTH, LEGEND_ENTRY_HEIGHT, LEGEND_BASE_HEIGHT = 0.4, 0.15, 0.08


def legend_height(entries: int) -> float:
    """Fraction of a view's height a legend of ``entries`` entries covers (at most 0.85)."""
    return min(0.85, LEGEND_BASE_HEIGHT + LEGEND_ENTRY_HEIGHT * max(int(entries), 1))


def legend_corner(t_s: np.ndarray, series: list[np.ndarray], entries: int,
                  y_range: tuple[float, float] | None = None,
                  max_covered: float = 0.02) -> str | None:
    """The corner of a plot whose legend box covers the fewest samples, or None (hide the
    legend) when every corner covers more than ``max_covered`` of them.

    Parameters
    ----------
    t_s : ndarray, shape (T,)
        The time axis (the view spans ``t_s[0] .. t_s[-1]``).
    series : list of ndarray, shape (T,) each
        The plotted values.
    entries : int
        Legend entries (the box's height grows with them).
    y_range : (float, float), optional
        The view's value range; default: the data's range (Rerun's automatic one).
    max_covered : float
        Largest acceptable fraction of covered samples.

    Returns
    -------
    str or None
        One of :data:`CORNERS` (ties go to the earlier one), or None.
    """
    t = np.asarray(t_s, dtype=float)
    ys = [np.asarray(y, dtype=float) for y in series if len(y) == len(t)]
    if not ys or len(t) < 2 or t[-1] <= t[0]:
        return CORNERS[0]
    y = np.concatenate(ys)
    x = np.tile((t - t[0]) / (t[-1] - t[0]), len(ys))
    finite = np.isfinite(y)
    x, y = x[finite], y[finite]
    if y.size == 0:
        return CORNERS[0]
    lo, hi = (float(y.min()), float(y.max())) if y_range is None else map(float, y_range)
    span = hi - lo if hi > lo else 1.0
    v = (y - lo) / span
    inside = (v >= 0.0) & (v <= 1.0)
    x, v = x[inside], v[inside]
    h = legend_height(entries)
    w = LEGEND_WIDTH
    boxes = {"RightBottom": (x >= 1 - w) & (v <= h), "RightTop": (x >= 1 - w) & (v >= 1 - h),
             "LeftTop": (x <= w) & (v >= 1 - h), "LeftBottom": (x <= w) & (v <= h)}
    covered = {c: float(boxes[c].mean()) if x.size else 0.0 for c in CORNERS}
    best = min(CORNERS, key=lambda c: (covered[c], CORNERS.index(c)))
    return best if covered[best] <= max_covered else None
