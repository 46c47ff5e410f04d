"""Variance-constrained robust H-infinity filtering: what the designs of Wang & Fang (2006,
continuous time, parabolic pole region) and of the discrete-time variance-constrained
H2/H-infinity paper share.

* :func:`solve_symmetric_equation`: a generic damped Newton method (complex-step Jacobian,
  backtracking line search, several starts) for nonlinear matrix equations ``F(X) = 0`` in a
  symmetric ``X`` restricted to an admissible open set (``X > 0`` plus side conditions), with a
  least-squares fallback that reports the smallest residual reached when no admissible
  solution is found. The designs use it only as a fallback: their equations are solved by the
  structured solvers of :mod:`filters.matrix_equations` (standard Riccati solvers where an
  equation maps onto one, monotone Newton and continuation where it does not).
* :class:`LinearFilter`: the constant-gain filter ``xhat' = G xhat + K y`` (Wang & Fang (4))
  or ``xhat(k+1) = G xhat(k) + K y(k)`` (discrete paper (3)) as an
  :class:`~filters.base.Estimator`.
* :class:`VarianceDesign` (one design, solved or not), :class:`DesignSearch` (the grid search
  over the free scalars), :class:`DesignSearchRecord` (the optimizer-based search of
  :func:`~filters.variance_continuous.search_parabolic_design` and
  :func:`~filters.variance_discrete.search_discrete_design`) and :func:`verify_design` (the
  three requirements checked a posteriori with :func:`filters.analysis.robust_filter_analysis`).

The designs themselves are in :mod:`filters.variance_continuous` (Wang & Fang 2006) and
:mod:`filters.variance_discrete` (the discrete paper, reconstructed). Arrays are ``float64``;
times in seconds.
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares, minimize

from filters._linalg import (
    FloatArray,
    batch_symmetric_psd,
    matrix,
    positive_time,
    readonly,
    real_array,
    to_float_array,
    zoh,
)
from filters.analysis import (
    PoleRegion,
    RobustAnalysis,
    UncertainPlant,
    robust_filter_analysis,
)
from filters.errors import FiniteEscapeError
from filters.kalman import _SampledFilter

__all__ = [
    "INFEASIBLE",
    "DesignSearch",
    "DesignSearchRecord",
    "LinearFilter",
    "MatrixEquationSolution",
    "SearchCandidate",
    "VarianceDesign",
    "inverse_sqrt",
    "is_positive_definite",
    "passes",
    "run_design_search",
    "solve_symmetric_equation",
    "verify_design",
]

#: ``X -> F(X)``: a residual of a symmetric matrix equation. It must accept complex ``X``
#: and be analytic (``.T``, never ``.conj()``) for the complex-step Jacobian; otherwise
#: central differences are used.
Residual = Callable[[npt.NDArray[Any]], npt.NDArray[Any]]


# ====================================================================== helpers
def is_positive_definite(X: npt.ArrayLike) -> bool:
    """Symmetric ``X`` with a Cholesky factor (strictly positive definite)."""
    Xa = np.asarray(X)
    if Xa.ndim != 2 or Xa.shape[0] != Xa.shape[1] or not np.isfinite(Xa).all():
        return False
    try:
        np.linalg.cholesky(0.5 * (Xa + Xa.T))
    except np.linalg.LinAlgError:
        return False
    return True


def inverse_sqrt(R: FloatArray) -> FloatArray:
    """Symmetric positive definite ``R^(-1/2)`` (eigendecomposition), shape of ``R``."""
    w, V = np.linalg.eigh(0.5 * (R + R.T))
    if w.min() <= 0:
        raise np.linalg.LinAlgError(f"R is not positive definite (min eig {w.min():.3g})")
    return (V / np.sqrt(w)) @ V.T


@functools.lru_cache(maxsize=16)
def _triu(n: int) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], FloatArray]:
    iu = np.triu_indices(n)
    weight = np.where(iu[0] == iu[1], 1.0, math.sqrt(2.0))  # ||vech_w(F)|| = ||F||_F
    return iu[0], iu[1], weight


def _unvech(v: npt.NDArray[Any], n: int) -> npt.NDArray[Any]:
    i, j, _ = _triu(n)
    X = np.zeros((n, n), dtype=v.dtype)
    X[i, j] = v
    X[j, i] = v
    return X


def _vech(X: npt.NDArray[Any]) -> npt.NDArray[Any]:
    i, j, _ = _triu(X.shape[0])
    return X[i, j]


# ================================================================ equation solver
@dataclass(frozen=True)
class MatrixEquationSolution:
    """Outcome of :func:`solve_symmetric_equation`.

    Attributes
    ----------
    solved : bool
        An admissible ``X`` with ``||F(X)||_F <= tol`` was found.
    X : numpy.ndarray, shape (n, n), or None
        The solution (the one of smallest trace if several were found) or, if not solved,
        the admissible point of smallest residual reached (``None`` if no admissible point
        was ever evaluated).
    residual : float
        ``||F(X)||_F`` (``inf`` if ``X`` is None).
    iterations : int
        Newton iterations over all starts.
    message : str
    solutions : tuple of numpy.ndarray
        All distinct admissible solutions found, by increasing trace.
    method : str
        How it was solved: ``"newton-multistart"`` (:func:`solve_symmetric_equation`),
        ``"dare"`` (:func:`scipy.linalg.solve_discrete_are` through a mapping stated in the
        design's docstring), ``"monotone-newton"``, ``"dare+continuation"``.
    status : str
        ``"solved"`` or why not: ``"no_stabilizing_solution"`` (the Riccati solver found no
        stabilizing solution), ``"not_admissible"`` (the solution found violates a side
        condition such as ``X > 0``), ``"left_admissible_set"`` (a monotone iteration left it),
        ``"not_converged"`` (the iteration stopped at ``residual``), ``"branch_ended"`` (a
        continuation ended before its target), ``"unstable_derivative"``,
        ``"no_admissible_start"``.
    details : dict
        Method-specific numbers (JSON-safe), e.g. ``gamma_reached`` of a continuation in
        ``gamma``.
    """

    solved: bool
    X: FloatArray | None
    residual: float
    iterations: int
    message: str
    solutions: tuple[FloatArray, ...] = ()
    method: str = "newton-multistart"
    status: str = ""
    details: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.status:
            object.__setattr__(self, "status", "solved" if self.solved else "not_converged")

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe summary."""
        return {"solved": self.solved, "X": None if self.X is None else self.X.tolist(),
                "residual": self.residual if math.isfinite(self.residual) else None,
                "n_solutions": len(self.solutions), "message": self.message,
                "method": self.method, "status": self.status, "details": self.details}


def _evaluate(residual: Residual, X: npt.NDArray[Any]) -> npt.NDArray[Any] | None:
    try:
        with np.errstate(all="ignore"):
            R = np.asarray(residual(X))
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError):
        return None
    if R.shape != X.shape or not np.isfinite(R).all():
        return None
    return R


