"""An IMU on the helicopter: two rate gyros and the forward accelerometer axis, at the pivot.

The Quanser 2-DOF helicopter has encoders only; the ``hardware`` sensor preset adds a MEMS
IMU (MPU-9250 class) on the body at the pivot, the point where the pitch and yaw axes meet
(it does not move, so the accelerometer reads gravity only). Body axes: x forward (nose),
y left, z up along the body normal; the pitch hinge is ``-y``.

With ``x = [pitch, yaw, pitch_rate, yaw_rate]`` the body angular velocity is
``(yaw_rate sin(pitch), -pitch_rate, yaw_rate cos(pitch))`` and the specific force
``g (sin(pitch), 0, cos(pitch))``. Channels (exact, nonlinear):

- ``gyro_pitch`` = ``pitch_rate`` (sensitive axis ``-y``),
- ``gyro_yaw`` = ``yaw_rate cos(pitch)`` (body z),
- ``accel_x`` = ``g sin(pitch)`` (the vertical axis reads ``g cos(pitch)``: no first-order
  information; the lateral one reads 0).

Linear model about level pitch: ``C = [[0, 0, 1, 0], [0, 0, 0, 1], [g, 0, 0, 0]]``. A test
compares the channels with MuJoCo's own ``gyro`` and ``accelerometer`` sensors at the site.
"""

from __future__ import annotations

import numpy as np

from testbed.rigs.base import GRAVITY_M_S2
from testbed.sensors import Noise, Sample, Sensor, SensorModel, no_input_gradient


def gyro_yaw_value(x: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
    """``gyro_yaw = yaw_rate cos(pitch)``, shape (M,) for ``x`` (M, 4)."""
    return x[:, 3] * np.cos(x[:, 0])


def gyro_yaw_gradient(x: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
    """``d gyro_yaw / dx``, shape (M, 4)."""
    zero = np.zeros(len(x))
    return np.stack([-x[:, 3] * np.sin(x[:, 0]), zero, zero, np.cos(x[:, 0])], axis=1)


def accel_x_value(x: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
    """``accel_x = g sin(pitch)``, shape (M,) (pitch first in the state)."""
    return g * np.sin(x[:, 0])


def accel_x_gradient(x: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
    """``d accel_x / dx``, shape (M, n) for ``x`` (M, n) (pitch first: the 4 states, or the
    Aero's 2 with its yaw axis locked)."""
    return np.concatenate([g * np.cos(x[:, :1]), np.zeros_like(x[:, 1:])], axis=1)


class HelicopterIMU(Sensor):
    """Rate gyros (pitch, yaw) and the forward accelerometer axis of an IMU at the pivot."""

    names = ("gyro_pitch", "gyro_yaw", "accel_x")
    units = ("rad/s", "rad/s", "m/s^2")
    measured_state = (2, None, None)

    def draws_per_sample(self) -> int:
        """0: noise comes from decorators."""
        return 0

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``[pitch_rate, yaw_rate cos(pitch), g sin(pitch)]``, shape (k, 3)."""
        pitch, pitch_rate, yaw_rate = sample.x[:, 0], sample.x[:, 2], sample.x[:, 3]
        return np.stack([pitch_rate, yaw_rate * np.cos(pitch), GRAVITY_M_S2 * np.sin(pitch)],
                        axis=1)

    def linear_model(self) -> SensorModel:
        """The first-order model about level pitch (no noise: decorators add it), with the
        exact nonlinear ``gyro_yaw`` and ``accel_x``."""
        C = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0], [GRAVITY_M_S2, 0.0, 0.0, 0.0]])
        return SensorModel(C=C, D=np.zeros((3, 2)), R=np.zeros((3, 3)), Hw=np.zeros((3, 0)),
                           stochastic=np.ones(3, bool),
                           nonlinear={"gyro_yaw": (gyro_yaw_value, gyro_yaw_gradient,
                                                   no_input_gradient),
                                      "accel_x": (accel_x_value, accel_x_gradient,
                                                  no_input_gradient)})
