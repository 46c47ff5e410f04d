"""Controllers for the closed loop, batch-first: LQR tracking with integral action, open loop.

A controller is ``reset(num)`` then ``__call__(x_hat (N, n), t_s) -> u (N, nu)``; it acts on
the estimate (output feedback), never on the true state.
"""

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
    """Setpoint-tracking LQR with integral action and feed-forward, for N members.

    ``u = u_ff(x_hat) - K [x_hat - x_ref; xi]`` where ``x_ref`` holds the references of the
    tracked states (zero elsewhere), ``xi`` integrates the tracked errors (frozen while the
    input saturates: anti-windup) and ``u_ff`` is the rig's operating input (e.g. the
    gravity-compensating voltage) at the estimate. The gain is the discrete LQR of the
    design model ``(A, B)`` with ZOH at ``dt_s``.

    Parameters
    ----------
    A, B : ndarray, shapes (n, n), (n, nu)
        Continuous-time design model.
    dt_s : float
        Control period, s.
    tracked : ndarray of int, shape (r,)
        Indices of the tracked states.
    feedforward : callable ``x_hat (N, n) -> (N, nu)``
    setpoint : callable ``t_s -> (N, r) or (r,)``
    state_weight, input_weight, integral_weight : array_like
        Diagonals of the LQR weights (n states; nu inputs; r integrators).
    integral : bool
        Include integral action.
    low, high : array_like, shape (nu,)
        Saturation used for anti-windup.
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, dt_s: float, tracked: np.ndarray,
                 feedforward: Callable[[np.ndarray], np.ndarray],
                 setpoint: Callable[[float], np.ndarray], state_weight, input_weight,
                 integral_weight, integral: bool = True, low=-np.inf, high=np.inf):
        n, k = B.shape
        self.tracked = np.asarray(tracked, dtype=int)
        r = len(self.tracked)
        plant = LinearSystem(A=A, B=B, C=np.eye(n)[self.tracked], Q=np.zeros_like(A),
                             R=np.eye(r)).discretize(dt_s)
        Fd, Gd = plant.F, plant.B
        self.integral, self.dt_s = integral, dt_s
        if integral:
            Fa = np.zeros((n + r, n + r))
            Fa[:n, :n] = Fd
            Fa[n:, self.tracked] = dt_s * np.eye(r)
            Fa[n:, n:] = np.eye(r)
            Ga = np.vstack([Gd, np.zeros((r, k))])
            Q = np.diag(np.concatenate([state_weight, integral_weight]))
            self.K = discrete_lqr(Fa, Ga, Q, np.diag(input_weight))
        else:
            self.K = discrete_lqr(Fd, Gd, np.diag(state_weight), np.diag(input_weight))
        self._feedforward, self._setpoint = feedforward, setpoint
        self.low, self.high = np.asarray(low, float), np.asarray(high, float)
        # the tracked columns as a slice when consecutive (a view, not a fancy-index copy)
        r0 = int(self.tracked[0]) if r else 0
        self._cols = (slice(r0, r0 + r) if np.array_equal(self.tracked, np.arange(r0, r0 + r))
                      else self.tracked)
        self.reset(1)

    def reset(self, num: int) -> None:
        """Clear the integrators of ``num`` members."""
        self._xi = np.zeros((num, len(self.tracked)))
        self._z = np.empty((num, self.K.shape[1]))  # [x_hat - x_ref, xi] of a call

    def __call__(self, x_hat: np.ndarray, t_s: float) -> np.ndarray:
        """Inputs (N, nu) for the estimates ``x_hat`` (N, n) at time ``t_s``."""
        cols = self._cols
        x_ref = np.zeros(x_hat.shape)
        x_ref[:, cols] = self._setpoint(t_s)  # (N, r) or (r,), broadcast
        if self.integral:
            z = self._z  # what np.concatenate([err, xi], axis=1) returned, without its wrapper
            if z.shape[0] != len(x_hat):
                z = self._z = np.empty((len(x_hat), self.K.shape[1]))
            n = x_hat.shape[1]
            err = np.subtract(x_hat, x_ref, out=z[:, :n])
            z[:, n:] = self._xi
        else:
            z = err = x_hat - x_ref
        u = self._feedforward(x_hat) - np.matvec(self.K, z)
        # np.clip(u, low, high), bitwise (NaN stays NaN), without its Python wrappers
        u_sat = np.minimum(np.maximum(u, self.low), self.high)
        if self.integral:
            free = u_sat == u
            xi = self._xi + self.dt_s * err[:, cols]
            # (no member saturated, the usual case: np.where would pick every new value)
            self._xi = xi if free.all() else np.where(
                np.logical_and.reduce(free, axis=1)[:, None], xi, self._xi)
        return u_sat


class OpenLoop:
    """A constant input (the rig's operating input at its linearization point), N members."""

    def __init__(self, action: np.ndarray):
        self.action = np.asarray(action, dtype=float)
        self._out: np.ndarray | None = None  # the last call's read-only broadcast view

    def reset(self, num: int) -> None:
        """Nothing to clear."""

    def __call__(self, x_hat: np.ndarray, t_s: float) -> np.ndarray:
        """``action`` for every member, (N, nu): a read-only view of ``action``, the same
        object while ``action`` and N are (np.broadcast_to costs more than the step's use)."""
        out, n = self._out, len(x_hat)
        if out is None or len(out) != n or out.base is not self.action:
            out = self._out = np.broadcast_to(self.action, (n, len(self.action)))
        return out


#: LQR weights per rig name (diagonals); other rigs get identity weights.
LQR_WEIGHTS = {
    "helicopter": {"state_weight": (200.0, 100.0, 2.0, 5.0), "input_weight": (0.05, 0.05),
                   "integral_weight": (50.0, 20.0)},
}
CONTROLLERS = ("lqr", "open-loop")


def make_controller(name: str, rig, design, setpoint: Callable[[float], np.ndarray]):
    """A controller by name for a rig and its design model.

    Parameters
    ----------
    name : {"lqr", "open-loop"}
        ``open-loop``: the operating input at the linearization point (the helicopter's
        hover voltage, zero for the vehicle, whose manoeuvre drives it).
    rig : Rig
    design : DesignModel
    setpoint : callable ``t_s -> (N, r)``
    """
    nominal = rig.params_type()
    if name == "open-loop":
        return OpenLoop(rig.operating_input(nominal, rig.linearization_point()[None])[0])
    if name != "lqr":
        raise ValueError(f"unknown controller {name!r}; expected one of {CONTROLLERS}")
    n, k, r = rig.n_states, rig.n_actions, len(rig.tracked_states)
    # the rig's own weights (an instance may change its dimension: the Aero's yaw_locked)
    weights = rig.lqr_weights or LQR_WEIGHTS.get(
        rig.name, {"state_weight": np.ones(n), "input_weight": np.ones(k),
                   "integral_weight": np.ones(r)})
    return LQRTracker(design.continuous.A, design.continuous.B, design.dt_s, rig.tracked_index,
                      lambda x: rig.operating_input(nominal, x), setpoint, **weights,
                      low=rig.action_low, high=rig.action_high)