def _jacobian(residual: Residual, v: FloatArray, n: int, weight: FloatArray
              ) -> FloatArray | None:
    """Jacobian of ``vech_w(F(unvech(v)))`` by complex step (central differences fallback)."""
    m = v.size
    J = np.empty((m, m))
    h = 1e-30
    try:
        for k in range(m):
            vc = v.astype(np.complex128)
            vc[k] += 1j * h
            R = _evaluate(residual, _unvech(vc, n))
            if R is None or not np.iscomplexobj(R):
                raise TypeError
            J[:, k] = _vech(R).imag / h * weight
        return J
    except TypeError:
        pass
    for k in range(m):
        step = 1e-7 * max(1.0, abs(v[k]))
        vp, vm = v.copy(), v.copy()
        vp[k] += step
        vm[k] -= step
        Rp, Rm = _evaluate(residual, _unvech(vp, n)), _evaluate(residual, _unvech(vm, n))
        if Rp is None or Rm is None:
            return None
        J[:, k] = (_vech(Rp) - _vech(Rm)).real / (2 * step) * weight
    return J


def _newton(residual: Residual, admissible: Callable[[FloatArray], bool], X0: FloatArray,
            n: int, tol: float, max_iter: int) -> tuple[FloatArray, float, int]:
    """Damped Newton from ``X0`` inside the admissible set; returns (X, ||F||_F, iterations)."""
    _, _, weight = _triu(n)
    v = _vech(X0).astype(np.float64)
    R = _evaluate(residual, X0)
    if R is None or not admissible(X0):
        return X0, math.inf, 0
    r = _vech(R).real * weight
    f = float(r @ r)
    it = 0
    while it < max_iter and math.sqrt(f) > tol:
        it += 1
        J = _jacobian(residual, v, n, weight)
        if J is None:
            break
        d = np.linalg.lstsq(J, -r, rcond=None)[0]
        alpha, accepted, stalled = 1.0, False, False
        for _ in range(40):
            vn = v + alpha * d
            Xn = _unvech(vn, n)
            if admissible(Xn):
                Rn = _evaluate(residual, Xn)
                if Rn is not None:
                    rn = _vech(Rn).real * weight
                    fn = float(rn @ rn)
                    if fn <= (1.0 - 1e-4 * alpha) * f:
                        stalled = alpha < 1e-3 and f - fn < 1e-8 * f
                        v, r, f, accepted = vn, rn, fn, True
                        break
            alpha *= 0.5
        if not accepted or stalled:  # stuck at a local minimum of ||F||^2 or the boundary
            break
    return _unvech(v, n), math.sqrt(f), it


