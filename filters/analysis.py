"""Post-processing of estimator runs: performance measures from sampled trajectories.

Times are in seconds; arrays are ``float64``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.integrate import cumulative_trapezoid

from filters._linalg import FloatArray

__all__ = ["noise_output_ratio"]


def noise_output_ratio(
    t: npt.ArrayLike,
    z_err: npt.ArrayLike,
    w: npt.ArrayLike,
    x0: npt.ArrayLike,
    R: npt.ArrayLike,
) -> FloatArray:
    """Running noise-output ratio ``T`` of seed-000 (attenuation condition (6)).

    ``T(t) = ||z - L m||_2 / (||w||_2^2 + x0^T R x0)^(1/2)`` with
    ``||f||_2^2 = int_{t[0]}^{t} f^T f ds``, evaluated at every sample time. The paper's
    filter guarantees ``T < gamma`` for the mean (noise-free) trajectory.

    Parameters
    ----------
    t : array_like, shape (N,)
        Strictly increasing sample times, s.
    z_err : array_like, shape (N, q) or (N,)
        Output estimation error ``z - L m = L (x - m)`` at the sample times.
    w : array_like, shape (N, s) or (N,)
        Deterministic disturbance at the sample times.
    x0 : array_like, shape (n,)
        Initial state weighted in the denominator; seed-000's (6) uses ``E[x(t0)]``.
    R : array_like, shape (n, n)
        Weight of ``x0`` (the ``R`` of (6), ``S(t0) = R^-1``).

    Returns
    -------
    numpy.ndarray, shape (N,)
        ``T`` over ``[t[0], t[k]]`` for each ``k``. Where the denominator is 0 the ratio
        is 0 if the numerator is 0 as well, ``inf`` otherwise.

    Raises
    ------
    ValueError
        On inconsistent shapes, non-finite input or non-increasing ``t``.

    Notes
    -----
    Both integrals use the trapezoid rule on the given samples
    (:func:`scipy.integrate.cumulative_trapezoid`), so ``T(t[0]) = 0`` unless
    ``x0^T R x0 = 0``.
    """
    ts = np.asarray(t, dtype=np.float64)
    if ts.ndim != 1 or ts.size < 1:
        raise ValueError(f"t must have shape (N,), N >= 1, got shape {ts.shape}")
    N = ts.size

    def samples(name: str, value: npt.ArrayLike) -> FloatArray:
        arr = np.asarray(value, dtype=np.float64)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[0] != N:
            raise ValueError(f"{name} must have shape ({N},) or ({N}, d), got shape "
                             f"{np.shape(value)}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} must be finite")
        return arr

    ze = samples("z_err", z_err)
    ws = samples("w", w)
    if not np.isfinite(ts).all() or np.any(np.diff(ts) <= 0.0):
        raise ValueError("t must be finite and strictly increasing")
    x = np.asarray(x0, dtype=np.float64)
    Rm = np.asarray(R, dtype=np.float64)
    if x.ndim != 1 or Rm.shape != (x.size, x.size):
        raise ValueError(f"x0 must have shape (n,) and R shape (n, n), got {x.shape} and "
                         f"{Rm.shape}")
    weight = float(x @ Rm @ x)
    if not np.isfinite(weight):
        raise ValueError("x0 and R must be finite")
    num = cumulative_trapezoid(np.einsum("ij,ij->i", ze, ze), ts, initial=0.0)
    den = cumulative_trapezoid(np.einsum("ij,ij->i", ws, ws), ts, initial=0.0) + weight
    out = np.full(N, np.inf)
    pos = den > 0.0
    out[pos] = np.sqrt(num[pos] / den[pos])
    out[~pos & (num == 0.0)] = 0.0
    return out
