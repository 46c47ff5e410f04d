"""Central H-infinity filters for polynomial systems (Basin, Shi & Calderon-Alvarez) and the
linearized comparison.

Reference: M. Basin, P. Shi, D. Calderon-Alvarez, "Central suboptimal H-infinity filter design
for nonlinear polynomial systems".

System (:class:`~filters.polynomial_model.PolynomialModel`, eqs. (1)-(4))::

    dx/dt = f(x, t) + B w,   y = C x + D w,   z = L x,
    f(x, t) = a0 + a1 x + a2 x x^T + a3 x x x^T

Three filters, one integrator (:class:`_CentralHInfFilter`):

* :class:`PolynomialHInfFilter` -- Theorem 1, eqs. (11)-(15) (noise orthonormality (C3):
  ``D B^T = 0``, ``D D^T = I``);
* :class:`NonOrthonormalPolynomialHInfFilter` -- Corollary 1, eqs. (29)-(33) (no (C3));
* :class:`LinearizedHInfFilter` -- the conventional central H-infinity filter of the
  system linearized at the estimate, eqs. (27)-(28) of the example (the filter of
  Nagpal & Khargonekar, Theorems 3-4, with ``A(t) = df/dx`` at the estimate).

All three integrate, over each sample interval with ``y`` (and ``u``) held::

    dx_f/dt = F(x_f, P) + E u + K (y - C x_f),      K = (P C^T + B D^T)(D D^T)^-1
    dP/dt   = A(x_f, P) P + P A(x_f, P)^T + B B^T - K (D B^T + C P) + gamma^-2 P L^T L P

and differ only in ``F`` and ``A`` (with (C3) the gain is ``P C^T`` and
``- K (D B^T + C P) = - P C^T C P``, i.e. (11) and (13)).

Evaluation: for small systems (``n = 2`` or 3) with constant ``B, C, D, L, E``,
:meth:`~PolynomialHInfFilter.step` evaluates this right-hand side as one cubic form in
``z = [1, x_f, vec(P), y, u]`` (:mod:`filters._hinf_cubic`: a few array operations per RK4
stage, the batch on the last axis); otherwise, and in :meth:`~PolynomialHInfFilter.derivatives`,
term by term. Both give the same values up to rounding (tested to 1e-12). A batch of ``N``
filters is one object with ``x0`` of shape ``(N, n)``, stepped with ``y`` of shape ``(N, m)``.

Derivation of ``f_hat`` and ``g_hat`` (14)-(15)
-----------------------------------------------
Theorem 1 is built on the optimal polynomial filter of Basin, Calderon-Alvarez, Skliar
(2008, the paper's [24]): ``f_hat = E[f(x)]`` and ``g_hat = E[f(x) e^T] + E[e f(x)^T]``
with ``e = x - x_f`` conditionally Gaussian, ``E[e] = 0``, ``E[e e^T] = P`` (third moments
zero, fourth moments ``E[e_i e_j e_k e_l] = P_ij P_kl + P_ik P_jl + P_il P_jk``). With the
tensors symmetrized (:func:`~filters.polynomial_model.symmetrize_tensor`, which leaves ``f``
unchanged) this gives, ``m = x_f``::

    f_hat = a0 + a1 m + a2 m m^T + a2 P + 3 a3 m P + a3 m m m^T                    (14)
          = f(m) + a2 : P + 3 a3 : (m (x) P)
    E[f e^T] = A_hat P,  A_hat = a1 + 2 a2 m + 3 a3 (m m^T + P)
    g_hat = A_hat P + P A_hat^T
          = a1 P + P a1^T + 2 a2 m P + 2 (a2 m P)^T
            + 3 a3 [P P + m m^T P] + 3 (a3 [P P + m m^T P])^T                      (15)

where ``(a2 m)_kj = sum_i a2_kij m_i``, ``(a3 M)_kl = sum_ij a3_kijl M_ij``. So (13) is a
Riccati equation whose "A" is ``A_hat = J(m) + 3 a3 P`` (``J = df/dx``): the linearized
filter's (28) uses ``J(m)`` instead.

Misprints of the paper corrected here
-------------------------------------
* (32), Corollary 1's ``f_hat``, prints ``a3 P`` and ``a3 x x^T P`` where the derivation
  above (and Theorem 1's (14)) has ``a2 P`` and ``a3 x x x^T``: (32) is dimensionally
  wrong for ``a3 P`` (a 4-D tensor contracted with a matrix is a matrix, not a vector).
  Corollary 1 only changes the gain (Pila, Shaked, de Souza 1999), not ``f_hat``, so this
  module uses (14) for both; (33) equals (15).
* (15) misses a closing parenthesis after the first ``3 a3 [...]`` term.
* Corollary 1's initial condition ``x_f(theta) = 0, theta in [t0 - h, t0]`` is a leftover
  of the time-delay paper it is taken from; here ``x_f(t0) = x0`` (default 0).
* The example's (26) and (28) contain ``-(1 - gamma^-2) P C^T C P`` only, i.e. (13) with
  ``L = C = [1 0]``; the example's output is ``z = x`` (``L = I``), for which (13) adds
  ``+gamma^-2 P e2 e2^T P``. Both are obtained from these classes by the ``L`` of the
  model (see :mod:`testbed.reproductions.basin_polynomial.scenario`).
* (27) prints ``0.2 m^2 + (0.3 + 0.3 sin 50t) m^3`` for the linearized state equation:
  that is ``J(m) m`` (the Jacobian at the estimate times the estimate), not the system's
  ``f(m) = 0.1 m^2 + (0.1 + 0.1 sin 50t) m^3``; :class:`LinearizedHInfFilter` offers both
  (``state_equation="jacobian"`` / ``"system"``).

Finite escape
-------------
Remark 2: with an unstable top-degree term, ``x_f`` and ``P`` escape in finite time. After
every substep (RK4, or ROS2 with ``method="rosenbrock"``) ``x_f`` and ``P`` are tested by an
:class:`~filters.polynomial_model.EscapeTest` (a bound and a growth test, never NaN) and
``P`` for positive semidefiniteness; failures raise
:class:`~filters.errors.FiniteEscapeError` (quantity ``"x"`` or ``"P"``) or
:class:`~filters.errors.LossOfDefinitenessError` with the time of the substep, leaving the
filter unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import numpy.typing as npt

from filters._hinf_cubic import MAX_ENTRIES, CubicForm
from filters._linalg import FloatArray, positive_time, readonly, to_float_array
from filters.errors import check_symmetric_covariance
from filters.kalman import _IntegratedFilter
from filters.polynomial_model import EscapeTest, PolynomialCoefficients, PolynomialModel
from filters.stiff import difference_solver, rosenbrock2

__all__ = [
    "LinearizedHInfFilter",
    "NonOrthonormalPolynomialHInfFilter",
    "PolynomialHInfFilter",
    "f_hat",
    "g_hat",
    "moment_matrix",
]

#: Relative tolerance of the orthonormality check (C3).
_C3_RTOL = 1e-9
#: Integrators of :attr:`PolynomialHInfFilter.method`.
METHODS = ("rk4", "rosenbrock")


def _count(name: str, value: object) -> int:
    """``value`` as an integer >= 1, else ``ValueError`` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    return int(value)