def _least_squares(residual: Residual, admissible: Callable[[FloatArray], bool],
                   X0: FloatArray, n: int) -> tuple[FloatArray, float] | None:
    """Minimize ``||F(X)||_F`` over ``X = L L^T`` (admissible points only) from ``X0``."""
    i, j, weight = _triu(n)
    low = np.tril_indices(n)
    try:
        L0 = np.linalg.cholesky(X0)
    except np.linalg.LinAlgError:
        return None
    penalty = 1e6

    def fun(theta: FloatArray) -> FloatArray:
        Lm = np.zeros((n, n))
        Lm[low] = theta
        X = Lm @ Lm.T
        if not admissible(X):
            return np.full(i.size, penalty)
        R = _evaluate(residual, X)
        if R is None:
            return np.full(i.size, penalty)
        return _vech(R).real * weight

    try:
        sol = least_squares(fun, L0[low], method="trf", xtol=1e-14, ftol=1e-14, gtol=1e-14,
                            max_nfev=400 * (i.size + 1))
    except ValueError:
        return None
    Lm = np.zeros((n, n))
    Lm[low] = sol.x
    X = Lm @ Lm.T
    res = float(np.linalg.norm(fun(sol.x)))
    if not admissible(X) or res >= penalty:
        return None
    return X, res


