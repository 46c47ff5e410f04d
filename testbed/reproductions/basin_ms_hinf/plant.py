"""A linear stochastic plant ``dx = (A x + B u + G w) dt + b dW`` (the paper's own linear
model of Basin, Elvira-Ceja & Sanchez (n.d.), not the MuJoCo rig; see docs/references.md).

Integration: classical RK4 for the drift (``u(t)`` and ``w(t)`` evaluated at the RK4 stage
times, so smooth signals keep order 4), plus the Wiener increment ``b dW`` added once per
step (for additive noise this scheme has strong order 1). Without noise the result is the
mean trajectory ``E[x(t)]`` that the bound (6) is about.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


class LinearSDEPlant:
    """The plant as a :class:`~testbed.experiment.numpy_plant.NumpyPlant` (one state of
    shape (n,)).

    With ``output``, the interval averages ``(1/dt) int_{t_k}^{t_k+1} output(t, x) dt`` are
    integrated along with the state (same RK4 stages), as a continuous observation
    ``dy = output dt`` sampled by an integrate-and-dump converter would deliver them; they are
    step ``k``'s measurement.

    Parameters
    ----------
    A : ndarray, shape (n, n)
    B : ndarray, shape (n, k)
    G : ndarray, shape (n, s)
    b : ndarray, shape (n, p)
        Noise input; ``W`` is a standard Wiener process (unit intensity).
    w : callable ``t_s -> (s,)``
        Deterministic disturbance.
    dt_s : float
        Step in s.
    output : callable ``(t_s, x) -> (q,)``, optional
        Observation whose interval averages are the measurement (default: ``x``).

    Notes
    -----
    A step's noise (:meth:`step`) is ``None`` or ``(xi, dy)``: ``xi`` (p,) standard normal
    (the state gets ``b xi sqrt(dt)``) and ``dy`` (at most q,) added to the first entries of
    the measurement (e.g. the averaged white measurement noise, drawn by the caller).
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, G: np.ndarray, b: np.ndarray,
                 w: Callable[[float], np.ndarray], dt_s: float,
                 output: Callable[[float, np.ndarray], np.ndarray] | None = None) -> None:
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be a positive step in s, got {dt_s}")
        self.A, self.B, self.G, self.b, self.w = A, B, G, b, w
        self.dt_s = float(dt_s)
        self.output = output if output is not None else (lambda _t, x: x)

    def noise(self, rng: np.random.Generator | None, batch: tuple[int, ...]
              ) -> tuple[np.ndarray, None] | None:
        """``(xi, None)`` with ``xi ~ N(0, I)`` of shape (p,), or None without ``rng``."""
        return None if rng is None else (rng.standard_normal(self.b.shape[1]), None)

    def observe(self, x: np.ndarray, k: int) -> np.ndarray:
        """``output(t_k, x)``."""
        return self.output(k * self.dt_s, x)

    def step(self, x: np.ndarray, k: int, u: np.ndarray | None,
             noise: tuple[np.ndarray, np.ndarray | None] | None
             ) -> tuple[np.ndarray, np.ndarray, dict[str, object]]:
        """One RK4 step from ``t_k = k dt_s`` with ``u`` held (default 0): ``x_{k+1}``, the
        interval average of the output (plus ``dy``) and no extras.

        Raises
        ------
        ValueError
            ``x`` of the wrong shape.
        FloatingPointError
            The state became non-finite.
        """
        n = self.A.shape[0]
        if np.shape(x) != (n,):
            raise ValueError(f"x0 must have shape ({n},), got {np.shape(x)}")
        u = np.zeros(self.B.shape[1]) if u is None else u

        def f(t: float, z: np.ndarray) -> np.ndarray:
            state = z[:n]
            dx = self.A @ state + self.B @ u + self.G @ self.w(t)
            return np.concatenate([dx, self.output(t, state)])

        t, h = k * self.dt_s, self.dt_s
        z = np.concatenate([x, np.zeros(np.size(self.output(t, x)))])
        k1 = f(t, z)
        k2 = f(t + h / 2, z + h / 2 * k1)
        k3 = f(t + h / 2, z + h / 2 * k2)
        k4 = f(t + h, z + h * k3)
        z = z + h / 6 * (k1 + 2 * (k2 + k3) + k4)
        x, y = z[:n], z[n:] / h
        if noise is not None:
            xi, dy = noise
            x = x + self.b @ xi * np.sqrt(h)
            if dy is not None:
                y[:dy.shape[-1]] += dy
        if not np.isfinite(x).all():
            raise FloatingPointError(f"plant state became non-finite at t = {t + h:.6g} s")
        return x, y, {}