def _outer(x: FloatArray) -> FloatArray:
    return x[..., :, None] * x[..., None, :]


def _swap(X: FloatArray) -> FloatArray:
    return np.swapaxes(X, -1, -2)


def f_hat(c: PolynomialCoefficients, x: npt.ArrayLike, P: npt.ArrayLike) -> FloatArray:
    """``E[f(x)]`` for ``x ~ N(x_f, P)``: eq. (14) (and the corrected (32)).

    Parameters
    ----------
    c : PolynomialCoefficients
        Coefficients at the current time (symmetrized tensors).
    x : array_like, shape (..., n)
        Estimate ``x_f``.
    P : array_like, shape (..., n, n)
        Gain matrix (the conditional covariance of the equivalent H2 problem).

    Returns
    -------
    numpy.ndarray, shape (..., n)
        ``a0 + a1 x + a2 x x^T + a2 P + 3 a3 x P + a3 x x x^T``.
    """
    x = np.asarray(x, dtype=np.float64)
    P = np.asarray(P, dtype=np.float64)
    out = c.a0 + x @ c.a1.T
    if c.a2 is not None or c.a3 is not None:
        xx = _outer(x)
        if c.a2 is not None:
            out = out + np.einsum("kij,...ij->...k", c.a2, xx + P)
        if c.a3 is not None:
            out = out + np.einsum("kijl,...i,...jl->...k", c.a3, x, xx + 3.0 * P)
    return out


def moment_matrix(c: PolynomialCoefficients, x: npt.ArrayLike, P: npt.ArrayLike) -> FloatArray:
    """``A_hat = a1 + 2 a2 x + 3 a3 (x x^T + P)``, with ``E[f(x) e^T] = A_hat P``.

    Parameters
    ----------
    c : PolynomialCoefficients
    x : array_like, shape (..., n)
    P : array_like, shape (..., n, n)

    Returns
    -------
    numpy.ndarray, shape (..., n, n)
        The "A" of the Riccati equation (13): ``g_hat = A_hat P + P A_hat^T``.
    """
    x = np.asarray(x, dtype=np.float64)
    P = np.asarray(P, dtype=np.float64)
    batch = np.broadcast_shapes(x.shape[:-1], P.shape[:-2])
    A = c.a1
    if c.a2 is not None:
        A = A + 2.0 * np.einsum("kij,...i->...kj", c.a2, x)
    if c.a3 is not None:
        A = A + 3.0 * np.einsum("kijl,...ij->...kl", c.a3, _outer(x) + P)
    if A.shape[:-2] != batch:
        A = np.broadcast_to(A, batch + c.a1.shape)
    return np.array(A)


def g_hat(c: PolynomialCoefficients, x: npt.ArrayLike, P: npt.ArrayLike) -> FloatArray:
    """``E[f e^T] + E[e f^T]`` for ``x ~ N(x_f, P)``: eq. (15) (= (33)).

    Parameters
    ----------
    c : PolynomialCoefficients
    x : array_like, shape (..., n)
    P : array_like, shape (..., n, n)

    Returns
    -------
    numpy.ndarray, shape (..., n, n)
        ``A_hat P + P A_hat^T`` (see :func:`moment_matrix`), exactly symmetric.
    """
    AP = moment_matrix(c, x, P) @ np.asarray(P, dtype=np.float64)
    return AP + _swap(AP)


