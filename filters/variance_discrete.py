"""seed-004 (Liu, Deng & Wang, OCR damaged): discrete robust H2/H-infinity filter with error
variance constraints.

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
reference [7] (Wang & Huang, IEEE TSP 2000) that seed-003 uses in continuous time: with
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
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from filters._linalg import FloatArray, matrix
from filters.analysis import UncertainPlant, unit_disk
from filters.variance_constrained import (
    DesignSearch,
    MatrixEquationSolution,
    VarianceDesign,
    inverse_sqrt,
    is_positive_definite,
    passes,
    solve_symmetric_equation,
    verify_design,
)

__all__ = [
    "DiscreteDesignParameters",
    "Seed004Terms",
    "delta1_threshold",
    "design_discrete",
    "equation11",
    "equation12r",
    "equation12r_terms",
    "gains_discrete",
    "hat_terms_discrete",
    "least_solution11",
    "p_gamma",
    "search_discrete",
]

EQUATIONS = ("11", "12r")


@dataclass(frozen=True)
class DiscreteDesignParameters:
    """Free parameters of the (reconstructed) seed-004 design.

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
        raise ValueError("plant must be discrete-time (discrete=True) for seed-004")
    if prm.H.shape != (plant.n, plant.p):
        raise ValueError(f"H must have shape ({plant.n}, {plant.p}), got {prm.H.shape}")


# ---------------------------------------------------------------------- (11)
def _gamma(P1: npt.NDArray[Any], N: FloatArray, eps: float) -> npt.NDArray[Any]:
    """``P1 + P1 N^T (eps I - N P1 N^T)^-1 N P1 = (P1^-1 - eps^-1 N^T N)^-1``."""
    j = N.shape[0]
    return P1 + P1 @ N.T @ np.linalg.solve(eps * np.eye(j) - N @ P1 @ N.T, N @ P1)


