"""filterpy's extended Kalman filter as a testbed plug-in (``--filter fp_ekf.py:make``).

Written from ``docs/extending.md`` alone: the model is :func:`testbed.estimators.nonlinear_model`
(the rig's MJCF at nominal parameters, with a matched design's extra states), the filter is
filterpy's, the innovation attributes make ``testbed score`` report ANIS and whiteness.
"""

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from testbed.estimators import nonlinear_model


class FilterpyEKF:
    name = "fp-ekf"  # the label in run, mc and score

    def __init__(self, design):
        self.model = m = nonlinear_model(design)
        self.kf = ExtendedKalmanFilter(dim_x=m.n, dim_z=m.m, dim_u=m.k)
        self.kf.Q, self.kf.R = m.Q, m.R
        self.reset(m.x0, m.P0)

    x = property(lambda self: self.kf.x)
    P = property(lambda self: self.kf.P)
    innovation = property(lambda self: self.kf.y)  # y - h(x_prior), after a step
    innovation_cov = property(lambda self: self.kf.S)

    def reset(self, x0, P0):
        self.kf.x = np.array(x0, float)
        self.kf.P = np.array(self.model.P0 if P0 is None else P0, float)

    def step(self, y, u):
        m, kf = self.model, self.kf
        x_hat = kf.x  # the estimate the loop's u is relative to
        kf.F = m.F(x_hat, u, x_hat)
        kf.x = m.f(x_hat, u, x_hat)
        kf.P = kf.F @ kf.P @ kf.F.T + kf.Q
        kf.update(np.asarray(y, float), lambda x: m.H(x, u, x_hat),
                  lambda x: m.h(x, u, x_hat))
        return kf.x


make = FilterpyEKF  # the factory: make(design) -> estimator
