"""Channels of the vehicle roll rig: an automotive IMU and Zhang et al.'s output channels.

A white-noise density ``N`` (unit/sqrt(Hz)) sampled at ``f_s = 1 / dt_s`` has the per-sample
standard deviation ``N sqrt(f_s)`` (the sensor's bandwidth taken as the Nyquist band).
State ``x = [roll, roll_rate]`` (rad, rad/s); input ``a_y`` (m/s^2).
"""

from __future__ import annotations

import numpy as np

from testbed.manoeuvres import PaperDecay
from testbed.rigs.base import GRAVITY_M_S2
from testbed.rigs.vehicle_roll.model import paper_model
from testbed.sensors import (
    Bias,
    BiasRandomWalk,
    Delay,
    Noise,
    Sample,
    ScaleFactor,
    Sensor,
    SensorModel,
    StateChannel,
    Suite,
    WhiteNoise,
)

#: Representative automotive MEMS gyro white-noise density: 0.01 deg/s/sqrt(Hz), rad/s/sqrt(Hz).
GYRO_NOISE_DENSITY = float(np.deg2rad(0.01))
#: Representative gyro bias random walk: 1e-4 deg/s/sqrt(s), rad/s/sqrt(s).
GYRO_BIAS_WALK = float(np.deg2rad(1e-4))
#: Representative MEMS accelerometer noise density: 150 micro-g/sqrt(Hz), m/s^2/sqrt(Hz).
ACCEL_NOISE_DENSITY = 150e-6 * GRAVITY_M_S2
#: Representative roll-angle sensor noise (e.g. a dual-antenna GNSS/INS), rad per sample.
ROLL_NOISE_STD = float(np.deg2rad(0.1))

#: ``hardware`` preset (assumptions, docs/vehicle_roll.md): gyro offset left after the
#: standstill calibration, rad/s (per episode).
HW_GYRO_BIAS0_STD = float(np.deg2rad(0.05))
#: Accelerometer offset (mounting tilt and calibration residual), m/s^2 (per episode).
HW_ACCEL_BIAS0_STD = 0.02
#: Sensitivity (scale-factor) error of gyro and accelerometer, fraction (per episode).
HW_SCALE_FACTOR_STD = 0.01
#: Latency of the sensor cluster's CAN messages, s (rounded to whole samples, >= 1).
HW_CAN_DELAY_S = 0.01


