"""The replay's steps and their record (:class:`Collector`): the physical estimate, its
variances and the innovations after each step, into arrays allocated once, a block of steps
at a time.

Any estimator is stepped through the :class:`~testbed.experiment.loop.EstimatorStage`, as in
a run, and read after each step (``P``, ``innovation``, ``innovation_cov``).

A :class:`filters.KalmanFilter` (the class itself, not a subclass) whose batch of one shares
its covariance with itself (``shared_P``; possibly behind a channel selection) takes the
stage on its first step (its checks) and then a path of its own, :class:`_KalmanBlocks`,
with the filter's arithmetic and nothing else:

* the covariance recursion does not depend on the data: each block's innovation covariances,
  gains and posterior covariances come first, from the filter's own step of its shared
  covariance (:meth:`filters.KalmanFilter.shared_covariance_step`: what ``step`` uses, the
  same arrays); once a covariance it was given comes back (a fixed point of the
  floating-point recursion or a short cycle), the later steps repeat the cycle's and none is
  looked up again;
* the channels the filter reads are selected from the whole recording once, contiguous
  rows (what the stage's ``select`` gives one row);
* the mean is the filter's ``step`` of a shared covariance written out: the design's input
  transform at the current estimate, ``F x + B u``, ``y - H x_prior - D u`` and
  ``x_prior + K nu``, the same ``numpy`` calls on operands of the same shapes and layouts
  (:meth:`filters.KalmanFilter._predict_state` and ``_correct``), without the per-step
  validation, the stage's bookkeeping or any Python object but the numbers;
* the checks run once per block: estimates that are not finite, an input transform that
  does not return the filter's ``(1, k)`` input or anything that raises sends the whole
  replay back to the stage from the reset, step by step, where it fails as the run does
  (the same error at the same step; numpy's warnings of the failed block's steps after the
  first non-finite value come first: a block that passes warns where the run warns, the
  same operations on the same values).

The estimates are the run's bitwise (``tests/experiment/test_replay.py`` compares them with
a run's, and the block path with the stage's step by step).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from filters import KalmanFilter, all_finite
from testbed import estimators
from testbed.estimators import optional
from testbed.experiment.loop import EstimatorStage


def innermost(est: Any) -> Any:
    """The :class:`filters.KalmanFilter` inside wrappers that change none of ``x``, ``P`` and
    the innovations (:class:`~testbed.estimators.ChannelSelect` and the plain
    :class:`~testbed.estimators.EstimatorWrapper`), else ``est`` itself.

    Parameters
    ----------
    est : estimator

    Returns
    -------
    estimator
    """
    inner = est
    while type(inner) in (estimators.EstimatorWrapper, estimators.ChannelSelect):
        inner = inner.inner
    return inner if isinstance(inner, KalmanFilter) else est


_Step = tuple[np.ndarray, np.ndarray, np.ndarray]  # (S, K, P) of a covariance step


class _Fallback(Exception):
    """The Kalman block path cannot go on (see the module docstring)."""


class Collector:
    """The replay's steps and their record (see the module docstring).

    Parameters
    ----------
    stage : EstimatorStage
    inner : estimator
        What the innovations are read from (:func:`innermost`, or a per-member estimator's
        one instance).
    has_P : bool
        Whether the estimator reports a covariance.
    Y, U : ndarray, shape (K+1, 1, m) and (K+1, 1, nu)
        The channels and inputs of the samples used, as the stage takes them (C-contiguous).
    taps : list of (Tap, list of int)
        The sensors' taps and the channels they hold.
    """

    #: Steps per block.
    BLOCK = 1024

    def __init__(self, stage: EstimatorStage, inner: Any, has_P: bool, Y: np.ndarray,
                 U: np.ndarray, taps: Sequence[tuple[Any, Sequence[int]]]):
        self.stage, self.inner, self.Y, self.U, self.taps = stage, inner, Y, U, taps
        self.K = K = len(Y) - 1
        n = len(stage.prior[0]) if stage.physical_index is None else len(stage.physical_index)
        self.x_hat = np.empty((K + 1, n))
        self.P_diag = np.empty((K + 1, n)) if has_P else None
        self.nu: np.ndarray | None = None
        self.S: np.ndarray | None = None
        self.has_innovation = True
        # the class itself: a subclass may step otherwise
        self.kalman = type(inner) is KalmanFilter and has_P
        self._blocks: _KalmanBlocks | None = None
        # the record of the covariance's cycle: S (c, p, p) and the variances (c, n)
        self._cycle: tuple[np.ndarray, np.ndarray] | None = None

    def run(self, x0_hat: np.ndarray, P0: Any, progress: Callable[[int], Any]) -> None:
        """Reset the stage on row 0 (primed on its channels), then steps ``1..K``.

        Parameters
        ----------
        x0_hat : ndarray, shape (1, n)
            The prior mean (:meth:`EstimatorStage.priors`).
        P0 : ndarray or None
            The prior covariance.
        progress : callable
            Called with the number of steps of each finished block.
        """
        self._reset(x0_hat, P0)
        try:
            for j0 in range(1, self.K + 1, self.BLOCK):
                j1 = min(self.K + 1, j0 + self.BLOCK)
                self.block(j0, j1)
                progress(j1 - j0)
        except _Fallback:
            # again from the reset through the stage, where it fails as the run does
            self._reset(x0_hat, P0)
            self.nu = self.S = None
            self.has_innovation, self.kalman = True, False
            for j0 in range(1, self.K + 1, self.BLOCK):
                self._generic(j0, min(self.K + 1, j0 + self.BLOCK))

    def _reset(self, x0_hat: np.ndarray, P0: Any) -> None:
        self._blocks = self._cycle = None
        self.restore_taps(0)
        self.stage.reset(self.Y[0].copy(), None, x0_hat, P0)
        self.first()

    def block(self, j0: int, j1: int) -> None:
        """Steps ``j0..j1-1`` (rows ``j0..j1-1`` of the record)."""
        if self.kalman and (self._blocks is not None or self.inner.shared_P is not None):
            if j0 == 1:  # the first step through the stage: its checks
                self._generic(1, 2)
                j0 = 2
            if j0 < j1:
                try:
                    self._kalman(j0, j1)
                except Exception as exc:  # noqa: BLE001 (the stage steps again and raises)
                    raise _Fallback(str(exc)) from exc
        else:
            self._generic(j0, j1)

    def restore_taps(self, j: int) -> None:
        """Set each tap's latest values to the recorded channels of row ``j``."""
        for tap, cols in self.taps:
            tap.last[:] = self.Y[j][:, cols]

    def first(self) -> None:
        """Row 0: the estimate after the stage's reset."""
        self.x_hat[0] = self.stage.x[0]
        if self.P_diag is not None:
            self.P_diag[0] = self.stage.P[0].diagonal()

    def _allocate(self, nu: Any) -> None:
        p = np.shape(nu)[-1]
        self.nu, self.S = np.empty((self.K, p)), np.empty((self.K, p, p))

    def _kalman(self, j0: int, j1: int) -> None:
        """Steps ``j0..j1-1`` of a Kalman filter's batch of one (:class:`_KalmanBlocks`)."""
        if self._blocks is None:
            self._blocks = _KalmanBlocks(self)
        blocks = self._blocks
        steps, head = blocks.covariances(j0, j1)
        X, nus = blocks.states(j0, j1, steps)
        if not all_finite(X):
            raise _Fallback("a non-finite estimate")
        stage = self.stage
        index = stage.physical_index
        self.x_hat[j0:j1] = X if index is None else X[:, index]
        if self.nu is None:
            self._allocate(nus[0])
        self.nu[j0 - 1:j1 - 1] = np.concatenate(nus)  # type: ignore[index]
        # the covariances: those before the cycle one by one, the cycle's by its index
        end = j0 + head
        if head:
            self.S[j0 - 1:end - 1] = [s[0] for s in steps[:head]]  # type: ignore[index]
            self.P_diag[j0:end] = self._variances([s[2] for s in steps[:head]])
        if end < j1:
            if self._cycle is None:
                self._cycle = (np.array([s[0] for s in blocks.cycle]),  # type: ignore[union-attr]
                               self._variances([s[2] for s in blocks.cycle]))  # type: ignore[union-attr]
            at = (np.arange(end, j1) - blocks.cycle_start) % len(self._cycle[0])
            self.S[end - 1:j1 - 1] = self._cycle[0][at]  # type: ignore[index]
            self.P_diag[end:j1] = self._cycle[1][at]  # type: ignore[index]

    def _variances(self, Ps: list[np.ndarray]) -> np.ndarray:
        """The physical states' variances (len(Ps), n) of covariances (n_full, n_full)."""
        return np.diagonal(self.stage._physical_block(np.stack(Ps)), axis1=-2, axis2=-1)

    def _generic(self, j0: int, j1: int) -> None:
        """Steps ``j0..j1-1`` of any estimator."""
        step, stage, inner, Y, U = self.stage.step, self.stage, self.inner, self.Y, self.U
        for j in range(j0, j1):
            if self.taps:
                self.restore_taps(j)
            self.x_hat[j] = step(Y[j], U[j - 1], None, None)[0]
            if self.P_diag is not None:
                self.P_diag[j] = stage.P[0].diagonal()
            if not self.has_innovation:
                continue
            nu, S = optional.innovations(inner)
            if self.nu is None and nu is not None and S is not None:
                self._allocate(nu)
            try:
                # (N, p) and (N, p, p), or one member's (p,) and (p, p)
                self.nu[j - 1] = nu[0 if np.ndim(nu) == 2 else ()]  # type: ignore[index]
                self.S[j - 1] = S[0 if np.ndim(S) == 3 else ()]  # type: ignore[index]
            except (TypeError, ValueError, IndexError):  # none, or not (N, p) and (N, p, p)
                self.has_innovation = False

    def arrays(self) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None,
                              np.ndarray | None, bool]:
        """The record.

        Returns
        -------
        x_hat : ndarray, shape (K+1, n)
        P_diag : ndarray, shape (K+1, n), or None
        innovations : ndarray, shape (K, p), or None (none exposed)
        innovation_cov : ndarray, shape (K, p, p), or None
        has_innovation : bool
        """
        return (self.x_hat, self.P_diag, self.nu, self.S,
                self.has_innovation and self.nu is not None)