def equation11(P1: npt.NDArray[Any], plant: UncertainPlant,
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


def least_solution11(plant: UncertainPlant, prm: DiscreteDesignParameters, *,
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

    Existence is decided by :func:`least_solution11`; it is monotone in ``delta1`` (a larger
    constant term only raises the iterates). Geometric bisection to relative ``rtol``.

    Returns
    -------
    float or None
        ``None`` if (11) has no solution even for ``delta1 -> 0`` (``1e-12``).
    """
    _check(plant, prm)

    def exists(d: float) -> bool:
        return least_solution11(plant, replace(prm, delta1=d), max_iter=max_iter)[0] is not None

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
class Seed004Terms:
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
                       prm: DiscreteDesignParameters) -> Seed004Terms:
    """(10): ``Phi = Gamma A^T``, ``A_hat``, ``C_hat`` (pseudo-inverse if ``Phi`` is singular)."""
    A, C, M1, M2, D1, D2 = plant.A, plant.C, plant.M1, plant.M2, plant.D1, plant.D2
    Gm = _gamma(P1, plant.N, prm.eps)
    Phi = Gm @ A.T
    X = np.vstack([prm.eps * M1 @ M1.T + D1 @ D1.T, prm.eps * M2 @ M1.T + D2 @ D1.T])
    generalized = bool(np.linalg.cond(Phi) > 1e12)
    right = X @ np.linalg.pinv(Phi) if generalized else np.linalg.solve(Phi.T, X.T).T
    n = plant.n
    return Seed004Terms(P1, Gm, Phi, A + right[:n], C + right[n:], generalized)


def p_gamma(P2: npt.NDArray[Any], L: FloatArray, gamma: float) -> npt.NDArray[Any]:
    """``P2 + P2 L^T (gamma^2 I - L P2 L^T)^-1 L P2``, shape (n, n)."""
    q = L.shape[0]
    return P2 + P2 @ L.T @ np.linalg.solve(gamma**2 * np.eye(q) - L @ P2 @ L.T, L @ P2)


def equation12r_terms(P2: npt.NDArray[Any], plant: UncertainPlant,
                      prm: DiscreteDesignParameters, t: Seed004Terms
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


def equation12r(P2: npt.NDArray[Any], plant: UncertainPlant, prm: DiscreteDesignParameters,
                t: Seed004Terms) -> npt.NDArray[Any]:
    """Left side of (12r): ``Upsilon - Theta R^-1 Theta^T + H H^T + delta2 I``."""
    R, Theta, Ups = equation12r_terms(P2, plant, prm, t)
    return (Ups - Theta @ np.linalg.solve(R, Theta.T) + prm.H @ prm.H.T
            + prm.delta2 * np.eye(plant.n))


def _admissible12r(plant: UncertainPlant, prm: DiscreteDesignParameters):
    L, q = plant.L, plant.L.shape[0]

    def ok(P2: FloatArray) -> bool:
        return (is_positive_definite(P2)
                and is_positive_definite(prm.gamma**2 * np.eye(q) - L @ P2 @ L.T))

    return ok


def gains_discrete(P2: FloatArray, plant: UncertainPlant, prm: DiscreteDesignParameters,
                   t: Seed004Terms, U: npt.ArrayLike | None = None
                   ) -> tuple[FloatArray, FloatArray]:
    """``K = Theta R^-1 + H U R^-1/2``, ``G = A_hat - K C_hat`` (reconstructed).

    Returns
    -------
    K : numpy.ndarray, shape (n, p)
    G : numpy.ndarray, shape (n, n)
    """
    R, Theta, _ = equation12r_terms(P2, plant, prm, t)
    U_ = prm.U if U is None else np.asarray(U, dtype=np.float64)
    K = np.linalg.solve(R, Theta.T).T + prm.H @ U_ @ inverse_sqrt(R)
    return K, t.A_hat - K @ t.C_hat


# -------------------------------------------------------------------- design
def _solve11(plant: UncertainPlant, prm: DiscreteDesignParameters, *, tol: float,
             n_random: int, seed: int, polish: bool) -> tuple[MatrixEquationSolution, str]:
    least, _, how = least_solution11(plant, prm)
    starts = [] if least is None else [least]
    eq1 = solve_symmetric_equation(lambda P: equation11(P, plant, prm), plant.n,
                                   admissible=_admissible11(plant, prm), starts=starts,
                                   tol=tol, n_random=n_random, seed=seed, polish=polish)
    return eq1, how


def design_discrete(plant: UncertainPlant, prm: DiscreteDesignParameters, *,
                    sigma2: npt.ArrayLike | None = None, tol: float = 1e-10,
                    n_random: int = 6, seed: int = 0, polish: bool = True) -> VarianceDesign:
    """Solve (11), then (12r), then the gains; failure is a result, not an exception.

    The monotone iteration :func:`least_solution11` decides whether (11) is solvable and
    seeds the Newton solver. Every admissible ``P1`` found is tried (by increasing trace)
    until (12r) has an admissible solution ``P2 > 0``, ``gamma^2 I > L P2 L^T``.

    Parameters
    ----------
    plant : UncertainPlant
        Discrete-time plant.
    prm : DiscreteDesignParameters
    sigma2 : array_like, shape (n,), optional
        Variance bounds; sets ``variance_bounds_met`` (``diag(P2) <= sigma2``).
    tol, n_random, seed, polish
        Passed to :func:`~filters.variance_constrained.solve_symmetric_equation`.

    Returns
    -------
    VarianceDesign
        ``Q1 = P1``, ``Q2 = P2``, ``equation_names = ("11", "12r")``.
    """
    _check(plant, prm)
    n = plant.n
    params = prm.as_dict()
    eq1, how = _solve11(plant, prm, tol=tol, n_random=n_random, seed=seed, polish=polish)
    if not eq1.solved:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              f"(11): {how}; {eq1.message}", params, eq1, None)
    best: tuple[float, FloatArray, MatrixEquationSolution] | None = None
    for P1 in eq1.solutions:
        try:
            t = hat_terms_discrete(P1, plant, prm)
        except np.linalg.LinAlgError:
            continue
        eq2 = solve_symmetric_equation(lambda P, t=t: equation12r(P, plant, prm, t), n,
                                       admissible=_admissible12r(plant, prm), tol=tol,
                                       n_random=n_random, seed=seed, polish=polish)
        if eq2.solved:
            K, G = gains_discrete(eq2.X, plant, prm, t)
            met = None
            if sigma2 is not None:
                met = bool(np.all(np.diag(eq2.X) <= np.asarray(sigma2, dtype=float)))
            gi = "; Phi singular: generalized inverse used" if t.generalized_inverse else ""
            msg = (f"(11) and (12r) solved (residuals {eq1.residual:.1e}, "
                   f"{eq2.residual:.1e}){gi}")
            return VarianceDesign(True, P1, eq2.X, float(np.linalg.norm(
                equation11(P1, plant, prm))), eq2.residual, K, G, EQUATIONS, msg, params,
                eq1, eq2, met)
        if best is None or eq2.residual < best[0]:
            best = (eq2.residual, P1, eq2)
    if best is None:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              "(11) solved but (10) failed for every solution", params, eq1,
                              None)
    res2, P1, eq2 = best
    return VarianceDesign(False, P1, eq2.X, float(np.linalg.norm(equation11(P1, plant, prm))),
                          res2, None, None, EQUATIONS,
                          f"(11) solved ({how}); (12r): {eq2.message}", params, eq1, eq2)


def search_discrete(plant: UncertainPlant, prm: DiscreteDesignParameters,
                    sigma2: npt.ArrayLike, *, eps_values: npt.ArrayLike,
                    h_scales: npt.ArrayLike, h_direction: npt.ArrayLike | None = None,
                    delta_values: npt.ArrayLike | None = None, n_grid: int = 11,
                    max_verify: int = 3, seed: int = 0, tol: float = 1e-10) -> DesignSearch:
    """Search ``eps``, the scale ``c`` of ``H = c H0`` (and ``delta1 = delta2``) for a
    feasible design.

    Feasible: (11) and (12r) solved, ``diag(P2) <= sigma^2`` and the gains pass
    :func:`~filters.variance_constrained.verify_design` (unit disk, ``||H||_inf <= gamma``,
    variances on the vertices and a grid of ``F``). Candidates are verified by increasing
    ``max(diag(P2) / sigma^2)``.

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
        As in :func:`filters.variance_continuous.search_parabolic`.

    Returns
    -------
    DesignSearch
    """
    _check(plant, prm)
    H0 = prm.H if h_direction is None else matrix("h_direction", h_direction,
                                                  (plant.n, plant.p))
    s2 = np.asarray(sigma2, dtype=np.float64).reshape(-1)
    es = [float(v) for v in np.atleast_1d(eps_values)]
    cs = [float(v) for v in np.atleast_1d(h_scales)]
    ds = (None if delta_values is None else [float(v) for v in np.atleast_1d(delta_values)])
    tried = solved1 = solved2 = 0
    best_res, best_point = math.inf, {}
    candidates: list[tuple[float, VarianceDesign]] = []
    points = [(e, d) for d in (ds or [None]) for e in es]
    for e, d in points:
        p = replace(prm, eps=e) if d is None else replace(prm, eps=e, delta1=d, delta2=d)
        tried += len(cs)
        eq1, _ = _solve11(plant, p, tol=tol, n_random=2, seed=seed, polish=False)
        if not eq1.solved:
            continue
        solved1 += len(cs)
        for c in cs:
            pc = replace(p, H=c * H0)
            for P1 in eq1.solutions[:2]:
                try:
                    t = hat_terms_discrete(P1, plant, pc)
                except np.linalg.LinAlgError:
                    continue
                eq2 = solve_symmetric_equation(
                    lambda P, t=t, pc=pc: equation12r(P, plant, pc, t), plant.n,
                    admissible=_admissible12r(plant, pc), tol=tol, n_random=2, seed=seed,
                    polish=False)
                if eq2.residual < best_res:
                    best_res = eq2.residual
                    best_point = {"eps": e, "h_scale": c, "delta1": p.delta1,
                                  "delta2": p.delta2}
                if not eq2.solved:
                    continue
                solved2 += 1
                K, G = gains_discrete(eq2.X, plant, pc, t)
                ratio = float(np.max(np.diag(eq2.X) / s2))
                design = VarianceDesign(
                    True, P1, eq2.X, float(np.linalg.norm(equation11(P1, plant, pc))),
                    eq2.residual, K, G, EQUATIONS,
                    f"search point eps={e:g}, delta1=delta2={p.delta1:g}, H = {c:g} H0",
                    pc.as_dict(), eq1, eq2, ratio <= 1.0)
                if ratio <= 1.0:
                    candidates.append((ratio, design))
                break
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