def solve_symmetric_equation(residual: Residual, n: int, *,
                             admissible: Callable[[FloatArray], bool] | None = None,
                             starts: Sequence[npt.ArrayLike] = (), n_random: int = 6,
                             tol: float = 1e-10, max_iter: int = 60, seed: int = 0,
                             polish: bool = True) -> MatrixEquationSolution:
    """Find admissible symmetric solutions of ``F(X) = 0``, or the smallest residual.

    Damped Newton on the ``n (n + 1) / 2`` entries of the upper triangle, from the given
    starts, the scaled identities ``c I`` (``c = 1e-3 ... 100``) and ``n_random`` seeded random
    positive definite matrices. The Jacobian is exact (complex step). Each step is halved until
    the iterate stays admissible and ``||F||^2`` decreases (Armijo). Distinct admissible
    solutions are collected. Without one, a least-squares minimization of ``||F(X)||_F`` over
    ``X = L L^T`` (admissible points only) from the best Newton point gives the smallest
    residual reached (``polish=True``).

    Parameters
    ----------
    residual : callable ``X (n, n) -> F(X) (n, n)``
        Symmetric residual; see :data:`Residual`.
    n : int
        Dimension of ``X``.
    admissible : callable ``X -> bool``, optional
        The open set where solutions are accepted and iterates stay (default: ``X > 0``).
    starts : sequence of array_like, shape (n, n)
        Extra initial points (tried first).
    n_random : int
        Random starts.
    tol : float
        Residual tolerance on ``||F(X)||_F`` (absolute).
    max_iter : int
        Newton iterations per start.
    seed : int
        Seed of the random starts.
    polish : bool
        Run the least-squares fallback when no solution is found.

    Returns
    -------
    MatrixEquationSolution
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    adm = admissible or is_positive_definite
    rng = np.random.default_rng(seed)
    inits: list[FloatArray] = []
    for S in starts:
        S_ = np.asarray(S, dtype=np.float64)
        if S_.shape == (n, n) and np.isfinite(S_).all():
            inits.append(0.5 * (S_ + S_.T))
    inits += [c * np.eye(n) for c in (1.0, 0.1, 10.0, 0.01, 100.0, 1e-3)]
    for _ in range(n_random):
        Z = rng.standard_normal((n, n))
        inits.append(10.0 ** rng.uniform(-3, 2) * (Z @ Z.T / n + 0.1 * np.eye(n)))

    solutions: list[FloatArray] = []
    best: tuple[float, FloatArray] | None = None
    iterations = 0
    for X0 in inits:
        X, res, it = _newton(residual, adm, X0, n, tol, max_iter)
        iterations += it
        if not math.isfinite(res) or not adm(X):
            continue
        if best is None or res < best[0]:
            best = (res, X)
        if res <= tol:
            scale = max(1.0, float(np.abs(X).max()))
            if not any(np.abs(X - S).max() <= 1e-6 * scale for S in solutions):
                solutions.append(X)
    solutions.sort(key=lambda S: float(np.trace(S)))
    if solutions:
        X = solutions[0]
        R = _evaluate(residual, X)
        res = float(np.linalg.norm(R)) if R is not None else math.inf
        msg = (f"{len(solutions)} admissible solution(s) found; returning the one of smallest "
               f"trace (residual {res:.2e})")
        return MatrixEquationSolution(True, X, res, iterations, msg, tuple(solutions))
    if best is None:
        return MatrixEquationSolution(False, None, math.inf, iterations,
                                      "no admissible starting point: the residual is "
                                      "undefined on every start",
                                      status="no_admissible_start")
    res, X = best
    if polish:
        out = _least_squares(residual, adm, X, n)
        if out is not None and out[1] < res:
            X, res = out
            if res <= tol:  # the minimizer is a solution after all
                msg = f"admissible solution found by least squares (residual {res:.2e})"
                return MatrixEquationSolution(True, X, res, iterations, msg, (X,))
    msg = (f"local search: no admissible solution found from {len(inits)} starts (which does "
           f"not prove that none exists); smallest residual reached ||F||_F = {res:.4g}")
    return MatrixEquationSolution(False, X, res, iterations, msg)


# ================================================================== the filter
class LinearFilter(_SampledFilter):
    """Constant-gain filter ``xhat' = G xhat + K y + B u`` or ``xhat(k+1) = G xhat(k) + K y(k)
    + B u(k)``.

    Wang & Fang (4) (continuous) and Liu, Deng & Wang (3) (discrete); ``B`` is an optional
    input term (none in the papers).

    Parameters
    ----------
    G : array_like, shape (n, n)
    K : array_like, shape (n, p)
    x0 : array_like, shape (n,) or (..., n)
        Initial estimate; leading axes are a batch of independent filters.
    discrete : bool
        Discrete-time filter (``step`` applies (3) once) or continuous-time filter sampled
        every ``dt_s``.
    dt_s : float, optional
        Sample period in s (required for a continuous filter). Continuous: ``y`` passed to
        :meth:`step` is the average of ``y(t)`` over the last interval (integrate-and-dump),
        held constant for the exact integration
        ``xhat(t + dt) = e^{G dt} xhat(t) + int_0^dt e^{G s} ds (K y + B u)``.
    B : array_like, shape (n, k), optional
        Input matrix (``None``: no input, then ``u`` must be ``None``).
    covariance : array_like, shape (n, n), optional
        Constant covariance reported as :attr:`P` (e.g. the steady-state bound ``Q2`` or the
        computed error covariance); ``None``: :attr:`P` is ``None``.

    Attributes
    ----------
    name : str
        ``"linear-gain"``.
    x : numpy.ndarray, shape (..., n)
        Estimate. Discrete: after ``step(y(k))`` it is ``xhat(k+1)``, the paper's one-step
        prediction; continuous: ``xhat(t_k)`` after the measurement averaged over
        ``[t_{k-1}, t_k]``. ``testbed/UncertainLinear-v0`` returns exactly these
        measurements after each step, so the filter in
        :class:`~testbed.envs.wrappers.FilterInLoop` estimates the state of that step.
    P : numpy.ndarray, shape (..., n, n), or None
        The constant ``covariance`` (constant-gain filters propagate none).
    t_s : float
        ``steps * dt_s`` (number of steps if ``dt_s`` is None).
    """

    name: ClassVar[str] = "linear-gain"

    def __init__(self, G: npt.ArrayLike, K: npt.ArrayLike, x0: npt.ArrayLike, *,
                 discrete: bool, dt_s: float | None = None, B: npt.ArrayLike | None = None,
                 covariance: npt.ArrayLike | None = None) -> None:
        G_ = matrix("G", G, (None, None), what="a finite square matrix")
        n = G_.shape[0]
        if G_.shape != (n, n) or n == 0:
            raise ValueError(f"G must be a finite square matrix with shape (n, n), got shape "
                             f"{G_.shape}")
        K_ = matrix("K", K, (n, None), labels=("n", "p"))
        B_ = np.zeros((n, 0)) if B is None else matrix("B", B, (n, None), labels=("n", "k"))
        self._n, self._m, self._k = n, K_.shape[1], B_.shape[1]
        self.discrete = bool(discrete)
        self.G, self.K, self.B = readonly(G_), readonly(K_), readonly(B_)
        if self.discrete:
            self._dt = None if dt_s is None else positive_time("dt_s", dt_s)
            Phi, Gam = G_, np.hstack([K_, B_])
        else:
            if dt_s is None:
                raise ValueError("dt_s must be given (seconds) for a continuous-time filter")
            self._dt = positive_time("dt_s", dt_s)
            Phi, Gam = zoh(G_, np.hstack([K_, B_]), self._dt)
        self._PhiT = np.ascontiguousarray(Phi.T)
        self._GyT = np.ascontiguousarray(Gam[:, :self._m].T)
        self._GuT = np.ascontiguousarray(Gam[:, self._m:].T)
        self._cov0 = (None if covariance is None else
                      batch_symmetric_psd("covariance", to_float_array("covariance",
                                                                       covariance), n))
        self.reset(x0)

    def reset(self, x0: npt.ArrayLike, P0: npt.ArrayLike | None = None) -> None:
        """Re-initialize the estimate and set ``t_s = 0``.

        Parameters
        ----------
        x0 : array_like, shape (n,) or (..., n)
        P0 : array_like, shape (n, n) or (..., n, n), optional
            If given, replaces the reported constant covariance :attr:`P`; ``None`` (also
            ``numpy.array(None)``) keeps it.

        Raises
        ------
        ValueError
            On a wrong shape or non-finite ``x0``, or a ``P0`` that is not symmetric PSD.
        """
        n = self._n
        x = to_float_array("x0", x0)
        if x.ndim < 1 or x.shape[-1] != n:
            raise ValueError(f"x0 must have shape ({n},) or (..., {n}), got shape {x.shape}")
        if not np.isfinite(x).all():
            raise ValueError(f"x0 must be finite with shape (..., {n}), got non-finite entries")
        cov = self._cov0
        if isinstance(P0, np.ndarray) and P0.dtype == object and P0.shape == ():
            P0 = P0.item()  # np.array(None), as a wrapper copying a None covariance passes it
        if P0 is not None:
            cov = batch_symmetric_psd("P0", to_float_array("P0", P0), n)
            self._cov0 = cov
        self._batch = x.shape[:-1]
        self._x = readonly(x.copy())
        self._Pc = None if cov is None else readonly(
            np.array(np.broadcast_to(cov, (*self._batch, n, n))))
        self._steps = 0
        self.innovation = None

    @property
    def P(self) -> FloatArray | None:  # type: ignore[override]
        """The constant reported covariance, shape (..., n, n), or None."""
        return self._Pc

    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """Advance one sample with measurement ``y`` (and input ``u``).

        Parameters
        ----------
        y : array_like, shape (p,) or (..., p)
            Discrete: ``y(k)``; continuous: the average of ``y`` over the last interval.
        u : array_like, shape (k,) or (..., k), or None

        Returns
        -------
        numpy.ndarray, shape (..., n)
            The new estimate (same object as :attr:`x`).

        Raises
        ------
        ValueError
            On a wrong shape or non-finite input (state unchanged).
        FiniteEscapeError
            If the estimate becomes non-finite (state unchanged).
        """
        y = self._vector("y", y, self._m)
        u = self._input(u)
        with np.errstate(over="ignore", invalid="ignore"):
            x = np.vecmat(self._x, self._PhiT) + np.vecmat(y, self._GyT)
            if u is not None:
                x = x + np.vecmat(u, self._GuT)
        if not np.isfinite(x).all():
            raise FiniteEscapeError("estimate became non-finite", time=self._time(self._steps + 1),
                                    quantity="x", value=np.array(x))
        x.flags.writeable = False
        self._x = x
        self._steps += 1
        return x


# ============================================================ designs and checks
@dataclass(frozen=True)
class VarianceDesign:
    """One design by Theorem 1 of Wang & Fang or the discrete design, solved or not.

    Attributes
    ----------
    solved : bool
        Both matrix equations have admissible positive definite solutions; ``K`` and ``G``
        are then given by the gain formula.
    Q1, Q2 : numpy.ndarray, shape (n, n), or None
        Solutions (or, unsolved, the admissible points of smallest residual reached).
    residual_1, residual_2 : float or None
        ``||F(Q)||_F`` of the two equations (``None``: not attempted).
    K : numpy.ndarray, shape (n, p), or None
    G : numpy.ndarray, shape (n, n), or None
    equation_names : tuple of str
        The paper's numbers of the two equations (``("16", "17")`` for Wang & Fang).
    message : str
    parameters : dict
        The design parameters used.
    equation_1, equation_2 : MatrixEquationSolution or None
        Solver details.
    variance_bounds_met : bool or None
        ``diag(Q2) <= sigma^2`` (``None`` without ``sigma2`` or ``Q2``).
    attempts : tuple of MatrixEquationSolution
        Every solver run, in order (structured solvers first, then the multi-start fallback
        if it ran), so that a failure says which method failed and why.
    """

    solved: bool
    Q1: FloatArray | None
    Q2: FloatArray | None
    residual_1: float | None
    residual_2: float | None
    K: FloatArray | None
    G: FloatArray | None
    equation_names: tuple[str, str]
    message: str
    parameters: dict[str, Any] = field(default_factory=dict)
    equation_1: MatrixEquationSolution | None = None
    equation_2: MatrixEquationSolution | None = None
    variance_bounds_met: bool | None = None
    attempts: tuple[MatrixEquationSolution, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe: ``solved``, ``Q1``, ``Q2``, ``residual_<eq>`` (paper numbering, also as
        ``residual_1``, ``residual_2``), ``K``, ``G`` and more."""

        def arr(x: FloatArray | None) -> list | None:
            return None if x is None else np.asarray(x).tolist()

        def num(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)

        e1, e2 = self.equation_names
        return {
            "solved": self.solved, "Q1": arr(self.Q1), "Q2": arr(self.Q2),
            f"residual_{e1}": num(self.residual_1), f"residual_{e2}": num(self.residual_2),
            "residual_1": num(self.residual_1), "residual_2": num(self.residual_2),
            "K": arr(self.K), "G": arr(self.G), "message": self.message,
            "variance_bounds_met": self.variance_bounds_met,
            "parameters": {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v)
                           for k, v in self.parameters.items()},
            "solver_attempts": [{k: v for k, v in a.to_dict().items() if k != "X"}
                                for a in self.attempts],
        }


