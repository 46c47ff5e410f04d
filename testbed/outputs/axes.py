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
