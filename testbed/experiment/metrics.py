"""Streaming estimation metrics: RMSE, NEES, measurement RMSE and the noise-output ratio T.

Nothing is stored per step: sums accumulate, so an 80 s episode or a thousand of them cost
the same memory. A leading batch axis (``reset(x0)`` with ``x0`` of shape ``(N, n)``) tracks N
episodes stepped together (:mod:`testbed.batch`) with the same formulas.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: Largest state dimension whose NEES :func:`nees` computes elementwise (its operation count
#: grows as n**3); larger ones go through LAPACK's LU solve.
NEES_ELEMENTWISE_MAX = 8


def nees(error: np.ndarray, covariance: np.ndarray) -> Any:
    """Normalized estimation error squared ``e^T P^-1 e`` of every row.

    Computed as ``|z|^2`` with ``L z = e`` and ``P = L L^T``: the Cholesky factor and the
    forward substitution are written out entry by entry, one IEEE operation after another
    (no BLAS or LAPACK call, whose rounding depends on the CPU's kernel and on the call's
    shape). So the value of a row is the same bits whether it is computed alone, in a batch,
    against a covariance shared by the batch or against its own one, on any machine.

    Parameters
    ----------
    error : ndarray, shape (n,) or (..., n)
        Estimation errors.
    covariance : ndarray, shape (n, n) or (..., n, n)
        Their covariances: one shared by every row, or one per row (broadcast against
        ``error``'s leading axes).

    Returns
    -------
    float or ndarray, shape (...)
        A float for one error and one covariance, else an array of the broadcast leading
        shape.

    Notes
    -----
    A covariance that is not positive definite (a Cholesky pivot not > 0, or not finite)
    and any ``n > NEES_ELEMENTWISE_MAX`` get ``e^T solve(P, e)`` (LAPACK's LU) instead: the
    value of an indefinite but invertible matrix, and LAPACK's error for a singular one.
    """
    n = error.shape[-1]
    P = covariance
    if n <= NEES_ELEMENTWISE_MAX:
        rows = _cholesky_rows(P)
        if rows is not None:
            q = _forward_norm(rows, error.tolist() if error.ndim == 1 and P.ndim == 2
                              else [error[..., i] for i in range(n)])
            return q if isinstance(q, float) else np.asarray(q)
    if error.ndim == 1 and P.ndim == 2:
        return float(np.vecdot(error, np.linalg.solve(P, error[:, None])[:, 0]))
    if P.ndim == 2 or n > NEES_ELEMENTWISE_MAX:
        return np.vecdot(error, np.linalg.solve(P, error[..., None])[..., 0])
    return _nees_rows(error, P)


def _cholesky_rows(P: np.ndarray) -> list[list[Any]] | None:
    """The lower Cholesky factor of ``P`` (n, n) (Python floats) or of a stack (..., n, n)
    (arrays of shape (...)), as rows ``L[i][j]`` (``j <= i``); None unless every pivot of
    every matrix is finite and > 0 (NaN is not)."""
    n = P.shape[-1]
    if P.ndim == 2:
        A: list[list[Any]] = P.tolist()
        sqrt: Any = math.sqrt
    else:
        flat = P.ravel()
        if not math.isfinite(flat.dot(flat)):  # a non-finite entry (or a huge one)
            return None
        A = [[P[..., i, j] for j in range(i + 1)] for i in range(n)]
        sqrt = np.sqrt
    L: list[list[Any]] = []
    for i in range(n):
        row: list[Any] = []
        for j in range(i + 1):
            s = A[i][j]
            other = row if j == i else L[j]
            for k in range(j):
                s = s - row[k] * other[k]
            if j < i:
                row.append(s / L[j][j])
            elif (0.0 < s < math.inf) if P.ndim == 2 else bool(np.all(s > 0)):
                row.append(sqrt(s))
            else:
                return None
        L.append(row)
    return L


def _forward_norm(L: list[list[Any]], e: list[Any]) -> Any:
    """``|z|^2`` with ``L z = e`` by forward substitution (``e`` a list of the n entries:
    floats, or arrays of the rows)."""
    z: list[Any] = []
    q: Any = 0.0
    for i, row in enumerate(L):
        s = e[i]
        for k in range(i):
            s = s - row[k] * z[k]
        zi = s / row[i]
        z.append(zi)
        q = zi * zi if i == 0 else q + zi * zi
    return q


def _nees_rows(error: np.ndarray, P: np.ndarray) -> np.ndarray:
    """:func:`nees` of a stack with some matrix that is not positive definite: the positive
    definite rows elementwise, the others through LAPACK (row by row, as alone)."""
    shape = np.broadcast_shapes(error.shape[:-1], P.shape[:-2])
    n = error.shape[-1]
    e = np.broadcast_to(error, (*shape, n)).reshape(-1, n)
    Ps = np.broadcast_to(P, (*shape, n, n)).reshape(-1, n, n)
    out = np.empty(len(e))
    for r in range(len(e)):
        out[r] = nees(e[r], Ps[r])
    return out.reshape(shape)


class EpisodeMetrics:
    """Accumulate estimation metrics over one episode, or over a batch of episodes.

    Parameters
    ----------
    state_names : list of str, length n
    dt_s : float
        Control period; the integrals of the ratio ``T`` are rectangle sums with this step.
    measured_state_index : list of int or None, length m
        State measured directly by each sensor channel (``None``: no single state).
    output_matrix : ndarray, shape (q, n), optional
        ``L`` of ``z = L x`` for the ratio ``T`` (default: the first two states).
    ratio_weight : ndarray, shape (n, n), optional
        ``R`` in ``T``'s denominator ``||w||^2 + x0^T R x0`` (default identity).

    Notes
    -----
    The noise-output ratio follows Basin et al.::

        T = sqrt( sum_k |z_k - L xhat_k|^2 dt / (sum_k |w_k|^2 dt + x0^T R x0) )

    with ``x0`` the true initial state. It is reported only when a deterministic disturbance
    ``w`` is present.

    Batch axis: after ``reset(x0)`` with ``x0`` of shape ``(..., n)`` the leading axes
    (:attr:`batch_shape`) are independent episodes stepped together; :meth:`update` then takes
    ``(..., n)`` states, ``(..., n, n)`` (or one shared ``(n, n)``) covariances, ``(..., m)``
    measurements and a shared ``(s,)`` or per-episode ``(..., s)`` disturbance, and the
    accessors return arrays of shape :attr:`batch_shape` where they return floats for a single
    episode. The products are numpy's ``vecdot``/``matvec``/``vecmat``, which give bitwise the
    single-episode results row by row.
    """

    def __init__(self, state_names: list[str], dt_s: float,
                 measured_state_index: list[int | None],
                 output_matrix: np.ndarray | None = None,
                 ratio_weight: np.ndarray | None = None):
        n = len(state_names)
        self.state_names = list(state_names)
        self.dt_s = dt_s
        self.measured_state_index = list(measured_state_index)
        self.output_matrix = np.eye(n) if output_matrix is None else np.asarray(output_matrix)
        self.ratio_weight = np.eye(n) if ratio_weight is None else np.asarray(ratio_weight)
        self.reset(np.zeros(n))

    def reset(self, x0: np.ndarray) -> None:
        """Start a new episode from the true initial state ``x0``, shape (n,) or (..., n)."""
        x0 = np.asarray(x0, dtype=float)
        n = len(self.state_names)
        if x0.ndim < 1 or x0.shape[-1] != n:
            raise ValueError(f"x0 must have shape ({n},) or (..., {n}), got shape {x0.shape}")
        #: Leading batch axes (``()`` for a single episode).
        self.batch_shape: tuple[int, ...] = x0.shape[:-1]
        if self.batch_shape:
            self._x0_weight = np.vecdot(np.vecmat(x0, self.ratio_weight), x0)
        else:
            self._x0_weight = float(x0 @ self.ratio_weight @ x0)
        zero = np.zeros(self.batch_shape) if self.batch_shape else 0.0
        self.count = 0
        self._sq_err = np.zeros(x0.shape)
        self._nees_sum = zero
        self._nees_count = 0
        self._meas_sq: dict[str, float | np.ndarray] = {}
        self._z_err_sq = zero
        self._w_sq = zero
        self._has_w = False

    def update(self, x_true: np.ndarray, x_hat: np.ndarray, P: np.ndarray | None,
               y: np.ndarray, w: np.ndarray | None) -> None:
        """Add one control step.

        Parameters
        ----------
        x_true, x_hat : ndarray, shape (n,) or (..., n)
        P : ndarray, shape (n, n) or (..., n, n), or None
            Estimator covariance (NEES uses it when given).
        y : ndarray, shape (m,) or (..., m)
            Measurement.
        w : ndarray, shape (s,) or (..., s), or None
            Deterministic disturbance applied over the step (shared by a batch when 1-D).
        """
        err = x_hat - x_true
        single = err.ndim == 1  # plain products; the batched ones equal them row by row
        self.count += 1
        self._sq_err += err**2
        if P is not None:
            self._nees_sum = self._nees_sum + nees(err, P)
            self._nees_count += 1
        y_t, x_t = y.T, x_true.T  # channel-major: y_t[channel] is (...,) in both cases
        for channel, state in enumerate(self.measured_state_index):
            if state is not None:
                name = self.state_names[state]
                self._meas_sq[name] = self._meas_sq.get(name, 0.0) + (y_t[channel]
                                                                       - x_t[state]) ** 2
        if single:
            z_err = self.output_matrix @ err
            self._z_err_sq += float(z_err @ z_err) * self.dt_s
        else:
            z_err = np.matvec(self.output_matrix, err)
            self._z_err_sq = self._z_err_sq + np.vecdot(z_err, z_err) * self.dt_s
        if w is not None and np.size(w):
            self._has_w = True
            w_sq = float(w @ w) if np.ndim(w) == 1 else np.vecdot(w, w)
            self._w_sq = self._w_sq + w_sq * self.dt_s

    def _out(self, value: np.ndarray) -> float | np.ndarray:
        """A float for a single episode, an array of shape ``batch_shape`` for a batch."""
        return np.asarray(value) if self.batch_shape else float(value)

    def rmse(self) -> dict[str, float | np.ndarray]:
        """Root-mean-square estimation error per state."""
        values = np.sqrt(self._sq_err / max(self.count, 1))
        if self.batch_shape:
            return {name: values[..., i] for i, name in enumerate(self.state_names)}
        return dict(zip(self.state_names, values.tolist(), strict=True))

    def measurement_rmse(self) -> dict[str, float | np.ndarray]:
        """RMSE of each directly measuring channel against the state it measures."""
        return {k: self._out(np.sqrt(v / max(self.count, 1))) for k, v in self._meas_sq.items()}

    def nees_mean(self) -> float | np.ndarray | None:
        """Mean normalized estimation error squared (expected ``n`` for a consistent filter)."""
        return self._out(self._nees_sum / self._nees_count) if self._nees_count else None

    def noise_output_ratio(self) -> float | np.ndarray | None:
        """Basin et al.'s ratio ``T`` over the episode so far, or None without a disturbance."""
        if not self._has_w:
            return None
        return self._out(np.sqrt(self._z_err_sq / (self._w_sq + self._x0_weight)))

    def summary(self, index: int | tuple[int, ...] | None = None) -> dict:
        """All metrics as a dict (``None`` where undefined).

        Parameters
        ----------
        index : int or tuple, optional
            Batch member to report (batched metrics only): its summary then has exactly the
            single-episode form (floats, JSON-ready). Without it a batch reports arrays of
            shape :attr:`batch_shape`.
        """
        if index is not None:
            if not self.batch_shape:
                raise ValueError("index is only valid for batched metrics")

            def pick(v):
                return None if v is None else float(np.asarray(v)[index])

            return {
                "steps": self.count,
                "rmse": {k: pick(v) for k, v in self.rmse().items()},
                "measurement_rmse": {k: pick(v) for k, v in self.measurement_rmse().items()},
                "nees_mean": pick(self.nees_mean()),
                "T_final": pick(self.noise_output_ratio()),
            }
        return {
            "steps": self.count,
            "rmse": self.rmse(),
            "measurement_rmse": self.measurement_rmse(),
            "nees_mean": self.nees_mean(),
            "T_final": self.noise_output_ratio(),
        }
