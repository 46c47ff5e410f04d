"""A user estimator for the scoring tests: the steady-state Kalman filter (a fixed gain)."""

from __future__ import annotations

import numpy as np


class FixedGainKalman:
    """The steady-state Kalman filter: ``x+ = F x + B u``, ``x = x+ + K (y - H x+)`` with the
    steady-state gain times ``gain_scale`` (1: the Kalman filter at steady state).

    Its error system is linear time-invariant: ``e+ = (I - K H) (F e + E w)``.
    """

    batched = True

    def __init__(self, design, gain_scale: float = 1.0):
        from filters import KalmanFilter

        system = design.discrete
        P_prior, K = KalmanFilter(system, design.x0, design.P0).steady_state()
        self.F, self.B, self.H = system.F, system.B, system.H
        self.gain = float(gain_scale) * K
        self.P_post = P_prior - K @ system.H @ P_prior
        self.P_post = 0.5 * (self.P_post + self.P_post.T)
        self._x = np.array(design.x0, dtype=float)

    @property
    def x(self) -> np.ndarray:
        return self._x

    @property
    def P(self) -> np.ndarray:
        return np.broadcast_to(self.P_post, (*self._x.shape[:-1], *self.P_post.shape))

    def reset(self, x0, P0) -> None:
        self._x = np.array(x0, dtype=float)

    def step(self, y, u=None):
        x = self._x @ self.F.T
        if u is not None:
            x = x + np.asarray(u) @ self.B.T
        y = np.asarray(y)  # the channels the design's H describes (the loop selects them)
        self._x = x + (y - x @ self.H.T) @ self.gain.T
        return self._x


def make(design, **options):
    """``tests.score.fixed_gain:make`` (a ``module:factory`` path)."""
    return FixedGainKalman(design, **options)


def overconfident(design):
    """The Kalman filter whose covariance is divided by 10."""
    return ScaledCovariance(design, 0.1)


def half_covariance(design):
    """The Kalman filter reporting ``P / 2`` (overconfident)."""
    return ScaledCovariance(design, 0.5)


def double_covariance(design):
    """The Kalman filter reporting ``2 P`` (underconfident)."""
    return ScaledCovariance(design, 2.0)


def same_as_kalman(design):
    """The built-in Kalman filter under another name (an identical estimator)."""
    from testbed.estimators import kalman

    return kalman(design)


class ScaledCovariance:
    """The built-in Kalman filter reporting ``scale * P`` (its estimates unchanged)."""

    batched = True

    def __init__(self, design, scale: float):
        from testbed.estimators import kalman

        self.inner = kalman(design)
        self.scale = float(scale)

    @property
    def x(self):
        return self.inner.x

    @property
    def P(self):
        return self.scale * self.inner.P

    def reset(self, x0, P0):
        self.inner.reset(x0, P0)

    def step(self, y, u=None):
        return self.inner.step(y, u)


class BatchDependent(FixedGainKalman):
    """The fixed-gain filter whose reported estimate is offset by ``1e-4`` times the number
    of members it steps (an estimator whose arithmetic depends on its batch companions)."""

    @property
    def x(self) -> np.ndarray:
        return self._x + 1e-4 * len(np.atleast_2d(self._x))

    def step(self, y, u=None):
        return super().step(y, u) + 1e-4 * len(np.atleast_2d(self._x))


def batch_dependent(design, **options):
    """``fixed_gain:batch_dependent``."""
    return BatchDependent(design, **options)
