"""Kalman filters: discrete-time (:class:`KalmanFilter`) and continuous-time with
sampled measurements (:class:`KalmanBucyFilter`).

Conventions
-----------
* State ``x`` has shape ``(..., n)`` and covariance ``P`` shape ``(..., n, n)``; the
  optional leading axes are a batch of independent filters sharing one model.
* Measurements ``y`` have shape ``(m,)`` or ``(..., m)``, inputs ``u`` shape ``(k,)``
  or ``(..., k)`` (a single vector is broadcast over the batch). ``u=None`` means
  zero input.
* ``step(y, u)`` is the in-the-loop call: ``u`` was applied (zero-order hold) over
  the last sample interval and ``y`` is measured at its end.
* ``t_s`` is the filter time in seconds, ``k * dt_s`` after ``k`` steps.
* ``x`` and ``P`` are read-only arrays, replaced (never mutated) on every call; use
  :meth:`reset` to change them. A call that raises leaves the filter unchanged.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import ClassVar, NoReturn

import numpy as np
import numpy.typing as npt
from scipy.linalg import solve_continuous_are, solve_discrete_are
from scipy.linalg.lapack import dpotrf as _dpotrf
from scipy.linalg.lapack import dpotrs as _dpotrs

from filters._linalg import (
    FloatArray,
    all_finite,
    batch_symmetric_psd,
    max_abs_eigenvalue,
    positive_time,
    readonly,
    shared_member,
    to_float_array,
)
from filters.errors import (
    FiniteEscapeError,
    LossOfDefinitenessError,
    SubstepLimitError,
    check_covariance,
    check_shared_covariance,
    check_symmetric_covariance,
)
from filters.models import DiscreteLinearSystem, LinearSystem

__all__ = ["MAX_AUTO_SUBSTEPS", "CovarianceMemo", "KalmanBucyFilter", "KalmanFilter"]

_ESCAPE_BOUND = 1e12  # default of check_covariance
#: Cap of ``substeps="auto"`` (RK4 substeps per sample interval) of the continuous-time
#: filters: past it :class:`~filters.errors.SubstepLimitError` is raised instead of spending
#: minutes on one interval (10,000 RK4 substeps of one 4-state filter take about 0.3 s).
MAX_AUTO_SUBSTEPS = 10_000
_ESCAPE_BOUND_SQ = _ESCAPE_BOUND * _ESCAPE_BOUND
#: Steps of a shared covariance :meth:`KalmanFilter.step` remembers (a covariance that settles
#: into a cycle of floating-point values of at most this period is then not recomputed).
_MEMO_STEPS = 16
#: Steps a shared covariance :meth:`KalmanFilter.step` computes ahead when its step is not
#: kept: the recursion does not depend on the data, and computed back to back (instead of one
#: per loop iteration, between the simulator's and the controller's code) its Python and
#: numpy code stays in the CPU caches: about 20 instead of 45 us per step (2 states, in a
#: Monte Carlo loop).
_AHEAD_STEPS = 32

_Step = tuple[FloatArray, FloatArray, FloatArray]  # (S, K, P) of a shared covariance step
#: Entries up to which :func:`_finite` sums Python floats instead of a BLAS dot.
_SMALL = 32


def _finite(a: FloatArray) -> bool:
    """:func:`~filters._linalg.all_finite` of a float64 array, for a small one (a batch of
    one's state, measurement or input) as a sum of Python floats (finite only if every entry
    is; a sum that overflows falls through to the exact test): half the time of a dot."""
    if a.size <= _SMALL:
        return math.isfinite(sum(a.ravel().tolist())) or bool(np.isfinite(a).all())
    return all_finite(a)


class CovarianceMemo:
    """Shared-covariance steps of :class:`KalmanFilter` batches, shared between batches.

    A batch whose members share one covariance computes the covariance recursion once per
    step. Batches of one study that start from the same ``P0`` with the same model (the
    lanes of a Monte Carlo, stepped in parallel threads, and its successive batches)
    compute the same sequence; filters given one memo with
    :meth:`KalmanFilter.share_covariance_memo` look a step up here before computing it
    and keep what they computed, so each step is computed once for all of them.

    An entry is keyed as a filter's own memo: the bytes of the shared posterior
    covariance, within the filter's model (``F``, ``H``, ``Q``, ``R`` and the number of
    batch axes; filters of other models get tables of their own). Its value is what the
    computation gives for that covariance (a function of it alone; only a step that
    passed its checks is kept), so results are bitwise the same with or without a memo.

    Parameters
    ----------
    max_steps : int
        Entries kept per model (default 65,536, about 30 MB for 8 states); once full, no
        more are added (nothing is evicted).

    Notes
    -----
    Thread safety: one lock guards the look-up and the computation of a missing step, so
    filters in several threads compute a step once (a thread that finds it missing while
    another computes it waits, the GIL released, instead of computing it again). Meant
    to live for one study (its owner drops it afterwards), not as a process-wide cache.
    """

    def __init__(self, max_steps: int = 1 << 16) -> None:
        if isinstance(max_steps, bool) or int(max_steps) != max_steps or max_steps < 0:
            raise ValueError(f"max_steps must be a non-negative integer, got {max_steps!r}")
        self.max_steps = int(max_steps)
        self._tables: dict[bytes, dict[bytes, _Step]] = {}
        self.lock = threading.Lock()

    def table(self, model: bytes) -> dict[bytes, _Step]:
        """The table of one model (created on first use): ``P`` bytes -> ``(S, K, P)``."""
        with self.lock:
            return self._tables.setdefault(model, {})

    def step(self, table: dict[bytes, _Step], key: bytes,
             compute: Callable[[], _Step]) -> _Step:
        """The entry ``key`` of ``table`` (one of :meth:`table`), else ``compute()``, kept
        while the table has room; under the lock (a step raising in ``compute`` is not
        kept)."""
        with self.lock:
            done = table.get(key)
            if done is None:
                done = compute()
                if len(table) < self.max_steps:
                    table[key] = done
            return done

    def __len__(self) -> int:
        """Entries over all models."""
        with self.lock:
            return sum(len(t) for t in self._tables.values())


class _SampledFilter:
    """State, time keeping and input validation shared by the Kalman filters."""

    name: ClassVar[str] = ""
    #: Every filter of this library takes a leading batch axis (:class:`filters.base.Batched`).
    batched: ClassVar[bool] = True

    _n: int
    _m: int
    _k: int
    _dt: float | None

    # ------------------------------------------------------------------ state
    def reset(self, x0: npt.ArrayLike, P0: npt.ArrayLike) -> None:
        """Re-initialize the estimate and set ``t_s = 0``.

        Parameters
        ----------
        x0 : array_like, shape (n,) or (..., n)
            Initial state mean; leading axes define the batch.
        P0 : array_like, shape (n, n) or (..., n, n)
            Initial covariance (symmetric PSD), broadcast against the batch of ``x0``.

        Raises
        ------
        ValueError
            If ``x0`` or ``P0`` has the wrong shape, is non-finite, or ``P0`` is not
            symmetric PSD, or their batch shapes do not broadcast.
        """
        n = self._n
        x = to_float_array("x0", x0)
        if x.ndim < 1 or x.shape[-1] != n:
            raise ValueError(f"x0 must have shape ({n},) or (..., {n}), got shape {x.shape}")
        if not np.isfinite(x).all():
            raise ValueError(f"x0 must be finite with shape (..., {n}), got non-finite entries")
        P = batch_symmetric_psd("P0", to_float_array("P0", P0), n)
        try:
            batch = np.broadcast_shapes(x.shape[:-1], P.shape[:-2])
        except ValueError as exc:
            raise ValueError(
                f"x0 batch shape {x.shape[:-1]} and P0 batch shape {P.shape[:-2]} do not broadcast"
            ) from exc
        self._batch = batch
        self._x = readonly(np.array(np.broadcast_to(x, (*batch, n))))
        self._P = readonly(np.array(np.broadcast_to(P, (*batch, n, n))))
        self._steps = 0
        self.innovation: FloatArray | None = None

    @property
    def x(self) -> FloatArray:
        """Current state estimate, shape ``(..., n)`` (read-only)."""
        return self._x

    @property
    def P(self) -> FloatArray:
        """Current error covariance, shape ``(..., n, n)`` (read-only)."""
        return self._P

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading batch axes of ``x`` (``()`` for a single filter)."""
        return self._batch

    @property
    def t_s(self) -> float:
        """Filter time in seconds (number of steps if the sample period is unknown)."""
        return self._time(self._steps)

    def _time(self, steps: int) -> float:
        return steps * self._dt if self._dt is not None else float(steps)

    def _check_state(self, x: FloatArray, steps: int) -> None:
        """Raise :class:`FiniteEscapeError` (quantity ``"x"``) if ``x`` is not finite."""
        if x.ndim == 1:  # fast: Python float sum (overflow of finite entries falls through)
            if math.isfinite(sum(x.tolist())) or np.isfinite(x).all():
                return
        elif _finite(x):
            return
        raise FiniteEscapeError("state estimate became non-finite", time=self._time(steps),
                                quantity="x", value=np.array(x))

    def _commit(self, x: FloatArray, P: FloatArray, steps: int) -> None:
        x.flags.writeable = False
        P.flags.writeable = False
        self._x = x
        self._P = P
        self._steps = steps

    # ------------------------------------------------------------ validation
    def _vector(self, name: str, v: npt.ArrayLike, dim: int) -> FloatArray:
        """Validate ``y`` or ``u``: shape ``(dim,)`` or broadcastable ``(..., dim)``, finite;
        C-contiguous (numpy's batched products take another kernel for a strided batch: a
        member would differ in the last bit from the same filter alone)."""
        if type(v) is not np.ndarray or v.dtype != np.float64:
            v = to_float_array(name, v)
        if not self._batch:
            if v.shape != (dim,):
                if v.shape == () and dim == 1:
                    v = v.reshape(1)
                else:
                    raise ValueError(f"{name} must have shape ({dim},), got shape {v.shape}")
            if not math.isfinite(sum(v.tolist())) and not np.isfinite(v).all():
                raise ValueError(f"{name} must be finite, got {v}")
            return v
        full = (*self._batch, dim)
        if v.shape != full:
            try:
                ok = v.ndim >= 1 and np.broadcast_shapes(v.shape, full) == full
            except ValueError:
                ok = False
            if not ok:
                raise ValueError(
                    f"{name} must have shape ({dim},) or {full} for batch shape {self._batch}, "
                    f"got shape {v.shape}"
                )
        if not all_finite(v):
            raise ValueError(f"{name} must be finite, got non-finite entries")
        return np.ascontiguousarray(v)

    def _input(self, u: npt.ArrayLike | None) -> FloatArray | None:
        """Validate ``u`` (``None`` = zero input); returns ``None`` when it has no effect."""
        if u is None:
            return None
        if self._k == 0:
            arr = to_float_array("u", u)
            if arr.size == 0:
                return None
            raise ValueError(f"u must be None: the system has no input (k = 0), got {arr.shape}")
        return self._vector("u", u, self._k)


