"""The helicopter's ``hardware`` profile: rotor lag, amplifier limits, deadband, IMU data.

What the real Quanser 2-DOF helicopter adds to Basin et al.'s static "torque per volt" model
(every value, its source and what is assumed: docs/helicopter.md, "Hardware profile"):

- **rotor lag**: the propeller speed follows the motor voltage with a first-order lag
  (MuJoCo ``dyntype="filterexact"``: ``act' = (V - act) / tau``, thrust and reaction torque
  proportional to ``act``, the "volt-equivalent" rotor speed that equals ``V`` at rest);
- **amplifier voltage limits** (pitch +-24 V, yaw +-15 V) and **current limits**: the motor
  current ``i = (V - c act) / R`` (back-EMF ``c act``, ``c`` the share of the voltage that
  is back-EMF at steady speed) is kept within ``+-I_max`` by lowering the voltage, at every
  physics step;
- **deadband**: ``V -> sign(V) max(|V| - d, 0)`` (static friction of brushes and bearings);
- **IMU** (rate gyros and an accelerometer at the pivot, MPU-9250 class, see
  :mod:`testbed.rigs.helicopter.imu`).

The matched design model (``HelicopterRig.design_model`` in this profile) models these
effects from the declared parameters; ``design_profile="paper"`` keeps Basin et al.'s model,
for which the hardware is model mismatch.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from testbed.records import field_values


@dataclass(frozen=True)
class HelicopterHardware:
    """Actuator and IMU parameters of the ``hardware`` profile (pitch motor first).

    Attributes
    ----------
    motor_time_constant_s : tuple of float
        Rotor (propeller speed) time constants ``tau = c R J / K_t^2`` of the pitch and yaw
        rotors, s.
    voltage_limit_v : tuple of float
        Amplifier output limits, V.
    current_limit_a : tuple of float
        Amplifier current limits, A.
    resistance_ohm : tuple of float
        Motor armature resistances ``R``, Ohm.
    back_emf_fraction : tuple of float
        ``c``: back-EMF over applied voltage at steady rotor speed (0 < c < 1).
    deadband_v : tuple of float
        Voltage that produces no rotor motion, V.
    gyro_noise_density : float
        Rate-gyro white-noise density, rad/s/sqrt(Hz).
    gyro_bias_walk : float
        Gyro bias random walk, rad/s/sqrt(s).
    gyro_bias0_std : float
        Gyro bias left after the power-on calibration (per episode), rad/s.
    accel_noise_density : float
        Accelerometer white-noise density, m/s^2/sqrt(Hz).
    accel_bias0_std : float
        Accelerometer bias left after calibration (per episode), m/s^2.
    scale_factor_std : float
        Sensitivity error of gyros and accelerometer (per episode), fraction.
    imu_delay_s : float
        Group delay of the IMU's digital low-pass filter, s (rounded to whole samples, at
        least one).
    imu_rate_hz : float
        IMU output data rate, Hz (held between its samples when the loop is faster).
    """

    motor_time_constant_s: tuple[float, float] = (0.06, 0.025)
    voltage_limit_v: tuple[float, float] = (24.0, 15.0)
    current_limit_a: tuple[float, float] = (5.0, 3.0)
    resistance_ohm: tuple[float, float] = (0.83, 0.83)
    back_emf_fraction: tuple[float, float] = (0.85, 0.85)
    deadband_v: tuple[float, float] = (0.2, 0.2)
    gyro_noise_density: float = float(np.deg2rad(0.01))
    gyro_bias_walk: float = float(np.deg2rad(1e-3))
    gyro_bias0_std: float = float(np.deg2rad(0.05))
    accel_noise_density: float = 300e-6 * 9.81
    accel_bias0_std: float = 0.05
    scale_factor_std: float = 0.01
    imu_delay_s: float = 0.0059
    imu_rate_hz: float = 100.0

    def __post_init__(self) -> None:
        fields = field_values(self)
        for f in dataclasses.fields(self):
            value = np.asarray(fields[f.name], dtype=float)
            if f.type.startswith("tuple") and value.shape != (2,):
                raise ValueError(f"HelicopterHardware.{f.name} must be two numbers (pitch, yaw), "
                                 f"got {fields[f.name]!r}")
            if not np.all(np.isfinite(value)) or np.any(value < 0):
                raise ValueError(f"HelicopterHardware.{f.name} must be finite and >= 0, got "
                                 f"{fields[f.name]!r}")
        for name in ("motor_time_constant_s", "voltage_limit_v", "current_limit_a",
                     "resistance_ohm", "imu_rate_hz"):
            if np.any(np.asarray(fields[name]) <= 0):
                raise ValueError(f"HelicopterHardware.{name} must be positive, got "
                                 f"{fields[name]!r}")
        if np.any(np.asarray(self.back_emf_fraction) >= 1):
            raise ValueError("HelicopterHardware.back_emf_fraction must be below 1, got "
                             f"{self.back_emf_fraction!r}")

    def constants(self) -> np.ndarray:
        """``[d_p, d_y, c_p, c_y, R_p I_p, R_y I_y]`` for the actuation hooks, shape (6,)."""
        return np.concatenate([self.deadband_v, self.back_emf_fraction,
                               np.multiply(self.resistance_ohm, self.current_limit_a)])


def deadband(volts: np.ndarray, width_v: np.ndarray) -> np.ndarray:
    """``sign(V) max(|V| - d, 0)`` elementwise (broadcasting ``width_v`` over the last axis)."""
    return np.sign(volts) * np.maximum(np.abs(volts) - width_v, 0.0)


def current_limited(command_v: np.ndarray, act_v: np.ndarray, back_emf_fraction: np.ndarray,
                    r_times_i_max: np.ndarray) -> np.ndarray:
    """The voltage reaching the motors: within ``c act +- R I_max`` (the current limit).

    Parameters
    ----------
    command_v : ndarray, shape (2,)
        Amplifier voltage command (clipped and past the deadband), V.
    act_v : ndarray, shape (2,)
        Volt-equivalent rotor speeds (MuJoCo ``act``), V.
    back_emf_fraction, r_times_i_max : ndarray, shape (2,)

    Returns
    -------
    ndarray, shape (2,)
    """
    back_emf = back_emf_fraction * act_v
    return np.clip(command_v, back_emf - r_times_i_max, back_emf + r_times_i_max)