@dataclass(frozen=True, slots=True)
class _Terms:
    """Coefficients at one time plus the gain factors.

    ``BBt = B B^T`` (n, n); ``BDt = B D^T`` (n, m) or None if zero; ``Li = chol(D D^T)^-1``
    (m, m) or None if ``D D^T = I``, so that ``(D D^T)^-1 = Li^T Li``. The tensors as matrices
    for matmul contractions (``None`` without the term): ``a1T = a1^T``;
    ``F2[(i, j), k] = a2[k, i, j]`` (n^2, n), ``F3[(i, j, l), k] = a3[k, i, j, l]`` (n^3, n);
    ``J2[i, (k, j)] = 2 a2[k, i, j]`` (n, n^2); ``J3[(i, j), (k, l)] = 3 a3[k, i, j, l]``
    (n^2, n^2), so that ``f_hat = a0 + x a1^T + vec(x x^T + P) F2 + vec(x (x) (x x^T + 3 P))
    F3`` and ``A_hat = a1 + unvec(x J2) + unvec(vec(x x^T + P) J3)``.
    """

    c: PolynomialCoefficients
    BBt: FloatArray
    BDt: FloatArray | None
    Li: FloatArray | None
    CT: FloatArray
    LT: FloatArray
    a1T: FloatArray
    F2: FloatArray | None
    F3: FloatArray | None
    J2: FloatArray | None
    J3: FloatArray | None


def _contractions(c: PolynomialCoefficients) -> tuple[FloatArray | None, ...]:
    """``(F2, F3, J2, J3)`` of :class:`_Terms`."""
    n = c.a1.shape[0]
    F2 = F3 = J2 = J3 = None
    if c.a2 is not None:
        F2 = np.ascontiguousarray(c.a2.reshape(n, n * n).T)
        J2 = np.ascontiguousarray(2.0 * c.a2.transpose(1, 0, 2).reshape(n, n * n))
    if c.a3 is not None:
        F3 = np.ascontiguousarray(c.a3.reshape(n, n**3).T)
        J3 = np.ascontiguousarray(3.0 * c.a3.transpose(1, 2, 0, 3).reshape(n * n, n * n))
    return F2, F3, J2, J3