class _IntegratedFilter(_SampledFilter):
    """A sampled filter whose equations are integrated over each interval by RK4 substeps."""

    _t0: float = 0.0
    _substeps: int

    @property
    def dt_s(self) -> float:
        """Sample interval in seconds."""
        return self._dt  # type: ignore[return-value]

    @property
    def t0(self) -> float:
        """Initial time in seconds (:meth:`reset` returns to it)."""
        return self._t0

    @property
    def substeps(self) -> int:
        """RK4 substeps of the last (``"auto"``) or every sample interval."""
        return self._substeps

    def suggested_substeps(self) -> int:
        """Stiffness-based RK4 substeps for the next interval (see the subclasses)."""
        raise NotImplementedError

    def _auto_substeps_now(self) -> int:
        """``suggested_substeps()`` for the next interval, at most :data:`MAX_AUTO_SUBSTEPS`.

        Raises
        ------
        SubstepLimitError
            Past the cap (the filter is unchanged).
        """
        n = self.suggested_substeps()
        if n > MAX_AUTO_SUBSTEPS:
            raise SubstepLimitError(
                f"substeps='auto' needs {n} RK4 substeps for the interval of {self._dt:g} s, "
                f"more than the cap MAX_AUTO_SUBSTEPS = {MAX_AUTO_SUBSTEPS} (the equations are "
                "too stiff at this covariance: use a smaller P0 or an explicit integer substeps)",
                time=self.t_s, quantity="substeps", value=float(n))
        return n


