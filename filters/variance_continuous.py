"""seed-003 (Wang & Fang, IEEE SPL 2006): robust H-infinity filter with error-variance
constraints and parabolic pole assignment, continuous time.

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

``Gamma = (Q1^-1 - eps1^-1 N^T N)^-1`` (10). (16) is ``Psi11 = -delta1 I``. ``Psi12 = 0``
with ``Phi = b Gamma A^T + Q1`` (10) gives ``G = A_hat - K C_hat`` with::

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

Misprints corrected (PAPER_NOTES.md, checked against the proof above)
---------------------------------------------------------------------
* (11): ``C_hat`` has ``M2 M1^T`` and ``D2 D1^T`` (printed ``M2 M2^T``, ``D2 D2^T``, which do
  not even have the dimensions of ``C``).
* (14) and (17): the ``s``-term is ``s M1 M1^T`` (printed ``M2 M2^T``).
* The example's ``E = [0.1 0.1]^T`` is Theorem 1's ``H``.

Note: (28) shows ``b |lambda|^2 + 2 Re(lambda) + 2 a < 0``, i.e. the poles lie in the disk
:meth:`filters.analysis.Parabola.proof_disk`, a subset of ``P(a, b)``.

Solving (16) and (17)
---------------------
The paper gives no algorithm (Remark 1 cites local search). Both are solved by
:func:`~filters.variance_constrained.solve_symmetric_equation` (damped Newton, several starts,
residual tolerance) inside their admissible sets (``Q1 > 0``, ``N Q1 N^T < eps1 I``;
``Q2 > 0``). Without an admissible solution the design reports the smallest residual reached;
:func:`equation17_margin` then tells whether *any* ``H`` could help (it is the smallest
``lambda_max`` of ``Upsilon - Theta R^-1 Theta^T + delta2 I`` over ``Q2 > 0`` found; (17) needs
it ``<= 0``), and :func:`search_parabolic` looks over ``(eps1, eps2)`` and the scale of ``H``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.linalg import solve_continuous_lyapunov
from scipy.optimize import minimize

from filters._linalg import FloatArray, matrix
from filters.analysis import Parabola, UncertainPlant
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
    "ParabolicDesignParameters",
    "Seed003Terms",
    "design_parabolic",
    "equation16",
    "equation17",
    "equation17_margin",
    "equation17_terms",
    "gains18",
    "gamma_threshold",
    "hat_terms",
    "search_parabolic",
]

EQUATIONS = ("16", "17")


@dataclass(frozen=True)
class ParabolicDesignParameters:
    """The free parameters of seed-003's Theorem 1.

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
        raise ValueError("plant must be continuous-time (discrete=False) for seed-003")
    if prm.H.shape != (plant.n, plant.p):
        raise ValueError(f"H must have shape ({plant.n}, {plant.p}), got {prm.H.shape}")


# ---------------------------------------------------------------------- (16)
def _gamma(Q1: npt.NDArray[Any], N: FloatArray, eps1: float) -> npt.NDArray[Any]:
    """(10): ``Gamma = (Q1^-1 - eps1^-1 N^T N)^-1``."""
    return np.linalg.inv(np.linalg.inv(Q1) - N.T @ N / eps1)


def equation16(Q1: npt.NDArray[Any], plant: UncertainPlant,
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
class Seed003Terms:
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
              prm: ParabolicDesignParameters) -> Seed003Terms:
    """(10)-(11) with the corrected ``C_hat``; raises ``LinAlgError`` if ``Phi`` is singular."""
    A, C, M1, M2, D1, D2 = plant.A, plant.C, plant.M1, plant.M2, plant.D1, plant.D2
    Gm = _gamma(Q1, plant.N, prm.eps1)
    Phi = prm.b * Gm @ A.T + Q1
    X = np.vstack([prm.s * M1 @ M1.T + D1 @ D1.T, prm.s * M2 @ M1.T + D2 @ D1.T])
    right = np.linalg.solve(Phi.T, X.T).T  # X Phi^-1, shape (n + p, n)
    n = plant.n
    return Seed003Terms(Q1=Q1, Gamma=Gm, Phi=Phi, A_hat=A + right[:n], C_hat=C + right[n:])