class _CentralHInfFilter(_IntegratedFilter):
    """Shared integrator of the central H-infinity filters (see the module docstring).

    Subclasses define :meth:`_drift` (the ``F`` and ``A`` of the state and gain equations).
    """

    name: ClassVar[str] = ""

    def __init__(
        self,
        model: PolynomialModel,
        gamma: float,
        R: npt.ArrayLike,
        dt_s: float,
        x0: npt.ArrayLike | None = None,
        *,
        substeps: int = 1,
        t0: float = 0.0,
        escape: EscapeTest | None = None,
        method: str = "rk4",
        jacobian_every: int = 1,
    ) -> None:
        if not isinstance(model, PolynomialModel):
            raise TypeError(f"model must be a PolynomialModel, got {type(model).__name__}")
        self._model = model
        self.method = method
        self.jacobian_every = jacobian_every
        self.substeps = substeps
        self._dt = positive_time("dt_s", dt_s)
        t0 = float(t0)
        if not math.isfinite(t0):
            raise ValueError(f"t0 must be a finite time in s, got {t0!r}")
        self._t0 = t0
        try:
            g = float(gamma)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"gamma must be a positive float, got {gamma!r}") from exc
        if not g > 0.0:
            raise ValueError(f"gamma must be a positive float (attenuation level), got {gamma!r}")
        self._gamma = g
        self._gm2 = 0.0 if math.isinf(g) else 1.0 / (g * g)
        if escape is not None and not isinstance(escape, EscapeTest):
            raise TypeError(f"escape must be an EscapeTest, got {type(escape).__name__}")
        self._escape = escape or EscapeTest()
        n = model.n
        self._n, self._m, self._k = n, model.m, model.k
        Rm = to_float_array("R", R)
        if Rm.shape != (n, n) or not np.isfinite(Rm).all():
            raise ValueError(f"R must be a finite symmetric positive definite matrix of shape "
                             f"({n}, {n}), got shape {Rm.shape}")
        scale = float(np.abs(Rm).max())
        if float(np.abs(Rm - Rm.T).max()) > 1e-9 * scale:
            raise ValueError("R must be symmetric positive definite (P(t0) = R^-1), got a "
                             "non-symmetric matrix")
        Rm = 0.5 * (Rm + Rm.T)
        emin = float(np.linalg.eigvalsh(Rm)[0])
        if not emin > 0.0:
            raise ValueError(f"R must be symmetric positive definite (P(t0) = R^-1), got "
                             f"minimum eigenvalue {emin:.6g}")
        P0 = np.linalg.inv(Rm)
        self._R = readonly(Rm)
        self._P0 = readonly(0.5 * (P0 + P0.T))
        self._cache: dict[float, _Terms] = {}
        self._gain_terms: _Terms | None = None
        first = self._make_terms(t0)
        if model.constant_matrices:  # B, C, D, L fixed: the gain factors are computed once
            self._gain_terms = first
        self._const_terms = first if model.constant else None
        self._check_model(self._terms(t0))
        self._cubic: CubicForm | None = None
        self._magnitudes: tuple[FloatArray, FloatArray, FloatArray] | None = None
        variant = self._cubic_variant()
        if (variant is not None and model.constant_matrices
                and CubicForm.size(model) <= MAX_ENTRIES):
            self._cubic = CubicForm(model, variant, self._gm2, t0)
            self._CT = first.CT
        self.reset(np.zeros(n) if x0 is None else x0, self._P0)

    # ------------------------------------------------------------ properties
    @property
    def model(self) -> PolynomialModel:
        """The system model."""
        return self._model

    @property
    def gamma(self) -> float:
        """Attenuation level of (10)."""
        return self._gamma

    @property
    def R(self) -> FloatArray:
        """Weight of ``x(t0)`` in (10), shape (n, n)."""
        return self._R

    @property
    def P0(self) -> FloatArray:
        """``R^-1``, the initial gain matrix, shape (n, n)."""
        return self._P0




    @property
    def substeps(self) -> int:
        """Substeps of :attr:`method` per sample interval (may be changed between steps, e.g.
        as the Riccati equation's stiffness falls with ``P``)."""
        return self._substeps

    @substeps.setter
    def substeps(self, value: int) -> None:
        self._substeps = _count("substeps", value)

    @property
    def method(self) -> str:
        """Integrator of each sample interval: ``"rk4"`` (classical Runge-Kutta, explicit:
        about ``rate * dt`` substeps on stiff equations) or ``"rosenbrock"`` (ROS2 of
        :mod:`filters.stiff`: L-stable, order 2, for stiff equations); may be changed
        between steps."""
        return self._method

    @method.setter
    def method(self, value: str) -> None:
        if value not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {value!r}")
        self._method = value

    @property
    def jacobian_every(self) -> int:
        """``"rosenbrock"``: substeps between Jacobian evaluations (1: every substep; at
        least :attr:`substeps`: one per interval)."""
        return self._jacobian_every

    @jacobian_every.setter
    def jacobian_every(self, value: int) -> None:
        self._jacobian_every = _count("jacobian_every", value)

    @property
    def escape(self) -> EscapeTest:
        """The finite-escape test applied after every substep."""
        return self._escape

    def _time(self, steps: int) -> float:
        return self._t0 + steps * self._dt  # type: ignore[operator]

    # ----------------------------------------------------------- coefficients
    def _check_model(self, terms: _Terms) -> None:
        """Hook: assumptions on the model at ``t0`` (raise ``ValueError``)."""

    def _make_terms(self, t: float) -> _Terms:
        c = self._model.at(t)
        gain = self._gain_terms
        if gain is not None:
            return _Terms(c, gain.BBt, gain.BDt, gain.Li, gain.CT, gain.LT,
                          np.ascontiguousarray(c.a1.T), *_contractions(c))
        BDt = c.B @ c.D.T
        DDt = c.D @ c.D.T
        m = DDt.shape[0]
        if np.array_equal(DDt, np.eye(m)):
            Li = None
        else:
            try:
                Lc = np.linalg.cholesky(0.5 * (DDt + DDt.T))
            except np.linalg.LinAlgError:
                raise ValueError(f"D D^T must be positive definite (the gain inverts it), it "
                                 f"is not at t = {t:.6g} s") from None
            Li = np.linalg.inv(Lc)
        BBt = c.B @ c.B.T
        return _Terms(c, 0.5 * (BBt + BBt.T), BDt if np.any(BDt) else None, Li,
                      np.ascontiguousarray(c.C.T), np.ascontiguousarray(c.L.T),
                      np.ascontiguousarray(c.a1.T), *_contractions(c))

    def _terms(self, t: float) -> _Terms:
        if self._const_terms is not None:
            return self._const_terms
        terms = self._cache.get(t)
        if terms is None:
            if len(self._cache) > 8:
                self._cache.clear()
            terms = self._cache[t] = self._make_terms(t)
        return terms

    # ------------------------------------------------------------- equations
    def _cubic_variant(self) -> str | None:
        """Hook: the :class:`~filters._hinf_cubic.CubicForm` variant of this filter (None:
        always evaluate the equations term by term)."""
        return None

    def _drift(self, c: PolynomialCoefficients, x: FloatArray,
               P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``(F, A)``: state-equation drift (..., n) and Riccati "A" (..., n, n)."""
        raise NotImplementedError

    def _rhs(self, T: _Terms, x: FloatArray, P: FloatArray, y: FloatArray,
             u: FloatArray | None) -> tuple[FloatArray, FloatArray]:
        c = T.c
        F, A = self._drift_terms(T, x, P)
        if u is not None and c.E is not None:
            F = F + u @ c.E.T
        Kb = P @ T.CT  # (..., n, m): P C^T
        if T.BDt is not None:
            Kb = Kb + T.BDt
        innov = y - x @ T.CT
        if T.Li is not None:  # K = Kb Li^T Li: scale both factors by Li
            Kb = Kb @ T.Li.T
            innov = innov @ T.Li.T
        dx = F + (Kb @ innov[..., None])[..., 0]
        AP = A @ P
        dP = AP + AP.swapaxes(-1, -2)  # then in place: + B B^T - Kb Kb^T, in that order
        dP += T.BBt
        dP -= Kb @ Kb.swapaxes(-1, -2)
        if self._gm2:
            PL = P @ T.LT
            dP += self._gm2 * (PL @ PL.swapaxes(-1, -2))
        return dx, dP

    def _drift_terms(self, T: _Terms, x: FloatArray,
                     P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """:meth:`_drift` with the precomputed contractions of ``T`` available."""
        return self._drift(T.c, x, P)

    def derivatives(self, x: npt.ArrayLike, P: npt.ArrayLike, y: npt.ArrayLike, t: float,
                    u: npt.ArrayLike | None = None) -> tuple[FloatArray, FloatArray]:
        """Right-hand sides ``(dx_f/dt, dP/dt)`` of the filter at one point.

        Parameters
        ----------
        x : array_like, shape (..., n)
        P : array_like, shape (..., n, n)
        y : array_like, shape (m,) or (..., m)
        t : float
            Time in s (for time-varying coefficients).
        u : array_like, shape (k,) or (..., k), optional

        Returns
        -------
        dx : numpy.ndarray, shape (..., n)
        dP : numpy.ndarray, shape (..., n, n)
        """
        x = to_float_array("x", x)
        P = to_float_array("P", P)
        y = to_float_array("y", y)
        uu = None if u is None else to_float_array("u", u)
        return self._rhs(self._terms(float(t)), x, P, y, uu)

    # ------------------------------------------------------------------ step
    def reset(self, x0: npt.ArrayLike, P0: npt.ArrayLike) -> None:
        """Re-initialize ``x_f = x0``, ``P = P0`` and ``t_s = t0``.

        Parameters
        ----------
        x0 : array_like, shape (n,) or (..., n)
            Leading axes are a batch of independent filters.
        P0 : array_like, shape (n, n) or (..., n, n)
            Symmetric PSD, broadcast against the batch (the central filter uses ``R^-1``,
            :attr:`P0`).
        """
        super().reset(x0, P0)

    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """Integrate the filter over one sample interval with ``y`` (and ``u``) held.

        Parameters
        ----------
        y : array_like, shape (m,) or (..., m)
            Observation ``y = C x + D w`` representative of the interval (e.g. its average).
        u : array_like, shape (k,) or (..., k), or None
            Input held over the interval (the model's ``E u``; ``None``: zero).

        Returns
        -------
        numpy.ndarray, shape (..., n)
            The estimate at the end of the interval (same object as :attr:`x`).

        Raises
        ------
        ValueError
            ``y`` or ``u`` of the wrong shape or non-finite; state unchanged.
        FiniteEscapeError
            ``x`` (quantity ``"x"``) or ``P`` (``"P"``) failed the escape test after a
            substep (time = end of that substep); state unchanged.
        LossOfDefinitenessError
            ``P`` lost positive semidefiniteness; state unchanged.
        """
        y = self._vector("y", y, self._m)
        u = self._input(u)
        if self._method == "rosenbrock":
            return self._step_rosenbrock(y, u)
        if self._cubic is not None:
            x, P = self._step_cubic(self._cubic, y, u)
            self._commit(x, P, self._steps + 1)
            self.innovation = y - self._x_start @ self._CT
            return x
        x, P = self._x, self._P
        ns = self._substeps
        h = self._dt / ns  # type: ignore[operator]
        t0, n0 = self._t0, self._steps * ns  # stage times t0 + (n0 + j) h: exact cache keys
        esc = self._escape
        qx, qP = esc.magnitude(x, 1), esc.magnitude(P, 2)
        innovation = y - x @ self._terms(t0 + n0 * h).CT
        with np.errstate(over="ignore", invalid="ignore"):
            for i in range(ns):
                T1 = self._terms(t0 + (n0 + i) * h)
                Th = self._terms(t0 + (n0 + i + 0.5) * h)
                T2 = self._terms(t0 + (n0 + i + 1) * h)
                k1x, k1P = self._rhs(T1, x, P, y, u)
                k2x, k2P = self._rhs(Th, x + 0.5 * h * k1x, P + 0.5 * h * k1P, y, u)
                k3x, k3P = self._rhs(Th, x + 0.5 * h * k2x, P + 0.5 * h * k2P, y, u)
                k4x, k4P = self._rhs(T2, x + h * k3x, P + h * k3P, y, u)
                x = x + (h / 6.0) * (k1x + 2.0 * (k2x + k3x) + k4x)
                P = P + (h / 6.0) * (k1P + 2.0 * (k2P + k3P) + k4P)
                P = 0.5 * (P + _swap(P))
                t_end = t0 + (n0 + i + 1) * h
                qP = esc.check("P", qP, P, time=t_end, step_s=h, core_ndim=2)
                qx = esc.check("x", qx, x, time=t_end, step_s=h, core_ndim=1)
                check_symmetric_covariance(P, time=t_end, quantity="P",
                                           escape_bound=esc.bound)
        self._commit(x, P, self._steps + 1)
        self.innovation = innovation
        return x


    def _step_rosenbrock(self, y: FloatArray, u: FloatArray | None) -> FloatArray:
        """:meth:`step` with ROS2 substeps (:func:`filters.stiff.rosenbrock2`) on the stacked
        ``s = [x_f, vec(P)]``, with the same tests after every substep."""
        x, P = self._x, self._P
        n = self._n
        batch = x.shape[:-1]
        ns = self._substeps
        h = self._dt / ns  # type: ignore[operator]
        t0 = self._time(self._steps)
        esc = self._escape
        qx, qP = esc.magnitude(x, 1), esc.magnitude(P, 2)
        innovation = y - x @ self._terms(t0).CT

        def rhs(t: float, s: FloatArray) -> FloatArray:
            extra = s.ndim - 1 - len(batch)  # 1 for the Jacobian's perturbed states
            yy = y[..., None, :] if extra and y.ndim > 1 else y
            uu = u[..., None, :] if extra and u is not None and u.ndim > 1 else u
            dx, dP = self._rhs(self._terms(t), s[..., :n],
                               s[..., n:].reshape(*s.shape[:-1], n, n), yy, uu)
            return np.concatenate([dx, dP.reshape(*dP.shape[:-2], n * n)], axis=-1)

        def after(i: int, t_end: float, s: FloatArray) -> FloatArray:
            nonlocal x, P, qx, qP
            Pq = s[..., n:].reshape(*batch, n, n)
            P = 0.5 * (Pq + _swap(Pq))
            x = np.ascontiguousarray(s[..., :n])
            qP = esc.check("P", qP, P, time=t_end, step_s=h, core_ndim=2)
            qx = esc.check("x", qx, x, time=t_end, step_s=h, core_ndim=1)
            check_symmetric_covariance(P, time=t_end, quantity="P", escape_bound=esc.bound)
            return np.concatenate([x, P.reshape(*batch, n * n)], axis=-1)

        typical = np.concatenate([
            np.broadcast_to(np.maximum(np.abs(x).max(axis=-1, keepdims=True), 1e-8),
                            (*batch, n)),
            np.broadcast_to(np.maximum(np.abs(P).max(axis=(-2, -1))[..., None], 1e-12),
                            (*batch, n * n))], axis=-1) * 1e-3
        with np.errstate(over="ignore", invalid="ignore"):
            rosenbrock2(rhs, np.concatenate([x, P.reshape(*batch, n * n)], axis=-1), t0, h,
                        ns, difference_solver(rhs, typical), after, self._jacobian_every)
        self._commit(x, P, self._steps + 1)
        self.innovation = innovation
        self._magnitudes = None
        return x

    def _step_cubic(self, fz: CubicForm, y: FloatArray, u: FloatArray | None
                    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`step`'s RK4 substeps with the right-hand side as one cubic form (same
        equations, stage times and tests; equal to the term-by-term evaluation up to
        rounding). The batch is flattened onto the last axis: ``z`` is ``(d, N)``."""
        x, P = self._x, self._P
        self._x_start = x
        batch = x.shape[:-1]
        n, m, k, ns = self._n, self._m, fz.k, fz.ns
        if batch:
            N = math.prod(batch)
            z = np.empty((fz.d, N))
            z[1 + ns:1 + ns + m] = np.broadcast_to(y, (*batch, m)).reshape(N, m).T
            if k:
                z[1 + ns + m:] = (0.0 if u is None else
                                  np.broadcast_to(u, (*batch, k)).reshape(N, k).T)
            sv = np.concatenate([x.reshape(N, n).T, P.reshape(N, n * n).T])
            sq = (n, n, N)
        else:
            z = np.empty(fz.d)
            z[1 + ns:1 + ns + m] = y
            if k:
                z[1 + ns + m:] = 0.0 if u is None else u
            sv = np.concatenate([x, P.ravel()])
            sq = (n, n)
        z[0] = 1.0
        zs = z[1:1 + ns]
        ia, ib, ic = fz.A, fz.B, fz.C

        def rhs(v: FloatArray, R: FloatArray) -> FloatArray:
            zs[...] = v
            return R.dot(z[ia] * z[ib] * z[ic])

        nsub = self._substeps
        h = self._dt / nsub  # type: ignore[operator]
        t0, n0 = self._t0, self._steps * nsub  # stage times as in the term-by-term path
        esc = self._escape
        q = self._magnitudes
        qx, qP = (q[1], q[2]) if q is not None and q[0] is x else (esc.magnitude(x, 1),
                                                                  esc.magnitude(P, 2))
        half, sixth = 0.5 * h, h / 6.0
        with np.errstate(over="ignore", invalid="ignore"):
            for i in range(nsub):
                R1 = fz.matrix(t0 + (n0 + i) * h)
                Rh = fz.matrix(t0 + (n0 + i + 0.5) * h)
                R2 = fz.matrix(t0 + (n0 + i + 1) * h)
                k1 = rhs(sv, R1)
                k2 = rhs(sv + half * k1, Rh)
                k3 = rhs(sv + half * k2, Rh)
                k4 = rhs(sv + h * k3, R2)
                sv = sv + sixth * (k1 + 2.0 * (k2 + k3) + k4)
                Pq = sv[n:].reshape(sq)
                Pq = 0.5 * (Pq + Pq.swapaxes(0, 1))
                if batch:
                    x = np.ascontiguousarray(sv[:n].T).reshape(*batch, n)
                    P = np.ascontiguousarray(Pq.transpose(2, 0, 1)).reshape(*batch, n, n)
                else:
                    x, P = sv[:n].copy(), Pq
                t_end = t0 + (n0 + i + 1) * h
                qP = esc.check("P", qP, P, time=t_end, step_s=h, core_ndim=2)
                qx = esc.check("x", qx, x, time=t_end, step_s=h, core_ndim=1)
                check_symmetric_covariance(P, time=t_end, quantity="P",
                                           escape_bound=esc.bound)
                if i + 1 < nsub:
                    sv = np.concatenate([sv[:n], Pq.reshape(n * n, *sv.shape[1:])])
        self._magnitudes = (x, qx, qP)  # for the next step's growth test
        return x, P


class PolynomialHInfFilter(_CentralHInfFilter):
    """Central H-infinity filter for polynomial systems (Basin et al., Theorem 1, (11)-(15)).

    Equation map (paper numbering)::

        dx_f/dt = f_hat(x_f, t) + P C^T (y - C x_f),            x_f(t0) = x0 (= 0)  (11)
        z_f     = L x_f                                                             (12)
        dP/dt   = g_hat(x_f, t) + B B^T - P [C^T C - gamma^-2 L^T L] P,
                                                                P(t0) = R^-1        (13)

    with ``f_hat`` (14) and ``g_hat`` (15) for degree <= 3 written once for general tensors
    (:func:`f_hat`, :func:`g_hat`; degree 2 and 1 by zero ``a3``, ``a2``: Theorem 1's
    reduction). With ``a2 = a3 = 0`` this is the linear central H-infinity filter
    (Nagpal & Khargonekar 1991). See the module docstring for the derivation of (14)-(15)
    and the corrected misprints.

    Parameters
    ----------
    model : PolynomialModel
        The system; must satisfy (C3) ``D B^T = 0``, ``D D^T = I`` at ``t0`` (otherwise use
        :class:`NonOrthonormalPolynomialHInfFilter`).
    gamma : float
        Attenuation level of (10) (``math.inf``: the optimal H2 filter of [24]).
    R : array_like, shape (n, n)
        Symmetric positive definite weight of ``x(t0)`` in (10); ``P(t0) = R^-1``.
    dt_s : float
        Sample interval in s.
    x0 : array_like, shape (n,) or (..., n), optional
        Initial estimate (default 0, the central filter); leading axes are a batch.
    substeps : int
        Steps of ``method`` per sample interval on the joint ``(x_f, P)`` system
        (coefficients evaluated at the stage times).
    t0 : float
        Initial time in s.
    escape : EscapeTest, optional
        Finite-escape test applied after every substep (default :class:`EscapeTest()`).
    method : {"rk4", "rosenbrock"}
        Classical RK4, or the L-stable ROS2 of :mod:`filters.stiff` for stiff equations
        (accurate sensors); see :attr:`method`.
    jacobian_every : int
        ROS2's substeps between Jacobian evaluations (see :attr:`jacobian_every`).

    Attributes
    ----------
    name : str
        ``"poly-hinf"``.
    x : numpy.ndarray, shape (..., n)
        Estimate ``x_f``.
    P : numpy.ndarray, shape (..., n, n)
        Gain matrix of (13) (the error covariance of the equivalent H2 problem).
    t_s : float
        ``t0 + steps * dt_s``.
    innovation : numpy.ndarray, shape (..., m), or None
        ``y - C x_f`` at the start of the last interval.

    Raises
    ------
    ValueError
        Bad arguments; (C3) violated at ``t0`` (relative tolerance 1e-9).

    Notes
    -----
    ``y`` is held over each interval (zero-order hold); use an interval average or a
    sample period well below the time scales of ``y`` and of the coefficients. For
    time-varying ``D``, ``B`` (C3) is checked at ``t0`` only; the integrator always uses
    Corollary 1's gain, which equals Theorem 1's wherever (C3) holds.
    """

    name: ClassVar[str] = "poly-hinf"

    def _check_model(self, terms: _Terms) -> None:
        c = terms.c
        DDt = c.D @ c.D.T
        BDt = c.B @ c.D.T
        scale = max(1.0, float(np.abs(c.B).max(initial=0.0)) * float(np.abs(c.D).max()))
        err_b = float(np.abs(BDt).max(initial=0.0))
        err_d = float(np.abs(DDt - np.eye(DDt.shape[0])).max())
        if err_b > _C3_RTOL * scale or err_d > _C3_RTOL * max(1.0, float(np.abs(DDt).max())):
            raise ValueError(
                f"assumption (C3) violated at t0 = {terms.c.t:.6g} s: need D B^T = 0 and "
                f"D D^T = I, got max|D B^T| = {err_b:.3g}, max|D D^T - I| = {err_d:.3g}; use "
                "NonOrthonormalPolynomialHInfFilter (Corollary 1)")

    def _cubic_variant(self) -> str | None:
        return "poly"

    def _drift(self, c: PolynomialCoefficients, x: FloatArray,
               P: FloatArray) -> tuple[FloatArray, FloatArray]:
        return f_hat(c, x, P), moment_matrix(c, x, P)

    def _drift_terms(self, T: _Terms, x: FloatArray,
                     P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """:func:`f_hat` and :func:`moment_matrix` by matmul with ``T``'s contractions."""
        c = T.c
        F = c.a0 + x @ T.a1T
        A = c.a1
        if T.F2 is None and T.F3 is None:
            return F, np.broadcast_to(A, P.shape) if A.shape != P.shape else A
        n = x.shape[-1]
        xx = x[..., :, None] * x[..., None, :]
        S = xx + P
        Sv = S.reshape(*S.shape[:-2], n * n)
        if T.F2 is not None:
            F = F + Sv @ T.F2
            A = A + (x @ T.J2).reshape(*x.shape[:-1], n, n)
        if T.F3 is not None:
            X3 = x[..., :, None] * (S + 2.0 * P).reshape(*S.shape[:-2], 1, n * n)
            F = F + X3.reshape(*x.shape[:-1], n**3) @ T.F3
            A = A + (Sv @ T.J3).reshape(*S.shape)
        if A.shape != P.shape:
            A = np.broadcast_to(A, P.shape)
        return F, A


class NonOrthonormalPolynomialHInfFilter(PolynomialHInfFilter):
    """Central H-infinity filter without noise orthonormality, Basin et al., Corollary 1.

    Equation map (paper numbering)::

        dx_f/dt = f_hat(x_f, t) + [P C^T + B D^T] (D D^T)^-1 (y - C x_f)          (29)
        z_f     = L x_f                                                           (30)
        dP/dt   = g_hat(x_f, t) + B B^T - [P C^T + B D^T] (D D^T)^-1 [D B^T + C P]
                  + gamma^-2 P L^T L P,                         P(t0) = R^-1      (31)

    ``f_hat`` is (14), not the printed (32) (see the module docstring: (32)'s ``a3 P`` and
    ``a3 x x^T P`` are misprints of ``a2 P`` and ``a3 x x x^T``); ``g_hat`` is (33) = (15).
    Needs ``D D^T > 0`` (checked whenever the coefficients are evaluated). With (C3) it
    equals :class:`PolynomialHInfFilter`.

    Equivalently (used as the independent check in the tests): Theorem 1 applied to
    ``a1 - B D^T (D D^T)^-1 C``, the extra input ``B D^T (D D^T)^-1 y``, disturbance
    intensity ``B (I - D^T (D D^T)^-1 D) B^T`` and the whitened observation
    ``(D D^T)^-1/2 y``.

    Parameters and attributes are those of :class:`PolynomialHInfFilter` (``name`` is
    ``"poly-hinf-nonorthonormal"``), without the (C3) requirement.
    """

    name: ClassVar[str] = "poly-hinf-nonorthonormal"

    def _check_model(self, terms: _Terms) -> None:
        pass  # D D^T > 0 is enforced by _make_terms


class LinearizedHInfFilter(_CentralHInfFilter):
    """Central H-infinity filter of the linearized system: the comparison filter (27)-(28).

    The linear central H-infinity filter (Nagpal & Khargonekar 1991, Theorems 3-4) with the
    system matrix replaced by the Jacobian ``J = df/dx`` at the current estimate::

        dm/dt = F(m, t) + [P C^T + B D^T](D D^T)^-1 (y - C m),        m(t0) = x0 (= 0)   (27)
        dP/dt = J(m) P + P J(m)^T + B B^T - [P C^T + B D^T](D D^T)^-1 [D B^T + C P]
                + gamma^-2 P L^T L P,                                  P(t0) = R^-1     (28)

    ``state_equation`` chooses ``F``:

    * ``"system"`` (default): ``F = f(m, t)``, the system's own polynomial (an extended
      H-infinity filter);
    * ``"jacobian"``: ``F = a0 + J(m) m``, the state equation of the system linearized at
      the estimate. This is (27) **as printed** in the example
      (``0.2 m^2 + (0.3 + 0.3 sin 50t) m^3 = J(m) m`` for ``f = 0.1 x^2 +
      (0.1 + 0.1 sin 50t) x^3``).

    It differs from :class:`PolynomialHInfFilter` by the missing ``a2 P + 3 a3 x P`` in the
    state equation and ``3 a3 P`` in the Riccati "A" (``A_hat = J + 3 a3 P``). With
    ``a2 = a3 = 0`` both are the linear central H-infinity filter.

    Parameters
    ----------
    model, gamma, R, dt_s, x0, substeps, t0, escape
        As in :class:`PolynomialHInfFilter` (no (C3) requirement; ``D D^T > 0``).
    state_equation : {"system", "jacobian"}
        See above.

    Attributes
    ----------
    name : str
        ``"linearized-hinf"``.
    state_equation : str
    x, P, t_s, innovation
        As in :class:`PolynomialHInfFilter`.
    """

    name: ClassVar[str] = "linearized-hinf"

    def __init__(
        self,
        model: PolynomialModel,
        gamma: float,
        R: npt.ArrayLike,
        dt_s: float,
        x0: npt.ArrayLike | None = None,
        *,
        state_equation: str = "system",
        substeps: int = 1,
        t0: float = 0.0,
        escape: EscapeTest | None = None,
    ) -> None:
        if state_equation not in ("system", "jacobian"):
            raise ValueError(f"state_equation must be 'system' or 'jacobian', got "
                             f"{state_equation!r}")
        self._jacobian_state = state_equation == "jacobian"
        super().__init__(model, gamma, R, dt_s, x0, substeps=substeps, t0=t0, escape=escape)

    @property
    def state_equation(self) -> str:
        """``"system"`` (``f(m)``) or ``"jacobian"`` (``a0 + J(m) m``, (27) as printed)."""
        return "jacobian" if self._jacobian_state else "system"

    def _cubic_variant(self) -> str | None:
        return self.state_equation

    def _drift(self, c: PolynomialCoefficients, x: FloatArray,
               P: FloatArray) -> tuple[FloatArray, FloatArray]:
        J = c.jacobian(x)
        if self._jacobian_state:
            F = c.a0 + (J @ x[..., None])[..., 0]
        else:
            F = c.f(x)
        return F, np.broadcast_to(J, P.shape) if J.shape != P.shape else J

    def _drift_terms(self, T: _Terms, x: FloatArray,
                     P: FloatArray) -> tuple[FloatArray, FloatArray]:
        """:meth:`_drift` by matmul with ``T``'s contractions (same values up to rounding)."""
        c = T.c
        n = x.shape[-1]
        J = c.a1
        xxv = None
        if T.J2 is not None:
            J = J + (x @ T.J2).reshape(*x.shape[:-1], n, n)
        if T.J3 is not None:
            xxv = (x[..., :, None] * x[..., None, :]).reshape(*x.shape[:-1], n * n)
            J = J + (xxv @ T.J3).reshape(*x.shape[:-1], n, n)
        if self._jacobian_state:
            F = c.a0 + (J @ x[..., None])[..., 0]
        else:
            F = c.a0 + x @ T.a1T
            if T.F2 is not None or T.F3 is not None:
                if xxv is None:
                    xxv = (x[..., :, None] * x[..., None, :]).reshape(*x.shape[:-1], n * n)
                if T.F2 is not None:
                    F = F + xxv @ T.F2
                if T.F3 is not None:
                    x3 = (x[..., :, None] * xxv[..., None, :]).reshape(*x.shape[:-1], n**3)
                    F = F + x3 @ T.F3
        return F, np.broadcast_to(J, P.shape) if J.shape != P.shape else J