@dataclass(frozen=True)
class DesignSearch:
    """Result of a search for a feasible design over the free scalars.

    Attributes
    ----------
    found : bool
        A design was solved, met ``diag(Q2) <= sigma^2`` and passed :func:`verify_design`.
    design : VarianceDesign or None
        The feasible design (smallest ``max(diag(Q2) / sigma^2)``), else ``None``.
    verification : RobustAnalysis or None
        Its a-posteriori check.
    tried : int
        Parameter combinations tried.
    solved_1, solved_2 : int
        Combinations where the first / both equations had admissible solutions.
    best_residual_2 : float or None
        Smallest residual of the second equation reached over the search.
    best_point : dict
        Parameters at ``best_residual_2``.
    grid : dict
        The searched values.
    """

    found: bool
    design: VarianceDesign | None
    verification: RobustAnalysis | None
    tried: int
    solved_1: int
    solved_2: int
    best_residual_2: float | None
    best_point: dict[str, Any]
    grid: dict[str, list[float]]

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe summary including the verified design, if any."""
        return {
            "found": self.found,
            "design": None if self.design is None else self.design.to_dict(),
            "verification": None if self.verification is None else self.verification.to_dict(),
            "tried": self.tried, "solved_first_equation": self.solved_1,
            "solved_both_equations": self.solved_2,
            "best_residual_second_equation": self.best_residual_2,
            "best_point": self.best_point, "grid": self.grid,
        }


def verify_design(plant: UncertainPlant, G: npt.ArrayLike, K: npt.ArrayLike, *,
                  region: PoleRegion, gamma: float, sigma2: npt.ArrayLike,
                  n_grid: int = 21) -> RobustAnalysis:
    """Check the three requirements of the variance-constrained designs for all admissible
    ``F``.

    Thin wrapper of :func:`filters.analysis.robust_filter_analysis`: poles of the augmented
    system in ``region``, ``||H||_inf <= gamma`` and ``[P]_ii <= sigma_i^2`` at the vertices
    and on a grid of ``F`` (:meth:`RobustAnalysis.meets`).
    """
    return robust_filter_analysis(plant, G, K, region=region, gamma=gamma, sigma2=sigma2,
                                  n_grid=n_grid)


def passes(analysis: RobustAnalysis) -> bool:
    """All requirements recorded in ``analysis`` are met."""
    return all(v is not False for v in analysis.meets().values()) and analysis.all_stable


# ============================================================ optimizer-based search
def bound_ratio(Q2: FloatArray, sigma2: npt.ArrayLike | None) -> float:
    """``max(diag(Q2) / sigma2)`` (``trace(Q2)`` without bounds): smaller is better."""
    if sigma2 is None:
        return float(np.trace(Q2))
    return float(np.max(np.diag(Q2) / np.asarray(sigma2, dtype=float).reshape(-1)))


def structured_then_multistart(
        method: str, structured: Callable[[], VarianceDesign],
        multistart: Callable[[list[FloatArray], list[FloatArray]], VarianceDesign],
        sigma2: npt.ArrayLike | None) -> VarianceDesign:
    """The ``method`` switch shared by both variance-constrained designs.

    ``"multistart"``: only ``multistart([], [])``. ``"riccati"``: only ``structured()``.
    ``"auto"``: ``structured()``; if it fails, or misses ``sigma2``, also the multi-start
    (started from the structured solutions where positive definite), and the better of the
    two by :func:`bound_ratio`, with every attempt recorded.
    """
    if method not in ("auto", "riccati", "multistart"):
        raise ValueError(f"method must be 'auto', 'riccati' or 'multistart', got {method!r}")
    if method == "multistart":
        return multistart([], [])
    d = structured()
    if method == "riccati" or (d.solved and d.variance_bounds_met is not False):
        return d
    starts1 = [d.Q1] if d.Q1 is not None and is_positive_definite(d.Q1) else []
    starts2 = [d.Q2] if d.Q2 is not None and is_positive_definite(d.Q2) else []
    m = multistart(starts1, starts2)
    attempts = d.attempts + m.attempts
    if d.solved and (not m.solved or bound_ratio(d.Q2, sigma2) <= bound_ratio(m.Q2, sigma2)):
        return replace(d, attempts=attempts)
    if m.solved:
        return replace(m, message=f"{m.message} (multi-start fallback; structured solvers: "
                                  f"{d.message})", attempts=attempts)
    return replace(m, message=f"structured solvers: {d.message}. Multi-start fallback: "
                              f"{m.message}", attempts=attempts)


@dataclass(frozen=True)
class SearchCandidate:
    """One local optimum (or the given parameters) of an optimizer-based design search.

    Attributes
    ----------
    start : int
        Index of the start (0: the given parameters, e.g. the paper's printed ones, evaluated
        as they are).
    parameters : dict
        The design parameters (JSON-safe).
    objective : float
        The search objective at these parameters (see the search function); ``<= 1`` means
        both equations are solved with ``max(diag(Q2) / sigma^2) <= 1``.
    solved : bool
        Both matrix equations solved.
    certified : bool
        Solved and ``diag(Q2) <= sigma^2``: the theorem then guarantees the three requirements.
    verified : bool
        The gains pass :func:`verify_design` (vertices and a grid of ``F``).
    evaluations : int
        Objective evaluations spent on this start.
    design : VarianceDesign or None
    verification : RobustAnalysis or None
    message : str
    """

    start: int
    parameters: dict[str, Any]
    objective: float
    solved: bool
    certified: bool
    verified: bool
    evaluations: int
    design: VarianceDesign | None = None
    verification: RobustAnalysis | None = None
    message: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe summary (the design's ``K``, ``G``, ``Q1``, ``Q2`` included)."""
        return {"start": self.start, "parameters": self.parameters,
                "objective": self.objective if math.isfinite(self.objective) else None,
                "solved": self.solved, "certified": self.certified, "verified": self.verified,
                "evaluations": self.evaluations, "message": self.message,
                "design": None if self.design is None else self.design.to_dict(),
                "verification": (None if self.verification is None
                                 else self.verification.to_dict())}


