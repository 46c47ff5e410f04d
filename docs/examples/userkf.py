"""A user's estimator: a steady-state Kalman filter built from the design model.

Used as ``testbed run helicopter --filter userkf:make`` with this directory on PYTHONPATH.
"""

import numpy as np
import scipy.linalg


class SteadyStateKF:
    """Constant-gain Kalman filter on ``design.discrete``, for one run (not batched)."""

    def __init__(self, design):
        sys_ = design.discrete
        self.F, self.B, self.H = sys_.F, sys_.B, sys_.H
        P = scipy.linalg.solve_discrete_are(sys_.F.T, sys_.H.T, sys_.Q, sys_.R)
        S = sys_.H @ P @ sys_.H.T + sys_.R
        self.K = P @ sys_.H.T @ np.linalg.inv(S)
        self.D = sys_.D
        self.x = design.x0.copy()
        self.P = None  # no covariance reported

    def reset(self, x0, P0):
        self.x = np.array(x0, dtype=float)

    def step(self, y, u):
        x_pred = self.F @ self.x + self.B @ u
        y_pred = self.H @ x_pred + (0 if self.D is None else self.D @ u)
        self.x = x_pred + self.K @ (np.asarray(y) - y_pred)  # y: the channels H describes
        return self.x


def make(design):
    """The factory ``testbed`` calls: ``make(design) -> estimator``."""
    return SteadyStateKF(design)
