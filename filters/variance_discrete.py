"""Liu, Deng & Wang (Harbin Institute of Technology; the available text is OCR damaged):
discrete robust H2/H-infinity filter with error variance constraints.

Plant (1)-(2) (:class:`~filters.analysis.UncertainPlant`, ``discrete=True``), filter (3)
``xhat(k+1) = G xhat(k) + K y(k)``; augmented system (4)-(6), ``H(z)`` (7), covariance (8)-(9)
(:func:`filters.analysis.error_system`, :func:`filters.analysis.error_covariance`).

What is legible and used verbatim
---------------------------------
* (11), the first Riccati equation, in ``P1``::

      A P1 A^T - P1 + A P1 N^T (eps I - N P1 N^T)^-1 N P1 A^T + eps M1 M1^T + D1 D1^T
          + delta1 I = 0,        eps I > N P1 N^T,

  i.e. ``A Gamma A^T - P1 + ...`` with ``Gamma = (P1^-1 - eps^-1 N^T N)^-1`` (matrix
  inversion lemma).
* ``P_gamma = P2 + P2 L^T (gamma^2 I - L P2 L^T)^-1 L P2 = (P2^-1 - gamma^-2 L^T L)^-1``.
* (10): ``A_hat = A + (eps M1 M1^T + D1 D1^T) Phi^-1``,
  ``C_hat = C + (eps M2 M1^T + D2 D1^T) Phi^-1`` (the inverse is the "generalized inverse" of
  the abstract when ``Phi`` is singular).
* (23), the H-infinity condition: ``(A_f + dA_f) P (A_f + dA_f)^T - P + D_f D_f^T
  + (A_f + dA_f) P C_f^T (gamma^2 I - C_f P C_f^T)^-1 C_f P (A_f + dA_f)^T < 0`` implies
  ``||H(z)||_inf < gamma`` (the discrete bounded-real lemma in its dual form).

What is reconstructed (the text between (11) and (23) is illegible)
-------------------------------------------------------------------
The second Riccati equation and the gain formula, by the construction of the paper's own
reference [7] (Wang & Huang, IEEE TSP 2000) that Wang & Fang (2006) use in continuous
time: with
``P = diag(P1, P2)`` and ``P_f,gamma = diag(P1, P_gamma)``, Lemma 1 (2) bounds (23) by
``Psi = A_f diag(Gamma, P_gamma) A_f^T + eps M_f M_f^T - P + D_f D_f^T``.
``Psi11 = -delta1 I`` is (11). ``Psi12 = 0`` gives ``G = A_hat - K C_hat`` with
``Phi = Gamma A^T``, i.e. exactly the legible (10). Then, with ``dA = A - A_hat``,
``dC = C - C_hat``::

    R       = dC Gamma dC^T + C_hat P_gamma C_hat^T + eps M2 M2^T + D2 D2^T
    Theta   = dA Gamma dC^T + A_hat P_gamma C_hat^T + eps M1 M2^T + D1 D2^T
    Upsilon = dA Gamma dA^T + A_hat P_gamma A_hat^T + eps M1 M1^T + D1 D1^T - P2

    Psi22 = Upsilon - K Theta^T - Theta K^T + K R K^T
    (12r)   Upsilon - Theta R^-1 Theta^T + H H^T + delta2 I = 0,  gamma^2 I > L P2 L^T
            K = Theta R^-1 + H U R^-1/2,  G = A_hat - K C_hat.

Then ``Psi = diag(-delta1 I, -delta2 I) < 0`` and, for every ``F^T F <= I``: the filter is
robustly stable, ``||H(z)||_inf < gamma`` and the error covariance ``P <= P2`` (subtract (9)
from the inequality). ``(12r)`` is our numbering. The paper's legible ``W1``-``W3`` and the
right inverse ``C_hat^T (C_hat C_hat^T)^-1`` suggest it parametrizes the solutions ``K``
differently (by a generalized inverse instead of ``H U``); with ``H = 0`` both give the
central gain ``K = Theta R^-1``. The example prints no ``H`` and no legible ``delta2``.

Solving (11) and (12r)
----------------------
Both map onto the filter-form discrete algebraic Riccati equation
``X = A X A^T - (A X C^T + S)(C X C^T + R)^-1 (A X C^T + S)^T + Q`` solved by
:func:`scipy.linalg.solve_discrete_are` (stabilizing solution; here ``R`` is indefinite):

* (11): ``C = N``, ``R = -eps I``, ``Q = eps M1 M1^T + D1 D1^T + delta1 I``, ``S = 0``
  (``Gamma = P1 - P1 N^T (N P1 N^T - eps I)^-1 N P1``); :func:`solve_state_bound_discrete`.
  Fallback, and proof of non-existence: monotone Newton from ``P1 = 0`` ((11) is convex).
* (12r), for any ``gamma``: ``A = A_hat``, ``C = [L; C_hat]``, ``R = diag(-gamma^2 I, R0)``,
  ``S = [0, S0]``; eliminating the ``L`` block first produces ``P_gamma``
  (:func:`solve_error_bound_discrete`).

The generic multi-start solver remains as a fallback (``method="auto"`` of
:func:`design_discrete`); :func:`search_discrete_design` searches the free parameters with an
optimizer and verifies the candidates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from filters._linalg import FloatArray, matrix, real_array
from filters.analysis import PoleRegion, UncertainPlant, unit_disk
from filters.matrix_equations import newton_solve, solve_filter_dare
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
    "DiscreteDesignParameters",
    "DiscreteTerms",
    "delta1_threshold",
    "design_discrete",
    "state_bound_residual_discrete",
    "error_bound_residual_discrete",
    "error_bound_terms_discrete",
    "gains_discrete",
    "hat_terms_discrete",
    "least_state_bound_discrete",
    "p_gamma",
    "search_discrete",
    "search_discrete_design",
    "solve_state_bound_discrete",
    "solve_error_bound_discrete",
]

EQUATIONS = ("11", "12r")


@dataclass(frozen=True)
class DiscreteDesignParameters:
    """Free parameters of the (reconstructed) discrete design.

    Attributes
    ----------
    gamma : float
        H-infinity bound (> 0).
    eps : float
        Scalar of Lemma 1 (> 0).
    delta1, delta2 : float
        Small positive constants of (11) and (12r).
    H : array_like, shape (n, p)
        Free matrix of (12r) and the gain (``0``: central gain ``Theta R^-1``).
    U : array_like, shape (p, p), optional
        Orthogonal matrix of the gain (default identity).
    """

    gamma: float
    eps: float
    delta1: float
    delta2: float
    H: Any
    U: Any = None

    def __post_init__(self) -> None:
        for name in ("gamma", "eps", "delta1", "delta2"):
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

    def as_dict(self) -> dict[str, Any]:
        return {"gamma": self.gamma, "eps": self.eps, "delta1": self.delta1,
                "delta2": self.delta2, "H": self.H.tolist(), "U": self.U.tolist()}


def _check(plant: UncertainPlant, prm: DiscreteDesignParameters) -> None:
    if not plant.discrete:
        raise ValueError("plant must be discrete-time (discrete=True) for the discrete design")
    if prm.H.shape != (plant.n, plant.p):
        raise ValueError(f"H must have shape ({plant.n}, {plant.p}), got {prm.H.shape}")


# ---------------------------------------------------------------------- (11)
def _gamma(P1: npt.NDArray[Any], N: FloatArray, eps: float) -> npt.NDArray[Any]:
    """``P1 + P1 N^T (eps I - N P1 N^T)^-1 N P1 = (P1^-1 - eps^-1 N^T N)^-1``."""
    j = N.shape[0]
    return P1 + P1 @ N.T @ np.linalg.solve(eps * np.eye(j) - N @ P1 @ N.T, N @ P1)


def state_bound_residual_discrete(P1: npt.NDArray[Any], plant: UncertainPlant,
                                  prm: DiscreteDesignParameters) -> npt.NDArray[Any]:
    """Left side of (11) at ``P1``, shape (n, n)."""
    A = plant.A
    return (A @ _gamma(P1, plant.N, prm.eps) @ A.T - P1 + prm.eps * plant.M1 @ plant.M1.T
            + plant.D1 @ plant.D1.T + prm.delta1 * np.eye(plant.n))


def _admissible11(plant: UncertainPlant, prm: DiscreteDesignParameters):
    N, j = plant.N, plant.N.shape[0]

    def ok(P1: FloatArray) -> bool:
        return (is_positive_definite(P1)
                and is_positive_definite(prm.eps * np.eye(j) - N @ P1 @ N.T))

    return ok


def least_state_bound_discrete(plant: UncertainPlant, prm: DiscreteDesignParameters, *,
                               max_iter: int = 100_000, tol: float = 1e-13
                               ) -> tuple[FloatArray | None, int, str]:
    """Least solution of (11) by the monotone iteration ``P <- A Gamma(P) A^T + c``.

    From ``P = 0`` the iterates increase (``Gamma`` is monotone on ``eps I > N P N^T``); they
    converge to the least solution iff (11) has an admissible solution, and otherwise leave
    the admissible set (``N P N^T >= eps I``) or grow without bound. This decides existence.

    Returns
    -------
    P1 : numpy.ndarray, shape (n, n), or None
        The least solution, ``None`` if none exists (or no convergence in ``max_iter``).
    iterations : int
    message : str
    """
    _check(plant, prm)
    n, j = plant.n, plant.N.shape[0]
    c = (prm.eps * plant.M1 @ plant.M1.T + plant.D1 @ plant.D1.T + prm.delta1 * np.eye(n))
    P = np.zeros((n, n))
    for k in range(1, max_iter + 1):
        if not is_positive_definite(prm.eps * np.eye(j) - plant.N @ P @ plant.N.T):
            return None, k, (f"no solution: the monotone iteration left eps I > N P1 N^T "
                             f"after {k} iterations")
        Pn = plant.A @ _gamma(P, plant.N, prm.eps) @ plant.A.T + c
        Pn = 0.5 * (Pn + Pn.T)
        if not np.isfinite(Pn).all() or np.abs(Pn).max() > 1e12:
            return None, k, f"no solution: the monotone iteration diverged after {k} iterations"
        if np.abs(Pn - P).max() <= tol * max(1.0, np.abs(Pn).max()):
            return Pn, k, f"least solution after {k} iterations"
        P = Pn
    return None, max_iter, f"monotone iteration not converged in {max_iter} iterations"


def delta1_threshold(plant: UncertainPlant, prm: DiscreteDesignParameters, *,
                     rtol: float = 1e-4, max_iter: int = 20_000) -> float | None:
    """Supremum of the ``delta1`` for which (11) has an admissible solution at ``prm.eps``.

    Existence is decided by the monotone Newton iteration of :func:`solve_state_bound_discrete` (the
    same decision as :func:`least_state_bound_discrete`, quadratically convergent; ``max_iter`` is
    kept for compatibility and caps its iterations at ``min(max_iter, 300)``); it is
    monotone in ``delta1`` (a larger constant term only raises the iterates). Geometric
    bisection to relative ``rtol``.

    Returns
    -------
    float or None
        ``None`` if (11) has no solution even for ``delta1 -> 0`` (``1e-12``).
    """
    _check(plant, prm)

    def exists(d: float) -> bool:
        return _monotone11(replace(prm, delta1=d), min(max_iter, 300)) is not None

    def _monotone11(p: DiscreteDesignParameters, iters: int) -> FloatArray | None:
        n, j = plant.n, plant.N.shape[0]
        if np.abs(np.linalg.eigvals(plant.A)).max() >= 1.0:
            return None
        out = newton_solve(_residual11(plant, p), np.zeros((n, n)), monotone=True,
                           admissible=lambda P: is_positive_definite(
                               p.eps * np.eye(j) - plant.N @ P @ plant.N.T),
                           tol=1e-13, max_iter=iters)
        ok = out.converged or (out.status == "not_converged"
                               and out.residual <= _tol(1e-9, out.X))  # rounding floor
        return out.X if ok else None

    lo = 1e-12
    if not exists(lo):
        return None
    hi = prm.delta1
    while exists(hi):
        lo, hi = hi, 2.0 * hi
    while hi / lo > 1.0 + rtol:
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if exists(mid) else (lo, mid)
    return lo


# --------------------------------------------------------------------- (12r)
@dataclass(frozen=True)
class DiscreteTerms:
    """Quantities (10) fixed by ``P1``.

    Attributes
    ----------
    P1, Gamma, Phi, A_hat : numpy.ndarray, shape (n, n)
    C_hat : numpy.ndarray, shape (p, n)
    generalized_inverse : bool
        ``Phi`` was singular and its Moore-Penrose inverse was used.
    """

    P1: FloatArray
    Gamma: FloatArray
    Phi: FloatArray
    A_hat: FloatArray
    C_hat: FloatArray
    generalized_inverse: bool


def hat_terms_discrete(P1: FloatArray, plant: UncertainPlant,
                       prm: DiscreteDesignParameters) -> DiscreteTerms:
    """(10): ``Phi = Gamma A^T``, ``A_hat``, ``C_hat`` (pseudo-inverse if ``Phi`` is singular)."""
    A, C, M1, M2, D1, D2 = plant.A, plant.C, plant.M1, plant.M2, plant.D1, plant.D2
    Gm = _gamma(P1, plant.N, prm.eps)
    Phi = Gm @ A.T
    X = np.vstack([prm.eps * M1 @ M1.T + D1 @ D1.T, prm.eps * M2 @ M1.T + D2 @ D1.T])
    generalized = bool(np.linalg.cond(Phi) > 1e12)
    right = X @ np.linalg.pinv(Phi) if generalized else np.linalg.solve(Phi.T, X.T).T
    n = plant.n
    return DiscreteTerms(P1, Gm, Phi, A + right[:n], C + right[n:], generalized)


def p_gamma(P2: npt.NDArray[Any], L: FloatArray, gamma: float) -> npt.NDArray[Any]:
    """``P2 + P2 L^T (gamma^2 I - L P2 L^T)^-1 L P2``, shape (n, n)."""
    q = L.shape[0]
    return P2 + P2 @ L.T @ np.linalg.solve(gamma**2 * np.eye(q) - L @ P2 @ L.T, L @ P2)


def error_bound_terms_discrete(P2: npt.NDArray[Any], plant: UncertainPlant,
                               prm: DiscreteDesignParameters, t: DiscreteTerms
                               ) -> tuple[npt.NDArray[Any], npt.NDArray[Any], npt.NDArray[Any]]:
    """``(R, Theta, Upsilon)`` of the reconstructed (12r), shapes (p, p), (n, p), (n, n)."""
    A, C, M1, M2, D1, D2 = plant.A, plant.C, plant.M1, plant.M2, plant.D1, plant.D2
    e = prm.eps
    dA, dC, Ah, Ch, Gm = A - t.A_hat, C - t.C_hat, t.A_hat, t.C_hat, t.Gamma
    Pg = p_gamma(P2, plant.L, prm.gamma)
    R = dC @ Gm @ dC.T + Ch @ Pg @ Ch.T + e * M2 @ M2.T + D2 @ D2.T
    Theta = dA @ Gm @ dC.T + Ah @ Pg @ Ch.T + e * M1 @ M2.T + D1 @ D2.T
    Ups = dA @ Gm @ dA.T + Ah @ Pg @ Ah.T + e * M1 @ M1.T + D1 @ D1.T - P2
    return R, Theta, Ups


def error_bound_residual_discrete(P2: npt.NDArray[Any], plant: UncertainPlant,
                                  prm: DiscreteDesignParameters, t: DiscreteTerms
                                  ) -> npt.NDArray[Any]:
    """Left side of (12r): ``Upsilon - Theta R^-1 Theta^T + H H^T + delta2 I``."""
    R, Theta, Ups = error_bound_terms_discrete(P2, plant, prm, t)
    return (Ups - Theta @ np.linalg.solve(R, Theta.T) + prm.H @ prm.H.T
            + prm.delta2 * np.eye(plant.n))


def _admissible12r(plant: UncertainPlant, prm: DiscreteDesignParameters):
    L, q = plant.L, plant.L.shape[0]

    def ok(P2: FloatArray) -> bool:
        return (is_positive_definite(P2)
                and is_positive_definite(prm.gamma**2 * np.eye(q) - L @ P2 @ L.T))

    return ok


def gains_discrete(P2: FloatArray, plant: UncertainPlant, prm: DiscreteDesignParameters,
                   t: DiscreteTerms, U: npt.ArrayLike | None = None
                   ) -> tuple[FloatArray, FloatArray]:
    """``K = Theta R^-1 + H U R^-1/2``, ``G = A_hat - K C_hat`` (reconstructed).

    Returns
    -------
    K : numpy.ndarray, shape (n, p)
    G : numpy.ndarray, shape (n, n)
    """
    R, Theta, _ = error_bound_terms_discrete(P2, plant, prm, t)
    U_ = prm.U if U is None else real_array(U, "U", finite=False)
    K = np.linalg.solve(R, Theta.T).T + prm.H @ U_ @ inverse_sqrt(R)
    return K, t.A_hat - K @ t.C_hat


# ----------------------------------------------------------- structured solvers
def _tol(tol: float, X: FloatArray | None) -> float:
    """Residual tolerance relative to the size of the solution (absolute for ``||X|| <= 1``)."""
    return tol * max(1.0, 0.0 if X is None else float(np.linalg.norm(X)))


def _residual11(plant: UncertainPlant, prm: DiscreteDesignParameters):
    """``P1 -> (F11(P1), derivative terms)``: ``F11'(P1)[D] = (A T) D (A T)^T - D`` with
    ``T = I + P1 N^T (eps I - N P1 N^T)^-1 N``."""
    A, N = plant.A, plant.N
    n, j = plant.n, N.shape[0]
    eye = np.eye(n)
    const = prm.eps * plant.M1 @ plant.M1.T + plant.D1 @ plant.D1.T + prm.delta1 * eye

    def fun(P: FloatArray) -> tuple[FloatArray, list[tuple[FloatArray, FloatArray]]]:
        NP = N @ P
        X = np.linalg.solve(prm.eps * np.eye(j) - NP @ N.T, NP)
        AT = A @ (eye + X.T @ N)
        F = A @ (P + NP.T @ X) @ A.T - P + const
        return F, [(AT, AT), (-eye, eye)]

    return fun


def _monotone11(plant: UncertainPlant, prm: DiscreteDesignParameters, tol: float
                ) -> tuple[FloatArray | None, int, str]:
    """Monotone Newton from ``P1 = 0`` for (11) (convex, resolvent-positive derivative):
    ``(least solution or None, iterations, status)``."""
    n, j = plant.n, plant.N.shape[0]
    if np.abs(np.linalg.eigvals(plant.A)).max() >= 1.0:
        return None, 0, "unstable_derivative"

    def domain(P: FloatArray) -> bool:
        return is_positive_definite(prm.eps * np.eye(j) - plant.N @ P @ plant.N.T)

    out = newton_solve(_residual11(plant, prm), np.zeros((n, n)), admissible=domain,
                       tol=tol, max_iter=300, monotone=True)
    return (out.X if out.converged else None), out.iterations, out.status


def solve_state_bound_discrete(plant: UncertainPlant, prm: DiscreteDesignParameters, *,
                               tol: float = 1e-10) -> MatrixEquationSolution:
    """Least solution of (11): a DARE with indefinite weight, monotone Newton as fallback.

    Mapping: with ``Gamma = P1 - P1 N^T (N P1 N^T - eps I)^-1 N P1``, (11) is the filter-form
    DARE ``P1 = A P1 A^T - A P1 N^T (N P1 N^T + R)^-1 N P1 A^T + Q`` with ``C = N``,
    ``R = -eps I`` (indefinite) and ``Q = eps M1 M1^T + D1 D1^T + delta1 I``
    (:func:`~filters.matrix_equations.solve_filter_dare`). Its stabilizing solution, when
    admissible (``P1 > 0``, ``eps I > N P1 N^T``), is the least solution. Otherwise monotone
    Newton from ``P1 = 0`` decides (as :func:`least_state_bound_discrete`, but quadratically
    convergent): (11) is convex with a resolvent-positive derivative, so its iterates increase
    to the least solution if there is one, and leaving ``eps I > N P1 N^T`` proves that there
    is none.

    Returns
    -------
    MatrixEquationSolution
        ``method`` is ``"dare"`` or ``"monotone-newton"``.
    """
    _check(plant, prm)
    n, j = plant.n, plant.N.shape[0]
    adm = _admissible11(plant, prm)
    c = prm.eps * plant.M1 @ plant.M1.T + plant.D1 @ plant.D1.T + prm.delta1 * np.eye(n)
    why = ""
    try:
        P = solve_filter_dare(plant.A, plant.N, c, -prm.eps * np.eye(j))
        res = float(np.linalg.norm(state_bound_residual_discrete(P, plant, prm)))
        if adm(P) and res <= _tol(tol, P):
            return MatrixEquationSolution(True, P, res, 0, f"least solution of (11) by the DARE "
                                          f"mapping (residual {res:.1e})", (P,), method="dare",
                                          status="solved")
        why = ("the stabilizing DARE solution is not admissible" if not adm(P) else
               f"the DARE solution has residual {res:.3g}")
    except np.linalg.LinAlgError as exc:
        why = f"no stabilizing DARE solution ({exc})"
    P, it, status = _monotone11(plant, prm, tol * 1e-2)
    if P is not None and adm(P):
        res = float(np.linalg.norm(state_bound_residual_discrete(P, plant, prm)))
        if res <= _tol(tol, P):
            return MatrixEquationSolution(True, P, res, it, f"least solution of (11) by "
                                          f"monotone Newton ({why}; residual {res:.1e})", (P,),
                                          method="monotone-newton", status="solved")
    msg = {"unstable_derivative": "A is not Schur stable: (11) has no positive definite "
                                  "solution",
           "left_admissible_set": f"(11) has no solution with eps I > N P1 N^T: the monotone "
                                  f"Newton iteration left that set at iteration {it}"
           }.get(status, f"monotone Newton for (11) did not converge ({status}, {it} "
                         f"iterations)")
    return MatrixEquationSolution(False, None, math.inf, it, f"{why}; {msg}",
                                  method="monotone-newton", status=status)


def _dare12r(plant: UncertainPlant, prm: DiscreteDesignParameters, t: DiscreteTerms,
             gamma: float) -> FloatArray:
    """The stabilizing solution of (12r) at ``gamma`` by the augmented DARE (raises
    ``LinAlgError``)."""
    A, C, M1, M2, D1, D2, L = (plant.A, plant.C, plant.M1, plant.M2, plant.D1, plant.D2,
                               plant.L)
    e, n, p, q = prm.eps, plant.n, plant.p, L.shape[0]
    dA, dC, Gm = A - t.A_hat, C - t.C_hat, t.Gamma
    S = dA @ Gm @ dC.T + e * M1 @ M2.T + D1 @ D2.T
    R0 = dC @ Gm @ dC.T + e * M2 @ M2.T + D2 @ D2.T
    Q0 = dA @ Gm @ dA.T + e * M1 @ M1.T + D1 @ D1.T + prm.H @ prm.H.T + prm.delta2 * np.eye(n)
    if not math.isfinite(gamma):
        return solve_filter_dare(t.A_hat, t.C_hat, Q0, R0, S)
    W = np.vstack([L, t.C_hat])
    R = np.zeros((q + p, q + p))
    R[:q, :q] = -gamma**2 * np.eye(q)
    R[q:, q:] = R0
    return solve_filter_dare(t.A_hat, W, Q0, R, np.hstack([np.zeros((n, q)), S]))


def solve_error_bound_discrete(plant: UncertainPlant, prm: DiscreteDesignParameters,
                               t: DiscreteTerms, *, tol: float = 1e-10,
                               find_gamma_reached: bool = False
                               ) -> MatrixEquationSolution:
    """Stabilizing solution of (12r) by the augmented DARE, for any ``gamma``.

    Mapping: with ``W = [L; C_hat]``, ``R = diag(-gamma^2 I, R0)`` and ``S = [0, S0]``, the
    filter-form DARE ``P2 = A_hat P2 A_hat^T - (A_hat P2 W^T + S)(W P2 W^T + R)^-1 (...)^T +
    Q0`` *is* (12r): eliminating the ``L`` block first (Schur complement) turns ``P2`` into
    ``P_gamma = P2 + P2 L^T (gamma^2 I - L P2 L^T)^-1 L P2`` and leaves
    ``A_hat P_gamma A_hat^T - Theta R^-1 Theta^T + Q0``. Here ``R0 = dC Gamma dC^T + eps M2
    M2^T + D2 D2^T``, ``S0 = dA Gamma dC^T + eps M1 M2^T + D1 D2^T``, ``Q0 = dA Gamma dA^T +
    eps M1 M1^T + D1 D1^T + H H^T + delta2 I`` (``dA = A - A_hat``, ``dC = C - C_hat``). The
    solution is accepted if ``P2 > 0``, ``gamma^2 I > L P2 L^T`` and the residual of
    :func:`error_bound_residual_discrete` is small.

    Parameters
    ----------
    plant, prm
    t : DiscreteTerms
        :func:`hat_terms_discrete` of the ``P1`` used.
    tol : float
        Tolerance on ``||(12r)||_F`` relative to ``max(1, ||P2||_F)``.
    find_gamma_reached : bool
        On failure, bisect for the smallest ``gamma`` (to 0.1 %) at which the stabilizing
        solution exists and is admissible (``details["gamma_reached"]``, ``X`` there).

    Returns
    -------
    MatrixEquationSolution
        ``method = "dare"``.
    """
    _check(plant, prm)
    adm = _admissible12r(plant, prm)

    def attempt(g: float) -> tuple[FloatArray | None, str]:
        try:
            P = _dare12r(plant, prm, t, g)
        except np.linalg.LinAlgError as exc:
            return None, f"no stabilizing solution ({exc})"
        pg = replace(prm, gamma=g) if math.isfinite(g) else replace(prm, gamma=1e150)
        if not _admissible12r(plant, pg)(P):
            return None, "the stabilizing solution is not admissible (P2 > 0, gamma^2 I > L P2 L^T)"
        return P, ""

    P, why = attempt(prm.gamma)
    if P is not None:
        res = float(np.linalg.norm(error_bound_residual_discrete(P, plant, prm, t)))
        if res <= _tol(tol, P) and adm(P):
            return MatrixEquationSolution(True, P, res, 0, f"stabilizing solution of (12r) by "
                                          f"the augmented DARE (residual {res:.1e})", (P,),
                                          method="dare", status="solved")
        return MatrixEquationSolution(False, P, res, 0, f"(12r): the augmented DARE solution "
                                      f"has residual {res:.3g}", method="dare",
                                      status="not_converged")
    status = "no_stabilizing_solution" if why.startswith("no") else "not_admissible"
    details: dict[str, Any] = {}
    X = None
    res = math.inf
    if find_gamma_reached:
        Pinf, _ = attempt(math.inf)
        if Pinf is not None:
            lo, hi = prm.gamma, 2.0 * prm.gamma
            Phi_, _ = attempt(hi)
            while Phi_ is None and hi < 1e6 * prm.gamma:
                lo, hi = hi, 4.0 * hi
                Phi_, _ = attempt(hi)
            X = Phi_ if Phi_ is not None else Pinf
            while Phi_ is not None and hi / lo > 1.001:
                mid = math.sqrt(lo * hi)
                Pm, _ = attempt(mid)
                if Pm is None:
                    lo = mid
                else:
                    hi, X = mid, Pm
            details["gamma_reached"] = hi if Phi_ is not None else None
            res = float(np.linalg.norm(error_bound_residual_discrete(X, plant, prm, t)))
    return MatrixEquationSolution(False, X, res, 0, f"(12r) at gamma = {prm.gamma:g}: {why}",
                                  method="dare", status=status, details=details)


# -------------------------------------------------------------------- design
def _solve11(plant: UncertainPlant, prm: DiscreteDesignParameters, *, tol: float,
             n_random: int, seed: int, polish: bool, starts: list[FloatArray] | None = None
             ) -> tuple[MatrixEquationSolution, str]:
    least, _, how = least_state_bound_discrete(plant, prm)
    st = ([] if least is None else [least]) + (starts or [])
    eq1 = solve_symmetric_equation(lambda P: state_bound_residual_discrete(P, plant, prm), plant.n,
                                   admissible=_admissible11(plant, prm), starts=st,
                                   tol=tol, n_random=n_random, seed=seed, polish=polish)
    return eq1, how


def _met(P2: FloatArray, sigma2: npt.ArrayLike | None) -> bool | None:
    if sigma2 is None:
        return None
    return bool(np.all(np.diag(P2) <= np.asarray(sigma2, dtype=float).reshape(-1)))


def _design_structured(plant: UncertainPlant, prm: DiscreteDesignParameters,
                       sigma2: npt.ArrayLike | None, tol: float,
                       find_gamma_reached: bool = False) -> VarianceDesign:
    params = prm.as_dict()
    eq1 = solve_state_bound_discrete(plant, prm, tol=tol)
    if not eq1.solved:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              f"(11): {eq1.message}", params, eq1, None, attempts=(eq1,))
    P1 = eq1.X
    try:
        t = hat_terms_discrete(P1, plant, prm)
    except np.linalg.LinAlgError:
        return VarianceDesign(False, P1, None, eq1.residual, None, None, None, EQUATIONS,
                              "(11) solved but (10) failed", params, eq1, None,
                              attempts=(eq1,))
    eq2 = solve_error_bound_discrete(plant, prm, t, tol=tol, find_gamma_reached=find_gamma_reached)
    if not eq2.solved:
        return VarianceDesign(False, P1, eq2.X, eq1.residual, eq2.residual, None, None,
                              EQUATIONS, f"(11) solved (least solution); {eq2.message}",
                              params, eq1, eq2, attempts=(eq1, eq2))
    K, G = gains_discrete(eq2.X, plant, prm, t)
    gi = "; Phi singular: generalized inverse used" if t.generalized_inverse else ""
    msg = (f"(11) and (12r) solved (residuals {eq1.residual:.1e}, {eq2.residual:.1e}; "
           f"both by DARE mappings){gi}")
    return VarianceDesign(True, P1, eq2.X, eq1.residual, eq2.residual, K, G, EQUATIONS, msg,
                          params, eq1, eq2, _met(eq2.X, sigma2), attempts=(eq1, eq2))


def _design_multistart(plant: UncertainPlant, prm: DiscreteDesignParameters,
                       sigma2: npt.ArrayLike | None, tol: float, n_random: int, seed: int,
                       polish: bool, starts1: list[FloatArray], starts2: list[FloatArray]
                       ) -> VarianceDesign:
    """Generic multi-start Newton on (11), then (12r) for every admissible ``P1``; of all
    solution pairs the one of smallest ``max(diag(P2) / sigma2)``."""
    n = plant.n
    params = prm.as_dict()
    eq1, how = _solve11(plant, prm, tol=tol, n_random=n_random, seed=seed, polish=polish,
                        starts=starts1)
    if not eq1.solved:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              f"(11): {how}; {eq1.message}", params, eq1, None,
                              attempts=(eq1,))
    best: tuple[float, FloatArray, MatrixEquationSolution] | None = None
    pairs: list[tuple[float, FloatArray, FloatArray, DiscreteTerms,
                      MatrixEquationSolution]] = []
    attempts = [eq1]
    for P1 in eq1.solutions:
        try:
            t = hat_terms_discrete(P1, plant, prm)
        except np.linalg.LinAlgError:
            continue
        eq2 = solve_symmetric_equation(
            lambda P, t=t: error_bound_residual_discrete(P, plant, prm, t), n,
                                       admissible=_admissible12r(plant, prm), starts=starts2,
                                       tol=tol, n_random=n_random, seed=seed, polish=polish)
        attempts.append(eq2)
        pairs += [(bound_ratio(P2, sigma2), P1, P2, t, eq2) for P2 in eq2.solutions]
        if not eq2.solved and (best is None or eq2.residual < best[0]):
            best = (eq2.residual, P1, eq2)
    if pairs:
        _, P1, P2, t, eq2 = min(pairs, key=lambda item: item[0])
        K, G = gains_discrete(P2, plant, prm, t)
        res2 = float(np.linalg.norm(error_bound_residual_discrete(P2, plant, prm, t)))
        gi = "; Phi singular: generalized inverse used" if t.generalized_inverse else ""
        msg = (f"(11) and (12r) solved (residuals {eq1.residual:.1e}, {res2:.1e}){gi}")
        eq2 = replace(eq2, X=P2, residual=res2)
        res1 = float(np.linalg.norm(state_bound_residual_discrete(P1, plant, prm)))
        return VarianceDesign(True, P1, P2, res1,
                              res2, K, G, EQUATIONS, msg, params, eq1, eq2, _met(P2, sigma2),
                              attempts=tuple(attempts))
    if best is None:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              "(11) solved but (10) failed for every solution", params, eq1,
                              None, attempts=tuple(attempts))
    res2, P1, eq2 = best
    res1 = float(np.linalg.norm(state_bound_residual_discrete(P1, plant, prm)))
    return VarianceDesign(False, P1, eq2.X, res1,
                          res2, None, None, EQUATIONS,
                          f"(11) solved ({how}); (12r): {eq2.message}", params, eq1, eq2,
                          attempts=tuple(attempts))


def design_discrete(plant: UncertainPlant, prm: DiscreteDesignParameters, *,
                    sigma2: npt.ArrayLike | None = None, tol: float = 1e-10,
                    n_random: int = 6, seed: int = 0, polish: bool = True,
                    method: str = "auto") -> VarianceDesign:
    """Solve (11), then (12r), then the gains; failure is a result, not an exception.

    Parameters
    ----------
    plant : UncertainPlant
        Discrete-time plant.
    prm : DiscreteDesignParameters
    sigma2 : array_like, shape (n,), optional
        Variance bounds; sets ``variance_bounds_met`` (``diag(P2) <= sigma2``).
    tol : float
        Residual tolerance, ``||F(P)||_F <= tol max(1, ||P||_F)`` (absolute in the fallback).
    n_random, seed, polish
        Passed to :func:`~filters.variance_constrained.solve_symmetric_equation` (fallback).
    method : {"auto", "riccati", "multistart"}
        ``"riccati"``: both equations by their DARE mappings
        (:func:`solve_state_bound_discrete`, the
        least ``P1``; :func:`solve_error_bound_discrete`, the stabilizing ``P2``). ``"multistart"``:
        the monotone iteration :func:`least_state_bound_discrete` (which decides whether (11) is
        solvable) seeds the generic multi-start Newton solver, then (12r) for every
        admissible ``P1``; of all pairs the one of smallest ``max(diag(P2) / sigma2)``.
        ``"auto"`` (default): ``"riccati"``; if it fails, or ``sigma2`` is given and not met,
        also the multi-start, and the better of the two.

    Returns
    -------
    VarianceDesign
        ``Q1 = P1``, ``Q2 = P2``, ``equation_names = ("11", "12r")``.
    """
    _check(plant, prm)

    def multistart(starts1: list[FloatArray], starts2: list[FloatArray]) -> VarianceDesign:
        return _design_multistart(plant, prm, sigma2, tol, n_random, seed, polish, starts1,
                                  starts2)

    return structured_then_multistart(method, lambda: _design_structured(plant, prm, sigma2, tol),
                                      multistart, sigma2)


def search_discrete(plant: UncertainPlant, prm: DiscreteDesignParameters,
                    sigma2: npt.ArrayLike, *, eps_values: npt.ArrayLike,
                    h_scales: npt.ArrayLike, h_direction: npt.ArrayLike | None = None,
                    delta_values: npt.ArrayLike | None = None, n_grid: int = 11,
                    max_verify: int = 3, seed: int = 0, tol: float = 1e-10) -> DesignSearch:
    """Grid search over ``eps``, the scale ``c`` of ``H = c H0`` (and ``delta1 = delta2``).

    Kept for compatibility; :func:`search_discrete_design` searches all free parameters with
    an optimizer. Each point is solved by the DARE mappings (:func:`design_discrete` with
    ``method="riccati"``). Feasible: (11) and (12r) solved, ``diag(P2) <= sigma^2`` and the
    gains pass :func:`~filters.variance_constrained.verify_design` (unit disk,
    ``||H||_inf <= gamma``, variances on the vertices and a grid of ``F``). Candidates are
    verified by increasing ``max(diag(P2) / sigma^2)``.

    Parameters
    ----------
    plant, prm
        As in :func:`design_discrete`.
    sigma2 : array_like, shape (n,)
    eps_values, h_scales : array_like
    h_direction : array_like, shape (n, p), optional
        ``H0`` (default ``prm.H``).
    delta_values : array_like, optional
        Values of ``delta1 = delta2`` (default: ``prm``'s ``delta1, delta2`` only).
    n_grid, max_verify, seed, tol
        As in :func:`filters.variance_continuous.search_parabolic` (``seed`` is unused).

    Returns
    -------
    DesignSearch
    """
    del seed
    _check(plant, prm)
    H0 = prm.H if h_direction is None else matrix("h_direction", h_direction,
                                                  (plant.n, plant.p))
    s2 = real_array(sigma2, "sigma2", finite=False).reshape(-1)
    es = [float(v) for v in np.atleast_1d(eps_values)]
    cs = [float(v) for v in np.atleast_1d(h_scales)]
    ds = (None if delta_values is None else [float(v) for v in np.atleast_1d(delta_values)])
    tried = solved1 = solved2 = 0
    best_res, best_point = math.inf, {}
    candidates: list[tuple[float, VarianceDesign]] = []
    points = [(e, d) for d in (ds or [None]) for e in es]
    for e, dl in points:
        p = replace(prm, eps=e) if dl is None else replace(prm, eps=e, delta1=dl, delta2=dl)
        for c in cs:
            pc = replace(p, H=c * H0)
            tried += 1
            d = _design_structured(plant, pc, s2, tol)
            if d.equation_1 is None or not d.equation_1.solved:
                continue
            solved1 += 1
            if d.residual_2 is not None and d.residual_2 < best_res:
                best_res = d.residual_2
                best_point = {"eps": e, "h_scale": c, "delta1": p.delta1, "delta2": p.delta2}
            if not d.solved:
                continue
            solved2 += 1
            ratio = float(np.max(np.diag(d.Q2) / s2))
            if ratio <= 1.0:
                candidates.append((ratio, replace(
                    d, message=f"search point eps={e:g}, delta1=delta2={p.delta1:g}, H = "
                               f"{c:g} H0; {d.message}")))
    candidates.sort(key=lambda item: item[0])
    grid = {"eps": es, "h_scale": cs, "h_direction": H0.tolist(),
            "delta": ds if ds is not None else [prm.delta1]}
    best = best_res if math.isfinite(best_res) else None
    for _, design in candidates[:max_verify]:
        check = verify_design(plant, design.G, design.K, region=unit_disk(), gamma=prm.gamma,
                              sigma2=s2, n_grid=n_grid)
        if passes(check):
            return DesignSearch(True, design, check, tried, solved1, solved2, best, best_point,
                                grid)
    return DesignSearch(False, None, None, tried, solved1, solved2, best, best_point, grid)


# ------------------------------------------------------------ optimizer search
def search_discrete_design(plant: UncertainPlant, prm: DiscreteDesignParameters,
                           sigma2: npt.ArrayLike, *, region: PoleRegion | None = None,
                           n_starts: int = 8, seed: int = 0, max_evaluations: int = 300,
                           n_grid: int = 21, eps_bounds: tuple[float, float] = (1e-4, 1e4),
                           delta_bounds: tuple[float, float] = (1e-6, 1.0),
                           h_bound: float = 10.0, tol: float = 1e-10) -> DesignSearchRecord:
    """Search the discrete design's free parameters for a design meeting a specification.

    The specification is ``prm.gamma``, ``sigma2``, the plant's uncertainty and the pole
    region of the verification (default the unit disk, i.e. robust stability, which the
    design guarantees; a smaller disk ``Disk(0, r)`` asks for spectral radius ``< r`` and is
    only verified, not guaranteed). Coordinates: ``log10 eps``, ``log10 delta1``,
    ``log10 delta2`` and the ``n p`` entries of ``H``; ``U`` stays ``prm.U`` (``(H, U)`` and
    ``(H U, I)`` give the same design).

    Objective: both equations solved by their DARE mappings: ``max_i [P2]_ii / sigma_i^2``;
    (12r) unsolvable at ``gamma`` but solvable at ``gamma_reached > gamma``: that ratio there
    plus ``10 log(gamma_reached / gamma)``; otherwise
    :data:`~filters.variance_constrained.INFEASIBLE`. Candidates (the given ``prm`` first,
    then each local optimum of the multi-start Nelder-Mead) are verified with
    :func:`~filters.variance_constrained.verify_design`; see
    :func:`~filters.variance_constrained.run_design_search`.

    Parameters
    ----------
    plant : UncertainPlant
        Discrete-time plant, any dimension.
    prm : DiscreteDesignParameters
        ``gamma`` and the first candidate.
    sigma2 : array_like, shape (n,)
    region : PoleRegion, optional
    n_starts, seed, max_evaluations, n_grid, eps_bounds, delta_bounds, h_bound, tol
        As in :func:`filters.variance_continuous.search_parabolic_design`.

    Returns
    -------
    DesignSearchRecord
    """
    _check(plant, prm)
    n, p = plant.n, plant.p
    s2, le, ld = search_space(n, sigma2, eps_bounds, delta_bounds, h_bound)
    reg = unit_disk() if region is None else region
    bounds = [le, ld, ld] + [(-h_bound, h_bound)] * (n * p)
    variables = (["log10_eps", "log10_delta1", "log10_delta2"]
                 + [f"H[{i},{j}]" for i in range(n) for j in range(p)])

    def params(x: FloatArray) -> DiscreteDesignParameters:
        return replace(prm, eps=10.0 ** x[0], delta1=10.0 ** x[1], delta2=10.0 ** x[2],
                       H=x[3:].reshape(n, p))

    def objective(x: FloatArray) -> tuple[float, VarianceDesign | None]:
        pr = params(x)
        d = _design_structured(plant, pr, s2, tol, find_gamma_reached=True)
        if d.solved:
            return float(np.max(np.diag(d.Q2) / s2)), d
        eq2 = d.equation_2
        if eq2 is not None and eq2.X is not None and eq2.details.get("gamma_reached"):
            g = float(eq2.details["gamma_reached"])
            return float(np.max(np.diag(eq2.X) / s2)) + 10.0 * math.log(g / pr.gamma), d
        return INFEASIBLE, d

    def random_start(rng: np.random.Generator) -> FloatArray:
        return random_search_start(rng, 1, le, ld, n * p, (-2.0, 1.0))

    x0 = np.concatenate([[math.log10(prm.eps), math.log10(prm.delta1),
                          math.log10(prm.delta2)], prm.H.reshape(-1)])

    def verify(d: VarianceDesign):
        return verify_design(plant, d.G, d.K, region=reg, gamma=prm.gamma, sigma2=s2,
                             n_grid=n_grid)

    spec = {"region": reg.describe(), "gamma": prm.gamma, "sigma2": s2.tolist(),
            "f_shape": list(plant.f_shape), "U": prm.U.tolist(), "n_grid": n_grid}
    return run_design_search(objective, x0, random_start, bounds, n_starts=n_starts,
                             seed=seed, max_evaluations=max_evaluations, verify=verify,
                             sigma2=s2, describe=lambda x: params(x).as_dict(),
                             variables=variables, specification=spec,
                             simplex_step=[0.5] * 3 + [0.05 * h_bound] * (n * p))
