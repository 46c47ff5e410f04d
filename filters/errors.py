"""Typed numerical failures of the estimators and the per-step covariance check.

Conventions: times are in seconds (``t_s`` of the filter that raised); covariance
arrays have shape ``(n, n)`` or a batch ``(..., n, n)``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.linalg.lapack import dpotrf as _dpotrf

from filters._linalg import PSD_RTOL

__all__ = [
    "FilterError",
    "FiniteEscapeError",
    "LossOfDefinitenessError",
    "SubstepLimitError",
    "check_covariance",
    "check_shared_covariance",
    "check_symmetric_covariance",
]


class FilterError(RuntimeError):
    """Base class of numerical failures raised by the filters."""


class _LocatedFilterError(FilterError):
    """A numerical failure located in time and attributed to one quantity.

    Parameters
    ----------
    message : str
        Human-readable description; time and quantity are appended.
    time : float
        Filter time in seconds at which the failure was detected.
    quantity : str
        Name of the offending quantity (e.g. ``"P"``, ``"innovation_cov"``, ``"x"``).
    value : numpy.ndarray or float
        The offending value (for :func:`check_covariance`: the symmetrized matrix or
        batch of matrices, shape ``(..., n, n)``).

    Attributes
    ----------
    message, time, quantity, value
        As given.
    """

    def __init__(
        self, message: str, *, time: float, quantity: str, value: npt.NDArray[np.float64] | float
    ) -> None:
        self.message = message
        self.time = float(time)
        self.quantity = quantity
        self.value = value
        super().__init__(f"{message} [quantity {quantity!r}, t = {self.time:.9g} s]")

    def __reduce__(self) -> tuple[object, ...]:
        # Keyword-only constructor: make the exception picklable (multiprocessing, ray).
        return (_rebuild, (type(self), self.message, self.time, self.quantity, self.value))


def _rebuild(
    cls: type[_LocatedFilterError], message: str, time: float, quantity: str, value: object
) -> _LocatedFilterError:
    return cls(message, time=time, quantity=quantity, value=value)  # type: ignore[arg-type]


class LossOfDefinitenessError(_LocatedFilterError):
    """A covariance that must be positive semidefinite has a negative eigenvalue.

    See :class:`_LocatedFilterError` for the constructor ``(message, *, time, quantity, value)``.
    """


class FiniteEscapeError(_LocatedFilterError):
    """A quantity became non-finite or exceeded the escape bound in magnitude.

    See :class:`_LocatedFilterError` for the constructor ``(message, *, time, quantity, value)``.
    """


class SubstepLimitError(_LocatedFilterError):
    """``substeps="auto"`` would need more RK4 substeps per interval than its cap.

    Raised by the continuous-time filters before they change state (``quantity``
    ``"substeps"``, ``value`` the number the stiffness estimate asked for). The equations are
    too stiff for the sample interval at the current covariance (a large ``P0`` with accurate
    sensors); a smaller ``P0``, a shorter interval or an explicit integer ``substeps`` avoid it.

    See :class:`_LocatedFilterError` for the constructor ``(message, *, time, quantity, value)``.
    """


def check_covariance(
    P: npt.ArrayLike, *, time: float, quantity: str = "P", escape_bound: float = 1e12
) -> npt.NDArray[np.float64]:
    """Symmetrize a covariance and check it is finite, bounded and PSD.

    Parameters
    ----------
    P : array_like, shape (n, n) or (..., n, n)
        Covariance matrix or batch of matrices.
    time : float
        Current time in seconds, recorded in a raised error.
    quantity : str
        Name recorded in a raised error.
    escape_bound : float
        Largest admissible entry magnitude.

    Returns
    -------
    numpy.ndarray, shape like ``P``
        The symmetrized ``0.5 * (P + P^T)`` (a new array).

    Raises
    ------
    FiniteEscapeError
        An entry is non-finite or its magnitude exceeds ``escape_bound``.
    LossOfDefinitenessError
        Some matrix has ``min eig < -1e-9 * max|eig|``.
    ValueError
        ``P`` is not a (stack of) square matrices.

    Notes
    -----
    Fast path (one unbatched matrix): if the Frobenius norm is ``<= escape_bound``
    and LAPACK ``dpotrf`` succeeds, ``P`` is accepted (about 2 us for 4x4). Otherwise
    the exact criteria above are evaluated with ``eigvalsh``, so semidefinite
    (singular) covariances are accepted, only more slowly.
    """
    P = np.asarray(P, dtype=np.float64)
    if P.ndim < 2 or P.shape[-1] != P.shape[-2]:
        raise ValueError(f"{quantity} must have shape (n, n) or (..., n, n), got shape {P.shape}")
    if P.ndim == 2:
        Ps = P + P.T
        Ps *= 0.5
    else:
        Ps = 0.5 * (P + P.mT)
    check_symmetric_covariance(Ps, time=time, quantity=quantity, escape_bound=escape_bound)
    return Ps


def check_symmetric_covariance(
    Ps: npt.NDArray[np.float64], *, time: float, quantity: str = "P", escape_bound: float = 1e12
) -> None:
    """:func:`check_covariance` without the symmetrization, for exactly symmetric input.

    Parameters
    ----------
    Ps : numpy.ndarray, shape (n, n) or (..., n, n)
        Exactly symmetric ``float64`` matrix or stack (only the lower triangle is read on
        the fast path: a bounded stack whose Cholesky factorization succeeds passes; anything
        else gets the exact eigenvalue test).
    time, quantity, escape_bound
        As in :func:`check_covariance`.

    Raises
    ------
    FiniteEscapeError, LossOfDefinitenessError
        As in :func:`check_covariance`.
    """
    v = Ps.ravel()
    if v.dot(v) <= escape_bound * escape_bound:  # all entries bounded (False for NaN)
        if Ps.ndim == 2 or 0 < Ps.size == Ps.shape[-1] ** 2:  # one matrix
            if _dpotrf(Ps.reshape(Ps.shape[-2:]))[1] == 0:
                return
        elif Ps.size:
            try:  # positive definite stack: nothing more to check
                np.linalg.cholesky(Ps)
                return
            except np.linalg.LinAlgError:
                pass
    _check_exact(Ps, time=time, quantity=quantity, escape_bound=escape_bound)


def check_shared_covariance(
    P: npt.NDArray[np.float64], batch: tuple[int, ...], *, time: float, quantity: str = "P",
    escape_bound: float = 1e12
) -> npt.NDArray[np.float64]:
    """:func:`check_covariance` of the stack ``P`` broadcast to the batch, evaluated on ``P``.

    For a batch of filters whose members share one covariance, ``P`` is that member (a
    length-1 axis per batch axis) and only it is symmetrized and factored; the stack itself
    (shape ``(*batch, n, n)``) is also accepted.

    Parameters
    ----------
    P : numpy.ndarray, shape (..., n, n)
        Broadcasts to ``(*batch, n, n)``.
    batch : tuple of int
        The batch shape of the stack.
    time, quantity, escape_bound
        As in :func:`check_covariance`.

    Returns
    -------
    numpy.ndarray, shape like ``P``
        The symmetrized ``P``.

    Raises
    ------
    FiniteEscapeError, LossOfDefinitenessError
        The errors :func:`check_covariance` raises on the whole stack (same message, the
        stack as ``value``).
    """
    try:
        return check_covariance(P, time=time, quantity=quantity, escape_bound=escape_bound)
    except FilterError:
        check_covariance(np.broadcast_to(P, (*batch, *P.shape[-2:])), time=time,
                         quantity=quantity, escape_bound=escape_bound)
        raise


def _check_exact(
    Ps: npt.NDArray[np.float64], *, time: float, quantity: str, escape_bound: float
) -> None:
    """Exact (slow) finiteness, bound and semidefiniteness checks on a symmetric stack."""
    if Ps.size == 0:
        return
    absmax = np.abs(Ps).max(axis=(-2, -1))
    bad = ~(absmax <= escape_bound)  # NaN compares False
    if bad.any():
        where = _first_index(bad)
        raise FiniteEscapeError(
            f"{quantity}{where} escaped: max |entry| = {float(np.max(absmax[bad])):.6g} "
            f"(bound {escape_bound:.3g}, non-finite entries: {bool(~np.isfinite(Ps).all())})",
            time=time,
            quantity=quantity,
            value=Ps.copy(),
        )
    eig = np.linalg.eigvalsh(Ps)
    emin = eig[..., 0]
    tol = PSD_RTOL * np.abs(eig).max(axis=-1)
    bad = emin < -tol
    if bad.any():
        where = _first_index(bad)
        raise LossOfDefinitenessError(
            f"{quantity}{where} is not positive semidefinite: minimum eigenvalue "
            f"{float(np.min(emin[bad])):.6g} < -{PSD_RTOL:g} * max|eig|",
            time=time,
            quantity=quantity,
            value=Ps.copy(),
        )


def _first_index(mask: npt.NDArray[np.bool_]) -> str:
    """Describe the first batch index where ``mask`` is true (empty for a single matrix)."""
    if mask.ndim == 0:
        return ""
    idx = tuple(int(i[0]) for i in np.nonzero(mask))
    return f"[batch index {idx}]"