@dataclass(frozen=True)
class DesignSearchRecord:
    """Result and record of an optimizer-based design search.

    Attributes
    ----------
    found : bool
        A candidate passed :func:`verify_design`.
    design : VarianceDesign or None
        The best verified design: certified ones first, then by smallest objective.
    verification : RobustAnalysis or None
        Its verification.
    candidates : tuple of SearchCandidate
        Every candidate, in the order of the starts (the given parameters first).
    evaluations : int
        Objective evaluations in total.
    seed : int
        Seed of the random starts.
    optimizer : str
        ``"scipy.optimize.minimize(Nelder-Mead)"`` with its options.
    variables : list of str
        Names of the optimized coordinates.
    bounds : list of (float, float)
        Their bounds.
    specification : dict
        Region, ``gamma``, ``sigma2``, uncertainty shape.
    wall_s : float
        Wall-clock time of the search, s.
    """

    found: bool
    design: VarianceDesign | None
    verification: RobustAnalysis | None
    candidates: tuple[SearchCandidate, ...]
    evaluations: int
    seed: int
    optimizer: str
    variables: list[str]
    bounds: list[tuple[float, float]]
    specification: dict[str, Any]
    wall_s: float

    @property
    def best(self) -> SearchCandidate | None:
        """The candidate of :attr:`design` (``None`` if nothing was verified)."""
        for c in self.candidates:
            if c.design is self.design and self.design is not None:
                return c
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe summary including every candidate."""
        best = self.best
        return {
            "found": self.found,
            "design": None if self.design is None else self.design.to_dict(),
            "verification": None if self.verification is None else self.verification.to_dict(),
            "best_start": None if best is None else best.start,
            "certified": None if best is None else best.certified,
            "candidates": [c.to_dict() for c in self.candidates],
            "evaluations": self.evaluations, "seed": self.seed, "optimizer": self.optimizer,
            "variables": self.variables, "bounds": [list(b) for b in self.bounds],
            "specification": self.specification, "wall_s": self.wall_s,
        }


def _single_threaded_blas() -> contextlib.AbstractContextManager[Any]:
    """``threadpoolctl.threadpool_limits(1, "blas")`` if available, else a no-op."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - optional
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


