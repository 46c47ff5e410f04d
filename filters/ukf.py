"""Unscented Kalman filter on user callables (:class:`UnscentedKalmanFilter`).

Model (discrete time, additive noise)::

    x_{k+1} = f(x_k, u_k) + w_k,     w_k ~ N(0, Q)
    y_k     = h(x_k, u_k) + v_k,     v_k ~ N(0, R)

The unscented transform of Julier & Uhlmann (1997, 2004) with the scaled sigma points of
Wan & van der Merwe (2000): for a mean ``x`` and covariance ``P`` of dimension ``n``,
``lambda = alpha^2 (n + kappa) - n`` and the ``2n + 1`` points

    X_0 = x,   X_i = x + c_i,   X_{n+i} = x - c_i,   c_i = row i of U,
    U^T U = (n + lambda) P   (U the upper Cholesky factor),

with weights ``Wm_0 = lambda / (n + lambda)``, ``Wc_0 = Wm_0 + 1 - alpha^2 + beta``,
``Wm_i = Wc_i = 1 / (2 (n + lambda))``. (The points and weights are those of filterpy's
``MerweScaledSigmaPoints``.)

Predict: the points of the estimate go through ``f`` in one call (all ``N (2n + 1)`` points
of a batch stacked as an ``(N (2n + 1), n)`` array, so a batched process model, e.g. many
MuJoCo simulations, does the work at once); their weighted mean and covariance plus ``Q``
are the prior. Update: new points are drawn from the prior (Wan & van der Merwe's additive
noise form: the points carry ``Q``, so on a linear model the filter equals the Kalman filter)
and go through ``h`` in one call; ``S = P_yy + R``, ``K = P_xy S^-1``, ``x <- x + K e``,
``P <- P - K S K^T`` (symmetrized and checked).

Conventions (shapes, batching, ``step`` order, read-only state, typed errors) are those of
:mod:`filters.ekf`.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import numpy.typing as npt

from filters._linalg import FloatArray
from filters.ekf import ModelFunction, _CallableModelFilter, _swap
from filters.errors import check_covariance

__all__ = ["UnscentedKalmanFilter", "merwe_weights"]


def merwe_weights(n: int, alpha: float, beta: float, kappa: float
                  ) -> tuple[FloatArray, FloatArray, float]:
    """Weights of Wan & van der Merwe's scaled sigma points.

    Parameters
    ----------
    n : int
        State dimension.
    alpha, beta, kappa : float
        Spread (``0 < alpha <= 1``), prior-knowledge (``beta >= 0``; 2 is optimal for a
        Gaussian) and secondary scaling (``n + kappa > 0``) parameters.

    Returns
    -------
    Wm, Wc : numpy.ndarray, shape (2n + 1,)
        Mean and covariance weights.
    scale : float
        ``n + lambda`` (the factor of ``P`` whose Cholesky factor gives the points).
    """
    lam = alpha * alpha * (n + kappa) - n
    scale = n + lam
    Wm = np.full(2 * n + 1, 0.5 / scale)
    Wc = Wm.copy()
    Wm[0] = lam / scale
    Wc[0] = lam / scale + (1.0 - alpha * alpha + beta)
    return Wm, Wc, scale


class UnscentedKalmanFilter(_CallableModelFilter):
    """Discrete-time unscented Kalman filter (scaled sigma points, additive noise).

    Parameters
    ----------
    f : callable ``(x (M, n), u (M, k)) -> (M, n)``
        Transition over one sample interval (``u`` held); called once per prediction with
        all sigma points stacked (``M = N (2n + 1)``, member ``j``'s points in rows
        ``j (2n + 1) ... (j + 1)(2n + 1) - 1``, its mean first).
    h : callable ``(x (M, n), u (M, k)) -> (M, m)``
        Measurement function, called once per update on the stacked points.
    Q : array_like, shape (n, n)
        Process-noise covariance (symmetric PSD).
    R : array_like, shape (m, m)
        Measurement-noise covariance (symmetric positive definite).
    x0 : array_like, shape (n,) or (N, n)
        Initial mean (leading axis: batch of independent filters).
    P0 : array_like, shape (n, n) or (N, n, n)
        Initial covariance, broadcast to the batch.
    alpha : float
        Spread of the points, ``0 < alpha <= 1`` (default 1e-3, Wan & van der Merwe).
    beta : float
        ``>= 0``; 2 is optimal for a Gaussian prior (default).
    kappa : float
        Secondary scaling, ``n + kappa > 0`` (default 0).
    k : int
        Input dimension (0: no input; ``u`` must be ``None``).
    dt_s : float, optional
        Sample period in seconds.

    Attributes
    ----------
    name : str
        ``"ukf"``.
    x, P : numpy.ndarray
        Estimate and covariance.
    Wm, Wc : numpy.ndarray, shape (2n + 1,)
        Sigma-point weights.
    innovation : numpy.ndarray, shape (m,) or (N, m), or None
        ``y - sum_i Wm_i h(X_i, u)`` of the last update.
    innovation_cov : numpy.ndarray, shape (m, m) or (N, m, m), or None
        ``S = P_yy + R`` of the last update.
    gain : numpy.ndarray, shape (n, m) or (N, n, m), or None

    Raises
    ------
    TypeError
        ``f`` or ``h`` is not callable.
    ValueError
        ``Q``, ``R``, ``x0``, ``P0``, ``alpha``, ``beta``, ``kappa``, ``k`` or ``dt_s`` is
        malformed (named in the message).

    References
    ----------
    Julier & Uhlmann (1997, 2004); Wan & van der Merwe (2000) (docs/references.md).
    """

    name: ClassVar[str] = "ukf"

    def __init__(self, f: ModelFunction, h: ModelFunction, Q: npt.ArrayLike,
                 R: npt.ArrayLike, x0: npt.ArrayLike, P0: npt.ArrayLike, *,
                 alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0, k: int = 0,
                 dt_s: float | None = None) -> None:
        self._setup(f, h, Q, R, k, dt_s)
        n = self._n
        params = {}
        for label, value in (("alpha", alpha), ("beta", beta), ("kappa", kappa)):
            try:
                params[label] = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"{label} must be a real number, got {value!r}") from None
            if not np.isfinite(params[label]) or isinstance(value, bool):
                raise ValueError(f"{label} must be a finite real number, got {value!r}")
        if not 0.0 < params["alpha"] <= 1.0:
            raise ValueError(f"alpha must lie in (0, 1], got {alpha!r}")
        if params["beta"] < 0.0:
            raise ValueError(f"beta must be >= 0, got {beta!r}")
        if n + params["kappa"] <= 0.0:
            raise ValueError(f"kappa must exceed -n = {-n}, got {kappa!r}")
        self.alpha, self.beta, self.kappa = params["alpha"], params["beta"], params["kappa"]
        Wm, Wc, self._scale = merwe_weights(n, self.alpha, self.beta, self.kappa)
        Wm.flags.writeable = False
        Wc.flags.writeable = False
        self.Wm, self.Wc = Wm, Wc
        self._Wc_col = Wc[:, None]
        self.reset(x0, P0)

    # ------------------------------------------------------------- public API
    def sigma_points(self, x: npt.ArrayLike | None = None,
                     P: npt.ArrayLike | None = None) -> FloatArray:
        """The scaled sigma points of ``(x, P)`` (default: the current estimate).

        Parameters
        ----------
        x : array_like, shape (N, n), optional
        P : array_like, shape (N, n, n), optional

        Returns
        -------
        numpy.ndarray, shape (N, 2n + 1, n)
            Member ``j``'s points ``[x, x + c_1 ... x + c_n, x - c_1 ... x - c_n]``.
        """
        if x is None or P is None:
            x, P = self._stack()
        return self._points(np.asarray(x, float), np.asarray(P, float), self._steps)

    def predict(self, u: npt.ArrayLike | None = None) -> FloatArray:
        """Time update through ``f`` (one call on all sigma points); advances ``t_s``.

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
            Bad ``u`` or a wrong shape from ``f``; state unchanged.
        LossOfDefinitenessError, FiniteEscapeError
            ``P`` has no square root, ``f`` returned non-finite values (``quantity``
            ``"x"``), or the prior ``P`` escaped; state unchanged.
        """
        u = self._input(u)
        steps = self._steps + 1
        x, P = self._predict(u, steps)
        x, P = self._unstack(x), self._unstack(P)
        self._commit(x, P, steps)
        return x

    # -------------------------------------------------------------- internals
    def _points(self, x: FloatArray, P: FloatArray, steps: int) -> FloatArray:
        """Sigma points ``(N, 2n + 1, n)`` of ``(x (N, n), P (N, n, n))``."""
        scaled = self._scale * P
        try:
            L = np.linalg.cholesky(scaled)  # lower: column i of L is row i of U = L^T
        except np.linalg.LinAlgError:
            # semidefinite (or worse): the exact test raises for a covariance that is not PSD
            sym = check_covariance(scaled, time=self._time(steps), quantity="P")
            w, V = np.linalg.eigh(sym)
            L = V * np.sqrt(np.maximum(w, 0.0))[..., None, :]
        C = _swap(L)  # (N, n, n): row i = c_i
        xc = x[:, None, :]
        return np.concatenate([xc, xc + C, xc - C], axis=1)

    def _moments(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Weighted mean ``(N, d)`` and deviations ``(N, 2n + 1, d)`` of points."""
        mean = self.Wm @ X
        return mean, X - mean[:, None, :]

    def _predict(self, u: FloatArray | None, steps: int) -> tuple[FloatArray, FloatArray]:
        x, P = self._stack()
        N, n = x.shape
        X = self._points(x, P, steps)
        M = N * (2 * n + 1)
        ub = np.repeat(self._inputs(u, N), 2 * n + 1, axis=0)
        Xf = self._eval("f", self._f, X.reshape(M, n), ub, (M, n)).reshape(N, 2 * n + 1, n)
        self._finite("x", Xf, steps, "f(x, u) at a sigma point")
        xp, dX = self._moments(Xf)
        Pp = _swap(dX) @ (self._Wc_col * dX)
        Pp += self._Q
        Pp = check_covariance(Pp, time=self._time(steps), quantity="P")
        return xp, Pp

    def _update(self, x: FloatArray, P: FloatArray, y: FloatArray, u: FloatArray | None,
                steps: int) -> FloatArray:
        N, n = x.shape
        m = self._m
        X = self._points(x, P, steps)
        M = N * (2 * n + 1)
        ub = np.repeat(self._inputs(u, N), 2 * n + 1, axis=0)
        Y = self._eval("h", self._h, X.reshape(M, n), ub, (M, m)).reshape(N, 2 * n + 1, m)
        self._finite("y", Y, steps, "h(x, u) at a sigma point")
        yp, dY = self._moments(Y)
        WdY = self._Wc_col * dY
        S = _swap(dY) @ WdY
        S += self._R
        Pxy = _swap(X - x[:, None, :]) @ WdY
        K = self._gain(Pxy, S, steps)
        innov = y - yp
        xn = x + (K @ innov[..., None])[..., 0]
        Pn = P - K @ S @ _swap(K)
        return self._finish(xn, Pn, innov, S, K, steps)
