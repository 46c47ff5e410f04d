"""A new sensor decorator: a deadband that reports zero for small values."""

import numpy as np

from testbed.sensors import Decorator


class Deadband(Decorator):
    """``y`` where ``|y| > width``, else 0 (a sensor that cannot resolve small values)."""

    own_draws = 0  # no noise of its own

    def __init__(self, inner, width):
        super().__init__(inner)
        self.width = float(width)

    def apply(self, y, sample, noise):
        return np.where(np.abs(y) > self.width, y, 0.0)
