"""Numerical building blocks for the nonlinear symmetric matrix equations of the
variance-constrained designs (:mod:`filters.variance_continuous`, :mod:`filters.variance_discrete`).

* :func:`solve_linear_matrix_equation`: ``sum_i A_i X B_i^T = Y`` (generalized Lyapunov /
  Stein equation; the Newton equation of every Riccati-like equation here), by its Kronecker
  form with ``n^2`` unknowns.
* :func:`operator_spectral_abscissa`: the largest real part of the eigenvalues of that linear
  operator (negative: the operator is "stable", so its inverse maps ``Y >= 0`` to ``X <= 0`` when
  it is resolvent positive, the case of all derivatives here).
* :func:`solve_filter_dare`: the filter-form discrete algebraic Riccati equation
  ``X = A X A^T - (A X C^T + S)(C X C^T + R)^-1 (A X C^T + S)^T + Q`` by
  :func:`scipy.linalg.solve_discrete_are` (stabilizing solution; ``R`` may be indefinite).
* :func:`newton_solve`: Newton's method with the exact derivative, either monotone (full
  steps, for convex equations started below their least solution) or with a backtracking line
  search on ``||F||_F`` inside an admissible set.
* :func:`continuation`: a homotopy ``F(X, theta) = 0`` from ``theta = 0`` (solved) to a target
  ``theta`` with tangent predictor and Newton corrector; it reports how far the solution branch
  reaches when it ends (fold) before the target.

All outcomes are results (:class:`NewtonOutcome`, :class:`ContinuationOutcome`), never
exceptions, except :func:`solve_linear_matrix_equation` and :func:`solve_filter_dare`, which
raise :class:`numpy.linalg.LinAlgError`. Arrays are ``float64``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.linalg import solve_discrete_are

from filters._linalg import FloatArray

__all__ = [
    "ContinuationOutcome",
    "NewtonOutcome",
    "Terms",
    "continuation",
    "newton_solve",
    "operator_matrix",
    "operator_spectral_abscissa",
    "solve_filter_dare",
    "solve_linear_matrix_equation",
]

#: A linear matrix operator ``X -> sum_i A_i X B_i^T`` given by its pairs ``(A_i, B_i)``,
#: each of shape (n, n).
Terms = Sequence[tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]

#: ``X -> (F(X), terms of the derivative F'(X))``: a symmetric residual with its exact
#: derivative ``F'(X)[D] = sum_i A_i D B_i^T``. It may raise ``LinAlgError`` (undefined at X).
ResidualWithDerivative = Callable[[FloatArray], tuple[FloatArray, Terms]]


def _sym(X: FloatArray) -> FloatArray:
    return 0.5 * (X + X.T)


def operator_matrix(terms: Terms) -> FloatArray:
    """Kronecker matrix ``sum_i B_i (x) A_i`` of ``X -> sum_i A_i X B_i^T`` on ``vec(X)``
    (column-major), shape (n^2, n^2)."""
    A0 = np.asarray(terms[0][0])
    n = A0.shape[0]
    M = np.zeros((n, n, n, n))  # M[k, i, l, j] = sum B[k, l] A[i, j]
    for A, B in terms:
        M += np.multiply.outer(B, A).transpose(0, 2, 1, 3)
    return M.reshape(n * n, n * n)


def solve_linear_matrix_equation(terms: Terms, rhs: npt.ArrayLike) -> FloatArray:
    """Solve ``sum_i A_i X B_i^T = Y`` for ``X`` (symmetrized).

    Parameters
    ----------
    terms : sequence of (A_i, B_i), each shape (n, n)
    rhs : array_like, shape (n, n)
        ``Y`` (symmetric for a symmetric solution).

    Returns
    -------
    numpy.ndarray, shape (n, n)

    Raises
    ------
    numpy.linalg.LinAlgError
        If the operator is singular (to working precision).

    Notes
    -----
    Dense Kronecker form: ``O(n^6)`` operations, meant for the design sizes (``n`` up to a few
    tens). A symmetric ``Y`` and an operator that maps symmetric matrices to symmetric ones (all
    derivatives here) give a symmetric ``X``; the result is symmetrized against rounding.
    """
    Y = np.asarray(rhs, dtype=np.float64)
    n = Y.shape[0]
    M = operator_matrix(terms)
    x = np.linalg.solve(M, Y.reshape(-1, order="F"))
    if not np.isfinite(x).all():
        raise np.linalg.LinAlgError("linear matrix equation: non-finite solution")
    return _sym(x.reshape(n, n, order="F"))


def operator_spectral_abscissa(terms: Terms) -> float:
    """Largest real part of the eigenvalues of ``X -> sum_i A_i X B_i^T``."""
    return float(np.linalg.eigvals(operator_matrix(terms)).real.max())


def solve_filter_dare(A: npt.ArrayLike, C: npt.ArrayLike, Q: npt.ArrayLike, R: npt.ArrayLike,
                      S: npt.ArrayLike | None = None) -> FloatArray:
    """Stabilizing solution of the filter-form discrete algebraic Riccati equation.

    ``X = A X A^T - (A X C^T + S)(C X C^T + R)^-1 (A X C^T + S)^T + Q``, i.e.
    :func:`scipy.linalg.solve_discrete_are` with ``a = A^T``, ``b = C^T``, ``s = S``. The
    closed loop ``A - (A X C^T + S)(C X C^T + R)^-1 C`` is Schur stable. ``R`` must be
    nonsingular but may be indefinite (H-infinity type equations).

    Parameters
    ----------
    A : array_like, shape (n, n)
    C : array_like, shape (m, n)
    Q : array_like, shape (n, n)
    R : array_like, shape (m, m)
    S : array_like, shape (n, m), optional

    Returns
    -------
    numpy.ndarray, shape (n, n)
        Symmetrized solution.

    Raises
    ------
    numpy.linalg.LinAlgError
        If no stabilizing solution is found (scipy's message is kept), or it is not finite.
    """
    A_ = np.asarray(A, dtype=np.float64)
    C_ = np.asarray(C, dtype=np.float64)
    try:
        with np.errstate(all="ignore"):
            X = solve_discrete_are(A_.T, C_.T, _sym(np.asarray(Q, dtype=np.float64)),
                                   _sym(np.asarray(R, dtype=np.float64)),
                                   s=None if S is None else np.asarray(S, dtype=np.float64))
    except ValueError as exc:  # scipy reports some singular pencils as ValueError
        raise np.linalg.LinAlgError(str(exc)) from exc
    if not np.isfinite(X).all():
        raise np.linalg.LinAlgError("DARE: non-finite solution")
    return _sym(X)


# ====================================================================== Newton
@dataclass(frozen=True)
class NewtonOutcome:
    """Result of :func:`newton_solve`.

    Attributes
    ----------
    X : numpy.ndarray, shape (n, n)
        Last admissible iterate.
    residual : float
        ``||F(X)||_F`` (``inf`` if ``F`` is undefined at ``X``).
    iterations : int
    status : str
        ``"converged"`` (``residual <= tol``), ``"not_converged"`` (iteration limit or the line
        search stalled), ``"left_admissible_set"`` (a monotone step left the set),
        ``"singular_derivative"`` or ``"undefined"`` (``F`` undefined at the start).
    """

    X: FloatArray
    residual: float
    iterations: int
    status: str

    @property
    def converged(self) -> bool:
        return self.status == "converged"


def _eval(fun: ResidualWithDerivative, X: FloatArray) -> tuple[FloatArray, Terms] | None:
    try:
        with np.errstate(all="ignore"):
            F, terms = fun(X)
    except (np.linalg.LinAlgError, ValueError, ZeroDivisionError, FloatingPointError):
        return None
    F = np.asarray(F, dtype=np.float64)
    if F.shape != X.shape or not np.isfinite(F).all():
        return None
    return _sym(F), terms


def newton_solve(fun: ResidualWithDerivative, X0: npt.ArrayLike, *,
                 admissible: Callable[[FloatArray], bool], tol: float, max_iter: int = 50,
                 monotone: bool = False, fast_only: bool = False) -> NewtonOutcome:
    """Newton's method ``X <- X - F'(X)^-1 F(X)`` with the exact derivative.

    Parameters
    ----------
    fun : callable ``X -> (F(X), terms of F'(X))``
        See :data:`ResidualWithDerivative`.
    X0 : array_like, shape (n, n)
        Start (must be admissible).
    admissible : callable ``X -> bool``
        Open set where iterates must stay.
    tol : float
        Absolute tolerance on ``||F(X)||_F``.
    max_iter : int
    monotone : bool
        Full Newton steps; a step that leaves the admissible set ends the iteration with
        ``status = "left_admissible_set"``. This is the right method for a convex ``F`` with
        resolvent-positive derivative started at ``X0`` with ``F(X0) >= 0`` and a stable
        ``F'(X0)`` (Damm & Hinrichsen 2001): the iterates then increase monotonically to the
        least solution if any admissible ``X`` with ``F(X) <= 0`` exists, and a step leaving the
        set proves that none exists. Otherwise (``False``) each step is halved until it stays
        admissible and decreases ``||F||_F`` (Armijo); no decrease in 40 halvings stops with
        ``"not_converged"``.
    fast_only : bool
        Stop with ``"not_converged"`` as soon as an iteration after the second reduces
        ``||F||_F`` by less than half (no quadratic convergence: the start is too far, e.g. a
        continuation step too long).

    Returns
    -------
    NewtonOutcome
    """
    X = _sym(np.asarray(X0, dtype=np.float64))
    ev = _eval(fun, X) if admissible(X) else None
    if ev is None:
        return NewtonOutcome(X, math.inf, 0, "undefined")
    F, terms = ev
    r = float(np.linalg.norm(F))
    r_prev = math.inf
    it = 0
    while r > tol:
        if it >= max_iter:
            return NewtonOutcome(X, r, it, "not_converged")
        it += 1
        try:
            D = solve_linear_matrix_equation(terms, -F)
        except np.linalg.LinAlgError:
            return NewtonOutcome(X, r, it, "singular_derivative")
        if monotone:
            Xn = X + D
            evn = _eval(fun, Xn) if admissible(Xn) else None
            if evn is None:
                return NewtonOutcome(X, r, it, "left_admissible_set")
            X, (F, terms) = Xn, evn
            r_new = float(np.linalg.norm(F))
            if r_new >= r and float(np.abs(D).max()) <= 1e-14 * max(1.0, float(np.abs(X).max())):
                return NewtonOutcome(X, r_new, it, "not_converged")  # rounding floor above tol
            r = r_new
            continue
        alpha, accepted = 1.0, False
        for _ in range(40):
            Xn = X + alpha * D
            evn = _eval(fun, Xn) if admissible(Xn) else None
            if evn is not None:
                rn = float(np.linalg.norm(evn[0]))
                if rn <= (1.0 - 1e-4 * alpha) * r:
                    X, (F, terms), r, accepted = Xn, evn, rn, True
                    break
            alpha *= 0.5
        if not accepted:
            return NewtonOutcome(X, r, it, "not_converged")
        if fast_only and it >= 2 and r > tol and (alpha < 1.0 or r > 0.5 * r_prev):
            return NewtonOutcome(X, r, it, "not_converged")
        r_prev = r
    return NewtonOutcome(X, r, it, "converged")


# ================================================================ continuation
@dataclass(frozen=True)
class ContinuationOutcome:
    """Result of :func:`continuation`.

    Attributes
    ----------
    X : numpy.ndarray, shape (n, n)
        Solution at ``theta_reached``.
    theta_reached : float
        Largest ``theta`` at which the branch was solved (the target on success).
    reached_target : bool
    residual : float
        ``||F(X, theta_reached)||_F``.
    steps, newton_iterations : int
    derivative_abscissa : float
        Spectral abscissa of ``F'(X)`` at ``theta_reached`` (near 0 at a fold of the branch).
    status : str
        ``"converged"`` or ``"branch_ended"`` (the step fell below ``min_step`` times the target:
        the solution stops existing or stops being admissible near ``theta_reached``).
    """

    X: FloatArray
    theta_reached: float
    reached_target: bool
    residual: float
    steps: int
    newton_iterations: int
    derivative_abscissa: float
    status: str


def continuation(fun: Callable[[FloatArray, float], tuple[FloatArray, Terms, FloatArray]],
                 X0: npt.ArrayLike, theta_target: float, *,
                 admissible: Callable[[FloatArray], bool], tol: float,
                 min_step: float = 1e-3, max_steps: int = 200,
                 newton_iter: int = 12) -> ContinuationOutcome:
    """Follow the solution of ``F(X, theta) = 0`` from ``theta = 0`` to ``theta_target``.

    Predictor: the tangent ``dX/dtheta = -F_X^-1 F_theta``; corrector: :func:`newton_solve`
    with line search (at most ``newton_iter`` iterations). A step that fails is halved, one
    that succeeds doubles the next; when the step falls below ``min_step * theta_target``
    the branch is declared ended at the last solved ``theta``.

    Parameters
    ----------
    fun : callable ``(X, theta) -> (F, terms of F_X, F_theta)``
        Residual, its derivative in ``X`` (terms) and its derivative in ``theta`` (n, n).
    X0 : array_like, shape (n, n)
        Solution at ``theta = 0``.
    theta_target : float
        > 0.
    admissible : callable ``X -> bool``
    tol : float
        Absolute residual tolerance of each corrector.
    min_step : float
        Relative to ``theta_target``.
    max_steps : int
        Largest number of attempted steps.
    newton_iter : int

    Returns
    -------
    ContinuationOutcome
    """
    X = _sym(np.asarray(X0, dtype=np.float64))
    theta, step = 0.0, float(theta_target)
    steps = iters = 0
    last_terms: Terms | None = None
    residual = math.nan
    try:
        F, last_terms, Ft = fun(X, 0.0)
        residual = float(np.linalg.norm(F))
    except np.linalg.LinAlgError:
        Ft = None
    while theta < theta_target and steps < max_steps:
        steps += 1
        tn = min(theta + step, theta_target)
        Xp = X
        if last_terms is not None and Ft is not None:
            try:
                Xp = X + (tn - theta) * solve_linear_matrix_equation(last_terms, -Ft)
            except np.linalg.LinAlgError:
                Xp = X
            if not admissible(Xp):
                Xp = X
        out = newton_solve(lambda Z, tn=tn: fun(Z, tn)[:2], Xp, admissible=admissible,
                           tol=tol, max_iter=newton_iter, fast_only=True)
        iters += out.iterations
        if out.converged:
            theta, X, residual = tn, out.X, out.residual
            try:
                _, last_terms, Ft = fun(X, theta)
            except np.linalg.LinAlgError:
                last_terms, Ft = None, None
            step *= 2.0
        else:
            step *= 0.5
            if step < min_step * theta_target:
                break
    abscissa = math.nan
    if last_terms is not None:
        try:
            abscissa = operator_spectral_abscissa(last_terms)
        except np.linalg.LinAlgError:
            pass
    done = theta >= theta_target
    return ContinuationOutcome(X, theta, done, residual, steps, iters, abscissa,
                               "converged" if done else "branch_ended")