#: Objective of a failed evaluation (an equation without solution and no finer measure).
INFEASIBLE = 1e3


def search_space(n: int, sigma2: npt.ArrayLike, eps_bounds: tuple[float, float],
                 delta_bounds: tuple[float, float], h_bound: float
                 ) -> tuple[FloatArray, tuple[float, float], tuple[float, float]]:
    """Checked inputs of a design search: ``sigma2`` (n,) and the log10 bounds of the eps and
    delta scalars (``ValueError`` naming the argument otherwise)."""
    s2 = real_array(sigma2, "sigma2", finite=False).reshape(-1)
    if s2.shape != (n,) or not np.all(np.isfinite(s2)) or np.any(s2 <= 0):
        raise ValueError(f"sigma2 must be a positive finite array of shape ({n},), got "
                         f"{np.shape(sigma2)}")
    for name, bd in (("eps_bounds", eps_bounds), ("delta_bounds", delta_bounds)):
        if not (0 < bd[0] < bd[1] < math.inf):
            raise ValueError(f"{name} must be (low, high) with 0 < low < high, got {bd!r}")
    if not (h_bound > 0 and math.isfinite(h_bound)):
        raise ValueError(f"h_bound must be a positive finite float, got {h_bound!r}")
    return (s2, (math.log10(eps_bounds[0]), math.log10(eps_bounds[1])),
            (math.log10(delta_bounds[0]), math.log10(delta_bounds[1])))


def random_search_start(rng: np.random.Generator, n_eps: int, log_eps: tuple[float, float],
                        log_delta: tuple[float, float], n_h: int,
                        eps_window: tuple[float, float]) -> FloatArray:
    """A random start ``[log10 eps (n_eps), log10 delta (2), H (n_h)]`` of a design search:
    eps and delta uniform in decades (within ``eps_window`` and ``[-4, -1]``), ``H`` a random
    direction of size ``10^U(-3, -0.5)``."""
    e = rng.uniform(max(log_eps[0], eps_window[0]), min(log_eps[1], eps_window[1]), n_eps)
    dl = rng.uniform(max(log_delta[0], -4.0), min(log_delta[1], -1.0), 2)
    h = rng.standard_normal(n_h)
    h *= 10.0 ** rng.uniform(-3.0, -0.5) / max(float(np.linalg.norm(h)), 1e-300)
    return np.concatenate([e, dl, h])