class LateralAccelerometer(Sensor):
    """Specific force along the body's lateral axis: ``a_y cos(roll) + g sin(roll)`` (m/s^2).

    Mounted on the roll axis; the tangential term of a lever arm is not modelled. Linear
    model about ``roll = 0``: ``C = [g, 0]``, ``D = [1]``.
    """

    names, units, measured_state = ("lateral_accel",), ("m/s^2",), (None,)

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``a_y cos(roll) + g sin(roll)``, shape (k, 1)."""
        roll = sample.x[:, 0]
        return (sample.u[:, 0] * np.cos(roll) + GRAVITY_M_S2 * np.sin(roll))[:, None]

    def linear_model(self) -> SensorModel:
        """``y = g roll + a_y``."""
        return SensorModel(C=np.array([[GRAVITY_M_S2, 0.0]]), D=np.ones((1, 1)),
                           R=np.zeros((1, 1)), Hw=np.zeros((1, 0)), stochastic=np.ones(1, bool))


def imu(dt_s: float = 0.01, gyro_noise_density: float = GYRO_NOISE_DENSITY,
        gyro_bias_walk: float = GYRO_BIAS_WALK, gyro_bias0_std: float = 0.0,
        accel_noise_density: float = ACCEL_NOISE_DENSITY, accel_bias: float = 0.0,
        roll_sensor: bool = False, roll_noise_std: float = ROLL_NOISE_STD,
        accel_bias0_std: float = 0.0, scale_factor_std: float = 0.0,
        delay_samples: int = 0) -> Suite:
    """Roll-rate gyro, lateral accelerometer and an optional roll-angle sensor.

    Channels: ``roll_rate`` (rad/s) = ``roll_rate + n_g + b_k`` with a bias random walk;
    ``lateral_accel`` (m/s^2) = :class:`LateralAccelerometer` ``+ b_a + n_a``; ``roll``
    (rad) = ``roll + n_r``. Defaults are representative of automotive MEMS IMUs (Bosch
    BMI088/SMI, ST ASM330 class): at 100 Hz ``sigma_g = 0.1 deg/s``,
    ``sigma_a = 0.0147 m/s^2`` per sample.

    Hardware effects (off by default; the ``hardware`` preset turns them on): a random
    accelerometer offset ``accel_bias0_std`` per episode, a sensitivity error
    ``scale_factor_std`` per episode on gyro and accelerometer, and a transport delay of
    ``delay_samples`` samples on both (CAN latency).
    """
    if int(delay_samples) != delay_samples or delay_samples < 0:
        raise ValueError(f"delay_samples must be a non-negative integer, got {delay_samples!r}")

    def scaled(channel: Sensor) -> Sensor:
        return ScaleFactor(channel, initial_std=scale_factor_std) if scale_factor_std else channel

    def delayed(channel: Sensor) -> Sensor:
        return Delay(channel, int(delay_samples)) if delay_samples else channel

    gyro = BiasRandomWalk(WhiteNoise(scaled(StateChannel(1, 2, 1, "roll_rate", "rad/s")),
                                     density=gyro_noise_density, dt_s=dt_s),
                          walk=gyro_bias_walk, dt_s=dt_s, initial_std=gyro_bias0_std)
    accel: Sensor = Bias(scaled(LateralAccelerometer()), accel_bias)
    if accel_bias0_std:
        accel = BiasRandomWalk(accel, walk=0.0, dt_s=dt_s, initial_std=accel_bias0_std)
    accel = WhiteNoise(accel, density=accel_noise_density, dt_s=dt_s)
    parts: list[Sensor] = [delayed(gyro), delayed(accel)]
    if roll_sensor:
        parts.append(WhiteNoise(StateChannel(0, 2, 1, "roll", "rad"), std=roll_noise_std))
    return Suite(*parts)


def hardware(dt_s: float = 0.01, **options) -> Suite:
    """The ``hardware`` preset: :func:`imu` with the documented hardware effects on.

    Gyro offset ``HW_GYRO_BIAS0_STD`` and accelerometer offset ``HW_ACCEL_BIAS0_STD`` per
    episode, sensitivity error ``HW_SCALE_FACTOR_STD``, CAN latency ``HW_CAN_DELAY_S``
    (whole samples, at least one). ``options`` override any :func:`imu` argument.
    """
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be a positive sampling period in s, got {dt_s}")
    defaults = {"gyro_bias0_std": HW_GYRO_BIAS0_STD, "accel_bias0_std": HW_ACCEL_BIAS0_STD,
                "scale_factor_std": HW_SCALE_FACTOR_STD,
                "delay_samples": max(1, int(round(HW_CAN_DELAY_S / dt_s)))}
    return imu(dt_s=dt_s, **{**defaults, **options})


class PaperRollChannel(Sensor):
    """Zhang et al.'s measurement ``y_k = H x_k + L v_k`` (52), optionally with white noise.

    ``v_k = 0.01 * 0.9^k`` is the paper's disturbance at the sample time
    (:class:`testbed.manoeuvres.PaperDecay`), unless the scenario's disturbance ``w``
    (size 1) is given. The channels mix both states (no ``measured_state``).

    Parameters
    ----------
    noise_std : float
        Extra white noise per sample on each channel (0: the paper's noiseless channel).
    """

    names, units, measured_state = ("y1", "y2"), ("-", "-"), (None, None)
    #: Floor on the design noise std so ``R`` is positive definite with ``noise_std = 0``.
    DESIGN_STD_FLOOR = 1e-4

    def __init__(self, noise_std: float = 0.0):
        noise_std = float(noise_std)
        if not (np.isfinite(noise_std) and noise_std >= 0):
            raise ValueError(f"noise_std must be finite and non-negative, got {noise_std}")
        self.noise_std = noise_std
        model = paper_model()
        self.H, self.L = model.H, model.L
        self._v = PaperDecay()
        self.lmi_amplitude = self._v.amplitude_m_s2

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``H x + L v (+ noise)``, shape (k, 2)."""
        v = sample.w if sample.w.shape[1] == 1 else np.asarray(self._v(sample.t_s))[:, None]
        y = np.matvec(self.H, sample.x) + np.matvec(self.L, v)
        if self.noise_std:
            y = y + self.noise_std * noise.normal(2)
        return y

    def linear_model(self) -> SensorModel:
        """``H`` and ``R = L L^T v_0^2 + s^2 I`` (``L v`` as white noise), ``s >= 1e-4``."""
        v0 = self._v.amplitude_m_s2
        s = max(self.noise_std, self.DESIGN_STD_FLOOR)
        return SensorModel(C=self.H.copy(), D=np.zeros((2, 1)),
                           R=self.L @ self.L.T * v0**2 + s**2 * np.eye(2),
                           Hw=np.zeros((2, 0)), stochastic=np.ones(2, bool))
