"""Process and measurement noise covariances identified from a filter's innovations.

Autocovariance least squares (ALS; Odelson, Rajamani & Rawlings 2006): a linear
time-invariant filter with any stabilizing gain ``K`` (not necessarily the optimal one) run
on

    x_{k+1} = F x_k + B u_k + w_k,     w_k ~ N(0, Q)
    y_k     = H x_k + D u_k + v_k,     v_k ~ N(0, R)

has predicted-state error ``e_{k+1} = F (I - K H) e_k + w_k - F K v_k`` and innovations
``r_k = y_k - H x_{k|k-1} = H e_k + v_k``. Their lag-``j`` autocovariances
``C_j = E[r_{k+j} r_k^T]`` are linear in ``Q`` and ``R``:

    C_0 = H P H^T + R,      C_j = H Abar^j P H^T - H Abar^(j-1) F K R   (j >= 1)

with ``Abar = F (I - K H)`` and ``P = Abar P Abar^T + Q + F K R K^T F^T``. Stacking the
sample autocovariances of lags ``0 .. N-1`` and solving the linear least-squares problem for
the coefficients of ``Q`` and ``R`` in a chosen structure (diagonal by default, or any list of
symmetric basis matrices) gives the noise covariances that explain the innovations. A Kalman
filter redesigned with them has white innovations when the model structure is right.

The gain ``K`` is the filter's measurement-update gain (``x_{k|k} = x_{k|k-1} + K r_k``), in
steady state: discard the innovations of a filter's transient (``burn_in``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.linalg
import scipy.optimize

from filters._linalg import FloatArray, matrix, real_array
from filters.models import DiscreteLinearSystem

__all__ = ["NoiseCovarianceEstimate", "autocovariance_least_squares", "fit_autocovariances",
           "innovation_autocovariances", "predicted_autocovariances"]


def innovation_autocovariances(innovations: npt.ArrayLike, lags: int, *,
                               burn_in: int = 0) -> FloatArray:
    """Sample autocovariances ``C_j = mean_k r_{k+j} r_k^T`` of zero-mean innovations.

    Parameters
    ----------
    innovations : array_like, shape (T, m) or (M, T, m)
        One sequence, or ``M`` independent sequences of one stationary process (pooled).
    lags : int
        Number of lags ``N`` (``j = 0 .. N-1``); at least 1 and less than ``T - burn_in``.
    burn_in : int
        Leading samples of every sequence left out (a filter's transient).

    Returns
    -------
    ndarray, shape (N, m, m)
    """
    r = real_array(innovations, "innovations", finite=False)
    if r.ndim == 2:
        r = r[None]
    if r.ndim != 3 or r.shape[2] == 0:
        raise ValueError(f"innovations must have shape (T, m) or (M, T, m), got shape "
                         f"{np.shape(innovations)}")
    if not np.all(np.isfinite(r)):
        raise ValueError("innovations must be finite")
    if int(burn_in) != burn_in or burn_in < 0:
        raise ValueError(f"burn_in must be a non-negative integer, got {burn_in}")
    r = r[:, int(burn_in):]
    T = r.shape[1]
    if int(lags) != lags or not 1 <= lags < T:
        raise ValueError(f"lags must be an integer in [1, {T - 1}] (the samples after "
                         f"burn_in), got {lags}")
    out = np.empty((int(lags), r.shape[2], r.shape[2]))
    for j in range(int(lags)):
        later, earlier = r[:, j:], r[:, :T - j]
        out[j] = np.einsum("ati,atj->ij", later, earlier) / (r.shape[0] * (T - j))
    return out


def _check_gain(system: DiscreteLinearSystem, gain: npt.ArrayLike) -> FloatArray:
    n, m = system.F.shape[0], system.H.shape[0]
    K = matrix("gain", gain, (n, m), labels=("n", "m"))
    Abar = system.F @ (np.eye(n) - K @ system.H)
    radius = float(np.max(np.abs(np.linalg.eigvals(Abar))))
    if radius >= 1.0:
        raise ValueError(f"gain must stabilize the error dynamics F (I - K H); its spectral "
                         f"radius is {radius:.4g} >= 1")
    return K


def _contribution(system: DiscreteLinearSystem, K: FloatArray, lags: int,
                  Qi: FloatArray, Ri: FloatArray) -> FloatArray:
    """Autocovariances of lags ``0 .. lags-1`` that noise ``(Qi, Ri)`` causes, (N, m, m)."""
    F, H = system.F, system.H
    n = F.shape[0]
    Abar = F @ (np.eye(n) - K @ H)
    FK = F @ K
    P = scipy.linalg.solve_discrete_lyapunov(Abar, Qi + FK @ Ri @ FK.T)
    P = 0.5 * (P + P.T)
    out = np.empty((lags, H.shape[0], H.shape[0]))
    out[0] = H @ P @ H.T + Ri
    power = np.eye(n)  # Abar^(j-1)
    for j in range(1, lags):
        out[j] = H @ power @ (Abar @ P @ H.T - FK @ Ri)
        power = power @ Abar
    return out


def predicted_autocovariances(system: DiscreteLinearSystem, gain: npt.ArrayLike,
                              lags: int, Q: npt.ArrayLike | None = None,
                              R: npt.ArrayLike | None = None) -> FloatArray:
    """The innovations' autocovariances a filter with gain ``gain`` has in steady state.

    Parameters
    ----------
    system : DiscreteLinearSystem
        ``F, H`` (its ``Q``, ``R`` unless given).
    gain : array_like, shape (n, m)
        Measurement-update gain ``K``; ``F (I - K H)`` must be stable.
    lags : int
        ``N``: lags ``0 .. N-1``.
    Q, R : array_like, shapes (n, n), (m, m), optional
        The true noise covariances (default the system's).

    Returns
    -------
    ndarray, shape (N, m, m)
    """
    K = _check_gain(system, gain)
    if int(lags) != lags or lags < 1:
        raise ValueError(f"lags must be a positive integer, got {lags}")
    n, m = system.F.shape[0], system.H.shape[0]
    Qv = system.Q if Q is None else matrix("Q", Q, (n, n))
    Rv = system.R if R is None else matrix("R", R, (m, m))
    return _contribution(system, K, int(lags), np.asarray(Qv, float), np.asarray(Rv, float))


@dataclass(frozen=True)
class NoiseCovarianceEstimate:
    """Noise covariances that explain a filter's innovations (:func:`autocovariance_least_squares`).

    Attributes
    ----------
    Q : ndarray, shape (n, n)
        Process-noise covariance per sample (symmetric positive semidefinite).
    R : ndarray, shape (m, m)
        Measurement-noise covariance per sample (symmetric positive semidefinite).
    q_coefficients, r_coefficients : ndarray
        The weights of the basis matrices (``Q = sum_i q_i Q_i``).
    identifiable : bool
        Whether the least-squares matrix has full column rank (else the autocovariances
        cannot tell some combination of the coefficients apart: the estimate is one of many).
    rank : int
        Rank of the least-squares matrix (columns: the number of coefficients).
    residual : float
        Frobenius norm of the stacked autocovariances the fit leaves unexplained.
    lags : int
    """

    Q: FloatArray
    R: FloatArray
    q_coefficients: FloatArray
    r_coefficients: FloatArray
    identifiable: bool
    rank: int
    residual: float
    lags: int


def _basis(name: str, basis: str | Sequence[npt.ArrayLike], dim: int) -> list[FloatArray]:
    if isinstance(basis, str):
        if basis == "diagonal":
            return [np.diag(np.eye(dim)[i]) for i in range(dim)]
        if basis == "full":
            out = []
            for i in range(dim):
                for j in range(i, dim):
                    E = np.zeros((dim, dim))
                    E[i, j] = E[j, i] = 1.0
                    out.append(E)
            return out
        raise ValueError(f"{name} must be 'diagonal', 'full' or a list of symmetric "
                         f"({dim}, {dim}) matrices, got {basis!r}")
    out = []
    for i, M in enumerate(basis):
        E = matrix(f"{name}[{i}]", M, (dim, dim))
        if not np.allclose(E, E.T, rtol=0, atol=1e-12 * max(1.0, float(np.max(np.abs(E))))):
            raise ValueError(f"{name}[{i}] must be symmetric")
        out.append(np.asarray(E, float))
    return out


def autocovariance_least_squares(
        system: DiscreteLinearSystem, gain: npt.ArrayLike, innovations: npt.ArrayLike, *,
        lags: int = 10, burn_in: int = 0, **structure: object) -> NoiseCovarianceEstimate:
    """Identify ``Q`` and ``R`` from the innovations of a filter with a fixed gain.

    Odelson, Rajamani & Rawlings (2006): the innovations' sample autocovariances of lags
    ``0 .. lags-1`` (:func:`innovation_autocovariances`) are fitted, in least squares, by
    those the noise ``Q = sum_i q_i Q_i``, ``R = sum_i r_i R_i`` would cause
    (:func:`predicted_autocovariances`; the fit: :func:`fit_autocovariances`).

    Parameters
    ----------
    system : DiscreteLinearSystem
        The filter's model ``F, H`` (its ``Q``, ``R`` are not used).
    gain : array_like, shape (n, m)
        The filter's steady-state measurement-update gain; ``F (I - K H)`` must be stable.
    innovations : array_like, shape (T, m) or (M, T, m)
        ``y_k - H x_{k|k-1} - D u_k`` of that filter, one or several independent runs.
    lags : int
        Lags fitted (``N``; more lags use more of the innovations' colour).
    burn_in : int
        Leading samples of each run left out (the filter's transient).
    **structure
        ``q_basis``, ``r_basis``, ``known_Q``, ``known_R`` of :func:`fit_autocovariances`.

    Returns
    -------
    NoiseCovarianceEstimate

    Raises
    ------
    ValueError
        Shapes, an unstable ``F (I - K H)``, too few samples for ``lags``.

    Examples
    --------
    >>> est = autocovariance_least_squares(system, kf.gain, innovations, lags=15)
    >>> tuned = DiscreteLinearSystem(F=system.F, B=system.B, H=system.H, Q=est.Q, R=est.R,
    ...                              dt_s=system.dt_s)
    """
    _check_gain(system, gain)
    C = innovation_autocovariances(innovations, lags, burn_in=burn_in)
    return fit_autocovariances(system, gain, C, **structure)  # type: ignore[arg-type]


def fit_autocovariances(
        system: DiscreteLinearSystem, gain: npt.ArrayLike, autocovariances: npt.ArrayLike, *,
        q_basis: str | Sequence[npt.ArrayLike] = "diagonal",
        r_basis: str | Sequence[npt.ArrayLike] = "diagonal",
        known_Q: npt.ArrayLike | None = None,
        known_R: npt.ArrayLike | None = None) -> NoiseCovarianceEstimate:
    """``Q`` and ``R`` whose predicted innovation autocovariances fit the given ones.

    The least-squares step of :func:`autocovariance_least_squares`, on autocovariances of
    lags ``0 .. N-1`` (sample ones, or exact ones from :func:`predicted_autocovariances`).

    With the diagonal structure (the default) the coefficients are variances: they are
    constrained to be non-negative (``scipy.optimize.nnls``), so ``Q`` and ``R`` are positive
    semidefinite. With ``"full"`` or a user basis the least-squares solution is projected on
    the positive semidefinite cone (negative eigenvalues set to zero).

    Parameters
    ----------
    system : DiscreteLinearSystem
        The filter's model ``F, H`` (its ``Q``, ``R`` are not used).
    gain : array_like, shape (n, m)
        The filter's steady-state measurement-update gain; ``F (I - K H)`` must be stable.
    autocovariances : array_like, shape (N, m, m)
        ``C_j = E[r_{k+j} r_k^T]``, ``j = 0 .. N-1``.
    q_basis, r_basis : {"diagonal", "full"} or list of symmetric matrices
        The structure of ``Q`` (n, n) and ``R`` (m, m): e.g. ``[G G^T]`` for a noise entering
        through a known ``G`` with unknown intensity.
    known_Q, known_R : array_like, optional
        Hold one of them at a known value and identify only the other.

    Returns
    -------
    NoiseCovarianceEstimate

    Raises
    ------
    ValueError
        Shapes, an unstable ``F (I - K H)``, a basis that is not symmetric.
    """
    K = _check_gain(system, gain)
    n, m = system.F.shape[0], system.H.shape[0]
    C = real_array(autocovariances, "autocovariances")
    if C.ndim != 3 or C.shape[1:] != (m, m) or C.shape[0] < 1:
        raise ValueError(f"autocovariances must have shape (N, {m}, {m}) (m: the system's "
                         f"measurements), got shape {C.shape}")
    lags = C.shape[0]
    target = C.reshape(-1).copy()
    zero_n, zero_m = np.zeros((n, n)), np.zeros((m, m))
    if known_Q is not None:
        target -= _contribution(system, K, lags, matrix("known_Q", known_Q, (n, n)),
                                zero_m).reshape(-1)
    if known_R is not None:
        target -= _contribution(system, K, lags, zero_n,
                                matrix("known_R", known_R, (m, m))).reshape(-1)
    qs = [] if known_Q is not None else _basis("q_basis", q_basis, n)
    rs = [] if known_R is not None else _basis("r_basis", r_basis, m)
    if not qs and not rs:
        raise ValueError("known_Q and known_R are both given: nothing to identify")
    columns = ([_contribution(system, K, lags, Qi, zero_m).reshape(-1) for Qi in qs]
               + [_contribution(system, K, lags, zero_n, Ri).reshape(-1) for Ri in rs])
    A = np.column_stack(columns)
    rank = int(np.linalg.matrix_rank(A))
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    diagonal = (isinstance(q_basis, str) and q_basis == "diagonal"
                and isinstance(r_basis, str) and r_basis == "diagonal")
    if diagonal:
        theta, _ = scipy.optimize.nnls(A / scale, target)
    else:
        theta = np.linalg.lstsq(A / scale, target, rcond=None)[0]
    theta = theta / scale
    residual = float(np.linalg.norm(A @ theta - target))
    q, r = theta[:len(qs)], theta[len(qs):]
    Q = (np.asarray(known_Q, float) if known_Q is not None
         else _psd(sum((c * Qi for c, Qi in zip(q, qs, strict=True)), zero_n)))
    R = (np.asarray(known_R, float) if known_R is not None
         else _psd(sum((c * Ri for c, Ri in zip(r, rs, strict=True)), zero_m)))
    return NoiseCovarianceEstimate(Q=Q, R=R, q_coefficients=q, r_coefficients=r,
                                   identifiable=rank == A.shape[1], rank=rank,
                                   residual=residual, lags=int(lags))


def _psd(M: FloatArray) -> FloatArray:
    """The nearest symmetric positive semidefinite matrix (Frobenius norm)."""
    S = 0.5 * (M + M.T)
    w, V = np.linalg.eigh(S)
    out = (V * np.clip(w, 0.0, None)) @ V.T
    return 0.5 * (out + out.T)