class _KalmanBlocks:
    """A Kalman filter's batch of one over the recording after its first step (see the
    module docstring): its state (the estimate and the shared covariance) and the operands
    its step uses, laid out as the filter lays them out.

    The recursion is a function of the covariance alone: when a covariance it was given
    comes back as the input of a later step (the same array: the filter's kept step; the
    filter keeps :data:`filters.kalman._MEMO_STEPS` and more), the steps between repeat for
    ever (a fixed point of the floating-point recursion, or a short cycle), and are not
    looked up again.
    """

    #: Steps whose inputs are remembered for the cycle's detection.
    HISTORY = 64

    def __init__(self, collector: Collector):
        stage, kf = collector.stage, collector.inner
        system = kf.system
        self.kf = kf
        # the operands of KalmanFilter.__init__ (the same values and layouts)
        self.FT = np.ascontiguousarray(system.F.T)
        self.BT = np.ascontiguousarray(system.B.T)
        self.HT = np.ascontiguousarray(system.H.T)
        self.DT = np.ascontiguousarray(system.D.T) if np.any(system.D) else None
        self.k = int(system.k)
        # the channels the filter reads: the stage's selection, then the wrappers' (rows of
        # one C-contiguous array, as the stage's select and ChannelSelect give one row)
        Y = stage.select(collector.Y)
        wrapper = stage.estimator
        while wrapper is not kf:
            if isinstance(wrapper, estimators.ChannelSelect):
                Y = np.ascontiguousarray(wrapper._pick(Y))
            wrapper = wrapper.inner
        if Y.shape[1:] != (1, system.m):
            raise _Fallback(f"the filter reads {system.m} channels, not {Y.shape[1:]}")
        self.Y, self.U = Y, collector.U
        self.transform = stage.input_transform
        self.restore = collector.restore_taps if collector.taps else None
        # the filter after the stage's first step
        self.x = kf.x
        self.P = kf.shared_P
        #: The steps the recursion repeats (period ``len(cycle)``, 1: a fixed point) from
        #: step :attr:`cycle_start` on, once a covariance it was given comes back.
        self.cycle: list[_Step] | None = None
        self.cycle_start = 0
        # the last HISTORY steps' inputs (kept: their ids stay theirs) by id, and the steps
        self._seen: dict[int, int] = {}
        self._history: list[tuple[np.ndarray, _Step]] = []
        self._first = 2  # the step of _history[0] (the stage took step 1)

    def covariances(self, j0: int, j1: int) -> tuple[list[_Step], int]:
        """``(S, K, P)`` of steps ``j0..j1-1``: the innovation covariance, the gain and the
        posterior covariance the filter's step uses (its arrays; never written).

        Returns
        -------
        steps : list of (S, K, P)
        head : int
            How many of them precede :attr:`cycle` (the rest are its steps).
        """
        if self.cycle is not None:
            return [self._in_cycle(j) for j in range(j0, j1)], 0
        step_of, P = self.kf.shared_covariance_step, self.P
        seen, history = self._seen, self._history
        out: list[_Step] = []
        for j in range(j0, j1):
            i = seen.get(id(P))
            if i is not None and history[i - self._first][0] is P:
                # P is the input of step i again: the steps from i on repeat with period j - i
                self.cycle = [h[1] for h in history[i - self._first:]]
                self.cycle_start = i
                self._seen, self._history = {}, []
                head = len(out)
                return out + [self._in_cycle(k) for k in range(j, j1)], head
            step = step_of(P, j)
            out.append(step)
            seen[id(P)] = j
            history.append((P, step))
            if len(history) > self.HISTORY:
                del seen[id(history.pop(0)[0])]
                self._first += 1
            P = step[2]
        self.P = P
        return out, len(out)

    def _in_cycle(self, j: int) -> _Step:
        """Step ``j`` of the recursion's cycle."""
        cycle = self.cycle
        return cycle[(j - self.cycle_start) % len(cycle)]  # type: ignore[arg-type]

    def _input(self, u: Any) -> None:
        """``ValueError`` unless ``u`` is what the filter's step takes as it is."""
        if not (type(u) is np.ndarray and u.dtype == np.float64 and u.shape == (1, self.k)
                and u.flags.c_contiguous):
            raise _Fallback(f"the input transform returned {type(u).__name__} "
                            f"{np.shape(u)}, not a (1, {self.k}) array")

    def states(self, j0: int, j1: int, steps: Sequence[tuple[np.ndarray, ...]]
               ) -> tuple[np.ndarray, list[np.ndarray]]:
        """The estimates (j1 - j0, n) and the innovations (each (1, p)) of steps
        ``j0..j1-1`` with their covariance steps: ``KalmanFilter.step`` of a shared
        covariance, its arithmetic only (``_predict_state`` and ``_correct``)."""
        vecmat, matmul = np.vecmat, np.matmul
        FT, BT, HT, DT = self.FT, self.BT, self.HT, self.DT
        Y, U, transform, restore = self.Y, self.U, self.transform, self.restore
        with_u = self.k > 0
        x = self.x
        xs: list[np.ndarray] = []
        nus: list[np.ndarray] = []
        keep_x, keep_nu = xs.append, nus.append
        for j, step in zip(range(j0, j1), steps, strict=True):
            if restore is not None:
                restore(j)
            u = U[j - 1]
            if transform is not None:
                u = transform(u, x)
            if j == j0 and with_u:
                self._input(u)
            xp = vecmat(x, FT)
            if with_u:
                xp += vecmat(u, BT)
            nu = Y[j] - vecmat(xp, HT)
            if DT is not None:
                nu -= vecmat(u, DT)
            x = xp + matmul(step[1], nu[..., None])[..., 0]
            keep_x(x)
            keep_nu(nu)
        if with_u:
            self._input(u)  # the first and the last of the block
        self.x = x
        return np.concatenate(xs), nus