class KalmanFilter(_SampledFilter):
    """Discrete-time Kalman filter with Joseph-form covariance update.

    Parameters
    ----------
    system : DiscreteLinearSystem
        ``x_{k+1} = F x_k + B u_k + w_k``, ``y_k = H x_k + D u_k + v_k``.
    x0 : array_like, shape (n,) or (..., n)
        Initial mean (leading axes: batch of independent filters).
    P0 : array_like, shape (n, n) or (..., n, n)
        Initial covariance, broadcast to the batch.

    Attributes
    ----------
    name : str
        ``"kalman"``.
    x : numpy.ndarray, shape (..., n)
        State estimate (a posteriori after :meth:`update`/:meth:`step`, a priori after
        :meth:`predict`).
    P : numpy.ndarray, shape (..., n, n)
        Error covariance of ``x``.
    t_s : float
        ``steps * system.dt_s`` (or the number of predictions if ``dt_s`` is None).
    innovation : numpy.ndarray, shape (..., m), or None
        ``y - H x_prior - D u`` of the last update.
    innovation_cov : numpy.ndarray, shape (..., m, m), or None
        ``H P_prior H^T + R`` of the last update.
    gain : numpy.ndarray, shape (..., n, m), or None
        Kalman gain of the last update.

    Notes
    -----
    Unbatched filters use a fast path: ``ndarray.dot``, a LAPACK Cholesky solve for the
    gain, and the Joseph form evaluated as a Gram matrix
    ``(I-KH) P (I-KH)^T + K R K^T = V^T V`` with ``V = [U_P (I-KH)^T; U_R K^T]``
    (``U`` upper Cholesky factors), which BLAS ``syrk`` returns exactly symmetric and
    PSD by construction (a singular prior falls back to the explicit Joseph product
    plus symmetrization). Batched filters use broadcasting ``matmul``,
    ``numpy.linalg.solve`` and the explicit Joseph product, symmetrized. Both agree to
    rounding (~1e-15 relative).

    ``P`` does not depend on the data: a batch whose members share one covariance (one
    ``P0``) computes the covariance recursion, the gain and the covariance check once, on one
    member broadcast against the means (the same operations on the same numbers as member
    by member, hence the same results and errors); ``P``, ``gain`` and ``innovation_cov``
    are still the stacks of all members. Such a covariance usually settles into a fixed
    point or a short cycle of floating-point values: :meth:`step` keeps its last 16 steps'
    results and reuses them for a bitwise equal covariance instead of recomputing them.
    Since the recursion does not depend on the data, :meth:`step` computes up to 31 steps
    ahead when it computes one (kept like the others; a step ahead that fails or would warn
    is dropped, then computed, and raises or warns, at its own time).
    """

    name: ClassVar[str] = "kalman"

    def __init__(self, system: DiscreteLinearSystem, x0: npt.ArrayLike, P0: npt.ArrayLike) -> None:
        if not isinstance(system, DiscreteLinearSystem):
            raise TypeError(f"system must be a DiscreteLinearSystem, got {type(system).__name__}")
        self._system = system
        self._n, self._m, self._k = system.n, system.m, system.k
        self._dt = system.dt_s
        self._F = system.F
        self._FT = np.ascontiguousarray(system.F.T)
        self._B = system.B
        self._BT = np.ascontiguousarray(system.B.T)  # type: ignore[union-attr]
        self._H = system.H
        self._D = system.D
        self._HT = np.ascontiguousarray(system.H.T)
        self._DT = np.ascontiguousarray(system.D.T) if np.any(system.D) else None  # type: ignore[union-attr]
        self._Q = system.Q
        self._R = system.R
        self._UR = np.linalg.cholesky(system.R).T  # R = U_R^T U_R
        self._I = np.eye(self._n)
        self._covariance_memo: CovarianceMemo | None = None
        self._memo_table: dict[bytes, _Step] | None = None
        self.reset(x0, P0)

    @property
    def system(self) -> DiscreteLinearSystem:
        """The filter model."""
        return self._system

    # A batch whose members share one covariance keeps the gain and innovation covariance as
    # that one member and makes the stack of copies only when it is read (most loops never
    # read them): the same values, without two stack copies per step.
    def _stacked(self, name: str) -> FloatArray | None:
        """The attribute ``name`` (a gain or innovation covariance, or None), as the stack
        of the batch's members: made from the shared member once, when first read."""
        M = getattr(self, name)
        if M is not None and M.shape[:-2] != self._batch:
            M = self._members(M)
            setattr(self, name, M)
        return M

    @property
    def shared_P(self) -> FloatArray | None:
        """The covariance every member of a batch shares, shape ``(n, n)`` (read-only), or
        None (a single filter, or members whose covariances differ): :attr:`P` is then this
        matrix repeated, and what is computed from one covariance can be computed once."""
        shared = self._P_shared
        return None if shared is None else shared.reshape(shared.shape[-2:])

    @property
    def shared_innovation_cov(self) -> FloatArray | None:
        """The innovation covariance of the last update that every member of a batch
        shares, shape ``(m, m)`` (do not write it: copy it), or None (no update yet, a single
        filter, or a batch of several members whose stack :attr:`innovation_cov` holds):
        what :attr:`innovation_cov` repeats, without making the stack."""
        S = self._innovation_cov
        if S is None or not self._batch:
            return None
        if S.shape[:-2] != self._batch or math.prod(self._batch) == 1:
            return S.reshape(S.shape[-2:])
        return None

    @property
    def gain(self) -> FloatArray | None:
        """Kalman gain of the last update, shape ``(..., n, m)``, or None."""
        return self._stacked("_gain")

    @gain.setter
    def gain(self, K: FloatArray | None) -> None:
        self._gain = K

    @property
    def innovation_cov(self) -> FloatArray | None:
        """``H P_prior H^T + R`` of the last update, shape ``(..., m, m)``, or None."""
        return self._stacked("_innovation_cov")

    @innovation_cov.setter
    def innovation_cov(self, S: FloatArray | None) -> None:
        self._innovation_cov = S

    def reset(self, x0: npt.ArrayLike, P0: npt.ArrayLike) -> None:
        """Re-initialize ``x``, ``P`` and ``t_s = 0`` (see :meth:`_SampledFilter.reset`).

        Parameters
        ----------
        x0 : array_like, shape (n,) or (..., n)
        P0 : array_like, shape (n, n) or (..., n, n)
        """
        super().reset(x0, P0)
        self._innovation_cov: FloatArray | None = None
        self._gain: FloatArray | None = None
        self._P_shared = self._shared(self._P)
        # the exact shapes of a whole batch's y and u (the fast path of step) and of P
        batch = self._batch
        self._y_shape = (*batch, self._m)
        self._u_shape = (*batch, self._k)
        self._P_shape = self._P.shape
        self._one = bool(batch) and math.prod(batch) == 1  # a batch of one
        # shared posterior covariance (bytes) -> the next step's S, K and posterior covariance
        self._memo: dict[bytes, _Step] = {}
        # the shared memo's table for this model and batch rank (reset may change the rank)
        self._memo_table = (None if self._covariance_memo is None
                            else self._covariance_memo.table(self._model_key()))

    def share_covariance_memo(self, memo: CovarianceMemo | None) -> None:
        """Look shared-covariance steps up in ``memo`` and keep computed ones there (see
        :class:`CovarianceMemo`); None: this filter's own memo only.

        Parameters
        ----------
        memo : CovarianceMemo or None
            Filters of one study, in one thread or several, may share one memo; the
            results do not depend on it (bitwise).
        """
        if memo is not None and not isinstance(memo, CovarianceMemo):
            raise TypeError(f"memo must be a CovarianceMemo or None, got {type(memo).__name__}")
        self._covariance_memo = memo
        self._memo_table = None if memo is None else memo.table(self._model_key())

    def _model_key(self) -> bytes:
        """What a shared-covariance step depends on besides ``P``: the model's matrices
        (shapes and values) and the number of batch axes (the shape of the shared member)."""
        parts = [np.asarray(len(self._batch), dtype=np.int64).tobytes()]
        for M in (self._F, self._H, self._Q, self._R):
            A = np.ascontiguousarray(M, dtype=float)
            parts += [np.asarray(A.shape, dtype=np.int64).tobytes(), A.tobytes()]
        return b"|".join(parts)

    # ------------------------------------------------------------- public API
    def predict(self, u: npt.ArrayLike | None = None) -> FloatArray:
        """Time update ``x <- F x + B u``, ``P <- F P F^T + Q``; advances ``t_s``.

        Only the cheap escape test runs here (``FiniteEscapeError`` if ``P`` is
        non-finite or its Frobenius norm exceeds 1e12 and an entry does); ``F P F^T + Q``
        is PSD whenever ``P`` is, and the full :func:`~filters.errors.check_covariance`
        runs in :meth:`update`. The a-priori ``P`` is symmetric only to rounding
        (~1e-16 relative); :meth:`update` returns an exactly symmetric ``P``.

        Parameters
        ----------
        u : array_like, shape (k,) or (..., k), or None
            Input held over the interval (``None``: zero).

        Returns
        -------
        numpy.ndarray, shape (..., n)
            The a-priori state.
        """
        u = self._input(u)
        x, P = self._predict(u)
        steps = self._steps + 1
        self._check_state(x, steps)
        shared = P if P.shape != self._P.shape else None
        if shared is not None:  # the escape test below reads the whole stack
            P = self._members(shared)
        v = P.ravel()
        if not v.dot(v) <= _ESCAPE_BOUND_SQ:  # cheap escape test; NaN compares False
            check_covariance(P, time=self._time(steps), quantity="P", escape_bound=_ESCAPE_BOUND)
        self._commit(x, P, steps)
        self._P_shared = shared
        return x

    def update(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """Measurement update (Joseph form) with ``y`` at the current time ``t_s``.

        Parameters
        ----------
        y : array_like, shape (m,) or (..., m)
            Measurement.
        u : array_like, shape (k,) or (..., k), or None
            Input, used only for the feedthrough ``D u`` (ignored if ``D = 0``).

        Returns
        -------
        numpy.ndarray, shape (..., n)
            The a-posteriori state.

        Raises
        ------
        ValueError
            If ``y`` (or ``u``) has the wrong shape or is non-finite; state unchanged.
        LossOfDefinitenessError, FiniteEscapeError
            If the updated covariance fails :func:`filters.errors.check_covariance`, or the
            state becomes non-finite (``quantity="x"``); state unchanged.
        """
        y = self._vector("y", y, self._m)
        u = self._input(u) if self._DT is not None else None
        P = self._P if self._P_shared is None else self._P_shared
        x, P = self._update(self._x, P, y, u, self._steps)
        self._commit_shared(x, P, self._steps)
        return x

    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """One in-the-loop cycle: :meth:`predict` with ``u``, then :meth:`update` with ``y``.

        Parameters
        ----------
        y : array_like, shape (m,) or (..., m)
            Measurement at the end of the interval.
        u : array_like, shape (k,) or (..., k), or None
            Input applied over the interval.

        Returns
        -------
        numpy.ndarray, shape (..., n)
            The a-posteriori state (same object as :attr:`x`).

        Raises
        ------
        ValueError
            If ``y`` or ``u`` has the wrong shape, is complex or non-finite; state unchanged.
        LossOfDefinitenessError, FiniteEscapeError
            As :meth:`update` (``quantity`` ``"P"``, ``"innovation_cov"`` or ``"x"``, with
            the time of the step); state unchanged.
        """
        shared = self._P_shared
        if shared is not None:
            return self._shared_step(shared, y, u)
        y = self._vector("y", y, self._m)
        u = self._input(u)
        steps = self._steps + 1
        xp, Pp = self._predict(u)
        x, P = self._update(xp, Pp, y, u if self._DT is not None else None, steps)
        self._commit_shared(x, P, steps)
        return x

    def steady_state(self) -> tuple[FloatArray, FloatArray]:
        """Stationary a-priori covariance and gain from the discrete algebraic Riccati equation.

        Returns
        -------
        P_pred_inf : numpy.ndarray, shape (n, n)
            Solution of ``P = F P F^T - F P H^T (H P H^T + R)^-1 H P F^T + Q``.
        K_inf : numpy.ndarray, shape (n, m)
            ``P H^T (H P H^T + R)^-1``, the limit of :attr:`gain`.
        """
        s = self._system
        P = solve_discrete_are(s.F.T, s.H.T, s.Q, s.R)
        P = 0.5 * (P + P.T)
        K = np.linalg.solve(s.H @ P @ s.H.T + s.R, s.H @ P).T
        return P, K

    def shared_covariance_step(self, P: FloatArray, steps: int) -> _Step:
        """The innovation covariance, gain and posterior covariance of the :meth:`step` that
        follows the shared posterior covariance ``P``: the arrays :meth:`step` itself uses
        (kept and reused as it keeps them; read-only, never written).

        The covariance recursion does not depend on the data: a caller that steps the mean
        itself (``testbed replay`` over a whole recording) takes them from here.

        Parameters
        ----------
        P : numpy.ndarray, shape (n, n)
            A shared posterior covariance (:attr:`shared_P`, or the ``P`` this returned).
        steps : int
            The number of the step (its time ``steps * dt_s`` in a raised error).

        Returns
        -------
        S : numpy.ndarray, shape (m, m)
        K : numpy.ndarray, shape (n, m)
        P : numpy.ndarray, shape (n, n)

        Raises
        ------
        LossOfDefinitenessError, FiniteEscapeError
            As :meth:`step` at that step.
        """
        return self._shared_covariance_step(P, steps)

    # -------------------------------------------------------------- internals
    def _shared(self, P: FloatArray) -> FloatArray | None:
        """The member every filter of a batch shares, shape ``(n, n)``, or None.

        ``P`` does not depend on the data: the members of a batch that start from one ``P0``
        keep one covariance, computed once on this member (a view of the stack). It is kept
        as one matrix, without the stack's batch axes: ``matmul`` and ``linalg.solve`` make the
        same per-matrix BLAS/LAPACK calls for ``(n, n)`` as for ``(1, ..., 1, n, n)``
        operands, and it broadcasts against the batch all the same.
        """
        if not self._batch:
            return None
        if math.prod(self._batch) == 1:  # a batch of one: its member (the same operations)
            return P.reshape(P.shape[-2:])
        first = shared_member(P)
        if first.shape == P.shape:  # members that differ
            return None
        return first.reshape(P.shape[-2:])

    def _shared_step(self, P: FloatArray, y: npt.ArrayLike,
                     u: npt.ArrayLike | None) -> FloatArray:
        """:meth:`step` of a batch whose members share the posterior covariance ``P``.

        A ``float64`` ``y`` (and ``u``) of exactly the batch's shape needs only its finiteness
        test (:meth:`_vector` raises when it fails); other inputs are validated in full.
        """
        if (type(y) is np.ndarray and y.dtype == np.float64 and y.shape == self._y_shape
                and (u is None or (type(u) is np.ndarray and u.dtype == np.float64
                                   and u.shape == self._u_shape and self._k > 0))):
            if not (_finite(y) and (u is None or _finite(u))):
                self._vector("y", y, self._m)  # raises for y, else:
                self._input(u)  # raises for u
        else:
            y = self._vector("y", y, self._m)
            u = self._input(u)
        steps = self._steps + 1
        S, K, P = self._shared_covariance_step(P, steps)
        x = self._correct(self._predict_state(u), y,  # type: ignore[arg-type]
                          u if self._DT is not None else None, S, K, steps)
        # commit: the stack of the shared member (the kept P is never written): a batch of
        # one's is a view of it, a larger batch's a new array
        if self._one:
            stack = P.reshape(self._P_shape)
        else:
            stack = np.empty(self._P_shape)
            stack[...] = P
        self._commit(x, stack, steps)
        self._P_shared = P
        return x

    def _commit_shared(self, x: FloatArray, P: FloatArray, steps: int) -> None:
        """:meth:`_commit` of a covariance that may be the batch's shared member."""
        shared = None
        if P.shape != self._P.shape:
            shared = P
            P = self._members(shared)
        self._commit(x, P, steps)
        self._P_shared = shared

    def _predict(self, u: FloatArray | None) -> tuple[FloatArray, FloatArray]:
        """Pure time update; a batch's shared covariance stays its one member."""
        if not self._batch:  # fast path: ndarray.dot has far less overhead than matmul
            F, P = self._F, self._P
            x = F.dot(self._x)
            if u is not None:
                x += self._B.dot(u)
            P = F.dot(P).dot(self._FT)
            P += self._Q
            return x, P
        P = self._P if self._P_shared is None else self._P_shared
        return self._predict_state(u), self._predict_covariance(P)

    def _predict_state(self, u: FloatArray | None) -> FloatArray:
        """``F x + B u`` of a batch."""
        x = np.vecmat(self._x, self._FT)
        if u is not None:
            x += np.vecmat(u, self._BT)
        return x

    def _predict_covariance(self, P: FloatArray) -> FloatArray:
        """``F P F^T + Q`` of a batch's stack or shared member."""
        P = self._F @ P @ self._FT
        P += self._Q
        return P

    def _shared_covariance_step(
        self, P: FloatArray, steps: int
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Innovation covariance, gain and posterior covariance of one :meth:`step` from the
        shared posterior covariance ``P`` (shape ``(n, n)``).

        A function of ``P`` alone: the results for the last :data:`_MEMO_STEPS` values of
        ``P``, and for up to :data:`_AHEAD_STEPS` - 1 steps computed ahead, are kept and
        returned for a bitwise equal ``P`` (the same numbers the computation gives; only a
        computation that passed its checks is kept). The kept arrays are never written: the
        public ``P``, ``gain`` and ``innovation_cov`` are copies. A step not among those is
        looked up in the :class:`CovarianceMemo` given to :meth:`share_covariance_memo`
        (other batches or threads may have computed it), and a computed one is kept there
        too; then the following steps are computed (or looked up) ahead (:meth:`_run_ahead`).
        """
        key = P.tobytes()
        done = self._memo.get(key)
        if done is None:
            done = self._computed_step(P, key, steps)  # raises: nothing kept
            self._run_ahead(done[2], steps)
        return done

    def _computed_step(self, P: FloatArray, key: bytes, steps: int) -> _Step:
        """The step from ``P`` (bytes ``key``): looked up in the :class:`CovarianceMemo` or
        computed (and kept there), then kept in the filter's own memo."""
        def compute() -> _Step:
            return self._gain_and_covariance(self._predict_covariance(P), steps)

        table = self._memo_table
        done = (compute() if table is None
                else self._covariance_memo.step(table, key, compute))  # type: ignore[union-attr]
        for kept in done:  # never written: read-only, and so every view of it (shared_P)
            kept.flags.writeable = False
        own = self._memo
        if len(own) >= _MEMO_STEPS + _AHEAD_STEPS:
            del own[next(iter(own))]  # the oldest
        own[key] = done
        return done

    def _run_ahead(self, P: FloatArray, steps: int) -> None:
        """Compute and keep the next ``_AHEAD_STEPS - 1`` steps from the posterior ``P`` of
        step ``steps``, up to one already kept, one that fails or one that would warn.

        Each is the step that :meth:`step` would compute from the same ``P`` (the same
        numbers). A step that raises is not kept and stops the run, as does one setting a
        floating-point flag that is not ignored (``numpy.errstate`` turned to ``"raise"``):
        :meth:`step` then computes it at its own time, raising or warning there.
        """
        strict = {k: "ignore" if v == "ignore" else "raise" for k, v in np.geterr().items()}
        own = self._memo
        try:
            with np.errstate(**strict):
                for ahead in range(1, _AHEAD_STEPS):
                    key = P.tobytes()
                    if key in own:
                        return
                    P = self._computed_step(P, key, steps + ahead)[2]
        except Exception:  # noqa: BLE001, S110 (computed again at its time, and raised there)
            pass

    def _update(
        self, x: FloatArray, P: FloatArray, y: FloatArray, u: FloatArray | None, steps: int
    ) -> tuple[FloatArray, FloatArray]:
        """Pure update; sets the diagnostics only after the covariance check passed."""
        H, R = self._H, self._R
        if not self._batch:
            innov = y - H.dot(x)
            if u is not None:
                innov -= self._D.dot(u)
            PHT = P.dot(self._HT)
            S = H.dot(PHT)
            S += R
            c, info = _dpotrf(S)
            if info != 0:
                self._raise_innovation_cov(S, steps)
            K = _dpotrs(c, PHT.T)[0].T
            x = x + K.dot(innov)
            IKH = self._I - K.dot(H)
            Up, info = _dpotrf(P)  # P = Up^T Up (reads the upper triangle)
            if info == 0:
                # Joseph form as a Gram matrix: (I-KH) P (I-KH)^T + K R K^T = V^T V with
                # V = [Up (I-KH)^T; U_R K^T]. ndarray.dot uses BLAS syrk for V^T V, so
                # the result is exactly symmetric and needs no symmetrization.
                n = self._n
                VT = np.empty((n + self._m, n))
                np.dot(Up, IKH.T, out=VT[:n])
                np.dot(self._UR, K.T, out=VT[n:])
                P = VT.T.dot(VT)
                check_symmetric_covariance(P, time=self._time(steps), quantity="P")
                self._check_state(x, steps)
                self.innovation, self.innovation_cov, self.gain = innov, S, K
                return x, P
            # singular prior: explicit Joseph form, symmetrized by check_covariance below
            P = IKH.dot(P).dot(IKH.T) + K.dot(R).dot(K.T)
        else:
            S, K, P = self._gain_and_covariance(P, steps)
            return self._correct(x, y, u, S, K, steps), P
        P = check_covariance(P, time=self._time(steps), quantity="P")
        self._check_state(x, steps)
        self.innovation, self.innovation_cov, self.gain = innov, S, K
        return x, P

    def _gain_and_covariance(
        self, P: FloatArray, steps: int
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Innovation covariance, gain and checked posterior covariance of a batch's update.

        ``P`` (prior) is the stack, or the one member a batch shares (the same operations on
        the same numbers as member by member, hence the same results); so are the results.
        """
        H, R = self._H, self._R
        PHT = P @ self._HT
        S = H @ PHT
        S += R  # (in place: the same sum as H @ PHT + R)
        try:
            K = np.linalg.solve(S, PHT.mT).mT  # .mT: swapaxes(-1, -2), no Python call
        except np.linalg.LinAlgError:
            self._raise_innovation_cov(self._members(S), steps)
        IKH = K @ H
        np.subtract(self._I, IKH, out=IKH)  # I - K H
        P = IKH @ P @ IKH.mT
        P += K @ R @ K.mT
        P = check_shared_covariance(P, self._batch, time=self._time(steps), quantity="P")
        return S, K, P

    def _correct(self, x: FloatArray, y: FloatArray, u: FloatArray | None, S: FloatArray,
                 K: FloatArray, steps: int) -> FloatArray:
        """A batch's a-posteriori state from the prior ``x`` and the gain ``K`` (checked); sets
        the diagnostics (``S`` and ``K`` may be the members' shared ones)."""
        innov = y - np.vecmat(x, self._HT)
        if u is not None:
            innov -= np.vecmat(u, self._DT)  # type: ignore[operator]
        x = x + (K @ innov[..., None])[..., 0]
        self._check_state(x, steps)
        # the shared S and K (never written) as they are: stacked when read (the properties)
        self.innovation, self._innovation_cov, self._gain = innov, S, K
        return x

    def _members(self, M: FloatArray) -> FloatArray:
        """``M``, a batch's stack or the member its filters share, as the stack.

        Returns ``M`` itself when it is the stack, else a new C-contiguous stack of copies.
        """
        full = (*self._batch, *M.shape[-2:])
        if M.shape == full:
            return M
        stack = np.empty(full)
        stack[...] = M  # (faster than a copy of np.broadcast_to)
        return stack

    def _raise_innovation_cov(self, S: FloatArray, steps: int) -> NoReturn:
        """Raise the typed error for an innovation covariance that cannot be factored."""
        if not np.isfinite(S).all():
            raise FiniteEscapeError(
                "innovation covariance H P H^T + R is non-finite",
                time=self._time(steps),
                quantity="innovation_cov",
                value=S,
            )
        raise LossOfDefinitenessError(
            "innovation covariance H P H^T + R is not positive definite",
            time=self._time(steps),
            quantity="innovation_cov",
            value=S,
        )


class KalmanBucyFilter(_IntegratedFilter):
    """Continuous-time Kalman-Bucy filter driven by sampled (interval-averaged) measurements.

    Over each sample interval ``[t, t + dt]`` it integrates::

        dm/dt = A m + B u + P C^T R^-1 (y - C m - D u)
        dP/dt = A P + P A^T + Q - P C^T R^-1 C P

    with ``u`` and ``y`` held constant (zero-order hold). ``y`` is the sampled
    average of ``dy/dt`` over the interval (covariance ``R / dt``, see
    :meth:`filters.models.LinearSystem.discretize`).

    Parameters
    ----------
    system : LinearSystem
        Continuous-time model; ``Q`` and ``R`` are intensities.
    x0 : array_like, shape (n,) or (..., n)
        Initial mean (leading axes: batch).
    P0 : array_like, shape (n, n) or (..., n, n)
        Initial covariance, broadcast to the batch.
    dt_s : float
        Sample interval in seconds.
    substeps : int or "auto"
        Classical Runge-Kutta (RK4) steps per interval on the joint ``(m, P)``
        system. The method has global order 4: the error per interval scales as
        ``(dt / substeps)^4``. ``"auto"`` picks, at the start of every interval,
        :meth:`suggested_substeps` at the current ``P`` (accurate sensors make the Riccati
        equation stiff: explicit RK4 needs ``h |rate| < 2.8``), at most
        :data:`MAX_AUTO_SUBSTEPS` (beyond it :meth:`step` raises
        :class:`~filters.errors.SubstepLimitError`).

    Attributes
    ----------
    name : str
        ``"kalman-bucy"``.
    x, P, t_s
        As in :class:`KalmanFilter`; ``t_s = steps * dt_s``.
    innovation : numpy.ndarray, shape (..., m), or None
        ``y - C m - D u`` at the start of the last interval.

    Notes
    -----
    After each RK4 substep ``P`` is symmetrized and checked with
    :func:`filters.errors.check_covariance` (time = end of the substep), so an
    unstable step size surfaces as :class:`LossOfDefinitenessError` or
    :class:`FiniteEscapeError`. A non-finite mean raises ``FiniteEscapeError``
    with ``quantity="x"``.

    ``P`` does not depend on the data: a batch whose members share one covariance (one
    ``P0``) integrates the Riccati equation once, on one member broadcast against the means
    (the same operations on the same numbers as member by member, the same checks).
    """

    name: ClassVar[str] = "kalman-bucy"

    def __init__(
        self,
        system: LinearSystem,
        x0: npt.ArrayLike,
        P0: npt.ArrayLike,
        dt_s: float,
        substeps: int | str = 1,
    ) -> None:
        if not isinstance(system, LinearSystem):
            raise TypeError(f"system must be a LinearSystem, got {type(system).__name__}")
        self._auto_substeps = substeps == "auto"
        if self._auto_substeps:
            substeps = 1
        elif (isinstance(substeps, bool) or not isinstance(substeps, int | np.integer)
              or substeps < 1):
            raise ValueError(f"substeps must be an integer >= 1 or 'auto', got {substeps!r}")
        self._system = system
        self._n, self._m, self._k = system.n, system.m, system.k
        self._dt = positive_time("dt_s", dt_s)
        self._substeps = int(substeps)
        self._A = system.A
        self._AT = np.ascontiguousarray(system.A.T)
        self._BT = np.ascontiguousarray(system.B.T)  # type: ignore[union-attr]
        self._CT = np.ascontiguousarray(system.C.T)
        self._DT = np.ascontiguousarray(system.D.T) if np.any(system.D) else None  # type: ignore[union-attr]
        self._Q = system.Q
        # R = L L^T; R^-1 = L^-T L^-1. With W = P C^T L^-T: P C^T R^-1 C P = W W^T and
        # P C^T R^-1 e = W (L^-1 e), so the Riccati right-hand side is symmetric by design.
        Linv = np.linalg.inv(np.linalg.cholesky(system.R))
        self._Linv = Linv
        self._LinvT = np.ascontiguousarray(Linv.T)
        self._C = system.C
        self._CtLinvT = np.ascontiguousarray(system.C.T @ Linv.T)
        self.reset(x0, P0)

    @property
    def system(self) -> LinearSystem:
        """The filter model."""
        return self._system


    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """Integrate the filter over one sample interval with ``u`` and ``y`` held.

        Parameters
        ----------
        y : array_like, shape (m,) or (..., m)
            Interval-averaged observation rate ``dy/dt``.
        u : array_like, shape (k,) or (..., k), or None
            Input held over the interval (``None``: zero).

        Returns
        -------
        numpy.ndarray, shape (..., n)
            The state estimate at the end of the interval (same object as :attr:`x`).

        Raises
        ------
        ValueError
            If ``y`` or ``u`` has the wrong shape or is non-finite; state unchanged.
        LossOfDefinitenessError, FiniteEscapeError
            If ``P`` fails the check after a substep, or ``x`` becomes non-finite;
            state unchanged.
        SubstepLimitError
            ``substeps="auto"`` would exceed :data:`MAX_AUTO_SUBSTEPS`; state unchanged.
        """
        y = self._vector("y", y, self._m)
        u = self._input(u)
        ybar, Bu = y, None
        if u is not None:
            Bu = np.vecmat(u, self._BT)
            if self._DT is not None:
                ybar = y - np.vecmat(u, self._DT)
        m, P = self._x, self._P
        if self._auto_substeps:
            self._substeps = self._auto_substeps_now()
        h = self._dt / self._substeps  # type: ignore[operator]
        t0 = self.t_s
        innovation = ybar - np.vecmat(m, self._CT)
        # P does not depend on the data: members that share it (one P0) keep sharing it, and
        # its equation is integrated once, on the first member, broadcast against the means
        P = shared_member(P)
        for i in range(self._substeps):
            k1m, k1P = self._rhs(m, P, ybar, Bu)
            k2m, k2P = self._rhs(m + 0.5 * h * k1m, P + 0.5 * h * k1P, ybar, Bu)
            k3m, k3P = self._rhs(m + 0.5 * h * k2m, P + 0.5 * h * k2P, ybar, Bu)
            k4m, k4P = self._rhs(m + h * k3m, P + h * k3P, ybar, Bu)
            m = m + (h / 6.0) * (k1m + 2.0 * (k2m + k3m) + k4m)
            P = P + (h / 6.0) * (k1P + 2.0 * (k2P + k3P) + k4P)
            P = check_shared_covariance(P, self._batch, time=t0 + (i + 1) * h, quantity="P")
        steps = self._steps + 1
        self._check_state(m, steps)
        if P.shape != self._P.shape:  # shared: every member's, C-contiguous as before
            P = np.ascontiguousarray(np.broadcast_to(P, self._P.shape))
        self._commit(m, P, steps)
        self.innovation = innovation
        return m

    def suggested_substeps(self, P: npt.ArrayLike | None = None, *, limit: float = 2.5) -> int:
        """Heuristic number of RK4 substeps per interval for a numerically stable step.

        The Riccati equation linearized at ``P`` is ``E' = M E + E M^T`` with
        ``M = A - P C^T R^-1 C`` (eigenvalues ``lambda_i + lambda_j``); the mean obeys
        ``m' = M m + ...``. Explicit RK4 needs ``h |mu| <~ 2.8`` for these rates ``mu``,
        so this returns ``ceil(dt * 2 max|lambda(M)| / limit)`` (at least 1). Accurate
        sensors (small ``R``) and large ``P`` make the equation stiff; since ``P``
        usually shrinks, evaluating at the initial ``P0`` is the conservative choice.

        Parameters
        ----------
        P : array_like, shape (n, n) or (..., n, n), optional
            Covariance to linearize at (default: the current :attr:`P`; the maximum over
            a batch is used).
        limit : float
            Admissible ``h * max rate``; 2.5 leaves a margin to RK4's real-axis bound 2.785.

        Returns
        -------
        int
            Suggested ``substeps`` for ``KalmanBucyFilter(..., substeps=...)``.
        """
        P_arr = self._P if P is None else to_float_array("P", P)
        M = self._A - P_arr @ self._CtLinvT @ np.swapaxes(self._CtLinvT, -1, -2)
        rate = 2.0 * max_abs_eigenvalue(M)
        return max(1, math.ceil(self._dt * rate / limit))  # type: ignore[operator]

    def steady_state_covariance(self) -> FloatArray:
        """Stationary covariance from the continuous algebraic Riccati equation.

        Returns
        -------
        numpy.ndarray, shape (n, n)
            ``P`` with ``A P + P A^T + Q - P C^T R^-1 C P = 0``.
        """
        s = self._system
        P = solve_continuous_are(s.A.T, s.C.T, s.Q, s.R)
        return 0.5 * (P + P.T)

    def _rhs(
        self, m: FloatArray, P: FloatArray, ybar: FloatArray, Bu: FloatArray | None
    ) -> tuple[FloatArray, FloatArray]:
        """Right-hand side of the joint Kalman-Bucy ODE; shapes ``(..., n)``, ``(..., n, n)``."""
        if not self._batch:  # fast path: ndarray.dot has far less overhead than matmul
            W = P.dot(self._CtLinvT)  # (n, m)
            dm = self._A.dot(m) + W.dot(self._Linv.dot(ybar - self._C.dot(m)))
            if Bu is not None:
                dm += Bu
            AP = self._A.dot(P)
            dP = AP + AP.T
            dP += self._Q
            dP -= W.dot(W.T)  # BLAS syrk: exactly symmetric
            return dm, dP
        W = P @ self._CtLinvT  # (..., n, m)
        z = np.vecmat(ybar - np.vecmat(m, self._CT), self._LinvT)  # (..., m) whitened innovation
        dm = np.vecmat(m, self._AT) + (W @ z[..., None])[..., 0]
        if Bu is not None:
            dm += Bu
        AP = self._A @ P
        dP = AP + np.swapaxes(AP, -1, -2)
        dP += self._Q
        dP -= W @ np.swapaxes(W, -1, -2)
        return dm, dP
