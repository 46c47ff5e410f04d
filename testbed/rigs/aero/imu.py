"""The Aero's IMU: rate gyros (pitch, yaw) and the body's long-axis accelerometer.

The IMU sits on the body where the pitch and yaw axes meet, a point that does not move, so
the accelerometer reads gravity only. Body axes: x along the body towards the pitch rotor,
y left, z up along the body normal; the pitch hinge is ``-y``.

With ``x = [pitch, yaw, pitch_rate, yaw_rate]`` the body angular velocity is
``(yaw_rate sin(pitch), -pitch_rate, yaw_rate cos(pitch))`` and the specific force
``g (sin(pitch), 0, cos(pitch))``. Channels (exact, nonlinear):

- ``gyro_pitch`` = ``pitch_rate`` (sensitive axis ``-y``),
- ``gyro_yaw`` = ``yaw_rate cos(pitch)`` (body z; not with the yaw axis locked, where it
  reads zero),
- ``accel_x`` = ``g sin(pitch)``.

With the yaw axis locked the state is ``[pitch, pitch_rate]`` and the channels are
``gyro_pitch`` and ``accel_x``. A test compares them with MuJoCo's own ``gyro`` and
``accelerometer`` sensors at the ``imu`` site.
"""

from __future__ import annotations

import numpy as np

from testbed.rigs.base import GRAVITY_M_S2
from testbed.rigs.helicopter.imu import (  # the same pivot IMU geometry
    accel_x_gradient,
    accel_x_value,
    gyro_yaw_gradient,
    gyro_yaw_value,
)
from testbed.sensors import Noise, Sample, Sensor, SensorModel, no_input_gradient


class AeroIMU(Sensor):
    """Rate gyros and the long-axis accelerometer of the IMU at the pivot.

    Parameters
    ----------
    yaw_locked : bool
        The state is ``[pitch, pitch_rate]`` (no ``gyro_yaw``) instead of
        ``[pitch, yaw, pitch_rate, yaw_rate]``.
    """

    def __init__(self, yaw_locked: bool = False):
        self.yaw_locked = bool(yaw_locked)
        if self.yaw_locked:
            self.names, self.units = ("gyro_pitch", "accel_x"), ("rad/s", "m/s^2")
            self.measured_state = (1, None)
        else:
            self.names = ("gyro_pitch", "gyro_yaw", "accel_x")
            self.units = ("rad/s", "rad/s", "m/s^2")
            self.measured_state = (2, None, None)

    def draws_per_sample(self) -> int:
        """0: noise comes from decorators."""
        return 0

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``[pitch_rate, (yaw_rate cos(pitch),) g sin(pitch)]``, shape (k, 2 or 3)."""
        x = sample.x
        pitch = x[:, 0]
        if self.yaw_locked:
            return np.stack([x[:, 1], GRAVITY_M_S2 * np.sin(pitch)], axis=1)
        return np.stack([x[:, 2], x[:, 3] * np.cos(pitch), GRAVITY_M_S2 * np.sin(pitch)],
                        axis=1)

    def linear_model(self) -> SensorModel:
        """The first-order model about level pitch (no noise: decorators add it), with the
        exact nonlinear ``gyro_yaw`` and ``accel_x`` (the EKF/UKF measure with them)."""
        if self.yaw_locked:
            C = np.array([[0.0, 1.0], [GRAVITY_M_S2, 0.0]])
        else:
            C = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0],
                          [GRAVITY_M_S2, 0.0, 0.0, 0.0]])
        nonlinear = {"accel_x": (accel_x_value, accel_x_gradient, no_input_gradient)}
        if not self.yaw_locked:
            nonlinear["gyro_yaw"] = (gyro_yaw_value, gyro_yaw_gradient, no_input_gradient)
        m = len(C)
        return SensorModel(C=C, D=np.zeros((m, 2)), R=np.zeros((m, m)), Hw=np.zeros((m, 0)),
                           stochastic=np.ones(m, bool), nonlinear=nonlinear)
