"""Extended Kalman filter on user callables (:class:`ExtendedKalmanFilter`).

Model (discrete time, additive noise)::

    x_{k+1} = f(x_k, u_k) + w_k,     w_k ~ N(0, Q)
    y_k     = h(x_k, u_k) + v_k,     v_k ~ N(0, R)

Conventions (as :mod:`filters.kalman`)
--------------------------------------
* State ``x`` has shape ``(n,)`` or ``(N, n)``, covariance ``P`` shape ``(n, n)`` or
  ``(N, n, n)``; the optional leading axis is a batch of ``N`` independent filters sharing
  one model.
* The model callables always receive batched arrays: ``x`` of shape ``(N, n)`` and ``u`` of
  shape ``(N, k)`` (``N = 1`` for an unbatched filter; ``u=None`` is passed as zeros), and
  return ``f -> (N, n)``, ``F -> (N, n, n)``, ``h -> (N, m)``, ``H -> (N, m, n)``. They must
  treat the rows independently (a row's result may not depend on the other rows).
* ``step(y, u)`` is the in-the-loop call: ``u`` was applied (zero-order hold) over the last
  sample interval and ``y`` is measured at its end; the order is that of
  :meth:`filters.KalmanFilter.step` (predict with ``u``, then update with ``y`` and the same
  ``u``), so on a linear model ``f = F x + B u``, ``h = H x + D u`` the filter equals
  :class:`filters.KalmanFilter` to rounding.
* ``x`` and ``P`` are read-only arrays, replaced (never mutated) on every call. A call that
  raises leaves the filter unchanged.

The batched and the unbatched filter run the same (stacked) arithmetic, so a batch of ``N``
equals, bitwise, ``N`` filters run one by one (given row-independent callables).

References: the extended Kalman filter as in Bar-Shalom, Li & Kirubarajan (2001), ch. 10;
the Joseph-form covariance update as in :class:`filters.KalmanFilter`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar, NoReturn

import numpy as np
import numpy.typing as npt

from filters._linalg import FloatArray, positive_time, symmetric_psd, to_float_array
from filters.errors import FiniteEscapeError, LossOfDefinitenessError, check_covariance
from filters.kalman import _SampledFilter

__all__ = ["ExtendedKalmanFilter", "ModelFunction"]

#: A model callable ``(x (N, n), u (N, k)) -> array``.
ModelFunction = Callable[[FloatArray, FloatArray], npt.ArrayLike]


def _swap(a: FloatArray) -> FloatArray:
    return np.swapaxes(a, -1, -2)


class _CallableModelFilter(_SampledFilter):
    """Validation, batching and model evaluation shared by the EKF and the UKF."""

    def _setup(self, f: ModelFunction, h: ModelFunction, Q: npt.ArrayLike, R: npt.ArrayLike,
               k: int, dt_s: float | None) -> None:
        for label, fn in (("f", f), ("h", h)):
            if not callable(fn):
                raise TypeError(f"{label} must be callable (x (N, n), u (N, k)) -> array, got "
                                f"{type(fn).__name__}")
        Qa = to_float_array("Q", Q)
        if Qa.ndim != 2 or Qa.shape[0] != Qa.shape[1] or Qa.shape[0] == 0:
            raise ValueError(f"Q must be a symmetric positive semidefinite matrix with shape "
                             f"(n, n), n >= 1, got shape {Qa.shape}")
        self._n = Qa.shape[0]
        self._Q = symmetric_psd("Q", Qa, self._n, definite=False)
        Ra = to_float_array("R", R)
        if Ra.ndim != 2 or Ra.shape[0] != Ra.shape[1] or Ra.shape[0] == 0:
            raise ValueError(f"R must be a symmetric positive definite matrix with shape "
                             f"(m, m), m >= 1, got shape {Ra.shape}")
        self._m = Ra.shape[0]
        self._R = symmetric_psd("R", Ra, self._m, definite=True)
        self._Q.flags.writeable = False
        self._R.flags.writeable = False
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 0:
            raise ValueError(f"k (input dimension) must be an integer >= 0, got {k!r}")
        self._k = int(k)
        self._dt = None if dt_s is None else positive_time("dt_s", dt_s)
        self._f, self._h = f, h
        self._I = np.eye(self._n)

    # ------------------------------------------------------------------ state
    def reset(self, x0: npt.ArrayLike, P0: npt.ArrayLike) -> None:
        """Re-initialize ``x``, ``P`` and ``t_s = 0``.

        Parameters
        ----------
        x0 : array_like, shape (n,) or (N, n)
            Initial mean; a leading axis defines the batch.
        P0 : array_like, shape (n, n) or (N, n, n)
            Initial covariance (symmetric PSD), broadcast to the batch of ``x0``.

        Raises
        ------
        ValueError
            If ``x0`` or ``P0`` has the wrong shape (more than one batch axis included), is
            non-finite, ``P0`` is not symmetric PSD, or their batches do not broadcast.
        """
        x = to_float_array("x0", x0)
        P = to_float_array("P0", P0)
        if x.ndim > 2 or P.ndim > 3:
            raise ValueError(f"x0 must have shape ({self._n},) or (N, {self._n}) and P0 shape "
                             f"({self._n}, {self._n}) or (N, {self._n}, {self._n}) (one batch "
                             f"axis at most), got shapes {x.shape} and {P.shape}")
        super().reset(x, P)
        self.innovation_cov: FloatArray | None = None
        self.gain: FloatArray | None = None

    @property
    def Q(self) -> FloatArray:
        """Process-noise covariance, shape (n, n) (read-only)."""
        return self._Q

    @property
    def R(self) -> FloatArray:
        """Measurement-noise covariance, shape (m, m) (read-only)."""
        return self._R

    @property
    def dt_s(self) -> float | None:
        """Sample period in seconds (None if not given)."""
        return self._dt

    # ------------------------------------------------------------ evaluation
    def _stack(self) -> tuple[FloatArray, FloatArray]:
        """``x`` and ``P`` with the batch axis, shapes ``(N, n)`` and ``(N, n, n)``."""
        if self._batch:
            return self._x, self._P
        return self._x[None], self._P[None]

    def _unstack(self, a: FloatArray) -> FloatArray:
        """Drop the batch axis of an unbatched filter's result."""
        return a if self._batch else a[0]

    def _inputs(self, u: FloatArray | None, num: int) -> FloatArray:
        """``u`` as an ``(num, k)`` array (zeros for ``None``)."""
        if u is None:
            return np.zeros((num, self._k))
        if u.shape == (num, self._k):  # a read-only view, as broadcast_to's (cheaper)
            view = u.view()
            view.flags.writeable = False
            return view
        return np.broadcast_to(u, (num, self._k))

    def _eval(self, label: str, fn: ModelFunction, x: FloatArray, u: FloatArray,
              shape: tuple[int, ...]) -> FloatArray:
        """Call a model function and check the shape of its result (``ValueError``)."""
        out = fn(x, u)
        if type(out) is not np.ndarray or out.dtype != np.float64:
            out = to_float_array(f"the result of {label}", out)
        if out.shape != shape:
            raise ValueError(f"{label}(x, u) must return shape {shape} for x of shape "
                             f"{x.shape} and u of shape {u.shape}, got shape {out.shape}")
        return out

    def _finite(self, label: str, a: FloatArray, steps: int, what: str) -> None:
        """Raise :class:`FiniteEscapeError` (``quantity=label``) for a non-finite array."""
        if not np.isfinite(a).all():
            raise FiniteEscapeError(f"{what} became non-finite", time=self._time(steps),
                                    quantity=label, value=np.array(a))

    def _innovation_factor(self, S: FloatArray, steps: int) -> None:
        """Check that the innovation covariance stack is finite and positive definite."""
        if not np.isfinite(S).all():
            self._raise_innovation_cov(S, steps)
        try:
            np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            self._raise_innovation_cov(S, steps)

    def _raise_innovation_cov(self, S: FloatArray, steps: int) -> NoReturn:
        if not np.isfinite(S).all():
            raise FiniteEscapeError("innovation covariance is non-finite",
                                    time=self._time(steps), quantity="innovation_cov",
                                    value=self._unstack(S))
        raise LossOfDefinitenessError("innovation covariance is not positive definite",
                                      time=self._time(steps), quantity="innovation_cov",
                                      value=self._unstack(S))

    def _finish(self, x: FloatArray, P: FloatArray, innov: FloatArray, S: FloatArray,
                K: FloatArray, steps: int) -> FloatArray:
        """Check, then commit the a-posteriori estimate and the diagnostics."""
        P = check_covariance(P, time=self._time(steps), quantity="P")
        self._check_state(x, steps)
        x, P = self._unstack(x), self._unstack(P)
        self._commit(x, P, steps)
        self.innovation = self._unstack(innov)
        self.innovation_cov = self._unstack(S)
        self.gain = self._unstack(K)
        return x

    def _gain(self, PHT: FloatArray, S: FloatArray, steps: int) -> FloatArray:
        """``K = PHT S^-1`` (S checked positive definite first), shape ``(N, n, m)``."""
        self._innovation_factor(S, steps)
        return _swap(np.linalg.solve(S, _swap(PHT)))


    def update(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """Measurement update with ``y`` at the current time ``t_s`` (the EKF in Joseph form,
        the UKF from its sigma points).

        Parameters
        ----------
        y : array_like, shape (m,) or (N, m)
            Measurement.
        u : array_like, shape (k,) or (N, k), or None
            Input (feedthrough of ``h``).

        Returns
        -------
        numpy.ndarray, shape (n,) or (N, n)
            The a-posteriori state.

        Raises
        ------
        ValueError
            Bad ``y`` or ``u``, or a model function returned the wrong shape.
        LossOfDefinitenessError, FiniteEscapeError
            ``quantity`` ``"innovation_cov"``, ``"P"``, ``"x"`` or ``"H"``; state unchanged.
        """
        y = self._vector("y", y, self._m)
        u = self._input(u)
        x, P = self._stack()
        return self._update(x, P, y, u, self._steps)

    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """One in-the-loop cycle: :meth:`predict` with ``u``, then :meth:`update` with ``y``.

        Parameters
        ----------
        y : array_like, shape (m,) or (N, m)
            Measurement at the end of the interval.
        u : array_like, shape (k,) or (N, k), or None
            Input applied over the interval (also the feedthrough of ``h``).

        Returns
        -------
        numpy.ndarray, shape (n,) or (N, n)
            The a-posteriori state (same object as :attr:`x`).

        Raises
        ------
        ValueError
            Bad ``y`` or ``u`` (shape, complex, non-finite) or a model function returned
            the wrong shape; state unchanged.
        LossOfDefinitenessError, FiniteEscapeError
            As :meth:`predict` and :meth:`update`, with the time of the step; state
            unchanged.
        """
        y = self._vector("y", y, self._m)
        u = self._input(u)
        steps = self._steps + 1
        x, P = self._predict(u, steps)
        return self._update(x, P, y, u, steps)


class ExtendedKalmanFilter(_CallableModelFilter):
    """Discrete-time extended Kalman filter with Joseph-form covariance update.

    Parameters
    ----------
    f : callable ``(x (N, n), u (N, k)) -> (N, n)``
        Transition over one sample interval (``u`` held).
    F : callable ``(x (N, n), u (N, k)) -> (N, n, n)``
        Jacobian ``df/dx``. It is evaluated before ``f`` at the same arguments, so a model
        that computes both in one pass may cache ``f``'s value.
    h : callable ``(x (N, n), u (N, k)) -> (N, m)``
        Measurement function (``u``: feedthrough).
    H : callable ``(x (N, n), u (N, k)) -> (N, m, n)``
        Jacobian ``dh/dx``.
    Q : array_like, shape (n, n)
        Process-noise covariance (symmetric PSD).
    R : array_like, shape (m, m)
        Measurement-noise covariance (symmetric positive definite).
    x0 : array_like, shape (n,) or (N, n)
        Initial mean (leading axis: batch of independent filters).
    P0 : array_like, shape (n, n) or (N, n, n)
        Initial covariance, broadcast to the batch.
    k : int
        Input dimension (0: no input; ``u`` must be ``None``).
    dt_s : float, optional
        Sample period in seconds (``t_s = steps * dt_s``; without it ``t_s`` counts steps).

    Attributes
    ----------
    name : str
        ``"ekf"``.
    x, P : numpy.ndarray
        Estimate and covariance (a posteriori after :meth:`update`/:meth:`step`, a priori
        after :meth:`predict`).
    innovation : numpy.ndarray, shape (m,) or (N, m), or None
        ``y - h(x_prior, u)`` of the last update.
    innovation_cov : numpy.ndarray, shape (m, m) or (N, m, m), or None
        ``H P_prior H^T + R`` of the last update.
    gain : numpy.ndarray, shape (n, m) or (N, n, m), or None
        Gain of the last update.

    Raises
    ------
    TypeError
        A model argument is not callable.
    ValueError
        ``Q``, ``R``, ``x0``, ``P0``, ``k`` or ``dt_s`` is malformed (named in the message).

    Notes
    -----
    Predict: ``x <- f(x, u)``, ``P <- F P F^T + Q`` with ``F = F(x, u)`` at the previous
    estimate. Update: ``e = y - h(x, u)``, ``S = H P H^T + R``, ``K = P H^T S^-1``,
    ``x <- x + K e``, ``P <- (I - K H) P (I - K H)^T + K R K^T`` (Joseph form), symmetrized
    and checked (:func:`filters.errors.check_covariance`).
    """

    name: ClassVar[str] = "ekf"

    def __init__(self, f: ModelFunction, F: ModelFunction, h: ModelFunction,
                 H: ModelFunction, Q: npt.ArrayLike, R: npt.ArrayLike, x0: npt.ArrayLike,
                 P0: npt.ArrayLike, *, k: int = 0, dt_s: float | None = None) -> None:
        for label, fn in (("F", F), ("H", H)):
            if not callable(fn):
                raise TypeError(f"{label} must be callable (x (N, n), u (N, k)) -> Jacobian, "
                                f"got {type(fn).__name__}")
        self._setup(f, h, Q, R, k, dt_s)
        self._F, self._H = F, H
        self.reset(x0, P0)

    # ------------------------------------------------------------- public API
    def predict(self, u: npt.ArrayLike | None = None) -> FloatArray:
        """Time update ``x <- f(x, u)``, ``P <- F P F^T + Q``; advances ``t_s``.

        Parameters
        ----------
        u : array_like, shape (k,) or (N, k), or None
            Input held over the interval (``None``: zero).

        Returns
        -------
        numpy.ndarray, shape (n,) or (N, n)
            The a-priori state.

        Raises
        ------
        ValueError
            Bad ``u``, or a model function returned the wrong shape; state unchanged.
        FiniteEscapeError
            ``f`` or ``F`` returned non-finite values (``quantity`` ``"x"`` or ``"F"``), or
            ``P`` escaped; state unchanged.
        """
        u = self._input(u)
        x, P = self._predict(u, self._steps + 1)
        steps = self._steps + 1
        P = check_covariance(P, time=self._time(steps), quantity="P")
        x, P = self._unstack(x), self._unstack(P)
        self._commit(x, P, steps)
        return x

    # -------------------------------------------------------------- internals
    def _predict(self, u: FloatArray | None, steps: int) -> tuple[FloatArray, FloatArray]:
        x, P = self._stack()
        N, n = x.shape
        ub = self._inputs(u, N)
        Fj = self._eval("F", self._F, x, ub, (N, n, n))
        self._finite("F", Fj, steps, "the Jacobian F")
        xp = self._eval("f", self._f, x, ub, (N, n))
        self._finite("x", xp, steps, "the predicted state f(x, u)")
        Pp = Fj @ P @ _swap(Fj)
        Pp += self._Q
        return xp, Pp

    def _update(self, x: FloatArray, P: FloatArray, y: FloatArray, u: FloatArray | None,
                steps: int) -> FloatArray:
        N, n = x.shape
        ub = self._inputs(u, N)
        Hj = self._eval("H", self._H, x, ub, (N, self._m, n))
        self._finite("H", Hj, steps, "the Jacobian H")
        yp = self._eval("h", self._h, x, ub, (N, self._m))
        self._finite("y", yp, steps, "the predicted measurement h(x, u)")
        innov = y - yp
        PHT = P @ _swap(Hj)
        S = Hj @ PHT
        S += self._R
        K = self._gain(PHT, S, steps)
        xn = x + (K @ innov[..., None])[..., 0]
        IKH = self._I - K @ Hj
        Pn = IKH @ P @ _swap(IKH) + K @ self._R @ _swap(K)
        return self._finish(xn, Pn, innov, S, K, steps)
