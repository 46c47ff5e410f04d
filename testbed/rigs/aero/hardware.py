"""The Aero's ``hardware`` profile: amplifier limits and the IMU's errors.

What the real Quanser Aero adds to Quanser's static "torque per volt" model (values, sources
and assumptions: docs/aero.md, "Hardware profile"):

- **rotor lag**: the propeller speed follows the motor voltage with a first-order lag
  (MuJoCo ``dyntype="filterexact"``; the time constants are parameters of the rig,
  :class:`testbed.rigs.aero.rig.AeroParams`, since a recording identifies them);
- **amplifier voltage limits** (+-24 V);
- **IMU** errors: a standing gyro bias drawn per episode (then a slow random walk), white
  noise per sample and the gyro's quantization, as a real unit's recording shows; the
  accelerometer's are assumptions (MEMS class);
- **rotor speeds and motor currents** (:mod:`testbed.rigs.aero.motors`): the DC motor's
  constants, white noise and quantization (assumptions).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from testbed.records import field_values
from testbed.rigs.aero.motors import AeroMotor


@dataclass(frozen=True)
class AeroHardware:
    """Amplifier and IMU parameters of the ``hardware`` profile (pitch motor first).

    Attributes
    ----------
    voltage_limit_v : tuple of float
        Amplifier output limits of the pitch and yaw motors, V.
    gyro_bias0_std : float
        Standing gyro bias drawn per episode (standard deviation), rad/s.
    gyro_bias_walk : float
        Gyro bias random walk, rad/s/sqrt(s).
    gyro_noise_std : float
        Gyro white noise per sample, rad/s (the loop reads the latest IMU sample: no
        averaging, whatever the loop's period).
    gyro_step : float
        Gyro quantization step, rad/s.
    accel_bias0_std : float
        Accelerometer bias left after calibration (per episode), m/s^2.
    accel_noise_std : float
        Accelerometer white noise per sample, m/s^2.
    accel_step : float
        Accelerometer quantization step, m/s^2.
    motor : AeroMotor
        The rotors' DC motor (resistance, motor constant, load).
    rotor_speed_noise_std : float
        Rotor speed (tachometer) white noise per sample, rad/s.
    rotor_speed_step : float
        Rotor speed quantization step, rad/s.
    current_noise_std : float
        Motor current white noise per sample, A.
    current_step : float
        Motor current quantization step, A.
    """

    voltage_limit_v: tuple[float, float] = (24.0, 24.0)
    gyro_bias0_std: float = 0.0125
    gyro_bias_walk: float = float(np.deg2rad(1e-3))
    gyro_noise_std: float = 0.0023
    gyro_step: float = 1.3e-4
    accel_bias0_std: float = 0.05
    accel_noise_std: float = 0.05
    accel_step: float = 4.0 * 9.81 / 65536.0
    motor: AeroMotor = AeroMotor()
    rotor_speed_noise_std: float = 0.5
    rotor_speed_step: float = 0.1
    current_noise_std: float = 0.005
    current_step: float = 0.001

    def __post_init__(self) -> None:
        if not isinstance(self.motor, AeroMotor):
            raise ValueError(f"AeroHardware.motor must be an AeroMotor, got {self.motor!r}")
        fields = field_values(self)
        for f in dataclasses.fields(self):
            if f.name == "motor":
                continue
            value = np.asarray(fields[f.name], dtype=float)
            if f.name == "voltage_limit_v" and value.shape != (2,):
                raise ValueError(f"AeroHardware.{f.name} must be two numbers (pitch, yaw), "
                                 f"got {fields[f.name]!r}")
            if not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(f"AeroHardware.{f.name} must be finite and >= 0, got "
                                 f"{fields[f.name]!r}")
        for name in ("voltage_limit_v", "gyro_step", "accel_step", "rotor_speed_step",
                     "current_step"):
            if np.any(np.asarray(fields[name]) <= 0):
                raise ValueError(f"AeroHardware.{name} must be positive, got "
                                 f"{fields[name]!r}")
