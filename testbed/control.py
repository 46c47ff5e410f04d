"""Controllers usable as policies: LQR (with integral action) and gravity feed-forward."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg

from filters.models import LinearSystem


def discrete_lqr(F: np.ndarray, G: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Infinite-horizon discrete LQR gain ``K`` (``u = -K x``) from scipy's DARE.

    Parameters
    ----------
    F : ndarray, shape (n, n)
    G : ndarray, shape (n, k)
    Q : ndarray, shape (n, n)
        State weight, PSD.
    R : ndarray, shape (k, k)
        Input weight, PD.

    Returns
    -------
    ndarray, shape (k, n)
    """
    P = scipy.linalg.solve_discrete_are(F, G, Q, R)
    return np.linalg.solve(R + G.T @ P @ G, G.T @ P @ F)


class LQRTracker:
    """Setpoint-tracking LQR with integral action and gravity feed-forward (output feedback).

    ``u = u_ff(pitch_hat) - K [x_hat - x_ref; xi]`` where ``x_ref = [pitch_ref, yaw_ref, 0, 0]``,
    ``xi`` integrates the angle errors (``xi += dt (y_hat - y_ref)``, frozen while the
    amplifier saturates: anti-windup), and ``u_ff`` the voltages that cancel gravity at the
    estimated pitch. The gain is the discrete LQR of the linear model with ZOH at ``dt_s``.

    Parameters
    ----------
    A, B : ndarray, shapes (4, 4), (4, 2)
        Continuous-time model used for design (e.g. seed-000's).
    dt_s : float
        Control period in s.
    feedforward : callable ``pitch_rad -> (2,) volts``
        Gravity compensation.
    setpoint : callable ``t_s -> (2,) rad``
        Reference schedule (pitch, yaw).
    state_weight, input_weight, integral_weight : array_like
        Diagonals of the LQR weights (4 states; 2 inputs; 2 integrators).
    integral : bool
        Include integral action.
    voltage_limit_v : float
        Saturation used for anti-windup.
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, dt_s: float,
                 feedforward: Callable[[float], np.ndarray],
                 setpoint: Callable[[float], np.ndarray],
                 state_weight=(200.0, 100.0, 2.0, 5.0), input_weight=(0.05, 0.05),
                 integral_weight=(50.0, 20.0), integral: bool = True,
                 voltage_limit_v: float = 24.0):
        plant = LinearSystem(A=A, B=B, C=np.eye(2, A.shape[0]), Q=np.zeros_like(A),
                             R=np.eye(2)).discretize(dt_s)
        Fd, Gd = plant.F, plant.B
        self.integral = integral
        self.dt_s = dt_s
        if integral:
            n, k = B.shape
            Fa = np.zeros((n + 2, n + 2))
            Fa[:n, :n] = Fd
            Fa[n:, :2] = dt_s * np.eye(2)
            Fa[n:, n:] = np.eye(2)
            Ga = np.vstack([Gd, np.zeros((2, k))])
            Q = np.diag(np.concatenate([state_weight, integral_weight]))
            self.K = discrete_lqr(Fa, Ga, Q, np.diag(input_weight))
        else:
            self.K = discrete_lqr(Fd, Gd, np.diag(state_weight), np.diag(input_weight))
        self._feedforward = feedforward
        self._setpoint = setpoint
        self.voltage_limit_v = voltage_limit_v
        self.reset()

    def reset(self) -> None:
        """Clear the integrators and the clock."""
        self._xi = np.zeros(2)
        self._k = 0

    def __call__(self, x_hat: np.ndarray) -> np.ndarray:
        """Voltages for the current estimate.

        Parameters
        ----------
        x_hat : ndarray, shape (4,)
            State estimate ``[pitch, yaw, pitch_rate, yaw_rate]``.

        Returns
        -------
        ndarray, shape (2,)
            Motor voltages (V), within the saturation limits.
        """
        t_s = self._k * self.dt_s
        ref = self._setpoint(t_s)
        err = x_hat - np.concatenate([ref, np.zeros(2)])
        z = np.concatenate([err, self._xi]) if self.integral else err
        u = self._feedforward(x_hat[0]) - self.K @ z
        u_sat = np.clip(u, -self.voltage_limit_v, self.voltage_limit_v)
        if self.integral and np.all(u_sat == u):
            self._xi = self._xi + self.dt_s * err[:2]
        self._k += 1
        return u_sat