def run_design_search(objective: Callable[[FloatArray], tuple[float, VarianceDesign | None]],
                      x_given: FloatArray, random_start: Callable[[np.random.Generator],
                                                                  FloatArray],
                      bounds: Sequence[tuple[float, float]], *, n_starts: int, seed: int,
                      max_evaluations: int, verify: Callable[[VarianceDesign],
                                                             RobustAnalysis],
                      sigma2: FloatArray, describe: Callable[[FloatArray], dict[str, Any]],
                      variables: list[str], specification: dict[str, Any],
                      simplex_step: Sequence[float]) -> DesignSearchRecord:
    """Multi-start Nelder-Mead over the design coordinates; verify every candidate.

    Start 0 is ``x_given`` evaluated as it is (the printed parameters) and then also optimized
    from; starts ``1 .. n_starts - 1`` are drawn by ``random_start`` from a generator seeded
    with ``seed``. Each local optimum with solved equations is checked by ``verify``.

    Parameters
    ----------
    objective : callable ``x -> (J, design or None)``
    x_given : numpy.ndarray, shape (d,)
    random_start : callable ``rng -> x``
    bounds : sequence of (low, high), length d
    n_starts : int
        Optimizer starts (>= 1), the given point included.
    seed : int
    max_evaluations : int
        Objective evaluations per start.
    verify : callable ``design -> RobustAnalysis``
    sigma2 : numpy.ndarray, shape (n,)
    describe : callable ``x -> dict``
        JSON-safe parameters of a point.
    variables : list of str
    specification : dict
    simplex_step : sequence of float, length d
        Size of the initial Nelder-Mead simplex along each coordinate.

    Returns
    -------
    DesignSearchRecord

    Notes
    -----
    BLAS runs single-threaded during the search (``threadpoolctl``, when installed): the
    matrices are small, and multi-threaded OpenBLAS costs milliseconds per call on a busy
    machine.
    """
    if n_starts < 1:
        raise ValueError(f"n_starts must be >= 1, got {n_starts}")
    if max_evaluations < 1:
        raise ValueError(f"max_evaluations must be >= 1, got {max_evaluations}")
    start_time = time.perf_counter()
    rng = np.random.default_rng(seed)
    lo = np.array([b[0] for b in bounds])
    hi = np.array([b[1] for b in bounds])
    options = {"maxfev": max_evaluations, "xatol": 1e-4, "fatol": 1e-6, "adaptive": True}
    candidates: list[SearchCandidate] = []
    total = 0

    def candidate(k: int, x: FloatArray, J: float, design: VarianceDesign | None,
                  nfev: int, note: str) -> SearchCandidate:
        solved = design is not None and design.solved
        certified = bool(solved and np.all(np.diag(design.Q2) <= sigma2))
        check = verify(design) if solved else None
        ok = check is not None and passes(check)
        msg = note + ("" if design is None else f"; {design.message}")
        return SearchCandidate(k, describe(x), float(J), solved, certified, ok, nfev,
                               design, check, msg)

    starts = [np.clip(np.asarray(x_given, dtype=np.float64), lo, hi)]
    starts += [np.clip(random_start(rng), lo, hi) for _ in range(n_starts - 1)]
    d = lo.size
    with _single_threaded_blas():
        for k, x0 in enumerate(starts):
            if k == 0:  # the given parameters as they are: the first candidate
                J0, d0 = objective(x0)
                total += 1
                candidates.append(candidate(0, x0, J0, d0, 1, "given parameters"))
            # initial simplex: x0 and a step of simplex_step[i] along each coordinate, towards
            # the inside of the bounds
            simplex = np.tile(x0, (d + 1, 1))
            for i in range(d):
                step = simplex_step[i] if x0[i] + simplex_step[i] <= hi[i] else -simplex_step[i]
                simplex[i + 1, i] += step
            out = minimize(lambda x: objective(x)[0], x0, method="Nelder-Mead",
                           bounds=list(zip(lo, hi, strict=True)),
                           options={**options, "initial_simplex": np.clip(simplex, lo, hi)})
            total += int(out.nfev)
            J, design = objective(out.x)
            total += 1
            candidates.append(candidate(k, out.x, J, design, int(out.nfev) + 1,
                                        f"Nelder-Mead from start {k}: {out.message}"))
    verified = [c for c in candidates if c.verified]
    verified.sort(key=lambda c: (not c.certified, c.objective))
    best = verified[0] if verified else None
    return DesignSearchRecord(
        found=best is not None, design=None if best is None else best.design,
        verification=None if best is None else best.verification,
        candidates=tuple(candidates), evaluations=total, seed=seed,
        optimizer=f"scipy.optimize.minimize(Nelder-Mead, {options})", variables=variables,
        bounds=[(float(a), float(b)) for a, b in zip(lo, hi, strict=True)],
        specification=specification, wall_s=time.perf_counter() - start_time)
