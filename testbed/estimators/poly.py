"""Basin et al.'s central polynomial H-infinity filter designed from a rig's cubic expansion.

A rig that can expand its nonlinearity to third order implements
:meth:`testbed.rigs.base.Rig.cubic_model`, returning a :class:`CubicExpansion` of its nominal
dynamics in the design model's state: ``dx/dt = a0 + a1 x + a2 x x + a3 x x x + E u_p``,
where ``u_p = u + input_offset(x_hat)`` undoes the design model's input transform when that
transform depends on the estimate (the helicopter's gravity-compensating voltage).

:func:`poly_hinf_estimator` builds :class:`~filters.hinf_polynomial.PolynomialHInfFilter`
(Theorem 1) on the polynomial model::

    dx/dt = f(x) + E u_p + B w,   B = [G, Q^(1/2), 0]                   (1)
    y_w   = R^(-1/2) (y - D_u u) = R^(-1/2) C x + [0, 0, I] w            (2)
    z     = L x                                     (design.output_matrix)

with ``Q`` and ``R`` the design's process- and measurement-noise intensities (the
continuous model's), ``G`` the scenario's disturbance matrix (when it has one) and the
observation whitened by ``R^(-1/2)`` so that (C3) holds (``D B^T = 0``, ``D D^T = I``).
``P(t0) = design.P0`` (the weight of ``x0`` in (10) is ``P0^-1``). ``gamma`` defaults to
``gamma_factor`` times the smallest ``gamma`` for which the H-infinity filtering Riccati
equation of the linear part ``a1`` has a stabilizing solution (:func:`linear_gamma_min`):
the polynomial terms add to the Riccati "A" (``A_hat = J(x_f) + 3 a3 P``), so the linear
bound is a necessary level, not a sufficient one.

The continuous filter integrates over each control period with ``y`` and ``u`` held (RK4,
``substeps`` per period; by default chosen before every period from the Riccati rate at the
current ``P``: accurate sensors make the first periods stiff, e.g. 4080 RK4 substeps on the
helicopter's encoders at ``P0 = 1e-4 I``, 3 once ``P`` has settled, about 170 on the
hardware profile's encoders throughout; settled periods that would need 17 to 256 are
integrated by the L-stable ROS2 method instead, see :func:`filters.stiff.integrator_for`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.linalg import solve_continuous_are

from filters.hinf_polynomial import PolynomialHInfFilter
from filters.polynomial_model import PolynomialModel
from filters.stiff import integrator_for
from testbed.design.cubic import CubicExpansion


def _factor(M: np.ndarray) -> np.ndarray:
    """Columns ``V`` with ``V V^T = M`` for a PSD ``M`` (zero directions dropped)."""
    values, vectors = np.linalg.eigh(0.5 * (M + M.T))
    keep = values > 1e-12 * max(float(values.max(initial=0.0)), 1e-300)
    return vectors[:, keep] * np.sqrt(values[keep])


def _riccati(A: np.ndarray, B: np.ndarray, C: np.ndarray, L: np.ndarray,
             gamma: float) -> np.ndarray | None:
    """Stabilizing ``P >= 0`` of ``A P + P A^T + B B^T - P (C^T C - gamma^-2 L^T L) P = 0``,
    or None when there is none."""
    m, q = C.shape[0], L.shape[0]
    r = np.diag(np.concatenate([np.ones(m), -np.ones(q)]))  # L scaled by 1/gamma instead
    try:
        P = solve_continuous_are(A.T, np.hstack([C.T, L.T / gamma]), B @ B.T, r)
    except (np.linalg.LinAlgError, ValueError):
        return None
    P = 0.5 * (P + P.T)
    if not np.all(np.isfinite(P)) or np.linalg.eigvalsh(P)[0] < -1e-9 * max(
            1.0, float(np.abs(P).max())):
        return None
    closed = A - P @ (C.T @ C - L.T @ L / gamma**2)
    if np.linalg.eigvals(closed).real.max() >= 0.0:
        return None
    return P


def linear_gamma_min(A: np.ndarray, B: np.ndarray, C: np.ndarray, L: np.ndarray, *,
                     rtol: float = 1e-3) -> tuple[float, np.ndarray]:
    """Smallest ``gamma`` whose H-infinity filtering Riccati equation is solvable.

    Bisection (in ``log gamma``, to ``rtol``) on the existence of a stabilizing ``P >= 0``
    of ``A P + P A^T + B B^T - P (C^T C - gamma^-2 L^T L) P = 0`` (Nagpal & Khargonekar
    1991: the stationary central filter of ``dx = A x + B w``, ``y = C x + w_y``).

    Parameters
    ----------
    A : ndarray, shape (n, n)
    B : ndarray, shape (n, p)
    C : ndarray, shape (m, n)
        Whitened observation matrix.
    L : ndarray, shape (q, n)
    rtol : float

    Returns
    -------
    gamma_min : float
        Upper end of the final bracket (solvable there).
    P : ndarray, shape (n, n)
        The stabilizing solution at ``gamma_min``.

    Raises
    ------
    ValueError
        Not solvable even at ``gamma = 1e8`` (e.g. an undetectable unstable mode).
    """
    hi = 1e8
    P_hi = _riccati(A, B, C, L, hi)
    if P_hi is None:
        raise ValueError("the H-infinity filtering Riccati equation of the linear part has no "
                         "stabilizing solution even at gamma = 1e8 (undetectable unstable "
                         "mode?)")
    lo = 1e-6
    if _riccati(A, B, C, L, lo) is not None:
        return lo, _riccati(A, B, C, L, lo)  # type: ignore[return-value]
    while hi / lo > 1.0 + rtol:
        mid = math.sqrt(hi * lo)
        P_mid = _riccati(A, B, C, L, mid)
        if P_mid is None:
            lo = mid
        else:
            hi, P_hi = mid, P_mid
    return hi, P_hi


#: Admissible ``h * rate`` of :func:`suggested_substeps`: RK4 is stable below 2.8; 1.0 keeps
#: the helicopter's RMSE within 1 % of a 1632-substep integration (2.5 moved it by 20 %).
SUBSTEP_LIMIT = 1.0


def suggested_substeps(A: np.ndarray, CtC: np.ndarray, P: np.ndarray, dt_s: float, *,
                       limit: float = SUBSTEP_LIMIT) -> int:
    """RK4 substeps per period for the Riccati rate ``2 max|eig(A - P C^T C)|``.

    Parameters
    ----------
    A : ndarray, shape (n, n)
    CtC : ndarray, shape (n, n)
        ``C^T C`` of the whitened observation.
    P : ndarray, shape (n, n) or (N, n, n)
        Gain matrix (the largest rate over a batch is used).
    dt_s : float
    limit : float
        Admissible ``h * rate`` (as :meth:`filters.KalmanBucyFilter.suggested_substeps`).
    """
    rate = 2.0 * float(np.abs(np.linalg.eigvals(A - P @ CtC)).max())
    return max(1, math.ceil(dt_s * rate / limit))


class PolynomialHInfEstimator:
    """The testbed estimator around a batched :class:`PolynomialHInfFilter`.

    ``step(y, u)`` takes the full sensor vector and the design-model input: it keeps the
    modelled channels, subtracts the input feedthrough, whitens, adds the input offset at the
    current estimate and integrates the filter over one period.

    Parameters
    ----------
    filt : PolynomialHInfFilter
    index : ndarray of int
        Channels of ``y`` the model observes (``design.measurement_index``).
    whiten : ndarray, shape (m, m)
        ``R^(-1/2)``.
    feedthrough : ndarray, shape (m, k) or None
        ``D_u`` of the design's observation.
    input_offset : callable or None
        :attr:`CubicExpansion.input_offset`.
    design_meta : dict
    auto_substeps : (A, C^T C), optional
        Before every step, set the filter's integrator and substeps by
        :func:`filters.stiff.integrator_for` of :func:`suggested_substeps` at the current
        ``P``.
    """

    batched = True

    def __init__(self, filt: PolynomialHInfFilter, index: np.ndarray, whiten: np.ndarray,
                 feedthrough: np.ndarray | None,
                 input_offset: Callable[[np.ndarray], np.ndarray] | None,
                 design_meta: dict[str, Any],
                 auto_substeps: tuple[np.ndarray, np.ndarray] | None = None):
        self.filter = filt
        self.index = np.asarray(index, int)
        self._whiten_T = np.ascontiguousarray(whiten.T)
        self._DuT = None if feedthrough is None else np.ascontiguousarray(feedthrough.T)
        self._offset = input_offset
        self.design_meta = design_meta
        self._auto = auto_substeps

    @property
    def x(self) -> np.ndarray:
        """Estimates, shape (n,) or (N, n)."""
        return self.filter.x

    @property
    def P(self) -> np.ndarray:
        """The filter's gain matrix ``P`` (the covariance of the equivalent H2 problem)."""
        return self.filter.P

    def reset(self, x0: np.ndarray, P0: np.ndarray | None) -> None:
        """Restart from ``x0`` (n,) or (N, n) and ``P0`` (default the design's)."""
        self.filter.reset(x0, self.filter.P0 if P0 is None else P0)

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """One control period: ``y`` (m_all,) or (N, m_all), ``u`` (k,) or (N, k)."""
        y = np.asarray(y, float)[..., self.index]
        if u is not None:
            u = np.asarray(u, float)
            if self._DuT is not None:
                y = y - u @ self._DuT
            if self._offset is not None:
                x = self.filter.x
                u = u + (self._offset(x[None])[0] if x.ndim == 1 else self._offset(x))
        if self._auto is not None:
            A, CtC = self._auto
            how = integrator_for(suggested_substeps(A, CtC, self.filter.P, self.filter.dt_s))
            self.filter.method, self.filter.substeps = how.method, how.substeps
            self.filter.jacobian_every = how.jacobian_every
        return self.filter.step(y @ self._whiten_T, u)


