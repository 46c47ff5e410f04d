"""filterpy's unscented Kalman filter as a testbed plug-in (``--filter fp_ukf.py:make``).

Sigma points of one estimate share its ``u`` and ``x_hat``: one call of ``model.f`` per
sigma point (filterpy's loop). On the ``hardware`` profile's augmented design ``P`` is only
semidefinite (a delay state copies a rate: no noise of its own), where filterpy's default
Cholesky square root fails at the first step: :func:`psd_sqrt` (an eigendecomposition) is
the square root that works on both profiles, as the built-in ``ukf`` does.
"""

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from testbed.estimators import nonlinear_model


def psd_sqrt(P):
    """``U`` with ``U.T @ U = P`` for a symmetric positive semidefinite ``P``."""
    w, V = np.linalg.eigh((P + P.T) / 2)
    return np.sqrt(np.maximum(w, 0.0))[:, None] * V.T


class FilterpyUKF:
    name = "fp-ukf"

    def __init__(self, design, alpha=1e-3, beta=2.0, kappa=0.0):
        self.model = m = nonlinear_model(design)
        points = MerweScaledSigmaPoints(m.n, alpha=alpha, beta=beta, kappa=kappa,
                                        sqrt_method=psd_sqrt)
        self.kf = UnscentedKalmanFilter(m.n, m.m, m.dt_s, hx=self._hx, fx=self._fx,
                                        points=points)
        self.kf.Q, self.kf.R = m.Q, m.R
        self.reset(m.x0, m.P0)

    def _fx(self, x, dt, u, x_hat):
        return self.model.f(x, u, x_hat)

    def _hx(self, x, u, x_hat):
        return self.model.h(x, u, x_hat)

    x = property(lambda self: self.kf.x)
    P = property(lambda self: self.kf.P)
    innovation = property(lambda self: self.kf.y)
    innovation_cov = property(lambda self: self.kf.S)

    def reset(self, x0, P0):
        self.kf.x = np.array(x0, float)
        self.kf.P = np.array(self.model.P0 if P0 is None else P0, float)

    def step(self, y, u):
        x_hat = self.kf.x.copy()
        self.kf.predict(u=u, x_hat=x_hat)
        self.kf.update(np.asarray(y, float), u=u, x_hat=x_hat)
        self.kf.P = (self.kf.P + self.kf.P.T) / 2  # the weights of alpha = 1e-3 are ~1e6
        return self.kf.x


make = FilterpyUKF  # the factory: make(design, alpha=..., beta=..., kappa=...)
