"""Simulation of a linear stochastic plant ``dx = (A x + B u + G w) dt + b dW``.

Used by the paper reproductions, where the plant is the paper's own linear model rather than
the MuJoCo rig.

Integration: classical RK4 for the drift (``u(t)`` and ``w(t)`` evaluated at the RK4 stage
times, so smooth signals keep order 4), plus the Wiener increment ``b dW`` added once per
step (for additive noise this scheme has strong order 1). With ``rng=None`` the noise is
left out and the result is the mean trajectory ``E[x(t)]`` that the bound (6) of
Basin, Elvira-Ceja & Sanchez (n.d.) is about (see docs/references.md).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def simulate_linear(A: np.ndarray, B: np.ndarray, G: np.ndarray, b: np.ndarray,
                    x0: np.ndarray, u: Callable[[float], np.ndarray],
                    w: Callable[[float], np.ndarray], dt_s: float, n_steps: int,
                    rng: np.random.Generator | None = None,
                    output: Callable[[float, np.ndarray], np.ndarray] | None = None,
                    ) -> tuple[np.ndarray, ...]:
    """Integrate the plant on a uniform grid.

    With ``output``, the interval averages ``(1/dt) int_{t_k}^{t_k+1} output(t, x) dt`` are
    integrated along with the state (same RK4 stages), as a continuous observation
    ``dy = output dt`` sampled by an integrate-and-dump converter would deliver them.

    Parameters
    ----------
    A : ndarray, shape (n, n)
    B : ndarray, shape (n, k)
    G : ndarray, shape (n, s)
    b : ndarray, shape (n, p)
        Noise input; ``W`` is a standard Wiener process (unit intensity).
    x0 : ndarray, shape (n,)
    u : callable ``t_s -> (k,)``
    w : callable ``t_s -> (s,)``
    dt_s : float
        Step in s.
    n_steps : int
    rng : numpy.random.Generator, optional
        Source of the Wiener increments; None gives the noise-free (mean) trajectory.
    output : callable ``(t_s, x) -> (q,)``, optional
        Observation whose interval averages are returned.

    Returns
    -------
    t_s : ndarray, shape (n_steps + 1,)
    x : ndarray, shape (n_steps + 1, n)
    y_avg : ndarray, shape (n_steps, q)
        Only with ``output``: row ``k`` is the average over ``[t_k, t_k+1]``.
    """
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be a positive step in s, got {dt_s}")
    if int(n_steps) != n_steps or n_steps < 1:
        raise ValueError(f"n_steps must be a positive integer, got {n_steps}")
    x = np.array(x0, dtype=float)
    if x.shape != (A.shape[0],):
        raise ValueError(f"x0 must have shape ({A.shape[0]},), got {x.shape}")

    n = x.size

    def f(t: float, z: np.ndarray) -> np.ndarray:
        state = z[:n]
        dx = A @ state + B @ u(t) + G @ w(t)
        return dx if output is None else np.concatenate([dx, output(t, state)])

    t_grid = np.arange(n_steps + 1) * dt_s
    out = np.empty((n_steps + 1, n))
    out[0] = x
    y_avg = None if output is None else np.empty((n_steps, np.size(output(0.0, x))))
    sqrt_dt = np.sqrt(dt_s)
    h = dt_s
    for k in range(n_steps):
        t = t_grid[k]
        z = x if output is None else np.concatenate([x, np.zeros(y_avg.shape[1])])
        k1 = f(t, z)
        k2 = f(t + h / 2, z + h / 2 * k1)
        k3 = f(t + h / 2, z + h / 2 * k2)
        k4 = f(t + h, z + h * k3)
        z = z + h / 6 * (k1 + 2 * (k2 + k3) + k4)
        x = z[:n]
        if y_avg is not None:
            y_avg[k] = z[n:] / h
        if rng is not None:
            x = x + b @ rng.standard_normal(b.shape[1]) * sqrt_dt
        if not np.isfinite(x).all():
            raise FloatingPointError(f"plant state became non-finite at t = {t + h:.6g} s")
        out[k + 1] = x
    return (t_grid, out) if y_avg is None else (t_grid, out, y_avg)
