"""Wang & Fang (IEEE Signal Processing Letters, 2006): robust H-infinity filter with
error-variance constraints and parabolic pole assignment, continuous time.

Plant (1)-(3) (:class:`~filters.analysis.UncertainPlant`, ``discrete=False``), filter (4)
``xhat' = G xhat + K y``. Theorem 1: given ``P(a, b)``, ``gamma``, small ``delta1, delta2 >
0``, an orthogonal ``U`` (p x p) and ``eps1, eps2 > 0``, ``H`` (n x p) with
``N Q1 N^T <= eps1 I``: if (16) and (17) have solutions ``Q1 > 0``, ``Q2 > 0``, the gains (18)
place the poles of the augmented system in ``P(a, b)``, give ``||H(s)||_inf <= gamma`` and
``P < Q2`` for every ``F^T F <= I``.

Derivation (the proof, (19)-(25), which wins over the printed definitions)
--------------------------------------------------------------------------
With ``Q = diag(Q1, Q2)``, Lemma 1 bounds (15) by ``Psi`` (21) with ``s = b eps1 + eps2``::

    Psi11 = (A + aI) Q1 + Q1 (A + aI)^T + b A Gamma A^T + s M1 M1^T
            + eps2^-1 Q1 N^T N Q1 + D1 D1^T                                    (22)
    Psi12 = (b A Gamma + Q1)(A - G - K C)^T + s M1 (M1 - K M2)^T + D1 (D1 - K D2)^T (23)

``Gamma = (Q1^-1 - eps1^-1 N^T N)^-1 = Q1 + Q1 N^T (eps1 I - N Q1 N^T)^-1 N Q1`` (10).
(16) is ``Psi11 = -delta1 I``. ``Psi12 = 0`` with ``Phi = b Gamma A^T + Q1`` (10) gives
``G = A_hat - K C_hat`` with::

    A_hat = A + (s M1 M1^T + D1 D1^T) Phi^-1                                   (11)
    C_hat = C + (s M2 M1^T + D2 D1^T) Phi^-1                                   (11, corrected)

Then ``A - G - K C = (A - A_hat) - K (C - C_hat)`` and (24) becomes
``Psi22 = Upsilon - K Theta^T - Theta K^T + K R K^T`` (25) with::

    R       = b (C - C_hat) Gamma (C - C_hat)^T + b C_hat Q2 C_hat^T + s M2 M2^T + D2 D2^T   (12)
    Theta   = b (A - A_hat) Gamma (C - C_hat)^T + b A_hat Q2 C_hat^T + Q2 C_hat^T
              + s M1 M2^T + D1 D2^T                                                          (13)
    Upsilon = b (A - A_hat) Gamma (A - A_hat)^T + b A_hat Q2 A_hat^T + A_hat Q2 + Q2 A_hat^T
              + 2 a Q2 + gamma^-2 Q2 L^T L Q2 + s M1 M1^T + D1 D1^T              (14, corrected)

(17) is ``Upsilon - Theta R^-1 Theta^T + H H^T + delta2 I = 0`` and (18)
``K = Theta R^-1 + H U R^-1/2`` makes ``Psi22 = -delta2 I``.

Misprints corrected (checked against the proof above)
-----------------------------------------------------
* (11): ``C_hat`` has ``M2 M1^T`` and ``D2 D1^T`` (printed ``M2 M2^T``, ``D2 D2^T``, which do
  not even have the dimensions of ``C``).
* (14) and (17): the ``s``-term is ``s M1 M1^T`` (printed ``M2 M2^T``).
* The example's ``E = [0.1 0.1]^T`` is Theorem 1's ``H``.

Note: (28) shows ``b |lambda|^2 + 2 Re(lambda) + 2 a < 0``, i.e. the poles lie in the disk
:meth:`filters.analysis.Parabola.proof_disk`, a subset of ``P(a, b)``.

Solving (16) and (17)
---------------------
The paper gives no algorithm (Remark 1 cites local search). Here:

* **(16)** maps onto no standard Riccati equation (it mixes the continuous-time terms
  ``(A + aI) Q1 + Q1 (A + aI)^T + eps2^-1 Q1 N^T N Q1`` with the discrete-time term
  ``b A Gamma A^T``). Its left side ``F16(Q1)`` is convex on ``{eps1 I > N Q1 N^T}``
  (``Gamma`` is: ``(X, Y) -> X^T Y^-1 X`` is jointly convex) with the resolvent-positive
  derivative::

      F16'(Q1)[D] = Ac D + D Ac^T + b (A T) D (A T)^T,
      Ac = A + aI + eps2^-1 Q1 N^T N,   T = I + Q1 N^T (eps1 I - N Q1 N^T)^-1 N.

  Newton's method from ``Q1 = 0`` (:func:`solve_state_bound`) therefore increases
  monotonically to the least solution whenever a solution exists (Damm & Hinrichsen 2001),
  and leaving ``{eps1 I > N Q1 N^T}`` proves that none exists. ``F16'(0)`` is stable iff the
  eigenvalues of ``A`` lie in the disk of (28); otherwise (16) has no ``Q1 > 0``.
* **(17)** with ``gamma = inf`` *is* a discrete algebraic Riccati equation: with
  ``c = 1/b - 2a`` (> 0 iff the disk of (28) is not empty),
  ``Abar = sqrt(b) A_hat + I / sqrt(b)`` and ``Cbar = sqrt(b) C_hat``::

      b A_hat Q2 A_hat^T + A_hat Q2 + Q2 A_hat^T + 2a Q2 = Abar Q2 Abar^T - c Q2,
      b A_hat Q2 C_hat^T + Q2 C_hat^T = Abar Q2 Cbar^T,   b C_hat Q2 C_hat^T = Cbar Q2 Cbar^T,

  so, divided by ``c``, (17) reads ``Q2 = Ad Q2 Ad^T - (Ad Q2 Cd^T + S)(Cd Q2 Cd^T + R)^-1
  (...)^T + Q + theta Q2 L^T L Q2 / c`` with ``Ad = Abar / sqrt(c)``, ``Cd = Cbar / sqrt(c)``,
  ``S = (b dA Gamma dC^T + s M1 M2^T + D1 D2^T) / c``,
  ``R = (b dC Gamma dC^T + s M2 M2^T + D2 D2^T) / c``,
  ``Q = (b dA Gamma dA^T + s M1 M1^T + D1 D1^T + H H^T + delta2 I) / c`` (``dA = A - A_hat``,
  ``dC = C - C_hat``) and ``theta = gamma^-2``: at ``theta = 0`` the stabilizing solution
  comes from :func:`scipy.linalg.solve_discrete_are`. The term ``theta Q2 L^T L Q2`` (a
  continuous-time one) has no such mapping, so :func:`solve_error_bound` follows the
  stabilizing solution by continuation in ``theta`` from 0 to ``gamma^-2`` (tangent predictor,
  Newton corrector with the exact derivative ``D -> Ak D Ak^T - c D + theta (Q2 L^T L D +
  D L^T L Q2)``, ``Ak = Abar - Kbar Cbar``). Where the branch ends first (a fold: the
  derivative becomes singular) it reports the smallest ``gamma`` reached.

Both solvers report residuals with :func:`state_bound_residual` and
:func:`error_bound_residual`. The generic
multi-start Newton solver :func:`~filters.variance_constrained.solve_symmetric_equation`
remains as a fallback (``method="auto"``) and finds other, non-least solutions of (16).
:func:`search_parabolic_design` searches the free parameters with an optimizer and verifies
the candidates; :func:`search_parabolic` is the older grid over ``(eps1, eps2)`` and the
scale of ``H``; :func:`error_bound_margin` tells whether *any* ``H`` could help for a given
``Q1``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.linalg import solve_continuous_lyapunov
from scipy.optimize import minimize

from filters._deprecated import deprecated_alias
from filters._linalg import FloatArray, matrix, real_array
from filters.analysis import Parabola, UncertainPlant
from filters.matrix_equations import (
    continuation,
    newton_solve,
    operator_spectral_abscissa,
    solve_filter_dare,
)
from filters.variance_constrained import (
    INFEASIBLE,
    DesignSearch,
    DesignSearchRecord,
    MatrixEquationSolution,
    VarianceDesign,
    bound_ratio,
    inverse_sqrt,
    is_positive_definite,
    passes,
    random_search_start,
    run_design_search,
    search_space,
    solve_symmetric_equation,
    structured_then_multistart,
    verify_design,
)

__all__ = [
    "ParabolicDesignParameters",
    "ParabolicTerms",
    "design_parabolic",
    "state_bound_residual",
    "error_bound_residual",
    "error_bound_margin",
    "error_bound_terms",
    "filter_gains",
    "gamma_threshold",
    "hat_terms",
    "search_parabolic",
    "search_parabolic_design",
    "solve_state_bound",
    "solve_error_bound",
]

EQUATIONS = ("16", "17")


@dataclass(frozen=True)
class ParabolicDesignParameters:
    """The free parameters of Wang & Fang's Theorem 1.

    Attributes
    ----------
    a, b : float
        Parabola ``P(a, b)`` (> 0).
    gamma : float
        H-infinity bound (> 0).
    eps1, eps2 : float
        Scalars of Lemma 1 (> 0).
    delta1, delta2 : float
        Small positive constants of (16), (17).
    H : array_like, shape (n, p)
        Free matrix of (17), (18).
    U : array_like, shape (p, p), optional
        Orthogonal matrix of (18) (default identity).
    """

    a: float
    b: float
    gamma: float
    eps1: float
    eps2: float
    delta1: float
    delta2: float
    H: Any
    U: Any = None

    def __post_init__(self) -> None:
        for name in ("a", "b", "gamma", "eps1", "eps2", "delta1", "delta2"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float, np.floating)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive finite float, got {v!r}")
            object.__setattr__(self, name, float(v))
        H = matrix("H", self.H, (None, None), labels=("n", "p"))
        object.__setattr__(self, "H", H)
        p = H.shape[1]
        U = np.eye(p) if self.U is None else matrix("U", self.U, (p, p))
        if not np.allclose(U @ U.T, np.eye(p), atol=1e-9):
            raise ValueError("U must be orthogonal (U U^T = I)")
        object.__setattr__(self, "U", U)

    @property
    def s(self) -> float:
        """``b eps1 + eps2``."""
        return self.b * self.eps1 + self.eps2

    def as_dict(self) -> dict[str, Any]:
        return {"a": self.a, "b": self.b, "gamma": self.gamma, "eps1": self.eps1,
                "eps2": self.eps2, "delta1": self.delta1, "delta2": self.delta2,
                "H": self.H.tolist(), "U": self.U.tolist()}


def _check(plant: UncertainPlant, prm: ParabolicDesignParameters) -> None:
    if plant.discrete:
        raise ValueError("plant must be continuous-time (discrete=False) for the parabolic "
                         "design")
    if prm.H.shape != (plant.n, plant.p):
        raise ValueError(f"H must have shape ({plant.n}, {plant.p}), got {prm.H.shape}")


# ---------------------------------------------------------------------- (16)
def _gamma(Q1: npt.NDArray[Any], N: FloatArray, eps1: float) -> npt.NDArray[Any]:
    """(10): ``Gamma = (Q1^-1 - eps1^-1 N^T N)^-1 = Q1 + Q1 N^T (eps1 I - N Q1 N^T)^-1 N Q1``
    (the inverse-free form, defined for every ``Q1`` with ``eps1 I > N Q1 N^T``)."""
    j = N.shape[0]
    NQ = N @ Q1
    return Q1 + NQ.T @ np.linalg.solve(eps1 * np.eye(j) - NQ @ N.T, NQ)


def state_bound_residual(Q1: npt.NDArray[Any], plant: UncertainPlant,
                         prm: ParabolicDesignParameters) -> npt.NDArray[Any]:
    """Left side of (16) at ``Q1`` (shape (n, n); zero at a solution)."""
    A, N, M1, D1 = plant.A, plant.N, plant.M1, plant.D1
    Aa = A + prm.a * np.eye(plant.n)
    Gm = _gamma(Q1, N, prm.eps1)
    return (Aa @ Q1 + Q1 @ Aa.T + prm.b * A @ Gm @ A.T + prm.s * M1 @ M1.T
            + Q1 @ N.T @ N @ Q1 / prm.eps2 + D1 @ D1.T + prm.delta1 * np.eye(plant.n))


def _admissible16(plant: UncertainPlant, prm: ParabolicDesignParameters):
    N, j = plant.N, plant.N.shape[0]

    def ok(Q1: FloatArray) -> bool:
        return (is_positive_definite(Q1)
                and is_positive_definite(prm.eps1 * np.eye(j) - N @ Q1 @ N.T))

    return ok


# ---------------------------------------------------------------------- (17)
@dataclass(frozen=True)
class ParabolicTerms:
    """Quantities (10)-(11) fixed by ``Q1``.

    Attributes
    ----------
    Q1, Gamma, Phi, A_hat : numpy.ndarray, shape (n, n)
    C_hat : numpy.ndarray, shape (p, n)
    """

    Q1: FloatArray
    Gamma: FloatArray
    Phi: FloatArray
    A_hat: FloatArray
    C_hat: FloatArray


def hat_terms(Q1: FloatArray, plant: UncertainPlant,
              prm: ParabolicDesignParameters) -> ParabolicTerms:
    """(10)-(11) with the corrected ``C_hat``; raises ``LinAlgError`` if ``Phi`` is singular."""
    A, C, M1, M2, D1, D2 = plant.A, plant.C, plant.M1, plant.M2, plant.D1, plant.D2
    Gm = _gamma(Q1, plant.N, prm.eps1)
    Phi = prm.b * Gm @ A.T + Q1
    X = np.vstack([prm.s * M1 @ M1.T + D1 @ D1.T, prm.s * M2 @ M1.T + D2 @ D1.T])
    right = np.linalg.solve(Phi.T, X.T).T  # X Phi^-1, shape (n + p, n)
    n = plant.n
    return ParabolicTerms(Q1=Q1, Gamma=Gm, Phi=Phi, A_hat=A + right[:n], C_hat=C + right[n:])


def error_bound_terms(Q2: npt.NDArray[Any], plant: UncertainPlant,
                      prm: ParabolicDesignParameters, t: ParabolicTerms
                      ) -> tuple[npt.NDArray[Any], npt.NDArray[Any], npt.NDArray[Any]]:
    """``(R, Theta, Upsilon)`` of (12)-(14) (corrected (14)), shapes (p, p), (n, p), (n, n)."""
    A, C, M1, M2, D1, D2, L = (plant.A, plant.C, plant.M1, plant.M2, plant.D1, plant.D2,
                               plant.L)
    b, s = prm.b, prm.s
    dA, dC, Ah, Ch, Gm = A - t.A_hat, C - t.C_hat, t.A_hat, t.C_hat, t.Gamma
    R = b * dC @ Gm @ dC.T + b * Ch @ Q2 @ Ch.T + s * M2 @ M2.T + D2 @ D2.T
    Theta = (b * dA @ Gm @ dC.T + b * Ah @ Q2 @ Ch.T + Q2 @ Ch.T + s * M1 @ M2.T
             + D1 @ D2.T)
    Ups = (b * dA @ Gm @ dA.T + b * Ah @ Q2 @ Ah.T + Ah @ Q2 + Q2 @ Ah.T + 2 * prm.a * Q2
           + Q2 @ L.T @ L @ Q2 / prm.gamma**2 + s * M1 @ M1.T + D1 @ D1.T)
    return R, Theta, Ups


def error_bound_residual(Q2: npt.NDArray[Any], plant: UncertainPlant,
                         prm: ParabolicDesignParameters, t: ParabolicTerms) -> npt.NDArray[Any]:
    """Left side of (17) = ``Upsilon - Theta R^-1 Theta^T + H H^T + delta2 I``, shape (n, n)."""
    R, Theta, Ups = error_bound_terms(Q2, plant, prm, t)
    return (Ups - Theta @ np.linalg.solve(R, Theta.T) + prm.H @ prm.H.T
            + prm.delta2 * np.eye(plant.n))


def filter_gains(Q2: FloatArray, plant: UncertainPlant, prm: ParabolicDesignParameters,
                 t: ParabolicTerms, U: npt.ArrayLike | None = None
                 ) -> tuple[FloatArray, FloatArray]:
    """(18): ``K = Theta R^-1 + H U R^-1/2``, ``G = A_hat - K C_hat``.

    Returns
    -------
    K : numpy.ndarray, shape (n, p)
    G : numpy.ndarray, shape (n, n)
    """
    R, Theta, _ = error_bound_terms(Q2, plant, prm, t)
    U_ = prm.U if U is None else real_array(U, "U", finite=False)
    K = np.linalg.solve(R, Theta.T).T + prm.H @ U_ @ inverse_sqrt(R)
    return K, t.A_hat - K @ t.C_hat


def error_bound_margin(plant: UncertainPlant, prm: ParabolicDesignParameters, Q1: FloatArray,
                       *, seed: int = 0, starts: list[FloatArray] | None = None
                       ) -> tuple[float, FloatArray]:
    """Smallest ``lambda_max(Upsilon - Theta R^-1 Theta^T + delta2 I)`` found over ``Q2 > 0``.

    (17) requires this matrix to equal ``-H H^T <= 0``, so a positive value means that no
    ``H`` makes (17) solvable for this ``Q1`` (a local search: Nelder-Mead on the Cholesky
    factor from several starts; the value is an upper bound of the true minimum).

    ``starts`` (positive definite ``Q2``) replace the default eight starts (plus ``0.01 I``).

    Returns
    -------
    value : float
    Q2 : numpy.ndarray, shape (n, n)
        Where it was reached.
    """
    t = hat_terms(Q1, plant, replace(prm, H=np.zeros_like(prm.H)))
    n = plant.n
    low = np.tril_indices(n)
    prm0 = replace(prm, H=np.zeros_like(prm.H))

    def f(theta: FloatArray) -> float:
        Lm = np.zeros((n, n))
        Lm[low] = theta
        Q2 = Lm @ Lm.T + 1e-12 * np.eye(n)
        try:
            S = error_bound_residual(Q2, plant, prm0, t)
        except np.linalg.LinAlgError:
            return 1e6
        return float(np.linalg.eigvalsh(0.5 * (S + S.T))[-1])

    rng = np.random.default_rng(seed)
    best = (math.inf, np.eye(n))
    if starts is None:
        starts = [c * np.eye(n) for c in (1e-3, 1e-2, 0.1, 1.0)]
        starts += [np.diag(10 ** rng.uniform(-3, 0, n)) for _ in range(4)]
    else:
        starts = [S + 1e-9 * np.eye(n) for S in starts] + [1e-2 * np.eye(n)]
    for S0 in starts:
        th0 = np.linalg.cholesky(S0)[low]
        out = minimize(f, th0, method="Nelder-Mead",
                       options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 4000})
        if out.fun < best[0]:
            Lm = np.zeros((n, n))
            Lm[low] = out.x
            best = (float(out.fun), Lm @ Lm.T)
    return best


def gamma_threshold(plant: UncertainPlant, prm: ParabolicDesignParameters, *,
                    gamma_max: float = 1e4, rtol: float = 1e-2, seed: int = 0,
                    n_random: int = 6, Q1_solutions: list[FloatArray] | None = None
                    ) -> float | None:
    """Smallest ``gamma`` at which (17) is not ruled out by :func:`error_bound_margin`.

    The margin decreases with ``gamma`` (the only ``gamma`` term of (17),
    ``gamma^-2 Q2 L^T L Q2``, does), so a geometric bisection finds where it reaches 0 for
    some admissible ``Q1`` of (16) (which does not depend on ``gamma``). Below the returned
    value no ``H`` and ``Q2 > 0`` found satisfy (17) with these ``eps1, eps2, delta``.

    ``Q1_solutions`` (admissible solutions of (16), e.g. a design's) skip solving (16), else
    it is solved with ``n_random`` random starts. Each margin is warm-started from the
    previous minimizers.

    Returns
    -------
    float or None
        ``prm.gamma`` itself if it is not ruled out; ``None`` if (16) has no admissible
        solution or the margin stays positive up to ``gamma_max``.
    """
    _check(plant, prm)
    if Q1_solutions is None:
        eq1 = solve_symmetric_equation(lambda Q: state_bound_residual(Q, plant, prm), plant.n,
                                       admissible=_admissible16(plant, prm),
                                       starts=_starts16(plant, prm), seed=seed,
                                       n_random=n_random)
        if not eq1.solved:
            return None
        Q1_solutions = list(eq1.solutions)
    if not Q1_solutions:
        return None
    warm: dict[int, list[FloatArray]] = {}

    def possible(g: float) -> bool:
        p = replace(prm, gamma=g)
        values = []
        for i, Q1 in enumerate(Q1_solutions):
            v, Q2 = error_bound_margin(plant, p, Q1, seed=seed, starts=warm.get(i))
            warm[i] = [Q2]
            values.append(v)
        return min(values) <= 0

    if possible(prm.gamma):
        return prm.gamma
    lo, hi = prm.gamma, 4.0 * prm.gamma
    while not possible(hi):
        lo, hi = hi, 4.0 * hi
        if hi > gamma_max:
            return None
    while hi / lo > 1.0 + rtol:
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if possible(mid) else (mid, hi)
    return hi


# ----------------------------------------------------------- structured solvers
def _tol(tol: float, X: FloatArray | None) -> float:
    """Residual tolerance relative to the size of the solution (absolute for ``||X|| <= 1``)."""
    return tol * max(1.0, 0.0 if X is None else float(np.linalg.norm(X)))


def _residual16(plant: UncertainPlant, prm: ParabolicDesignParameters, scale: float = 1.0):
    """``Q1 -> (F16(Q1), derivative terms)``; see the module docstring. ``scale`` multiplies
    the constant term ``s M1 M1^T + D1 D1^T + delta1 I``."""
    A, N = plant.A, plant.N
    n, j = plant.n, N.shape[0]
    eye = np.eye(n)
    Aa = A + prm.a * eye
    sb = math.sqrt(prm.b)
    const = scale * (prm.s * plant.M1 @ plant.M1.T + plant.D1 @ plant.D1.T
                     + prm.delta1 * eye)
    NtN = N.T @ N

    def fun(Q: FloatArray) -> tuple[FloatArray, list[tuple[FloatArray, FloatArray]]]:
        NQ = N @ Q
        X = np.linalg.solve(prm.eps1 * np.eye(j) - NQ @ N.T, NQ)  # W^-1 N Q, shape (j, n)
        Gm = Q + NQ.T @ X
        T = eye + X.T @ N
        QNN = Q @ NtN / prm.eps2
        F = Aa @ Q + Q @ Aa.T + prm.b * A @ Gm @ A.T + QNN @ Q + const
        Ac = Aa + QNN
        AT = sb * A @ T
        return F, [(Ac, eye), (eye, Ac), (AT, AT)]

    return fun


def solve_state_bound(plant: UncertainPlant, prm: ParabolicDesignParameters, *,
                      tol: float = 1e-10, max_iter: int = 300) -> MatrixEquationSolution:
    """Least solution of (16) by monotone Newton from ``Q1 = 0`` (no Riccati mapping exists).

    See the module docstring for the convexity argument: the iterates increase to the least
    solution if (16) has one in ``{eps1 I > N Q1 N^T}``; an iterate leaving that set, or an
    unstable derivative at ``Q1 = 0`` (eigenvalues of ``A`` outside the disk of (28)), proves
    that there is none (up to rounding).

    Parameters
    ----------
    plant : UncertainPlant
        Continuous-time plant.
    prm : ParabolicDesignParameters
    tol : float
        Tolerance on ``||(16)||_F`` relative to ``max(1, ||Q1||_F)``.
    max_iter : int

    Returns
    -------
    MatrixEquationSolution
        ``method = "monotone-newton"``; ``X`` is the solution or the last admissible iterate.
    """
    _check(plant, prm)
    n = plant.n
    fun = _residual16(plant, prm)
    adm = _admissible16(plant, prm)
    Z = np.zeros((n, n))
    _, terms0 = fun(Z)
    abscissa = operator_spectral_abscissa(terms0)
    if abscissa >= 0:
        return MatrixEquationSolution(
            False, None, math.inf, 0, "(16) has no positive definite solution: the eigenvalues "
            "of A are not all in the disk of (28) (b |lambda|^2 + 2 Re lambda + 2a < 0), so "
            "the derivative of (16) at 0 is unstable", method="monotone-newton",
            status="unstable_derivative", details={"derivative_abscissa_at_0": abscissa})

    def domain(Q: FloatArray) -> bool:
        j = plant.N.shape[0]
        return is_positive_definite(prm.eps1 * np.eye(j) - plant.N @ Q @ plant.N.T)

    out = newton_solve(fun, Z, admissible=domain, tol=tol * 1e-2, max_iter=max_iter,
                       monotone=True)
    X = out.X
    res = float(np.linalg.norm(state_bound_residual(X, plant, prm))) if np.any(X) else math.inf
    if adm(X) and res <= _tol(tol, X):
        return MatrixEquationSolution(True, X, res, out.iterations,
                                      f"least solution of (16) by monotone Newton after "
                                      f"{out.iterations} iterations (residual {res:.1e})",
                                      (X,), method="monotone-newton", status="solved")
    if out.status == "left_admissible_set":
        msg = (f"(16) has no solution with N Q1 N^T < eps1 I: the monotone Newton iteration "
               f"left that set at iteration {out.iterations}")
        status = "left_admissible_set"
    else:
        msg = (f"monotone Newton iteration for (16) did not converge ({out.status}) after "
               f"{out.iterations} iterations at residual {res:.3g}")
        status = "not_converged"
    return MatrixEquationSolution(False, X if adm(X) else None, res if adm(X) else math.inf,
                                  out.iterations, msg, method="monotone-newton", status=status)


def _solvable16_fraction(plant: UncertainPlant, prm: ParabolicDesignParameters, *,
                         rtol: float = 0.02) -> float:
    """Largest ``kappa`` in ``(0, 1]`` (to ``rtol``) for which (16) with its constant term
    times ``kappa`` has a solution (monotone Newton decides each); 0 if none.

    (16) is solvable iff the value is 1; below, it measures how far (16) is from solvable
    (a continuous penalty for :func:`search_parabolic_design`).
    """
    n, j = plant.n, plant.N.shape[0]

    def domain(Q: FloatArray) -> bool:
        return is_positive_definite(prm.eps1 * np.eye(j) - plant.N @ Q @ plant.N.T)

    def ok(kappa: float) -> bool:
        out = newton_solve(_residual16(plant, prm, kappa), np.zeros((n, n)), admissible=domain,
                           tol=1e-10 * kappa, max_iter=60, monotone=True)
        return out.converged

    if ok(1.0):
        return 1.0
    lo, hi = 0.0, 1.0
    while hi - lo > rtol * hi:
        mid = 0.5 * (lo + hi) if lo > 0 else hi / 8.0
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
        if hi < 1e-6:
            return 0.0
    return lo


def _disk_form17(plant: UncertainPlant, prm: ParabolicDesignParameters, t: ParabolicTerms
                 ) -> tuple[float, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """``(c, Abar, Cbar, S, R, Q)`` of the disk form of (17), unscaled (see the module
    docstring)."""
    A, C, M1, M2, D1, D2 = plant.A, plant.C, plant.M1, plant.M2, plant.D1, plant.D2
    b, s, n = prm.b, prm.s, plant.n
    dA, dC, Gm = A - t.A_hat, C - t.C_hat, t.Gamma
    c = 1.0 / b - 2.0 * prm.a
    sb = math.sqrt(b)
    Abar = sb * t.A_hat + np.eye(n) / sb
    Cbar = sb * t.C_hat
    S = b * dA @ Gm @ dC.T + s * M1 @ M2.T + D1 @ D2.T
    R = b * dC @ Gm @ dC.T + s * M2 @ M2.T + D2 @ D2.T
    Q = (b * dA @ Gm @ dA.T + s * M1 @ M1.T + D1 @ D1.T + prm.H @ prm.H.T
         + prm.delta2 * np.eye(n))
    return c, Abar, Cbar, S, 0.5 * (R + R.T), 0.5 * (Q + Q.T)


def _residual17(plant: UncertainPlant, prm: ParabolicDesignParameters, t: ParabolicTerms):
    """``(Q2, theta) -> (F17, derivative terms, dF17/dtheta)`` in the disk form
    (``theta = gamma^-2``; equal to :func:`error_bound_residual` at ``theta = prm.gamma^-2``)."""
    c, Abar, Cbar, S, R0, Q0 = _disk_form17(plant, prm, t)
    n = plant.n
    eye = np.eye(n)
    LtL = plant.L.T @ plant.L

    def fun(Q: FloatArray, theta: float):
        Th = Abar @ Q @ Cbar.T + S
        R = Cbar @ Q @ Cbar.T + R0
        Kb = np.linalg.solve(R, Th.T).T
        QL = Q @ LtL
        F = Abar @ Q @ Abar.T - c * Q - Kb @ Th.T + Q0 + theta * QL @ Q
        Ak = Abar - Kb @ Cbar
        Lin = theta * QL - 0.5 * c * eye
        return 0.5 * (F + F.T), [(Ak, Ak), (Lin, eye), (eye, Lin)], QL @ Q

    return fun


def solve_error_bound(plant: UncertainPlant, prm: ParabolicDesignParameters, t: ParabolicTerms,
                      *, tol: float = 1e-10) -> MatrixEquationSolution:
    """Stabilizing solution of (17): DARE at ``gamma = inf``, continuation to ``gamma``.

    See the module docstring for the mapping. Failure is a result: no stabilizing DARE
    solution at ``gamma = inf`` (``status = "no_stabilizing_solution"``), or the branch ends
    before ``prm.gamma`` (``"branch_ended"``; ``details["gamma_reached"]`` is the smallest
    ``gamma`` solved, ``X`` the solution there). Neither proves that (17) has no positive
    definite solution on another branch.

    Parameters
    ----------
    plant : UncertainPlant
    prm : ParabolicDesignParameters
    t : ParabolicTerms
        :func:`hat_terms` of the ``Q1`` used.
    tol : float
        Tolerance on ``||(17)||_F`` relative to ``max(1, ||Q2||_F, ||Theta R^-1 Theta^T||_F)``
        (the largest term: its rounding floor).

    Returns
    -------
    MatrixEquationSolution
        ``method = "dare+continuation"``; ``details``: ``gamma_reached``,
        ``continuation_steps``, ``newton_iterations``, ``derivative_abscissa``,
        ``residual_dare``.
    """
    _check(plant, prm)
    c, Abar, Cbar, S, R0, Q0 = _disk_form17(plant, prm, t)
    method = "dare+continuation"
    if not c > 0:
        return MatrixEquationSolution(
            False, None, math.inf, 0, f"2 a b = {2 * prm.a * prm.b:g} >= 1: the disk of (28) "
            "is empty, (17) has no positive definite solution", method=method,
            status="unstable_derivative")
    sc = math.sqrt(c)
    try:
        X0 = solve_filter_dare(Abar / sc, Cbar / sc, Q0 / c, R0 / c, S / c)
    except np.linalg.LinAlgError as exc:
        return MatrixEquationSolution(False, None, math.inf, 0,
                                      f"(17) at gamma = inf (a DARE): no stabilizing solution "
                                      f"({exc})", method=method,
                                      status="no_stabilizing_solution")
    fun = _residual17(plant, prm, t)
    res0 = float(np.linalg.norm(fun(X0, 0.0)[0]))
    if not is_positive_definite(X0):
        return MatrixEquationSolution(False, None, math.inf, 0,
                                      "(17) at gamma = inf: the stabilizing DARE solution is "
                                      "not positive definite", method=method,
                                      status="not_admissible", details={"residual_dare": res0})
    theta = prm.gamma ** -2
    # corrector tolerance: below the requested one, above the rounding floor of the DARE
    cont = continuation(fun, X0, theta, admissible=is_positive_definite,
                        tol=max(_tol(tol, X0) * 1e-2, 100.0 * res0))
    X = cont.X
    res = float(np.linalg.norm(error_bound_residual(X, plant, prm, t)))
    # acceptance relative to the largest term of (17) (its rounding floor), at least ||Q2||
    R_, Th_, _ = error_bound_terms(X, plant, prm, t)
    scale = max(float(np.linalg.norm(X)), float(np.linalg.norm(Th_ @ np.linalg.solve(R_, Th_.T))))
    g_reached = math.inf if cont.theta_reached <= 0 else cont.theta_reached ** -0.5
    details = {"gamma_reached": g_reached if math.isfinite(g_reached) else None,
               "continuation_steps": cont.steps, "newton_iterations": cont.newton_iterations,
               "derivative_abscissa": (cont.derivative_abscissa
                                       if math.isfinite(cont.derivative_abscissa) else None),
               "residual_dare": res0}
    if cont.reached_target and res <= tol * max(1.0, scale):
        return MatrixEquationSolution(
            True, X, res, cont.newton_iterations,
            f"stabilizing solution of (17): DARE at gamma = inf, continuation to gamma = "
            f"{prm.gamma:g} in {cont.steps} steps (residual {res:.1e})", (X,), method=method,
            status="solved", details=details)
    if cont.reached_target:
        return MatrixEquationSolution(False, X, res, cont.newton_iterations,
                                      f"(17): continuation reached gamma = {prm.gamma:g} but "
                                      f"the residual is {res:.3g}", method=method,
                                      status="not_converged", details=details)
    return MatrixEquationSolution(
        False, X, res, cont.newton_iterations,
        f"(17): the stabilizing solution branch from gamma = inf ends at gamma = "
        f"{g_reached:.6g} > {prm.gamma:g} (derivative abscissa "
        f"{cont.derivative_abscissa:.2g}: a fold); no positive definite solution on this "
        f"branch, residual {res:.3g} at the last point", method=method,
        status="branch_ended", details=details)


# -------------------------------------------------------------------- design
def _starts16(plant: UncertainPlant, prm: ParabolicDesignParameters) -> list[FloatArray]:
    """Lyapunov solution of the linear part of (16) as a start (when ``A + aI`` is Hurwitz)."""
    Aa = plant.A + prm.a * np.eye(plant.n)
    c = prm.s * plant.M1 @ plant.M1.T + plant.D1 @ plant.D1.T + prm.delta1 * np.eye(plant.n)
    if np.all(np.linalg.eigvals(Aa).real < 0):
        X = solve_continuous_lyapunov(Aa, -c)
        return [0.5 * (X + X.T)]
    return []


def _met(Q2: FloatArray, sigma2: npt.ArrayLike | None) -> bool | None:
    if sigma2 is None:
        return None
    return bool(np.all(np.diag(Q2) <= np.asarray(sigma2, dtype=float).reshape(-1)))


def _design_structured(plant: UncertainPlant, prm: ParabolicDesignParameters,
                       sigma2: npt.ArrayLike | None, tol: float) -> VarianceDesign:
    params = prm.as_dict()
    eq1 = solve_state_bound(plant, prm, tol=tol)
    if not eq1.solved:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              f"(16): {eq1.message}", params, eq1, None, attempts=(eq1,))
    Q1 = eq1.X
    try:
        t = hat_terms(Q1, plant, prm)
    except np.linalg.LinAlgError:
        return VarianceDesign(False, Q1, None, eq1.residual, None, None, None, EQUATIONS,
                              "(16) solved but Phi = b Gamma A^T + Q1 is singular", params,
                              eq1, None, attempts=(eq1,))
    eq2 = solve_error_bound(plant, prm, t, tol=tol)
    if not eq2.solved:
        return VarianceDesign(False, Q1, eq2.X, eq1.residual, eq2.residual, None, None,
                              EQUATIONS, f"(16) solved (least solution); {eq2.message}",
                              params, eq1, eq2, attempts=(eq1, eq2))
    K, G = filter_gains(eq2.X, plant, prm, t)
    msg = (f"(16) and (17) solved (residuals {eq1.residual:.1e}, {eq2.residual:.1e}; "
           f"least Q1 by monotone Newton, stabilizing Q2 by DARE + continuation)")
    return VarianceDesign(True, Q1, eq2.X, eq1.residual, eq2.residual, K, G, EQUATIONS, msg,
                          params, eq1, eq2, _met(eq2.X, sigma2), attempts=(eq1, eq2))


def _design_multistart(plant: UncertainPlant, prm: ParabolicDesignParameters,
                       sigma2: npt.ArrayLike | None, tol: float, n_random: int, seed: int,
                       polish: bool, starts1: list[FloatArray], starts2: list[FloatArray]
                       ) -> VarianceDesign:
    """The generic multi-start Newton on (16), then on (17) for every admissible ``Q1``.

    Of all solution pairs found, the one of smallest ``max(diag(Q2) / sigma2)`` is returned
    (smallest ``trace(Q2)`` without ``sigma2``).
    """
    n = plant.n
    params = prm.as_dict()
    eq1 = solve_symmetric_equation(lambda Q: state_bound_residual(Q, plant, prm), n,
                                   admissible=_admissible16(plant, prm),
                                   starts=starts1 + _starts16(plant, prm), tol=tol,
                                   n_random=n_random, seed=seed, polish=polish)
    if not eq1.solved:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              f"(16): {eq1.message}", params, eq1, None, attempts=(eq1,))
    best: tuple[float, FloatArray, MatrixEquationSolution] | None = None
    pairs: list[tuple[float, FloatArray, FloatArray, ParabolicTerms,
                      MatrixEquationSolution]] = []
    attempts = [eq1]
    for Q1 in eq1.solutions:
        try:
            t = hat_terms(Q1, plant, prm)
        except np.linalg.LinAlgError:
            continue
        eq2 = solve_symmetric_equation(lambda Q, t=t: error_bound_residual(Q, plant, prm, t), n,
                                       starts=starts2, tol=tol, n_random=n_random, seed=seed,
                                       polish=polish)
        attempts.append(eq2)
        pairs += [(bound_ratio(Q2, sigma2), Q1, Q2, t, eq2) for Q2 in eq2.solutions]
        if not eq2.solved and (best is None or eq2.residual < best[0]):
            best = (eq2.residual, Q1, eq2)
    if pairs:
        _, Q1, Q2, t, eq2 = min(pairs, key=lambda item: item[0])
        K, G = filter_gains(Q2, plant, prm, t)
        res2 = float(np.linalg.norm(error_bound_residual(Q2, plant, prm, t)))
        msg = (f"(16) and (17) solved (residuals {eq1.residual:.1e}, {res2:.1e}); "
               f"{len(eq1.solutions)} admissible Q1, {len(pairs)} solution pairs")
        eq2 = replace(eq2, X=Q2, residual=res2)
        res1 = float(np.linalg.norm(state_bound_residual(Q1, plant, prm)))
        return VarianceDesign(True, Q1, Q2, res1,
                              res2, K, G, EQUATIONS, msg, params, eq1, eq2, _met(Q2, sigma2),
                              attempts=tuple(attempts))
    if best is None:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              "(16) solved but Phi = b Gamma A^T + Q1 is singular for every "
                              "solution", params, eq1, None, attempts=tuple(attempts))
    res2, Q1, eq2 = best
    msg = (f"(16) solved ({len(eq1.solutions)} admissible Q1, residual "
           f"{eq1.residual:.1e}); (17): {eq2.message}")
    res1 = float(np.linalg.norm(state_bound_residual(Q1, plant, prm)))
    return VarianceDesign(False, Q1, eq2.X, res1,
                          res2, None, None, EQUATIONS, msg, params, eq1, eq2,
                          attempts=tuple(attempts))


def design_parabolic(plant: UncertainPlant, prm: ParabolicDesignParameters, *,
                     sigma2: npt.ArrayLike | None = None, tol: float = 1e-10,
                     n_random: int = 6, seed: int = 0, polish: bool = True,
                     method: str = "auto") -> VarianceDesign:
    """Theorem 1 of Wang & Fang: solve (16), then (17), then the gains (18).

    Failure is a result, not an exception; :attr:`VarianceDesign.attempts` says which solver
    failed and why.

    Parameters
    ----------
    plant : UncertainPlant
        Continuous-time plant.
    prm : ParabolicDesignParameters
    sigma2 : array_like, shape (n,), optional
        Variance bounds; sets ``variance_bounds_met`` (``diag(Q2) <= sigma2``).
    tol : float
        Residual tolerance of both equations, ``||F(Q)||_F <= tol max(1, ||Q||_F)`` (the
        multi-start fallback uses ``tol`` as an absolute tolerance).
    n_random, seed, polish
        Passed to :func:`~filters.variance_constrained.solve_symmetric_equation` (fallback).
    method : {"auto", "riccati", "multistart"}
        ``"riccati"``: the structured solvers only (:func:`solve_state_bound`, least ``Q1``;
        :func:`solve_error_bound`, stabilizing ``Q2``). ``"multistart"``: the generic
        multi-start Newton on (16), then on (17) for every admissible ``Q1`` found; of all
        solution pairs the one of smallest ``max(diag(Q2) / sigma2)`` (smallest
        ``trace(Q2)`` without ``sigma2``). ``"auto"`` (default): ``"riccati"``; if it fails,
        or ``sigma2`` is given and not met, also the multi-start (seeded with the structured
        solutions), and the better of the two. Other solutions ``Q1`` of (16) than the least
        one can give a much smaller ``Q2``.

    Returns
    -------
    VarianceDesign
        ``equation_names = ("16", "17")``.
    """
    _check(plant, prm)

    def multistart(starts1: list[FloatArray], starts2: list[FloatArray]) -> VarianceDesign:
        return _design_multistart(plant, prm, sigma2, tol, n_random, seed, polish, starts1,
                                  starts2)

    return structured_then_multistart(method, lambda: _design_structured(plant, prm, sigma2, tol),
                                      multistart, sigma2)


def search_parabolic(plant: UncertainPlant, prm: ParabolicDesignParameters,
                     sigma2: npt.ArrayLike, *, eps1_values: npt.ArrayLike,
                     eps2_values: npt.ArrayLike, h_scales: npt.ArrayLike, n_grid: int = 11,
                     max_verify: int = 3, seed: int = 0, tol: float = 1e-10) -> DesignSearch:
    """Grid search over ``(eps1, eps2)`` and the scale ``c`` of ``H = c H0``.

    Kept for compatibility; :func:`search_parabolic_design` searches all free parameters with
    an optimizer. Each point is solved by :func:`design_parabolic` (``method="auto"``, with a
    cheap multi-start fallback: two random starts, no polish). A point is feasible if (16) and
    (17) are solved, ``diag(Q2) <= sigma^2`` and the gains pass
    :func:`~filters.variance_constrained.verify_design` (poles in ``P(a, b)``,
    ``||H||_inf <= gamma``, variances ``<= sigma^2`` on the vertices and a grid of ``F``). The
    candidates are verified by increasing ``max(diag(Q2) / sigma^2)``; the first that passes
    is returned.

    Parameters
    ----------
    plant, prm
        As in :func:`design_parabolic`; ``prm.H`` is ``H0``.
    sigma2 : array_like, shape (n,)
    eps1_values, eps2_values, h_scales : array_like
        The grid (``h_scales`` may contain 0: ``H = 0``).
    n_grid : int
        Grid of ``F`` of the verification.
    max_verify : int
        Candidates verified at most.
    seed, tol
        Seed of the fallback's random starts; residual tolerance.

    Returns
    -------
    DesignSearch
        ``best_residual_2`` is the smallest residual of (17) reached at the target ``gamma``.
    """
    _check(plant, prm)
    s2 = real_array(sigma2, "sigma2", finite=False).reshape(-1)
    e1s = [float(v) for v in np.atleast_1d(eps1_values)]
    e2s = [float(v) for v in np.atleast_1d(eps2_values)]
    cs = [float(v) for v in np.atleast_1d(h_scales)]
    tried = solved1 = solved2 = 0
    best_res, best_point = math.inf, {}
    candidates: list[tuple[float, VarianceDesign]] = []
    for e1 in e1s:
        for e2 in e2s:
            for c in cs:
                pc = replace(prm, eps1=e1, eps2=e2, H=c * prm.H)
                tried += 1
                d = design_parabolic(plant, pc, sigma2=s2, tol=tol, n_random=2, seed=seed,
                                     polish=False)
                if d.equation_1 is None or not d.equation_1.solved:
                    continue
                solved1 += 1
                if d.residual_2 is not None and d.residual_2 < best_res:
                    best_res = d.residual_2
                    best_point = {"eps1": e1, "eps2": e2, "h_scale": c}
                if not d.solved:
                    continue
                solved2 += 1
                ratio = float(np.max(np.diag(d.Q2) / s2))
                if ratio <= 1.0:
                    candidates.append((ratio, replace(
                        d, message=f"search point eps1={e1:g}, eps2={e2:g}, H = {c:g} H0; "
                                   f"{d.message}")))
    candidates.sort(key=lambda item: item[0])
    region = Parabola(prm.a, prm.b)
    grid = {"eps1": e1s, "eps2": e2s, "h_scale": cs}
    best = best_res if math.isfinite(best_res) else None
    for _, design in candidates[:max_verify]:
        check = verify_design(plant, design.G, design.K, region=region, gamma=prm.gamma,
                              sigma2=s2, n_grid=n_grid)
        if passes(check):
            return DesignSearch(True, design, check, tried, solved1, solved2, best, best_point,
                                grid)
    return DesignSearch(False, None, None, tried, solved1, solved2, best, best_point, grid)


# ------------------------------------------------------------ optimizer search
def _objective_parabolic(plant: UncertainPlant, prm: ParabolicDesignParameters,
                         s2: FloatArray, tol: float) -> tuple[float, VarianceDesign]:
    """Search objective: ``max(diag(Q2) / sigma^2)`` if solved, else a continuous penalty."""
    d = _design_structured(plant, prm, s2, tol)
    if d.solved:
        return float(np.max(np.diag(d.Q2) / s2)), d
    eq1, eq2 = d.equation_1, d.equation_2
    if eq2 is not None and eq2.X is not None and eq2.details.get("gamma_reached"):
        g = float(eq2.details["gamma_reached"])
        return float(np.max(np.diag(eq2.X) / s2)) + 10.0 * math.log(g / prm.gamma), d
    if eq1 is not None and eq1.status in ("left_admissible_set", "not_converged"):
        kappa = _solvable16_fraction(plant, prm)
        if kappa > 0:
            return 0.1 * INFEASIBLE * (1.0 + math.log10(1.0 / kappa)), d
    return INFEASIBLE, d


def search_parabolic_design(plant: UncertainPlant, prm: ParabolicDesignParameters,
                            sigma2: npt.ArrayLike, *, n_starts: int = 8, seed: int = 0,
                            max_evaluations: int = 300, n_grid: int = 21,
                            eps_bounds: tuple[float, float] = (1e-4, 1e4),
                            delta_bounds: tuple[float, float] = (1e-6, 1.0),
                            h_bound: float = 10.0, tol: float = 1e-10) -> DesignSearchRecord:
    """Search Theorem 1's free parameters for a design meeting a specification; verify it.

    The specification is ``prm.a, prm.b`` (region ``P(a, b)``), ``prm.gamma``, ``sigma2`` and
    the plant's uncertainty (``F^T F <= I``). The searched coordinates are ``log10 eps1``,
    ``log10 eps2``, ``log10 delta1``, ``log10 delta2`` and the ``n p`` entries of ``H``
    (direction and size). ``U`` is kept at ``prm.U``: (17) depends on ``H`` only through
    ``H H^T`` and (18) only through ``H U``, so ``(H, U)`` and ``(H U, I)`` give the same
    design and searching ``H`` covers every ``U``.

    Objective (minimized by multi-start Nelder-Mead, see
    :func:`~filters.variance_constrained.run_design_search`): both equations solved by the
    structured solvers (:func:`design_parabolic` with ``method="riccati"``):
    ``max_i [Q2]_ii / sigma_i^2`` (``<= 1``: the theorem certifies the design); (17)'s branch
    ending at ``gamma_reached > gamma``: ``max_i [Q2]_ii / sigma_i^2`` there plus
    ``10 log(gamma_reached / gamma)`` (continuous across the boundary); (16) without solution:
    ``100 (1 + log10(1 / kappa))`` with ``kappa < 1`` the largest factor of (16)'s constant term
    for which it has one (a slope towards solvability); otherwise
    :data:`~filters.variance_constrained.INFEASIBLE`. ``Q2`` grows with ``H H^T``, so the
    optimizer tends to shrink ``H``; ``H`` selects among feasible filters.

    Every candidate (the given ``prm`` first, as it is, then each local optimum) whose
    equations are solved is verified by :func:`~filters.variance_constrained.verify_design`
    (poles of the augmented system in ``P(a, b)``, ``||H||_inf <= gamma``, variances ``<=
    sigma^2``, at the vertices and a grid of ``n_grid`` points of ``F``).

    Parameters
    ----------
    plant : UncertainPlant
        Continuous-time plant, any dimension.
    prm : ParabolicDesignParameters
        Specification (``a, b, gamma``) and the first candidate (``eps1, eps2, delta1,
        delta2, H, U``), e.g. the paper's printed values.
    sigma2 : array_like, shape (n,)
        Variance bounds.
    n_starts : int
        Optimizer starts, the given point included (>= 1).
    seed : int
        Seed of the random starts.
    max_evaluations : int
        Objective evaluations per start.
    n_grid : int
        Grid of ``F`` of the verification.
    eps_bounds, delta_bounds : (float, float)
        Bounds of ``eps1, eps2`` and of ``delta1, delta2`` (> 0).
    h_bound : float
        Bound of the entries of ``H`` in absolute value.
    tol : float
        Residual tolerance of the equations.

    Returns
    -------
    DesignSearchRecord
    """
    _check(plant, prm)
    n, p = plant.n, plant.p
    s2, le, ld = search_space(n, sigma2, eps_bounds, delta_bounds, h_bound)
    bounds = [le, le, ld, ld] + [(-h_bound, h_bound)] * (n * p)
    variables = (["log10_eps1", "log10_eps2", "log10_delta1", "log10_delta2"]
                 + [f"H[{i},{j}]" for i in range(n) for j in range(p)])

    def params(x: FloatArray) -> ParabolicDesignParameters:
        return replace(prm, eps1=10.0 ** x[0], eps2=10.0 ** x[1], delta1=10.0 ** x[2],
                       delta2=10.0 ** x[3], H=x[4:].reshape(n, p))

    def objective(x: FloatArray) -> tuple[float, VarianceDesign | None]:
        return _objective_parabolic(plant, params(x), s2, tol)

    def random_start(rng: np.random.Generator) -> FloatArray:
        return random_search_start(rng, 2, le, ld, n * p, (-3.0, 1.0))

    x0 = np.concatenate([[math.log10(prm.eps1), math.log10(prm.eps2), math.log10(prm.delta1),
                          math.log10(prm.delta2)], prm.H.reshape(-1)])
    region = Parabola(prm.a, prm.b)

    def verify(d: VarianceDesign):
        return verify_design(plant, d.G, d.K, region=region, gamma=prm.gamma, sigma2=s2,
                             n_grid=n_grid)

    spec = {"region": region.describe(), "gamma": prm.gamma, "sigma2": s2.tolist(),
            "f_shape": list(plant.f_shape), "U": prm.U.tolist(), "n_grid": n_grid}
    return run_design_search(objective, x0, random_start, bounds, n_starts=n_starts,
                             seed=seed, max_evaluations=max_evaluations, verify=verify,
                             sigma2=s2, describe=lambda x: params(x).as_dict(),
                             variables=variables, specification=spec,
                             simplex_step=[0.5] * 4 + [0.05 * h_bound] * (n * p))


# the names docs/references.md printed before the rename, for one release
solve_equation16 = deprecated_alias(solve_state_bound, "solve_equation16")
solve_equation17 = deprecated_alias(solve_error_bound, "solve_equation17")