def poly_hinf_estimator(design: Any, expansion: CubicExpansion, *, gamma: float | None = None,
                        gamma_factor: float = 1.5, substeps: int | None = None
                        ) -> PolynomialHInfEstimator:
    """The central polynomial H-infinity filter of ``expansion`` on ``design`` (see module).

    Parameters
    ----------
    design : testbed.design.DesignModel
    expansion : CubicExpansion
    gamma : float, optional
        Attenuation level; default ``gamma_factor * linear_gamma_min``.
    gamma_factor : float
        > 1.
    substeps : int, optional
        RK4 substeps per period (default: chosen before every step from the Riccati rate at
        the current ``P``, see :class:`PolynomialHInfEstimator`).

    Returns
    -------
    PolynomialHInfEstimator
        ``design_meta``: ``gamma``, ``gamma_min_linear``, ``substeps``, ``expansion``,
        ``certificate``; ``gamma_channel = "scenario"`` when the scenario's ``G`` is in ``B``.

    Raises
    ------
    ValueError
        Bad options, a singular measurement-noise intensity, or no solvable Riccati equation.
    """
    if not (np.isfinite(gamma_factor) and gamma_factor > 1.0):
        raise ValueError(f"gamma_factor must be a finite number > 1, got {gamma_factor!r}")
    if gamma is not None and not (np.isfinite(gamma) and gamma > 0):
        raise ValueError(f"gamma must be a positive finite attenuation level, got {gamma!r}")
    if substeps is not None and (int(substeps) != substeps or substeps < 1):
        raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
    plant = design.continuous
    n = design.n
    R = 0.5 * (plant.R + plant.R.T)
    evals, evecs = np.linalg.eigh(R)
    if not evals[0] > 0.0:
        raise ValueError("filter 'poly-hinf' whitens the observation: it needs a positive "
                         f"definite measurement-noise intensity, got minimum eigenvalue "
                         f"{evals[0]:.3g}")
    whiten = (evecs / np.sqrt(evals)) @ evecs.T  # R^(-1/2), symmetric
    Cw = whiten @ plant.C
    blocks = []
    G = design.disturbance_matrix
    scenario_channel = G is not None and bool(np.any(G))
    if scenario_channel:
        blocks.append(np.asarray(G, float))
    blocks.append(_factor(plant.Q))
    Bx = np.hstack(blocks)
    if Bx.shape[1] == 0:
        raise ValueError("filter 'poly-hinf' needs a process-noise intensity Q or a "
                         "disturbance matrix G (the design has neither)")
    m = Cw.shape[0]
    B = np.hstack([Bx, np.zeros((n, m))])
    D = np.hstack([np.zeros((m, Bx.shape[1])), np.eye(m)])
    L = design.output_matrix
    gamma_min, _ = linear_gamma_min(expansion.a1, Bx, Cw, L)
    gamma = gamma_factor * gamma_min if gamma is None else float(gamma)
    if _riccati(expansion.a1, Bx, Cw, L, gamma) is None:
        raise ValueError(f"gamma = {gamma:.6g} is below the linear part's level "
                         f"{gamma_min:.6g}: the filter's Riccati equation escapes")
    auto = substeps is None
    if auto:  # the first step's need; re-evaluated at every step as P settles
        substeps = suggested_substeps(expansion.a1, Cw.T @ Cw, design.P0, design.dt_s)
    model = PolynomialModel(a0=expansion.a0, a1=expansion.a1, a2=expansion.a2,
                            a3=expansion.a3, B=B, C=Cw, D=D, L=L, E=expansion.E)
    filt = PolynomialHInfFilter(model, gamma, np.linalg.inv(design.P0), design.dt_s,
                                x0=design.x0, substeps=int(substeps))
    meta: dict[str, Any] = {
        "gamma": gamma, "gamma_kind": "continuous-observation", "gamma_min_linear": gamma_min,
        "substeps": "auto" if auto else int(substeps),
        "expansion": expansion.description, "degree": model.degree,
        "certificate": "Basin et al. Theorem 1 on the rig's cubic expansion with "
                       "continuous observation (w = [G w, Q^1/2-normalized process noise, "
                       "R^1/2-normalized measurement noise]); the neglected terms, the "
                       "sampling (y held over a period) and quantization are not covered"}
    if scenario_channel:
        meta["gamma_channel"] = "scenario"
    return PolynomialHInfEstimator(filt, design.measurement_index, whiten, plant.D,
                                   expansion.input_offset, meta,
                                   (expansion.a1, Cw.T @ Cw) if auto else None)