def equation17_terms(Q2: npt.NDArray[Any], plant: UncertainPlant,
                     prm: ParabolicDesignParameters, t: Seed003Terms
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


def equation17(Q2: npt.NDArray[Any], plant: UncertainPlant, prm: ParabolicDesignParameters,
               t: Seed003Terms) -> npt.NDArray[Any]:
    """Left side of (17) = ``Upsilon - Theta R^-1 Theta^T + H H^T + delta2 I``, shape (n, n)."""
    R, Theta, Ups = equation17_terms(Q2, plant, prm, t)
    return (Ups - Theta @ np.linalg.solve(R, Theta.T) + prm.H @ prm.H.T
            + prm.delta2 * np.eye(plant.n))


def gains18(Q2: FloatArray, plant: UncertainPlant, prm: ParabolicDesignParameters,
            t: Seed003Terms, U: npt.ArrayLike | None = None) -> tuple[FloatArray, FloatArray]:
    """(18): ``K = Theta R^-1 + H U R^-1/2``, ``G = A_hat - K C_hat``.

    Returns
    -------
    K : numpy.ndarray, shape (n, p)
    G : numpy.ndarray, shape (n, n)
    """
    R, Theta, _ = equation17_terms(Q2, plant, prm, t)
    U_ = prm.U if U is None else np.asarray(U, dtype=np.float64)
    K = np.linalg.solve(R, Theta.T).T + prm.H @ U_ @ inverse_sqrt(R)
    return K, t.A_hat - K @ t.C_hat


def equation17_margin(plant: UncertainPlant, prm: ParabolicDesignParameters, Q1: FloatArray,
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
            S = equation17(Q2, plant, prm0, t)
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
    """Smallest ``gamma`` at which (17) is not ruled out by :func:`equation17_margin`.

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
        eq1 = solve_symmetric_equation(lambda Q: equation16(Q, plant, prm), plant.n,
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
            v, Q2 = equation17_margin(plant, p, Q1, seed=seed, starts=warm.get(i))
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


# -------------------------------------------------------------------- design
def _starts16(plant: UncertainPlant, prm: ParabolicDesignParameters) -> list[FloatArray]:
    """Lyapunov solution of the linear part of (16) as a start (when ``A + aI`` is Hurwitz)."""
    Aa = plant.A + prm.a * np.eye(plant.n)
    c = prm.s * plant.M1 @ plant.M1.T + plant.D1 @ plant.D1.T + prm.delta1 * np.eye(plant.n)
    if np.all(np.linalg.eigvals(Aa).real < 0):
        X = solve_continuous_lyapunov(Aa, -c)
        return [0.5 * (X + X.T)]
    return []


def design_parabolic(plant: UncertainPlant, prm: ParabolicDesignParameters, *,
                     sigma2: npt.ArrayLike | None = None, tol: float = 1e-10,
                     n_random: int = 6, seed: int = 0, polish: bool = True) -> VarianceDesign:
    """Theorem 1 of seed-003: solve (16), then (17), then the gains (18).

    Every admissible solution ``Q1`` of (16) is tried (by increasing trace) until (17) has a
    positive definite solution. Failure is a result, not an exception.

    Parameters
    ----------
    plant : UncertainPlant
        Continuous-time plant.
    prm : ParabolicDesignParameters
    sigma2 : array_like, shape (n,), optional
        Variance bounds; sets ``variance_bounds_met`` (``diag(Q2) <= sigma2``).
    tol : float
        Residual tolerance ``||F(Q)||_F`` of both equations.
    n_random, seed, polish
        Passed to :func:`~filters.variance_constrained.solve_symmetric_equation`.

    Returns
    -------
    VarianceDesign
        ``equation_names = ("16", "17")``.
    """
    _check(plant, prm)
    n = plant.n
    params = prm.as_dict()
    eq1 = solve_symmetric_equation(lambda Q: equation16(Q, plant, prm), n,
                                   admissible=_admissible16(plant, prm),
                                   starts=_starts16(plant, prm), tol=tol, n_random=n_random,
                                   seed=seed, polish=polish)
    if not eq1.solved:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              f"(16): {eq1.message}", params, eq1, None)
    best: tuple[float, FloatArray, MatrixEquationSolution] | None = None
    for Q1 in eq1.solutions:
        try:
            t = hat_terms(Q1, plant, prm)
        except np.linalg.LinAlgError:
            continue
        eq2 = solve_symmetric_equation(lambda Q, t=t: equation17(Q, plant, prm, t), n,
                                       tol=tol, n_random=n_random, seed=seed, polish=polish)
        if eq2.solved:
            K, G = gains18(eq2.X, plant, prm, t)
            met = None
            if sigma2 is not None:
                met = bool(np.all(np.diag(eq2.X) <= np.asarray(sigma2, dtype=float)))
            msg = (f"(16) and (17) solved (residuals {eq1.residual:.1e}, {eq2.residual:.1e}); "
                   f"{len(eq1.solutions)} admissible Q1, {len(eq2.solutions)} Q2")
            return VarianceDesign(True, Q1, eq2.X, float(np.linalg.norm(
                equation16(Q1, plant, prm))), eq2.residual, K, G, EQUATIONS, msg, params,
                eq1, eq2, met)
        if best is None or eq2.residual < best[0]:
            best = (eq2.residual, Q1, eq2)
    if best is None:
        return VarianceDesign(False, eq1.X, None, eq1.residual, None, None, None, EQUATIONS,
                              "(16) solved but Phi = b Gamma A^T + Q1 is singular for every "
                              "solution", params, eq1, None)
    res2, Q1, eq2 = best
    msg = (f"(16) solved ({len(eq1.solutions)} admissible Q1, residual "
           f"{eq1.residual:.1e}); (17): {eq2.message}")
    return VarianceDesign(False, Q1, eq2.X, float(np.linalg.norm(equation16(Q1, plant, prm))),
                          res2, None, None, EQUATIONS, msg, params, eq1, eq2)


def search_parabolic(plant: UncertainPlant, prm: ParabolicDesignParameters,
                     sigma2: npt.ArrayLike, *, eps1_values: npt.ArrayLike,
                     eps2_values: npt.ArrayLike, h_scales: npt.ArrayLike, n_grid: int = 11,
                     max_verify: int = 3, seed: int = 0, tol: float = 1e-10) -> DesignSearch:
    """Search ``(eps1, eps2)`` and the scale ``c`` of ``H = c H0`` for a feasible design.

    A point is feasible if (16) and (17) are solved, ``diag(Q2) <= sigma^2`` and the gains
    pass :func:`~filters.variance_constrained.verify_design` (poles in ``P(a, b)``,
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
        Solver seed and residual tolerance.

    Returns
    -------
    DesignSearch
    """
    _check(plant, prm)
    s2 = np.asarray(sigma2, dtype=np.float64).reshape(-1)
    e1s = [float(v) for v in np.atleast_1d(eps1_values)]
    e2s = [float(v) for v in np.atleast_1d(eps2_values)]
    cs = [float(v) for v in np.atleast_1d(h_scales)]
    n = plant.n
    tried = solved1 = solved2 = 0
    best_res, best_point = math.inf, {}
    candidates: list[tuple[float, VarianceDesign]] = []
    for e1 in e1s:
        for e2 in e2s:
            p = replace(prm, eps1=e1, eps2=e2)
            tried += len(cs)
            eq1 = solve_symmetric_equation(lambda Q, p=p: equation16(Q, plant, p), n,
                                           admissible=_admissible16(plant, p),
                                           starts=_starts16(plant, p), tol=tol, n_random=2,
                                           seed=seed, polish=False)
            if not eq1.solved:
                continue
            solved1 += len(cs)
            for c in cs:
                pc = replace(p, H=c * prm.H)
                found = False
                for Q1 in eq1.solutions[:2]:
                    try:
                        t = hat_terms(Q1, plant, pc)
                    except np.linalg.LinAlgError:
                        continue
                    eq2 = solve_symmetric_equation(
                        lambda Q, t=t, pc=pc: equation17(Q, plant, pc, t), n, tol=tol,
                        n_random=2, seed=seed, polish=False)
                    if eq2.residual < best_res:
                        best_res = eq2.residual
                        best_point = {"eps1": e1, "eps2": e2, "h_scale": c}
                    if not eq2.solved:
                        continue
                    found = True
                    K, G = gains18(eq2.X, plant, pc, t)
                    ratio = float(np.max(np.diag(eq2.X) / s2))
                    design = VarianceDesign(
                        True, Q1, eq2.X, float(np.linalg.norm(equation16(Q1, plant, pc))),
                        eq2.residual, K, G, EQUATIONS,
                        f"search point eps1={e1:g}, eps2={e2:g}, H = {c:g} H0", pc.as_dict(),
                        eq1, eq2, ratio <= 1.0)
                    if ratio <= 1.0:
                        candidates.append((ratio, design))
                    break
                solved2 += int(found)
    candidates.sort(key=lambda item: item[0])
    region = Parabola(prm.a, prm.b)
    for _, design in candidates[:max_verify]:
        check = verify_design(plant, design.G, design.K, region=region, gamma=prm.gamma,
                              sigma2=s2, n_grid=n_grid)
        if passes(check):
            return DesignSearch(True, design, check, tried, solved1, solved2,
                                best_res if math.isfinite(best_res) else None, best_point,
                                {"eps1": e1s, "eps2": e2s, "h_scale": cs})
    return DesignSearch(False, None, None, tried, solved1, solved2,
                        best_res if math.isfinite(best_res) else None, best_point,
                        {"eps1": e1s, "eps2": e2s, "h_scale": cs})
