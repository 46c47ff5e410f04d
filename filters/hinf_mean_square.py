"""Central suboptimal mean-square H-infinity filter (Basin, Elvira-Ceja & Sanchez, Theorem 1).

Reference: M. Basin, S. Elvira-Ceja, E. N. Sanchez, "Mean-square H-infinity filter design:
application to a 2DOF helicopter".

System (paper eqs. (1)-(4)), all matrices possibly time-varying::

    dx = (A x + B u + G w) dt + b dW1        (1)   w: deterministic L2 disturbance
    dy1 = C1 x dt + h dW2                    (2)   stochastic channel
    y2 = C2 x + H w                          (3)   deterministic channel
    z = L x                                  (4)   output to be estimated

Filter (Theorem 1)::

    dm = (A m + B u) dt + P C1^T (h h^T)^-1 (dy1 - C1 m dt)
                        + S C2^T (H H^T)^-1 (y2 - C2 m) dt                     (7)
    P' = A P + P A^T + b b^T - P C1^T (h h^T)^-1 C1 P,        P(t0) = P0      (8)
    S' = A S + S A^T + G G^T - S [C2^T (H H^T)^-1 C2 - gamma^-2 L^T L] S,
                                                              S(t0) = R^-1    (9)

``P`` is the minimum (Kalman-Bucy) error variance (5) of the stochastic part; ``S`` is the
H-infinity gain matrix for the deterministic disturbance, ``R`` the weight of the initial
condition in the attenuation condition (6).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import numpy.typing as npt
from scipy.linalg import solve_continuous_are
from scipy.linalg.lapack import dpotrf as _dpotrf

from filters._linalg import (
    FloatArray,
    TimeArg,
    TimeFunction,
    checked_array,
    max_abs_eigenvalue,
    positive_time,
    readonly,
    shared_member,
    to_float_array,
)
from filters.errors import (
    FilterError,
    FiniteEscapeError,
    check_covariance,
    check_shared_covariance,
)
from filters.kalman import _IntegratedFilter
from filters.stiff import integrator_for, rosenbrock2

__all__ = ["AssumptionWarning", "MeanSquareHInfFilter"]

MatrixArg = TimeArg
"""A constant matrix or a function ``t_s -> matrix`` (time-varying)."""

_ESCAPE_BOUND = 1e12  # default of check_covariance
_ESCAPE_BOUND_SQ = _ESCAPE_BOUND * _ESCAPE_BOUND
#: Relative tolerance of the algebraic assumption H G^T = 0 (C4).
_ORTHOGONALITY_RTOL = 1e-9
#: Relative tolerance of the PBH rank tests (defective eigenvalues are only known to
#: about sqrt(eps) relative accuracy, so the rank tolerance must be coarser than that).
_PBH_RTOL = 1e-6


class AssumptionWarning(UserWarning):
    """A stabilizability/detectability assumption (C1)-(C3) of Basin et al. fails."""


@dataclass(frozen=True, slots=True)
class _Coefficients:
    """Matrices of (7)-(9) at one time (all ``float64``; shapes for ``n`` states).

    ``W1 = (h h^T)^-1 C1`` (m1, n) so ``P C1^T (h h^T)^-1 y1 = P W1^T y1``;
    ``M1 = C1^T W1`` (n, n); ``W2 = (H H^T)^-1 C2`` (m2, n); ``N2 = C2^T W2`` (n, n);
    ``M2 = N2 - gamma^-2 L^T L`` (n, n); ``Q1 = b b^T``, ``Q2 = G G^T`` (n, n);
    ``B`` (n, k) or None.
    """

    A: FloatArray
    B: FloatArray | None
    Q1: FloatArray
    Q2: FloatArray
    W1: FloatArray
    M1: FloatArray
    W2: FloatArray
    N2: FloatArray
    M2: FloatArray


@dataclass(frozen=True, slots=True)
class _FastConstants:
    """Coefficients (scaled by ``a = h / 2``) and work buffers of the unbatched
    constant-coefficient path (frozen references; the buffers are mutated per step).

    The state is one contiguous ``(2n + 1, 2n)`` array ``X = [Z; v^T]``: rows ``0..2n-1``
    hold ``Z = blockdiag(P, S)``, the last row ``v = [m; 1; 0, ..., 0]`` (length 2n; the
    constant 1 carries the affine terms). The
    Riccati equations (8), (9) are one, ``a Z' = U + U^T + a Qbig`` with
    ``U = (a Abig - Z a Mbig / 2) Z`` (``Abig = blockdiag(A, A)``,
    ``Mbig = blockdiag(M1, M2)``, ``Qbig = blockdiag(b b^T, G G^T)``), and the mean (7) is
    ``a v' = Ae v + Je Z (Nr v)`` with, padded to (2n, 2n):
    ``Ae = a [[A, B u], [0, 0]]``, ``Nr = a [-[M1; N2], Kblk y]``, ``Je = [[I, I], [0, 0]]``,
    ``Kblk = blockdiag(W1^T, W2^T)`` (2n, m1 + m2), so that
    ``Z Nr v = a [P (W1^T y1 - M1 m); S (W2^T y2 - N2 m)]``. Column ``n`` of ``Ae`` and
    ``Nr`` (the ``u``- and ``y``-terms) is written per step.
    """

    half_step: float
    Ae: FloatArray  # (2n, 2n) work buffer, column n = a B u
    B: FloatArray | None  # a B, (n, k)
    Abig: FloatArray
    hMbig: FloatArray  # a Mbig / 2
    Q9: FloatArray  # [a Qbig; 0], (2n + 1, 2n)
    Kblk: FloatArray  # a Kblk
    Nr: FloatArray  # (2n, 2n) work buffer, column n = a Kblk y
    Je: FloatArray
    Cstack: FloatArray  # [C1; C2], unscaled, for the innovation
    work: tuple[tuple[FloatArray, FloatArray, FloatArray], ...]  # (buffer, Z view, v view)
    Nr_col: FloatArray  # contiguous view Nr[:, n] (Nr is Fortran-ordered)
    Ae_col: FloatArray  # contiguous view Ae[:n, n] (Ae is Fortran-ordered)


def _pbh_stabilizable(A: FloatArray, B: FloatArray) -> bool:
    """PBH test: ``rank [A - lambda I, B] = n`` for every eigenvalue with ``Re >= 0``.

    Eigenvalues with ``Re lambda >= -sqrt(eps) max(1, |A|)`` count as non-negative (a
    defective zero eigenvalue is computed with an error of that size); the rank is
    deficient if the smallest singular value is ``<= 1e-6 max(1, |[A B]|)``.
    """
    n = A.shape[0]
    scale = max(1.0, float(np.linalg.norm(np.hstack([A, B]), 2)) if B.size else
                float(np.linalg.norm(A, 2)))
    re_tol = math.sqrt(np.finfo(float).eps) * max(1.0, float(np.linalg.norm(A, 2)))
    for lam in np.linalg.eigvals(A):
        if lam.real < -re_tol:
            continue
        M = np.hstack([A - lam * np.eye(n), B.astype(complex)])
        smin = np.linalg.svd(M, compute_uv=False)[n - 1] if M.shape[1] >= n else 0.0
        if smin <= _PBH_RTOL * scale:
            return False
    return True


class MeanSquareHInfFilter(_IntegratedFilter):
    """Central suboptimal mean-square H-infinity filter of Basin et al., Theorem 1, (7)-(9).

    Equation map (paper numbering)
        * mean ``m``: eq. (7), **with** the input term ``B u`` (see misprints below);
        * ``P``: eq. (8), the Kalman-Bucy Riccati equation of the stochastic channel ``y1``
          (gain ``P C1^T (h h^T)^-1``); it is the minimum error variance (5) and is what
          :attr:`P` returns (use it for NEES);
        * ``S``: eq. (9), the H-infinity Riccati equation of the deterministic channel
          ``y2`` (gain ``S C2^T (H H^T)^-1``), ``S(t0) = R^-1`` with ``R`` the weight of
          ``x0`` in the attenuation condition (6).

    Misprints of the paper corrected here
        * The example's filter (16) omits ``B u``; Theorem 1's (7) has it and so does this
          implementation (without it the estimate is useless under the constant voltage
          ``u = [12.495, -3.835]`` V).
        * The example's ``B`` is printed with three rows; its missing first row is
          ``[0, 0]`` (``B = [[0, 0], [0, 0], [2.3667, 0.0790], [0.2410, 0.7913]]``). This
          class takes ``B`` as given; pass the corrected one.
        * The constant matrix printed in (17)/(18) is ``G G^T`` (``b b^T``), whose first two
          rows are zero; the printed ``1`` entries in rows 1-2 are misprints. This class
          computes ``G G^T`` and ``b b^T`` itself.

    Parameters
    ----------
    A : array_like, shape (n, n), or callable ``t -> (n, n)``
    B : array_like, shape (n, k), or callable, or None
        ``None``: no input (``k = 0``).
    C1 : array_like, shape (m1, n), or callable
        Stochastic observation channel (2).
    h : array_like, shape (m1, p2), or callable
        Noise matrix of (2); only ``h h^T`` (must be > 0) is used. With
        ``noise_intensities=True``: the intensity ``h h^T`` itself, shape (m1, m1).
    C2 : array_like, shape (m2, n), or callable
        Deterministic observation channel (3). ``C2 = 0`` is allowed: the ``y2`` term of (7)
        then vanishes and ``m, P`` follow the Kalman-Bucy equations, but the filter *is* the
        Kalman-Bucy filter only for ``gamma = math.inf``. With a finite ``gamma``, (9) becomes
        ``S' = A S + S A^T + G G^T + gamma^-2 S L^T L S``, whose positive quadratic term makes
        ``S`` escape in finite time (``FiniteEscapeError``) although ``m`` never uses it.
    H : array_like, shape (m2, s), or callable
        Disturbance matrix of (3); ``H H^T > 0`` and ``H G^T = 0`` (C4).
    G : array_like, shape (n, s), or callable
        Disturbance input of (1).
    b : array_like, shape (n, p1), or callable
        Noise matrix of (1); with ``noise_intensities=True`` the intensity ``b b^T`` (n, n).
    L : array_like, shape (q, n), or callable
        Estimated output (4).
    gamma : float
        Attenuation level ``gamma > 0`` (``math.inf`` allowed: no ``L^T L`` term).
    R : array_like, shape (n, n)
        Symmetric positive definite weight of (6); ``S(t0) = R^-1``.
    x0 : array_like, shape (n,) or (..., n)
        Initial estimate ``m(t0)``; leading axes are a batch of independent filters.
    P0 : array_like, shape (n, n) or (..., n, n)
        Initial error variance ``P(t0)`` (symmetric PSD), broadcast to the batch.
    dt_s : float
        Sample interval in seconds.
    substeps : int or "auto"
        Classical Runge-Kutta (RK4, global order 4) steps per interval on the joint
        ``(m, P, S)`` system. ``"auto"`` picks :meth:`suggested_substeps` at the start of
        every interval from the stiffness of both Riccati equations and of the mean, at most
        :data:`filters.kalman.MAX_AUTO_SUBSTEPS` (beyond it :meth:`step` raises
        :class:`~filters.errors.SubstepLimitError`).
    t0 : float
        Initial time in seconds (time-varying matrices are evaluated at ``t0 + ...``).
    noise_intensities : bool
        Interpret ``b`` and ``h`` as the intensities ``b b^T`` and ``h h^T``.
    method : {"rk4", "rosenbrock", "auto"}
        Integrator of every interval: RK4, or the L-stable ROS2 of :mod:`filters.stiff`
        (``substeps`` of it) with the analytic block-triangular Jacobian, for stiff
        equations; ``"auto"`` (with ``substeps="auto"``) chooses both, and how often ROS2
        evaluates its Jacobian, per interval by :func:`filters.stiff.integrator_for` (ROS2
        for settled stiff intervals; :data:`~filters.kalman.MAX_AUTO_SUBSTEPS` still caps
        RK4's).

    Attributes
    ----------
    name : str
        ``"ms-hinf"``.
    x : numpy.ndarray, shape (..., n)
        The mean-square H-infinity estimate ``m``.
    P : numpy.ndarray, shape (..., n, n)
        Minimum error variance of (8).
    S : numpy.ndarray, shape (..., n, n)
        Solution of (9). It depends neither on the data nor on ``P0``, so one matrix is
        shared by the batch (a read-only broadcast view).
    S0 : numpy.ndarray, shape (n, n)
        ``R^-1``, the initial ``S``.
    gamma : float
    t_s : float
        ``t0 + steps * dt_s``.
    innovation : numpy.ndarray, shape (..., m1 + m2), or None
        ``y - [C1 m; C2 m]`` at the start of the last interval.
    assumptions : dict of str to bool
        Results of the numerical checks of (C1)-(C3) (see Notes).

    Raises
    ------
    ValueError
        Wrong shapes or non-finite entries; ``h h^T`` or ``H H^T`` not positive definite;
        ``H G^T != 0`` (C4); ``R`` not symmetric positive definite; ``gamma <= 0``.

    Warns
    -----
    AssumptionWarning
        For each failed stabilizability/detectability condition of (C1)-(C3).

    Notes
    -----
    **Sampled data.** :meth:`step` takes ``y = concatenate([y1, y2])``, shape
    ``(..., m1 + m2)``: ``y1`` is the interval-averaged observation rate ``dy1/dt``
    (sampled noise covariance ``h h^T / dt_s``) and ``y2`` a sample of the deterministic
    channel representative of the interval. Both and ``u`` are held constant (zero-order
    hold) over ``[t, t + dt_s]``.

    **Integration.** Classical RK4 (order 4) on the joint ``(m, P, S)`` ODE, time-varying
    matrices evaluated at the stage times. The Riccati right-hand sides are evaluated as
    ``T X + (T X)^T + Q`` with ``T = A - X M / 2`` (identical to (8)/(9) for symmetric
    ``X``), so ``P`` and ``S`` stay exactly symmetric; after every substep both are
    checked (``P`` PSD, ``S`` PSD, entries bounded by 1e12) and a failure raises
    :class:`~filters.errors.LossOfDefinitenessError` or
    :class:`~filters.errors.FiniteEscapeError` with ``quantity="P"`` or ``"S"`` and the
    time of the substep. A too small ``gamma`` makes ``S`` escape in finite time; this
    surfaces as ``FiniteEscapeError(quantity="S")``. A non-finite mean raises
    ``FiniteEscapeError(quantity="x")``. A call that raises leaves the filter unchanged.

    **Fast path.** Unbatched filters with constant matrices integrate
    ``Z = blockdiag(P, S)`` as one ``2n x 2n`` Riccati equation, stacked with the mean in
    one ``(2n + 1, 2n)`` array, with precomputed block coefficients (BLAS calls on 8x8
    cost the same as on 4x4; per-call overhead dominates) and preallocated RK4 work
    buffers; ``x``, ``P``, ``S`` are then read-only views of that array. Batched or
    time-varying filters integrate ``P`` and ``S`` separately with broadcasting
    ``matmul``. The two paths agree to rounding (tested to 1e-13). ``P`` and ``S`` are
    exactly symmetric after every substep: the fast path by construction, the other by
    symmetrization in :func:`~filters.errors.check_covariance`. A failed check on the fast
    path re-runs the interval on the separate path to attribute it to ``P`` or ``S``.

    **Assumptions.** Checked numerically at construction: ``h h^T > 0``, ``H H^T > 0``,
    ``H G^T = 0`` (C4; relative tolerance 1e-9), ``R`` symmetric positive definite (hard:
    ``ValueError``), and with PBH rank tests on the eigenvalues with ``Re >= 0``:
    (C1) ``(A, b)`` stabilizable, ``(C1, A)`` detectable; (C2) ``(A, G)`` stabilizable,
    ``(C2, A)`` detectable; (C3) ``(A, B)`` stabilizable, ``(L, A)`` detectable (soft:
    :class:`AssumptionWarning`). Callables are checked at ``t0`` only (later, only the
    positive definiteness of ``h h^T`` and ``H H^T`` is enforced, when they are inverted).
    """

    name: ClassVar[str] = "ms-hinf"

    def __init__(
        self,
        A: MatrixArg,
        B: MatrixArg | None,
        C1: MatrixArg,
        h: MatrixArg,
        C2: MatrixArg,
        H: MatrixArg,
        G: MatrixArg,
        b: MatrixArg,
        L: MatrixArg,
        gamma: float,
        R: npt.ArrayLike,
        x0: npt.ArrayLike,
        P0: npt.ArrayLike,
        dt_s: float,
        substeps: int | str = 1,
        t0: float = 0.0,
        *,
        noise_intensities: bool = False,
        method: str = "rk4",
    ) -> None:
        self._auto_substeps = isinstance(substeps, str) and substeps == "auto"
        if method not in ("rk4", "rosenbrock", "auto"):
            raise ValueError(f"method must be 'rk4', 'rosenbrock' or 'auto', got {method!r}")
        if method == "auto" and not self._auto_substeps:
            raise ValueError("method='auto' needs substeps='auto' (it chooses both per "
                             "interval)")
        self._method = method
        if self._auto_substeps:
            substeps = 1
        elif (isinstance(substeps, bool) or not isinstance(substeps, int | np.integer)
              or substeps < 1):
            raise ValueError(f"substeps must be an integer >= 1 or 'auto', got {substeps!r}")
        self._substeps = int(substeps)
        self._dt = positive_time("dt_s", dt_s)
        t0 = float(t0)
        if not math.isfinite(t0):
            raise ValueError(f"t0 must be a finite time in seconds, got {t0!r}")
        self._t0 = t0
        try:
            g = float(gamma)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"gamma must be a positive float, got {gamma!r}") from exc
        if not g > 0.0:  # NaN compares False
            raise ValueError(f"gamma must be a positive float (attenuation level), got {gamma!r}")
        self._gamma = g
        self._gm2 = 0.0 if math.isinf(g) else 1.0 / (g * g)

        self._A = TimeFunction("A", A, (None, None), t0)
        n = self._A.shape[0]
        if self._A.shape != (n, n) or n == 0:
            raise ValueError(f"A must be a square matrix of shape (n, n), n >= 1, got "
                             f"shape {self._A.shape}")
        self._B = None if B is None else TimeFunction("B", B, (n, None), t0)
        self._C1 = TimeFunction("C1", C1, (None, n), t0)
        m1 = self._C1.shape[0]
        self._C2 = TimeFunction("C2", C2, (None, n), t0)
        m2 = self._C2.shape[0]
        self._G = TimeFunction("G", G, (n, None), t0)
        s = self._G.shape[1]
        self._H = TimeFunction("H", H, (m2, s), t0)
        self._L = TimeFunction("L", L, (None, n), t0)
        self._intensities = bool(noise_intensities)
        self._h = TimeFunction("h", h, (m1, m1 if self._intensities else None), t0)
        self._b = TimeFunction("b", b, (n, n if self._intensities else None), t0)
        if m1 == 0 or m2 == 0:
            raise ValueError(f"C1 and C2 need at least one row, got m1 = {m1}, m2 = {m2}")
        self._n, self._m1, self._m2 = n, m1, m2
        self._m = m1 + m2
        self._k = 0 if self._B is None else self._B.shape[1]

        Rm = checked_array("R", R, (n, n), t0)
        scale = float(np.abs(Rm).max())
        if float(np.abs(Rm - Rm.T).max()) > 1e-9 * scale:
            raise ValueError("R must be symmetric positive definite (S(t0) = R^-1), got a "
                             f"non-symmetric matrix (max |R - R^T| = "
                             f"{float(np.abs(Rm - Rm.T).max()):.3g})")
        Rm = 0.5 * (Rm + Rm.T)
        eig = np.linalg.eigvalsh(Rm)
        if not eig[0] > 0.0:
            raise ValueError("R must be symmetric positive definite (S(t0) = R^-1), got "
                             f"minimum eigenvalue {eig[0]:.6g}")
        S0 = np.linalg.inv(Rm)
        self._R = readonly(Rm)
        self._S0 = readonly(0.5 * (S0 + S0.T))

        mats = (self._A, self._B, self._C1, self._C2, self._G, self._H, self._L,
                self._h, self._b)
        self._constant = all(M is None or M.constant for M in mats)
        self._check_c4(t0)
        self.assumptions = self._check_stabilizability(t0)

        self._coef_cache: dict[float, _Coefficients] = {}
        self._coef0: _Coefficients | None = None
        if self._constant:
            self._coef0 = self._coefficients(t0)
        self._fast: _FastConstants | None = None
        self.reset(x0, P0)

    # ------------------------------------------------------------ properties
    @property
    def S(self) -> FloatArray:
        """Solution of (9), shape ``(..., n, n)`` (read-only; shared by the batch)."""
        if self._batch:
            return np.broadcast_to(self._S, (*self._batch, self._n, self._n))
        return self._S

    @property
    def innovation(self) -> FloatArray | None:
        """``y - [C1 m; C2 m]`` at the start of the last interval, shape (..., m1 + m2)."""
        data = self._innovation_data
        if data is not None:
            y, m, C = data
            self._innovation = y - C.dot(m)
            self._innovation_data = None
        return self._innovation

    @innovation.setter
    def innovation(self, value: FloatArray | None) -> None:
        self._innovation = value
        self._innovation_data: tuple[FloatArray, FloatArray, FloatArray] | None = None

    @property
    def S0(self) -> FloatArray:
        """``R^-1``, the initial value of :attr:`S`, shape (n, n)."""
        return self._S0

    @property
    def R(self) -> FloatArray:
        """Weight of ``x0`` in (6), shape (n, n)."""
        return self._R

    @property
    def gamma(self) -> float:
        """Attenuation level."""
        return self._gamma



    @property
    def measurement_layout(self) -> tuple[int, int]:
        """``(m1, m2)``: ``y[..., :m1]`` is ``y1``, ``y[..., m1:]`` is ``y2``."""
        return self._m1, self._m2

    def _time(self, steps: int) -> float:
        return self._t0 + steps * self._dt  # type: ignore[operator]

    # ----------------------------------------------------------------- state
    def reset(self, x0: npt.ArrayLike, P0: npt.ArrayLike) -> None:
        """Re-initialize ``m = x0``, ``P = P0``, ``S = R^-1`` and ``t_s = t0``.

        Parameters
        ----------
        x0 : array_like, shape (n,) or (..., n)
        P0 : array_like, shape (n, n) or (..., n, n)
            Symmetric PSD, broadcast against the batch of ``x0``.

        Raises
        ------
        ValueError
            Wrong shapes, non-finite entries, ``P0`` not symmetric PSD.
        """
        super().reset(x0, P0)
        self._S = self._S0
        self._Z: FloatArray | None = None
        if self._constant and not self._batch:
            self._set_fast_state(readonly(self._pack(self._x, self._P, self._S0)))

    def _pack(self, m: FloatArray, P: FloatArray, S: FloatArray) -> FloatArray:
        """Fast-path state ``X = [blockdiag(P, S); [m; 1; 0...]^T]``, shape (2n + 1, 2n)."""
        n = self._n
        X = np.zeros((2 * n + 1, 2 * n))
        X[:n, :n] = P
        X[n: 2 * n, n:] = S
        X[2 * n, :n] = m
        X[2 * n, n] = 1.0
        return X

    def _set_fast_state(self, X: FloatArray) -> None:
        """Fast-path storage; ``x``, ``P``, ``S`` are (read-only) views of ``X``."""
        n = self._n
        self._Z = X
        self._x = X[2 * n, :n]
        self._P = X[:n, :n]
        self._S = X[n: 2 * n, n:]

    # ---------------------------------------------------------- coefficients
    def _coefficients(self, t: float) -> _Coefficients:
        """The matrices of (7)-(9) at time ``t`` (cached per step for callables)."""
        if self._coef0 is not None:
            return self._coef0
        cached = self._coef_cache.get(t)
        if cached is not None:
            return cached
        A = self._A(t)
        C1, C2, L = self._C1(t), self._C2(t), self._L(t)
        h, b, G, H = self._h(t), self._b(t), self._G(t), self._H(t)
        hh = h if self._intensities else h @ h.T
        Q1 = b if self._intensities else b @ b.T
        W1 = _spd_solve("h h^T", hh, C1, t)
        W2 = _spd_solve("H H^T", H @ H.T, C2, t)
        N2 = _sym(C2.T @ W2)
        M2 = N2 - self._gm2 * (L.T @ L) if self._gm2 else N2
        coef = _Coefficients(
            A=A, B=None if self._B is None else self._B(t), Q1=_sym(Q1), Q2=_sym(G @ G.T),
            W1=W1, M1=_sym(C1.T @ W1), W2=W2, N2=N2, M2=_sym(M2),
        )
        if not self._constant:
            self._coef_cache[t] = coef
        return coef

    def _build_fast(self, h: float) -> _FastConstants:
        """Fast-path coefficients for the RK4 substep ``h`` (see :class:`_FastConstants`)."""
        c = self._coef0
        assert c is not None
        n, m1, m2 = self._n, self._m1, self._m2
        a = 0.5 * h

        def blockdiag(X: FloatArray, Y: FloatArray) -> FloatArray:
            out = np.zeros((X.shape[0] + Y.shape[0], X.shape[1] + Y.shape[1]))
            out[: X.shape[0], : X.shape[1]] = X
            out[X.shape[0]:, X.shape[1]:] = Y
            return out

        Ae = np.zeros((2 * n, 2 * n))
        Ae[:n, :n] = a * c.A
        Kblk = np.zeros((2 * n, m1 + m2))
        Kblk[:n, :m1] = c.W1.T
        Kblk[n:, m1:] = c.W2.T
        Nr = np.zeros((2 * n, 2 * n))
        Nr[:, :n] = -a * np.vstack([c.M1, c.N2])
        Je = np.zeros((2 * n, 2 * n))
        Je[:n, :n] = Je[:n, n:] = np.eye(n)
        Q9 = np.zeros((2 * n + 1, 2 * n))
        Q9[: 2 * n] = a * blockdiag(c.Q1, c.Q2)
        work = []
        for _ in range(7):  # increments a1..a4 and stage states X2..X4
            buf = np.empty((2 * n + 1, 2 * n))
            work.append((buf, buf[: 2 * n], buf[2 * n]))
        Ae = np.asfortranarray(Ae)
        Nr = np.asfortranarray(Nr)
        return _FastConstants(
            work=tuple(work), Nr_col=Nr[:, n], Ae_col=Ae[:n, n],
            half_step=a, Ae=Ae, B=None if c.B is None else a * c.B,
            Abig=a * blockdiag(c.A, c.A), hMbig=(0.5 * a) * blockdiag(c.M1, c.M2),
            Q9=Q9, Kblk=a * Kblk, Nr=Nr, Je=Je,
            Cstack=np.vstack([self._C1.value, self._C2.value]),
        )

    # -------------------------------------------------------------- stepping
    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """Integrate (7)-(9) over one sample interval with ``y`` and ``u`` held.

        Parameters
        ----------
        y : array_like, shape (m1 + m2,) or (..., m1 + m2)
            ``concatenate([y1, y2])``: interval-averaged ``dy1/dt`` and the deterministic
            channel ``y2`` for the interval.
        u : array_like, shape (k,) or (..., k), or None
            Input held over the interval (``None``: zero).

        Returns
        -------
        numpy.ndarray, shape (..., n)
            The estimate ``m`` at the end of the interval (same object as :attr:`x`).

        Raises
        ------
        ValueError
            If ``y`` or ``u`` has the wrong shape or is non-finite; state unchanged.
        LossOfDefinitenessError, FiniteEscapeError
            If ``P`` or ``S`` fails the check after a substep (``quantity`` ``"P"`` or
            ``"S"``), or ``m`` becomes non-finite (``"x"``); state unchanged.
        SubstepLimitError
            ``substeps="auto"`` would exceed the cap; state unchanged.
        """
        y = self._vector("y", y, self._m)
        u = self._input(u)
        if not self._constant:
            self._coef_cache.clear()
        method, every = self._method, 1
        if self._auto_substeps and method == "auto":
            method, self._substeps, every = integrator_for(self._auto_substeps_now())
        elif self._auto_substeps:
            self._substeps = self._auto_substeps_now()
        if method == "rosenbrock":
            m, P, S = self._step_rosenbrock(y, u, every)
            if self._Z is not None:
                X = self._pack(m, P, S)
                X.flags.writeable = False
                self._set_fast_state(X)
                m = self._x
            else:
                for X in (m, P, S):
                    X.flags.writeable = False
                self._x, self._P, self._S = m, P, S
        elif self._Z is not None:
            try:
                X = self._step_fast(y, u)
            except _FastPathFailure:
                # attribute the failure to P or S with the separate-block integrator
                X = self._pack(*self._step_generic(y, u))
            X.flags.writeable = False
            self._set_fast_state(X)
            m = self._x
        else:
            m, P, S = self._step_generic(y, u)
            m.flags.writeable = False
            P.flags.writeable = False
            S.flags.writeable = False
            self._x, self._P, self._S = m, P, S
        self._steps += 1
        return m

    def _step_fast(self, y: FloatArray, u: FloatArray | None) -> FloatArray:
        """RK4 on ``X = [blockdiag(P, S); [m; 1; 0...]^T]``: unbatched, constant matrices.

        The right-hand side returns the stage increments ``a_i = (h/2) k_i`` directly
        (coefficients pre-scaled), so RK4 reads ``X2 = X + a1``, ``X3 = X + a2``,
        ``X4 = X + 2 a3``, ``X+ = X + (a1 + 2 a2 + 2 a3 + a4) / 3``. Returns the new ``X``.
        """
        ns = self._substeps
        h = self._dt / ns  # type: ignore[operator]
        f = self._fast
        if f is None or f.half_step != 0.5 * h:
            f = self._fast = self._build_fast(h)
        assert self._Z is not None
        n = self._n
        n2 = 2 * n
        Abig, hM, Q9, Je = f.Abig, f.hMbig, f.Q9, f.Je
        Nr, Ae = f.Nr, f.Ae  # private work buffers: per-step columns written in place
        np.dot(f.Kblk, y, out=f.Nr_col)
        if f.B is not None:
            if u is not None:
                np.dot(f.B, u, out=f.Ae_col)
            else:
                f.Ae_col[:] = 0.0
        X = X0 = self._Z
        (A1, A1z, A1v), (A2, A2z, A2v), (A3, A3z, A3v), (A4, A4z, A4v), \
            (X2, X2z, X2v), (X3, X3z, X3v), (X4, X4z, X4v) = f.work

        def rhs(Z: FloatArray, v: FloatArray, out: FloatArray, outZ: FloatArray,
                outv: FloatArray) -> None:
            U = (Abig - Z.dot(hM)).dot(Z)
            np.add(U, U.T, out=outZ)  # exactly symmetric
            np.add(Ae.dot(v), Je.dot(Z.dot(Nr.dot(v))), out=outv)
            out += Q9

        third = 1.0 / 3.0
        add = np.add
        for i in range(ns):
            rhs(X[:n2], X[n2], A1, A1z, A1v)
            add(X, A1, out=X2)
            rhs(X2z, X2v, A2, A2z, A2v)
            add(X, A2, out=X3)
            rhs(X3z, X3v, A3, A3z, A3v)
            add(X, A3, out=X4)
            X4 += A3
            rhs(X4z, X4v, A4, A4z, A4v)
            A2 += A3
            A2 += A2
            A2 += A1
            A2 += A4
            A2 *= third
            X = X + A2  # a new array; the Z block stays exactly symmetric
            Z = X[:n2]
            v = Z.ravel()
            if not (v.dot(v) <= _ESCAPE_BOUND_SQ and _dpotrf(Z)[1] == 0):
                # singular PSD blocks are legal; anything else is attributed to P or S by
                # the generic integrator
                t = self.t_s + (i + 1) * h
                try:
                    check_covariance(Z[:n, :n], time=t, quantity="P")
                    check_covariance(Z[n:, n:], time=t, quantity="S")
                except FilterError:
                    raise _FastPathFailure from None
        mv = X[n2]
        if not math.isfinite(mv.dot(mv)) and not np.isfinite(mv).all():
            raise FiniteEscapeError("state estimate became non-finite",
                                    time=self._time(self._steps + 1), quantity="x",
                                    value=X[n2, :n].copy())
        self._innovation_data = (y.copy(), X0[n2, :n], f.Cstack)  # evaluated on access
        return X

    @staticmethod
    def _rhs(c: _Coefficients, y1: FloatArray, y2: FloatArray, u: FloatArray | None,
             m: FloatArray, P: FloatArray, S: FloatArray
             ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Right-hand sides of (7)-(9): ``(dm, dP, dS)``, broadcasting over leading axes."""
        e1 = np.vecmat(y1, c.W1) - np.vecmat(m, c.M1)  # (..., n); M1, N2 symmetric
        e2 = np.vecmat(y2, c.W2) - np.vecmat(m, c.N2)
        dm = (np.vecmat(m, c.A.T) + (P @ e1[..., None])[..., 0]
              + np.vecmat(e2, S))
        if u is not None and c.B is not None:
            dm = dm + np.vecmat(u, c.B.T)
        TP = (c.A - 0.5 * (P @ c.M1)) @ P
        dP = TP + np.swapaxes(TP, -1, -2) + c.Q1
        TS = (c.A - 0.5 * (S @ c.M2)) @ S
        dS = TS + np.swapaxes(TS, -1, -2) + c.Q2
        return dm, dP, dS

    def _step_rosenbrock(
        self, y: FloatArray, u: FloatArray | None, jacobian_every: int = 1
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """ROS2 substeps (:func:`filters.stiff.rosenbrock2`) on the stacked
        ``s = [m, vec(P), vec(S)]`` (``S`` broadcast to the batch: every member's copy is
        the same), with the analytic, block upper triangular Jacobian (``W^-1`` by blocks:
        ``P`` and ``S`` through the inverse of their Lyapunov operators, ``m`` through
        ``I - gamma h (A - P M1 - S N2)``) and the checks of the RK4 paths after every
        substep."""
        n, m1, batch = self._n, self._m1, self._batch
        m = np.broadcast_to(self._x, (*batch, n))
        P = np.broadcast_to(self._P, (*batch, n, n))
        S = np.broadcast_to(self._S, (*batch, n, n))
        ns = self._substeps
        h = self._dt / ns  # type: ignore[operator]
        t_start = self.t_s
        C = np.vstack([self._C1(t_start), self._C2(t_start)])
        innovation = y - np.vecmat(m, C.T)
        y = np.broadcast_to(y, (*batch, self._m))
        u = None if u is None else np.broadcast_to(u, (*batch, self._k))
        nn = n * n
        # P and S do not depend on m: members that share P0 share P (S is shared). Blocks
        # shared by all members (the filter's own substeps keep them so: the same operations
        # on the same numbers) are evaluated on the first member, shape (1, ..., 1, n, n),
        # broadcast against the means: equations, blocks of W^-1 and checks.

        def split(s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
            PS = shared_member(s[..., n:], core_ndim=1)  # P and S shared: one comparison
            if PS.shape[:-1] == s.shape[:-1]:  # not both shared (or one member)
                return (s[..., :n], shared_member(s[..., n:n + nn].reshape(*batch, n, n)),
                        shared_member(s[..., n + nn:].reshape(*batch, n, n)))
            return (s[..., :n], PS[..., :nn].reshape(*PS.shape[:-1], n, n),
                    PS[..., nn:].reshape(*PS.shape[:-1], n, n))

        def stack(m: FloatArray, P: FloatArray, S: FloatArray) -> FloatArray:
            """``[m, vec(P), vec(S)]`` of the members (shared ``P``, ``S`` broadcast)."""
            s = np.empty((*batch, n + 2 * nn))
            s[..., :n] = m
            s[..., n:n + nn] = P.reshape(*P.shape[:-2], nn)
            s[..., n + nn:] = S.reshape(*S.shape[:-2], nn)
            return s

        def rhs(t: float, s: FloatArray) -> FloatArray:
            return stack(*self._rhs(self._coefficients(t), y[..., :m1], y[..., m1:], u,
                                    *split(s)))

        eye_n = np.eye(n)

        def lyapunov(T: FloatArray, gh: float) -> FloatArray:
            """``(I - gh (T (x) I + I (x) T))^-1``: the Riccati block of ``W`` (row-major
            ``vec(T X + X T^T)``)."""
            K = (np.einsum("...ik,jl->...ijkl", T, eye_n)
                 + np.einsum("ik,...jl->...ijkl", eye_n, T)).reshape(*T.shape[:-2], nn, nn)
            return np.linalg.inv(np.eye(nn) - gh * K)

        def solver(t: float, s: FloatArray, f: FloatArray, gh: float
                   ) -> Callable[[FloatArray], FloatArray]:
            # J is block upper triangular: P and S do not depend on m, nor on each other;
            # dm = (A - P M1 - S N2) m + P W1^T y1 + S W2^T y2 + B u
            c = self._coefficients(t)
            mm, PP, SS = split(s)
            e1 = np.vecmat(y[..., :m1], c.W1) - np.vecmat(mm, c.M1)
            e2 = np.vecmat(y[..., m1:], c.W2) - np.vecmat(mm, c.N2)
            Wm = np.linalg.inv(eye_n - gh * (c.A - PP @ c.M1 - SS @ c.N2))
            WP = lyapunov(c.A - PP @ c.M1, gh)
            WS = lyapunov(c.A - SS[(0,) * len(batch)] @ c.M2, gh)  # the same for all

            def solve(v: FloatArray) -> FloatArray:
                _, vP, vS = split(v)  # the P and S blocks of v are shared as P and S
                kP = (WP @ vP.reshape(*vP.shape[:-2], nn, 1))[..., 0].reshape(vP.shape)
                kS = np.vecmat(vS.reshape(*vS.shape[:-2], nn), WS.T).reshape(vS.shape)
                coupling = (kP @ e1[..., None])[..., 0] + np.vecmat(e2, kS)
                km = ((Wm @ (v[..., :n] + gh * coupling)[..., None])[..., 0])
                return stack(km, kP, kS)

            return solve

        def after(i: int, t_end: float, s: FloatArray) -> FloatArray:
            nonlocal m, P, S
            m, PP, SS = split(s)
            P = check_shared_covariance(PP, batch, time=t_end, quantity="P")
            S = check_shared_covariance(SS, batch, time=t_end, quantity="S")
            return stack(m, P, S)

        with np.errstate(over="ignore", invalid="ignore"):
            rosenbrock2(rhs, np.concatenate([m, P.reshape(*batch, nn), S.reshape(*batch, nn)],
                                            -1), t_start, h, ns, solver, after,
                        jacobian_every)
        m = np.array(m)
        if not np.isfinite(m).all():
            raise FiniteEscapeError("state estimate became non-finite",
                                    time=self._time(self._steps + 1), quantity="x", value=m)
        S = np.array(S[(0,) * len(batch)])
        self.innovation = innovation
        return m, np.array(np.broadcast_to(P, (*batch, n, n)), order="C"), S

    def _step_generic(
        self, y: FloatArray, u: FloatArray | None
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """RK4 on ``(m, P, S)`` with broadcasting matmul (batched and/or time-varying)."""
        m1 = self._m1
        y1, y2 = y[..., :m1], y[..., m1:]
        m, P, S = self._x, self._P, self._S
        ns = self._substeps
        h = self._dt / ns  # type: ignore[operator]
        t_start = self.t_s
        C = np.vstack([self._C1(t_start), self._C2(t_start)])
        innovation = y - np.vecmat(m, C.T)
        # P does not depend on m: members that share P0 share P, integrated once
        P = shared_member(P)

        def rhs(t: float, m: FloatArray, P: FloatArray,
                S: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
            return self._rhs(self._coefficients(t), y1, y2, u, m, P, S)

        for i in range(ns):
            t = t_start + i * h
            tm, te = t + 0.5 * h, t_start + (i + 1) * h
            k1 = rhs(t, m, P, S)
            k2 = rhs(tm, m + 0.5 * h * k1[0], P + 0.5 * h * k1[1], S + 0.5 * h * k1[2])
            k3 = rhs(tm, m + 0.5 * h * k2[0], P + 0.5 * h * k2[1], S + 0.5 * h * k2[2])
            k4 = rhs(te, m + h * k3[0], P + h * k3[1], S + h * k3[2])
            m, P, S = (
                X + (h / 6.0) * (a + 2.0 * (b_ + c_) + d)
                for X, a, b_, c_, d in zip((m, P, S), k1, k2, k3, k4, strict=True)
            )
            P = check_shared_covariance(P, self._batch, time=te, quantity="P")
            S = check_covariance(S, time=te, quantity="S")
        m = np.array(np.broadcast_to(m, (*self._batch, self._n)))
        P = np.array(np.broadcast_to(P, (*self._batch, self._n, self._n)), order="C")
        if not np.isfinite(m).all():
            raise FiniteEscapeError("state estimate became non-finite",
                                    time=self._time(self._steps + 1), quantity="x", value=m)
        self.innovation = innovation
        return m, P, S

    # ------------------------------------------------------------- analysis
    def suggested_substeps(self, P: npt.ArrayLike | None = None, S: npt.ArrayLike | None = None,
                           *, limit: float = 2.5) -> int:
        """Heuristic number of RK4 substeps per interval for a numerically stable step.

        Linearized at ``(P, S)``, the error of (8) evolves with ``M_P = A - P M1`` (rates
        ``lambda_i + lambda_j``), that of (9) with ``M_S = A - S M2`` and the mean (7) with
        ``M_m = A - P M1 - S N2`` (``M1 = C1^T (h h^T)^-1 C1``, ``N2 = C2^T (H H^T)^-1 C2``,
        ``M2 = N2 - gamma^-2 L^T L``). Explicit RK4 needs ``h |rate| <~ 2.8``, so this
        returns ``ceil(dt * max(2|lambda(M_P)|, 2|lambda(M_S)|, |lambda(M_m)|) / limit)``.

        Parameters
        ----------
        P : array_like, shape (n, n) or (..., n, n), optional
            Default: the current :attr:`P` (maximum over a batch).
        S : array_like, shape (n, n), optional
            Default: the current :attr:`S`.
        limit : float
            Admissible ``h * max rate`` (2.5 leaves a margin to RK4's real-axis bound 2.785).

        Returns
        -------
        int
            At least 1.
        """
        c = self._coefficients(self.t_s)
        P_arr = self._P if P is None else to_float_array("P", P)
        S_arr = self._S if S is None else to_float_array("S", S)
        PM1 = P_arr @ c.M1
        rates = (
            2.0 * max_abs_eigenvalue(c.A - PM1),
            2.0 * max_abs_eigenvalue(c.A - S_arr @ c.M2),
            max_abs_eigenvalue(c.A - PM1 - S_arr @ c.N2),
        )
        if not all(math.isfinite(r) for r in rates):
            return self._substeps
        return max(1, math.ceil(self._dt * max(rates) / limit))  # type: ignore[operator]

    def steady_state(self) -> tuple[FloatArray, FloatArray]:
        """Stationary ``P`` and ``S`` (constant matrices only).

        Returns
        -------
        P_inf : numpy.ndarray, shape (n, n)
            Stabilizing solution of ``A P + P A^T + b b^T - P M1 P = 0`` (8).
        S_inf : numpy.ndarray, shape (n, n)
            Stabilizing solution of ``A S + S A^T + G G^T - S M2 S = 0`` (9), from
            ``scipy.linalg.solve_continuous_are`` with the indefinite weight
            ``blockdiag(H H^T, -gamma^2 I)`` on ``[C2; L]``.

        Raises
        ------
        ValueError
            If a matrix is time-varying, or an algebraic Riccati equation has no
            stabilizing positive semidefinite solution (for ``S``: ``gamma`` below the
            achievable level). Checked: residual <= 1e-8 (relative), ``min eig >= 0``,
            ``A - X M`` Hurwitz.
        """
        if not self._constant:
            raise ValueError("steady_state needs constant matrices")
        c = self._coef0
        assert c is not None
        A = c.A
        C1, C2, L = self._C1.value, self._C2.value, self._L.value
        hh = self._h.value if self._intensities else self._h.value @ self._h.value.T
        H = self._H.value
        try:
            P = solve_continuous_are(A.T, C1.T, c.Q1, hh)
            if self._gm2:
                q = L.shape[0]
                Bs = np.hstack([C2.T, L.T])
                Rs = np.zeros((Bs.shape[1], Bs.shape[1]))
                Rs[: C2.shape[0], : C2.shape[0]] = H @ H.T
                Rs[C2.shape[0]:, C2.shape[0]:] = -(self._gamma**2) * np.eye(q)
                S = solve_continuous_are(A.T, Bs, c.Q2, Rs)
            else:
                S = solve_continuous_are(A.T, C2.T, c.Q2, H @ H.T)
        except (ValueError, np.linalg.LinAlgError) as exc:
            raise ValueError(f"no stabilizing solution of the algebraic Riccati equation: "
                             f"{exc}") from exc
        for name, X, Q, M in (("P", _sym(P), c.Q1, c.M1), ("S", _sym(S), c.Q2, c.M2)):
            residual = float(np.abs(A @ X + X @ A.T + Q - X @ M @ X).max())
            scale = max(1.0, float(np.abs(X).max()) ** 2 * float(np.abs(M).max()),
                        float(np.abs(Q).max()))
            emin = float(np.linalg.eigvalsh(X)[0])
            abscissa = float(np.linalg.eigvals(A - X @ M).real.max())
            if not (residual <= 1e-8 * scale and emin >= -1e-9 * float(np.abs(X).max())
                    and abscissa < 0.0):
                raise ValueError(
                    f"no stabilizing positive semidefinite solution of the algebraic Riccati "
                    f"equation for {name} (residual {residual:.3g}, min eigenvalue {emin:.3g}, "
                    f"closed-loop spectral abscissa {abscissa:.3g})"
                    + ("; gamma is below the achievable level" if name == "S" else ""))
        return _sym(P), _sym(S)

    # ------------------------------------------------------------ assumptions
    def _check_c4(self, t0: float) -> None:
        """Hard algebraic assumptions at ``t0``: ``h h^T > 0``, ``H H^T > 0``, ``H G^T = 0``."""
        h, H, G = self._h.value, self._H.value, self._G.value
        hh = h if self._intensities else h @ h.T
        if self._intensities and float(np.abs(hh - hh.T).max()) > 1e-9 * float(
                np.abs(hh).max()):
            raise ValueError("h h^T (noise_intensities=True) must be symmetric")
        if not _is_pd(hh):
            raise ValueError("h h^T must be positive definite (intensity of the y1 noise), "
                             f"got eigenvalues {np.linalg.eigvalsh(_sym(hh))} at t = {t0:.6g} s")
        HH = H @ H.T
        if not _is_pd(HH):
            raise ValueError("assumption C4 violated: H H^T must be positive definite, got "
                             f"eigenvalues {np.linalg.eigvalsh(_sym(HH))} at t = {t0:.6g} s")
        HG = H @ G.T
        err = float(np.abs(HG).max()) if HG.size else 0.0
        scale = max(1.0, float(np.abs(H).max()) * float(np.abs(G).max()) if G.size else 1.0)
        if err > _ORTHOGONALITY_RTOL * scale:
            raise ValueError(f"assumption C4 violated: H G^T must be 0, max |H G^T| = "
                             f"{err:.6g} at t = {t0:.6g} s")
        if self._intensities:
            Q1 = self._b.value
            if float(np.abs(Q1 - Q1.T).max()) > 1e-9 * max(1.0, float(np.abs(Q1).max())) or \
                    np.linalg.eigvalsh(_sym(Q1))[0] < -1e-9 * max(1.0, float(np.abs(Q1).max())):
                raise ValueError("b b^T (noise_intensities=True) must be symmetric PSD")

    def _check_stabilizability(self, t0: float) -> dict[str, bool]:
        """Soft assumptions (C1)-(C3) at ``t0`` by PBH tests; warns for each failure."""
        A = self._A.value
        n = self._n
        b = self._b.value
        if self._intensities:  # any square root of b b^T has the same range
            w, V = np.linalg.eigh(_sym(b))
            b = V * np.sqrt(np.clip(w, 0.0, None))
        B = np.zeros((n, 0)) if self._B is None else self._B.value
        tests = {
            "C1: (A, b) stabilizable": _pbh_stabilizable(A, b),
            "C1: (C1, A) detectable": _pbh_stabilizable(A.T, self._C1.value.T),
            "C2: (A, G) stabilizable": _pbh_stabilizable(A, self._G.value),
            "C2: (C2, A) detectable": _pbh_stabilizable(A.T, self._C2.value.T),
            "C3: (A, B) stabilizable": _pbh_stabilizable(A, B),
            "C3: (L, A) detectable": _pbh_stabilizable(A.T, self._L.value.T),
        }
        where = "(constant matrices)" if self._constant else f"at t0 = {t0:.6g} s"
        for label, ok in tests.items():
            if not ok:
                warnings.warn(f"assumption {label} fails {where} (PBH rank test on the "
                              "eigenvalues of A with Re >= 0)", AssumptionWarning, stacklevel=3)
        return tests


class _FastPathFailure(Exception):
    """Internal: the block integrator saw a failed check; redo with the generic one."""


def _sym(X: FloatArray) -> FloatArray:
    return 0.5 * (X + X.T)


def _is_pd(X: FloatArray) -> bool:
    if X.size == 0 or not np.isfinite(X).all():
        return False
    return _dpotrf(_sym(X))[1] == 0 and float(np.linalg.eigvalsh(_sym(X))[0]) > 0.0


def _spd_solve(name: str, M: FloatArray, C: FloatArray, t: float) -> FloatArray:
    """``M^-1 C`` for symmetric positive definite ``M`` (Cholesky); ValueError naming it."""
    Ms = _sym(M)
    try:
        Lc = np.linalg.cholesky(Ms)
    except np.linalg.LinAlgError:
        raise ValueError(f"{name} must be positive definite, it is not at t = {t:.6g} s") \
            from None
    Z = np.linalg.solve(Lc, C)
    return np.linalg.solve(Lc.T, Z)
