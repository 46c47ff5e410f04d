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

Or (``sigma_points="simplex"``) the spherical simplex set of Julier (2003): ``n + 2`` points
``X_0 = x``, ``X_i = x + alpha L z_i`` (``i = 1 .. n + 1``, ``L L^T = P`` the lower Cholesky
factor, ``z_i`` the unit-covariance simplex points of :func:`simplex_points` for the weights
``W_0 = w0``, ``W_i = (1 - w0) / (n + 1)``), scaled as Julier's (2002) scaled unscented
transformation: ``Wm_0 = w0 / alpha^2 + 1 - 1 / alpha^2``, ``Wm_i = W_i / alpha^2``,
``Wc_0 = Wm_0 + 1 - alpha^2 + beta``, ``Wc_i = Wm_i``. Both sets give the exact mean and
covariance of a linear map and the mean of a quadratic one; the simplex set is not symmetric
(its third moments are not zero). Point ``i`` of the simplex set is zero in the coordinates
before ``i - 1``, so with the lower factor its first ``i - 2`` states are the mean's: a
process model that rolls out each distinct leading block once (the matched designs' MuJoCo
states before their bias and delay states) needs ``d + 2`` rollouts for ``d`` leading states
instead of the standard set's ``2 d + 1``.

Predict: the points of the estimate go through ``f`` in one call (all ``N p`` points of a
batch, ``p`` per member, stacked as an ``(N p, n)`` array, so a batched process model, e.g. many
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

__all__ = ["SIGMA_POINT_SETS", "UnscentedKalmanFilter", "merwe_weights", "simplex_points"]

#: The sigma-point sets of :class:`UnscentedKalmanFilter`: ``"scaled"`` (``2n + 1`` points,
#: Wan & van der Merwe) and ``"simplex"`` (``n + 2`` points, Julier 2003).
SIGMA_POINT_SETS = ("scaled", "simplex")


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


def simplex_points(n: int, w0: float = 0.0) -> tuple[FloatArray, FloatArray]:
    """Julier's (2003) spherical simplex sigma points of unit covariance.

    For ``W_1 = (1 - w0) / (n + 1)`` and ``c_j = 1 / sqrt(j (j + 1) W_1)`` the points are
    ``z_0 = 0`` and, for ``i = 1 .. n + 1``, ``z_i[j] = -c_j`` for ``j >= i``, ``z_i[i - 1] =
    (i - 1) c_{i - 1}`` (``i >= 2``), zero before (coordinates ``j = 1 .. n``): the closed form
    of the paper's recursion over the dimension. ``sum_i W_i z_i = 0`` and ``sum_i W_i z_i
    z_i^T = I``; every ``z_i`` (``i >= 1``) has the same length ``sqrt(n / (n + 1) / W_1)``.

    Parameters
    ----------
    n : int
        Dimension, ``>= 1``.
    w0 : float
        Weight of the centre point, ``0 <= w0 < 1``.

    Returns
    -------
    Z : numpy.ndarray, shape (n + 2, n)
        The points ``z_0 .. z_{n+1}`` as rows.
    W : numpy.ndarray, shape (n + 2,)
        Their weights ``[w0, W_1, ..., W_1]`` (sum 1).

    Raises
    ------
    ValueError
        ``n`` or ``w0`` out of range.
    """
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if not (np.isfinite(w0) and 0.0 <= w0 < 1.0):
        raise ValueError(f"w0 must lie in [0, 1), got {w0!r}")
    W1 = (1.0 - w0) / (n + 1)
    j = np.arange(1, n + 1)
    c = 1.0 / np.sqrt(j * (j + 1) * W1)  # c_j, j = 1 .. n
    i = np.arange(1, n + 2)[:, None]  # point index of the rows of Z[1:]
    jj = j[None, :]
    Z = np.zeros((n + 2, n))
    Z[1:] = np.where(jj >= i, -c[None, :], 0.0)
    Z[1:] = np.where(jj == i - 1, (i - 1) * c[None, :], Z[1:])
    W = np.full(n + 2, W1)
    W[0] = w0
    return Z, W


class UnscentedKalmanFilter(_CallableModelFilter):
    """Discrete-time unscented Kalman filter (scaled sigma points, additive noise).

    Parameters
    ----------
    f : callable ``(x (M, n), u (M, k)) -> (M, n)``
        Transition over one sample interval (``u`` held); called once per prediction with
        all sigma points stacked (``M = N p``, ``p`` points per member: ``2n + 1`` or, for
        the simplex set, ``n + 2``; member ``j``'s points in rows ``j p ... (j + 1) p - 1``,
        its mean first).
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
        Secondary scaling, ``n + kappa > 0`` (default 0; the scaled set only).
    sigma_points : {"scaled", "simplex"}
        The ``2n + 1`` scaled points (default) or Julier's (2003) ``n + 2`` spherical simplex
        points (scaled by ``alpha``, ``beta`` as the scaled unscented transformation).
    w0 : float
        The simplex set's centre weight before scaling, ``0 <= w0 < 1`` (default 0).
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
    Wm, Wc : numpy.ndarray, shape (p,)
        Sigma-point weights (``p = 2n + 1``, or ``n + 2`` for the simplex set).
    sigma_point_set : str
        ``"scaled"`` or ``"simplex"``.
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
        ``Q``, ``R``, ``x0``, ``P0``, ``alpha``, ``beta``, ``kappa``, ``sigma_points``,
        ``w0``, ``k`` or ``dt_s`` is malformed (named in the message).

    References
    ----------
    Julier & Uhlmann (1997, 2004); Wan & van der Merwe (2000); Julier (2002, 2003)
    (docs/references.md).
    """

    name: ClassVar[str] = "ukf"

    def __init__(self, f: ModelFunction, h: ModelFunction, Q: npt.ArrayLike,
                 R: npt.ArrayLike, x0: npt.ArrayLike, P0: npt.ArrayLike, *,
                 alpha: float = 1e-3, beta: float = 2.0, kappa: float = 0.0,
                 sigma_points: str = "scaled", w0: float = 0.0, k: int = 0,
                 dt_s: float | None = None) -> None:
        if sigma_points not in SIGMA_POINT_SETS:
            raise ValueError(f"sigma_points must be one of {SIGMA_POINT_SETS}, "
                             f"got {sigma_points!r}")
        self._setup(f, h, Q, R, k, dt_s)
        n = self._n
        params = {}
        for label, value in (("alpha", alpha), ("beta", beta), ("kappa", kappa), ("w0", w0)):
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
        if not 0.0 <= params["w0"] < 1.0:
            raise ValueError(f"w0 must lie in [0, 1), got {w0!r}")
        self.alpha, self.beta, self.kappa = params["alpha"], params["beta"], params["kappa"]
        self.w0, self.sigma_point_set = params["w0"], sigma_points
        self._unit: FloatArray | None = None  # the simplex set's scaled points (n, n + 1)
        if sigma_points == "scaled":
            Wm, Wc, self._scale = merwe_weights(n, self.alpha, self.beta, self.kappa)
        else:
            Z, W = simplex_points(n, self.w0)
            a2 = self.alpha * self.alpha
            Wm = W / a2
            Wm[0] = W[0] / a2 + 1.0 - 1.0 / a2
            Wc = Wm.copy()
            Wc[0] += 1.0 - a2 + self.beta
            self._unit = np.ascontiguousarray((self.alpha * Z[1:]).T)  # column i: alpha z_i
            self._scale = 1.0
        self._npoints = len(Wm)
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
        numpy.ndarray, shape (N, p, n)
            Member ``j``'s points ``[x, x + c_1 ... x + c_n, x - c_1 ... x - c_n]`` (the
            simplex set: ``[x, x + alpha L z_1 ... x + alpha L z_{n+1}]``).
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
        """Sigma points ``(N, p, n)`` of ``(x (N, n), P (N, n, n))``."""
        scaled = self._scale * P if self._unit is None else P
        try:
            L = np.linalg.cholesky(scaled)  # lower: column i of L is row i of U = L^T
        except np.linalg.LinAlgError:
            # semidefinite (or worse): the exact test raises for a covariance that is not PSD
            sym = check_covariance(scaled, time=self._time(steps), quantity="P")
            w, V = np.linalg.eigh(sym)
            L = V * np.sqrt(np.maximum(w, 0.0))[..., None, :]
        xc = x[:, None, :]
        if self._unit is not None:  # simplex: x + alpha L z_i, i = 1 .. n + 1
            return np.concatenate([xc, xc + _swap(L @ self._unit)], axis=1)
        C = _swap(L)  # (N, n, n): row i = c_i
        return np.concatenate([xc, xc + C, xc - C], axis=1)

    def _moments(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Weighted mean ``(N, d)`` and deviations ``(N, p, d)`` of points."""
        mean = self.Wm @ X
        return mean, X - mean[:, None, :]

    def _predict(self, u: FloatArray | None, steps: int) -> tuple[FloatArray, FloatArray]:
        x, P = self._stack()
        N, n = x.shape
        X = self._points(x, P, steps)
        p = self._npoints
        M = N * p
        ub = np.repeat(self._inputs(u, N), p, axis=0)
        Xf = self._eval("f", self._f, X.reshape(M, n), ub, (M, n)).reshape(N, p, n)
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
        p = self._npoints
        M = N * p
        ub = np.repeat(self._inputs(u, N), p, axis=0)
        Y = self._eval("h", self._h, X.reshape(M, n), ub, (M, m)).reshape(N, p, m)
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
