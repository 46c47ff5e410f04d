"""Simulation of a polynomial plant ``dx/dt = f(x, t) + B w + E u`` (the class of systems of
Basin, Shi & Calderon-Alvarez (n.d.); of degree 1, also the linear helicopter model of Basin,
Elvira-Ceja & Sanchez (n.d.): :func:`testbed.reproductions.basin_ms_hinf.helicopter._plant`;
see docs/references.md).

A :class:`PolynomialPlant` wraps a :class:`~filters.polynomial_model.PolynomialModel`
(coefficient tensors of degree <= 3, constant or functions of time) and integrates it with
classical RK4 on a fixed step. Users define their own systems by building the model::

    model = PolynomialModel(a1=..., a2=..., a3=lambda t: ..., B=..., C=..., D=..., L=...)
    run = rollout(PolynomialPlant(model, dt_s=1e-3, w=my_w), x0, 1000)  # experiment.numpy_plant

Disturbances: a deterministic ``w(t)`` (evaluated at the RK4 stage times, so smooth
signals keep order 4) and/or white noise of intensity ``q`` (``w = sqrt(q) dW/dt``, one
standard Wiener increment per substep added to the state as ``B sqrt(q) dW``: strong order 1
for this additive noise). The observation is integrated along the state: the returned ``y``
is the interval average ``(1/dt) int (C x + D w) dt`` an integrate-and-dump converter would
deliver (for white noise its noise part is ``D sqrt(q) (W(t + dt) - W(t)) / dt``, the same
increments the state saw, so ``D B^T != 0`` correlations are kept).

Finite escape (Remark 2 of Basin, Shi & Calderon-Alvarez (n.d.): an unstable cubic term
escapes in finite time) is detected by an :class:`~filters.polynomial_model.EscapeTest` after
every substep (a bound and a growth test; never NaN) and reported as
:class:`~filters.errors.FiniteEscapeError` with ``quantity="state"``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from filters import TimeFunction, positive_time
from filters.polynomial_model import EscapeTest, PolynomialCoefficients, PolynomialModel


class PolynomialPlant:
    """A polynomial system integrated with RK4 on a fixed step, a
    :class:`~testbed.experiment.numpy_plant.NumpyPlant` for one state of shape (n,): its
    :meth:`step` returns the interval averages of ``y`` and ``w``.

    Parameters
    ----------
    model : PolynomialModel
        ``f``, ``B``, ``C``, ``D``, ``E`` (``L`` is not used by the plant).
    escape : EscapeTest, optional
        Finite-escape test of the state (default :class:`EscapeTest()`: bound 1e8, growth
        +10 % per substep above 100).
    dt_s : float
        Grid step (sample period of ``y``), s.
    substeps : int
        RK4 steps per grid interval.
    w : callable ``t -> (p,)`` or ndarray, optional
        Deterministic disturbance (default zero).
    noise_intensity : float or ndarray, shape (p,), optional
        White-noise intensity ``q`` per disturbance component (default: no white noise).

    Attributes
    ----------
    model : PolynomialModel
    n, m, p, k : int
        State, observation, disturbance and input dimensions.
    """

    def __init__(self, model: PolynomialModel, escape: EscapeTest | None = None, *,
                 dt_s: float = 1e-3, substeps: int = 1,
                 w: Callable[[float], np.ndarray] | np.ndarray | None = None,
                 noise_intensity: float | np.ndarray | None = None) -> None:
        if not isinstance(model, PolynomialModel):
            raise TypeError(f"model must be a PolynomialModel, got {type(model).__name__}")
        dt_s = positive_time("dt_s", dt_s)
        if isinstance(substeps, bool) or not isinstance(substeps, int | np.integer) or substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
        self.model = model
        self.escape = escape or EscapeTest()
        self.n, self.m, self.p, self.k = model.n, model.m, model.p, model.k
        self.dt_s, self.substeps = float(dt_s), int(substeps)
        self.w = None if w is None or self.p == 0 else TimeFunction("w", w, (self.p,), 0.0)
        self.q = None
        if noise_intensity is not None:
            self.q = np.broadcast_to(np.asarray(noise_intensity, dtype=float), (self.p,)).copy()
            if not np.all(np.isfinite(self.q)) or np.any(self.q < 0):
                raise ValueError(f"noise_intensity must be finite and >= 0, got "
                                 f"{noise_intensity!r}")
        self._last: PolynomialCoefficients | None = None  # coefficients at the last time

    def noise(self, rng: np.random.Generator | None, batch: tuple[int, ...]) -> np.ndarray | None:
        """Standard normal variates of one step, shape ``batch + (substeps, p)`` (None
        without white noise)."""
        if rng is None or self.q is None:
            return None
        return rng.standard_normal((*batch, self.substeps, self.p))

    def observe(self, x: np.ndarray, k: int) -> np.ndarray:
        """``C x + D w`` at ``t = k dt_s`` (deterministic part), shape (m,)."""
        t = k * self.dt_s
        c = self.model.at(t)
        return c.C @ x + c.D @ (np.zeros(self.p) if self.w is None else self.w(t))

    def rhs(self, t: float, x: np.ndarray, w: np.ndarray | None,
            u: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``(dx/dt, y)`` at one point: ``f(x, t) + B w + E u`` and ``C x + D w``."""
        cached = self._last
        if cached is not None and cached.t == t:
            c = cached
        else:
            c = self._last = self.model.at(t)
        dx = c.f(x)
        y = c.C @ x
        if w is not None:
            dx = dx + c.B @ w
            y = y + c.D @ w
        if u is not None and c.E is not None:
            dx = dx + c.E @ u
        return dx, y

    def step(self, x: np.ndarray, k: int, u: np.ndarray | None, noise: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Integrate step ``k``, the interval ``[k dt_s, (k + 1) dt_s]``, in ``substeps`` RK4
        steps.

        Parameters
        ----------
        x : ndarray, shape (n,)
        k : int
        u : ndarray, shape (k,), optional
            Input held over the interval.
        noise : ndarray, shape (substeps, p), optional
            Standard normal variates, one row per substep (:meth:`noise`: the white noise of
            intensity ``q``).

        Returns
        -------
        x : ndarray, shape (n,)
            State at ``(k + 1) dt_s``.
        y : ndarray, shape (m,)
            Interval average of ``C x + D w``.
        extras : dict
            ``{"disturbance": interval average of w}``, shape (p,).

        Raises
        ------
        FiniteEscapeError
            ``quantity="state"``, time = end of the failing substep.
        """
        p, w, dt_s, substeps = self.p, self.w, self.dt_s, self.substeps
        t_s = k * dt_s
        h = dt_s / substeps
        x = np.array(x, dtype=float)
        y_int = np.zeros(self.m)
        w_int = np.zeros(p)
        q = self.escape.magnitude(x, 1)

        def stage(t: float, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            ws = None if w is None else np.asarray(w(t), dtype=float)
            dx, y = self.rhs(t, xs, ws, u)
            return dx, y, (np.zeros(p) if ws is None else ws)

        with np.errstate(over="ignore", invalid="ignore"):
            for i in range(substeps):
                t = t_s + i * h
                k1, y1, w1 = stage(t, x)
                k2, y2, w2 = stage(t + h / 2, x + h / 2 * k1)
                k3, y3, w3 = stage(t + h / 2, x + h / 2 * k2)
                k4, y4, w4 = stage(t + h, x + h * k3)
                x = x + h / 6 * (k1 + 2 * (k2 + k3) + k4)
                y_int += h / 6 * (y1 + 2 * (y2 + y3) + y4)
                w_int += h / 6 * (w1 + 2 * (w2 + w3) + w4)
                if noise is not None:
                    c = self.model.at(t + h)
                    inc = np.sqrt(self.q * h) * noise[i]  # int w dt over the substep
                    x = x + c.B @ inc
                    y_int += c.D @ inc
                    w_int += inc
                q = self.escape.check("state", q, x, time=t + h, step_s=h, core_ndim=1)
        return x, y_int / dt_s, {"disturbance": w_int / dt_s}
