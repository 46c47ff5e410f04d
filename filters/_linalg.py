"""Private validation and linear-algebra helpers shared by the :mod:`filters` modules.

Nothing here is public API. All arrays are ``float64``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt
from scipy.linalg import expm

FloatArray = npt.NDArray[np.float64]

#: Relative tolerance for symmetry: ``max|M - M^T| <= SYM_RTOL * max|M|``.
SYM_RTOL = 1e-9
#: Relative tolerance for semidefiniteness: ``min eig >= -PSD_RTOL * max|eig|``.
PSD_RTOL = 1e-9


def fmt_shape(shape: Sequence[int | str]) -> str:
    """Format a shape such as ``(4, "k")`` as ``"(4, k)"`` (symbolic dimensions unquoted)."""
    inner = ", ".join(str(s) for s in shape)
    return f"({inner},)" if len(shape) == 1 else f"({inner})"


def real_array(
    value: object,
    name: str,
    shape: Sequence[int | None] | None = None,
    *,
    finite: bool = True,
) -> FloatArray:
    """``value`` as a new real ``float64`` array, else ``ValueError`` naming ``name``.

    The one conversion of user input to arrays in :mod:`filters` and ``testbed``: complex
    values (even with a zero imaginary part), strings, containers that are not numeric
    (dicts, sets, ``None``, ragged lists) and Python integers beyond the ``float64`` range
    are refused instead of being cast with a warning, an ``OverflowError`` or a
    ``TypeError``.

    Parameters
    ----------
    value : array_like
        Candidate array (real numbers, booleans or a nested sequence of them).
    name : str
        Argument name used in error messages (e.g. ``"x0"``, ``"options['x0']"``).
    shape : sequence of (int or None), optional
        Required shape (``None`` entries are free); default: any shape.
    finite : bool
        Also require every entry to be finite (no NaN or inf).

    Returns
    -------
    numpy.ndarray
        A fresh ``float64`` array.

    Raises
    ------
    ValueError
        ``value`` is not a real numeric array, has the wrong shape or (with ``finite``)
        non-finite entries; the message names ``name``.
    """
    try:
        raw = np.asarray(value)
        kind = raw.dtype.kind
        if kind == "c":
            raise ValueError(f"{name} must be real, got complex values")
        if kind not in "biufO":
            raise ValueError(f"{name} must be a real numeric array, got {type(value).__name__} "
                             f"of dtype {raw.dtype}")
        arr = np.array(raw, dtype=np.float64)
    except OverflowError:
        raise ValueError(f"{name} has a number beyond the float64 range (|x| > 1.8e308)") \
            from None
    except (TypeError, ValueError) as exc:
        if str(exc).startswith(name):
            raise
        raise ValueError(
            f"{name} must be a real numeric array, got {type(value).__name__}"
        ) from None
    if shape is not None and arr.shape != tuple(shape) and (arr.ndim != len(shape) or any(
            s is not None and s != a for s, a in zip(shape, arr.shape, strict=True))):
        raise ValueError(f"{name} must have shape "
                         f"{fmt_shape(['*' if s is None else s for s in shape])}, got shape "
                         f"{arr.shape}")
    if finite and np.count_nonzero(np.isfinite(arr)) != arr.size:  # (cheaper than .all())
        raise ValueError(f"{name} must be finite, got non-finite entries (NaN or inf)")
    return arr


def to_float_array(name: str, value: object) -> FloatArray:
    """:func:`real_array` without shape or finiteness checks (argument order of old callers)."""
    return real_array(value, name, finite=False)


def all_finite(a: np.ndarray) -> bool:
    """Whether every entry of ``a`` is finite.

    For float64, first as one BLAS sum of squares (finite only if every entry is; NaN and
    infinities make it NaN or infinite); when that overflows, or for another dtype, the
    exact test.
    """
    if a.dtype == np.float64:
        w = a.ravel()
        if math.isfinite(w.dot(w)):
            return True
    return bool(np.count_nonzero(np.isfinite(a)) == a.size)


def shared_member(X: FloatArray, core_ndim: int = 2) -> FloatArray:
    """A stack reduced to its first member when all its members are equal.

    Parameters
    ----------
    X : numpy.ndarray, shape (..., *core)
        A stack of ``core_ndim``-dimensional members (a batch of filters' covariances).
    core_ndim : int
        Number of trailing axes of one member.

    Returns
    -------
    numpy.ndarray
        A view of the first member, shape ``(1, ..., 1, *core)`` (it broadcasts against the
        stack), when ``X`` has batch axes and every member equals the first (NaN compares
        unequal); else ``X`` itself.
    """
    lead = X.ndim - core_ndim
    if lead <= 0:
        return X
    first = X[(slice(0, 1),) * lead]
    return first if (X == first).all() else X


def max_abs_eigenvalue(M: FloatArray) -> float:
    """``max |lambda|`` over the eigenvalues of a matrix or of every matrix of a stack.

    A stack whose matrices are all equal (a batch of filters sharing one covariance) costs
    one eigenvalue computation (:func:`shared_member`): the same LAPACK call on the same
    numbers, hence the same value as the whole stack's.

    Parameters
    ----------
    M : numpy.ndarray, shape (n, n) or (..., n, n)

    Returns
    -------
    float
        The largest eigenvalue magnitude (NaN if an eigenvalue is NaN).
    """
    return float(np.abs(np.linalg.eigvals(shared_member(M))).max())


def readonly(arr: FloatArray) -> FloatArray:
    """Mark ``arr`` read-only in place and return it."""
    arr.flags.writeable = False
    return arr


def matrix(
    name: str,
    value: object,
    shape: tuple[int | None, int | None],
    *,
    what: str = "a finite matrix",
    labels: tuple[str, str] = ("n", "n"),
) -> FloatArray:
    """Validate a finite 2-D matrix.

    Parameters
    ----------
    name : str
        Argument name used in error messages.
    value : array_like
        Candidate matrix.
    shape : tuple of (int or None)
        Required shape; ``None`` entries are free.
    what : str
        Description of the expected property, used in error messages.
    labels : tuple of str
        Symbols printed for free dimensions.

    Returns
    -------
    numpy.ndarray, shape ``shape``
        A fresh ``float64`` copy.
    """
    arr = to_float_array(name, value)
    expected = fmt_shape(
        [s if s is not None else lab for s, lab in zip(shape, labels, strict=True)]
    )
    ok = arr.ndim == 2 and all(s is None or s == a for s, a in zip(shape, arr.shape, strict=True))
    if not ok:
        raise ValueError(f"{name} must be {what} with shape {expected}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be {what} with shape {expected}, got non-finite entries")
    return arr


def symmetric_psd(name: str, value: object, n: int, *, definite: bool) -> FloatArray:
    """Validate a symmetric positive (semi)definite ``(n, n)`` matrix.

    Parameters
    ----------
    name : str
        Argument name used in error messages.
    value : array_like, shape (n, n)
        Candidate matrix. Asymmetry up to ``SYM_RTOL`` (relative) is removed.
    n : int
        Required dimension.
    definite : bool
        Require positive definiteness (Cholesky must succeed) instead of
        semidefiniteness (``min eig >= -PSD_RTOL * max|eig|``).

    Returns
    -------
    numpy.ndarray, shape (n, n)
        The symmetrized ``float64`` copy.
    """
    what = "symmetric positive " + ("definite" if definite else "semidefinite")
    arr = matrix(name, value, (n, n), what=what)
    return batch_symmetric_psd(name, arr, n, definite=definite, what=what)


def batch_symmetric_psd(
    name: str, arr: FloatArray, n: int, *, definite: bool = False, what: str | None = None
) -> FloatArray:
    """Validate a finite stack of symmetric PSD matrices, shape ``(..., n, n)``.

    Returns the symmetrized stack; raises ``ValueError`` naming ``name`` otherwise.
    """
    what = what or "symmetric positive " + ("definite" if definite else "semidefinite")
    expected = f"(..., {n}, {n})"
    if arr.ndim < 2 or arr.shape[-2:] != (n, n):
        raise ValueError(f"{name} must be {what} with shape {expected}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be {what} with shape {expected}, got non-finite entries")
    if arr.size == 0:
        return arr
    scale = float(np.abs(arr).max())
    asym = float(np.abs(arr - np.swapaxes(arr, -1, -2)).max())
    if asym > SYM_RTOL * scale:
        raise ValueError(
            f"{name} must be {what} with shape {expected}, got a non-symmetric matrix "
            f"(max |{name} - {name}^T| = {asym:.3g})"
        )
    sym = 0.5 * (arr + np.swapaxes(arr, -1, -2))
    eig = np.linalg.eigvalsh(sym)
    emin = float(eig[..., 0].min())
    if definite:
        try:
            np.linalg.cholesky(sym)
            ok = emin > 0.0
        except np.linalg.LinAlgError:
            ok = False
    else:
        ok = bool((eig[..., 0] >= -PSD_RTOL * np.abs(eig).max(axis=-1)).all())
    if not ok:
        raise ValueError(
            f"{name} must be {what} with shape {expected}, got minimum eigenvalue {emin:.6g}"
        )
    return sym


def positive_time(name: str, value: object) -> float:
    """Validate a finite, strictly positive time step in seconds."""
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name} must be a positive finite float (seconds), got {value!r}"
        ) from exc
    if not (np.isfinite(out) and out > 0.0):
        raise ValueError(f"{name} must be a positive finite float (seconds), got {value!r}")
    return out


def zoh(A: FloatArray, B: FloatArray, dt_s: float) -> tuple[FloatArray, FloatArray]:
    """Exact zero-order-hold discretization of ``dx/dt = A x + B u``.

    Parameters
    ----------
    A : numpy.ndarray, shape (n, n)
    B : numpy.ndarray, shape (n, k)
    dt_s : float
        Hold interval in seconds.

    Returns
    -------
    F : numpy.ndarray, shape (n, n)
        ``exp(A dt)``.
    Bd : numpy.ndarray, shape (n, k)
        ``int_0^dt exp(A s) ds B``.
    """
    n, k = B.shape
    M = np.zeros((n + k, n + k))
    M[:n, :n] = A
    M[:n, n:] = B
    E = expm(M * dt_s)
    return E[:n, :n].copy(), E[:n, n:].copy()


def van_loan(A: FloatArray, Q: FloatArray, dt_s: float) -> FloatArray:
    """Discrete process-noise covariance ``Q_d = int_0^dt e^{As} Q e^{A^T s} ds`` (Van Loan).

    Parameters
    ----------
    A : numpy.ndarray, shape (n, n)
    Q : numpy.ndarray, shape (n, n)
        Continuous noise intensity (symmetric PSD).
    dt_s : float
        Interval in seconds.

    Returns
    -------
    numpy.ndarray, shape (n, n)
        Symmetrized ``Q_d``.

    Notes
    -----
    With ``G = expm([[-A, Q], [0, A^T]] dt)``: ``F = G22^T`` and ``Q_d = F G12``
    (C. F. Van Loan, IEEE TAC 23(3), 1978).
    """
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = Q
    M[n:, n:] = A.T
    G = expm(M * dt_s)
    Qd = G[n:, n:].T @ G[:n, n:]
    return 0.5 * (Qd + Qd.T)


#: A constant array or a function ``t_s -> array`` (a time-varying coefficient).
TimeArg = npt.ArrayLike | Callable[[float], npt.ArrayLike]


def checked_array(name: str, value: object, shape: tuple[int | None, ...],
                  t: float) -> FloatArray:
    """A finite ``float64`` array of the given shape (``None``: free), else ``ValueError``."""
    arr = to_float_array(name, value)
    if arr.ndim != len(shape) or any(s is not None and s != a
                                     for s, a in zip(shape, arr.shape, strict=True)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + \
            ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name} must have shape {want}, got shape {arr.shape} "
                         f"(at t = {t:.6g} s)")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} must be finite, got non-finite entries at t = {t:.6g} s")
    return arr


class TimeFunction:
    """One coefficient: constant (validated once) or a callable of time (validated per call).

    Parameters
    ----------
    name : str
        Argument name used in error messages.
    arg : array_like or callable ``t_s -> array_like``
    shape : tuple of (int or None)
        Expected shape (``None``: free dimension, fixed by the value at ``t0``).
    t0 : float
        Time at which a callable is first evaluated and checked.
    """

    __slots__ = ("name", "shape", "value", "func")

    def __init__(self, name: str, arg: TimeArg, shape: tuple[int | None, ...], t0: float):
        self.name = name
        self.func: Callable[[float], npt.ArrayLike] | None = arg if callable(arg) else None
        value = checked_array(name, arg(t0) if self.func is not None else arg, shape, t0)
        self.shape = value.shape
        self.value = readonly(value)

    @property
    def constant(self) -> bool:
        """True when the coefficient does not depend on time."""
        return self.func is None

    def __call__(self, t: float) -> FloatArray:
        """The value at time ``t`` (s)."""
        if self.func is None:
            return self.value
        v = self.func(t)
        # fast path (a float64 array of the right shape whose sum is finite), else the full
        # conversion and checks with their error messages
        if (type(v) is np.ndarray and v.dtype == np.float64 and v.shape == self.shape
                and math.isfinite(v.sum())):
            return v.copy()
        return checked_array(self.name, v, self.shape, t)
