"""Streaming estimation metrics: RMSE, NEES, measurement RMSE and the noise-output ratio T.

Nothing is stored per step: sums accumulate, so an 80 s episode or a thousand of them cost
the same memory.
"""

from __future__ import annotations

import numpy as np


class EpisodeMetrics:
    """Accumulate estimation metrics over one episode.

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
    The noise-output ratio follows seed-000::

        T = sqrt( sum_k |z_k - L xhat_k|^2 dt / (sum_k |w_k|^2 dt + x0^T R x0) )

    with ``x0`` the true initial state. It is reported only when a deterministic disturbance
    ``w`` is present.
    """

    def __init__(self, state_names: list[str], dt_s: float,
                 measured_state_index: list[int | None],
                 output_matrix: np.ndarray | None = None,
                 ratio_weight: np.ndarray | None = None):
        n = len(state_names)
        self.state_names = list(state_names)
        self.dt_s = dt_s
        self.measured_state_index = list(measured_state_index)
        self.output_matrix = np.eye(2, n) if output_matrix is None else np.asarray(output_matrix)
        self.ratio_weight = np.eye(n) if ratio_weight is None else np.asarray(ratio_weight)
        self.reset(np.zeros(n))

    def reset(self, x0: np.ndarray) -> None:
        """Start a new episode from the true initial state ``x0`` (shape (n,))."""
        n = len(self.state_names)
        self._x0_weight = float(x0 @ self.ratio_weight @ x0)
        self.count = 0
        self._sq_err = np.zeros(n)
        self._nees_sum = 0.0
        self._nees_count = 0
        self._meas_sq = {}
        self._z_err_sq = 0.0
        self._w_sq = 0.0
        self._has_w = False

    def update(self, x_true: np.ndarray, x_hat: np.ndarray, P: np.ndarray | None,
               y: np.ndarray, w: np.ndarray | None) -> None:
        """Add one control step.

        Parameters
        ----------
        x_true, x_hat : ndarray, shape (n,)
        P : ndarray, shape (n, n) or None
            Estimator covariance (NEES uses it when given).
        y : ndarray, shape (m,)
            Measurement.
        w : ndarray, shape (s,) or None
            Deterministic disturbance applied over the step.
        """
        err = x_hat - x_true
        self.count += 1
        self._sq_err += err**2
        if P is not None:
            self._nees_sum += float(err @ np.linalg.solve(P, err))
            self._nees_count += 1
        for channel, state in enumerate(self.measured_state_index):
            if state is not None:
                name = self.state_names[state]
                self._meas_sq[name] = self._meas_sq.get(name, 0.0) + (y[channel]
                                                                       - x_true[state]) ** 2
        z_err = self.output_matrix @ err
        self._z_err_sq += float(z_err @ z_err) * self.dt_s
        if w is not None and len(w):
            self._has_w = True
            self._w_sq += float(w @ w) * self.dt_s

    def rmse(self) -> dict[str, float]:
        """Root-mean-square estimation error per state."""
        values = np.sqrt(self._sq_err / max(self.count, 1))
        return dict(zip(self.state_names, values.tolist(), strict=True))

    def measurement_rmse(self) -> dict[str, float]:
        """RMSE of each directly measuring channel against the state it measures."""
        return {k: float(np.sqrt(v / max(self.count, 1))) for k, v in self._meas_sq.items()}

    def nees_mean(self) -> float | None:
        """Mean normalized estimation error squared (expected ``n`` for a consistent filter)."""
        return self._nees_sum / self._nees_count if self._nees_count else None

    def noise_output_ratio(self) -> float | None:
        """seed-000's ratio ``T`` over the episode so far, or None without a disturbance."""
        if not self._has_w:
            return None
        return float(np.sqrt(self._z_err_sq / (self._w_sq + self._x0_weight)))

    def summary(self) -> dict:
        """All metrics as a JSON-ready dict (``None`` where undefined)."""
        return {
            "steps": self.count,
            "rmse": self.rmse(),
            "measurement_rmse": self.measurement_rmse(),
            "nees_mean": self.nees_mean(),
            "T_final": self.noise_output_ratio(),
        }
