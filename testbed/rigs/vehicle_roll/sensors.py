"""Channels of the vehicle roll rig: an automotive IMU and Zhang et al.'s output channels.

A white-noise density ``N`` (unit/sqrt(Hz)) sampled at ``f_s = 1 / dt_s`` has the per-sample
standard deviation ``N sqrt(f_s)`` (the sensor's bandwidth taken as the Nyquist band).
State ``x = [roll, roll_rate]`` (rad, rad/s); input ``a_y`` (m/s^2).

The estimator's input ``a_y`` is not known exactly on a real vehicle: the ``imu`` and
``hardware`` presets carry a wheel-speed channel and a yaw-rate gyro
(:class:`SpeedYawRate`), tapped so that the design model's input transform gives the
estimator ``a_y = speed x yaw rate`` of the same sample (``a_y_source="measured"``).
"""

from __future__ import annotations

import numpy as np

from testbed.rigs.base import GRAVITY_M_S2
from testbed.rigs.vehicle_roll.manoeuvres import PaperDecay
from testbed.rigs.vehicle_roll.model import paper_model
from testbed.sensors import (
    Bias,
    BiasRandomWalk,
    Delay,
    Noise,
    Quantize,
    Sample,
    SampleAndHold,
    ScaleFactor,
    Sensor,
    SensorModel,
    StateChannel,
    Suite,
    Tap,
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

#: Vehicle speed of the speed channel, m/s (80 km/h, the double lane change's speed).
SPEED_M_S = 80.0 / 3.6
#: Wheel-speed-derived vehicle speed: white noise per sample, m/s (assumption).
SPEED_NOISE_STD = 0.05
#: Resolution of the speed signal on CAN, m/s (0.01 km/h; assumption).
SPEED_RESOLUTION = 0.01 / 3.6

#: ``hardware`` preset (assumptions, docs/vehicle_roll.md): gyro offset left after the
#: standstill calibration, rad/s (per episode).
HW_GYRO_BIAS0_STD = float(np.deg2rad(0.05))
#: Accelerometer offset (mounting tilt and calibration residual), m/s^2 (per episode).
HW_ACCEL_BIAS0_STD = 0.02
#: Sensitivity (scale-factor) error of gyro and accelerometer, fraction (per episode).
HW_SCALE_FACTOR_STD = 0.01
#: Latency of the sensor cluster's CAN messages, s (rounded to whole samples, >= 1).
HW_CAN_DELAY_S = 0.01
#: Wheel-speed (vehicle speed) message period, s (held in between; assumption).
HW_SPEED_PERIOD_S = 0.02
#: Vehicle-speed scale error from the rolling radius (tyre wear, pressure), fraction.
HW_SPEED_SCALE_STD = 0.01


class SpeedYawRate(Sensor):
    """Vehicle speed and yaw rate, the channels the input ``a_y`` is computed from.

    The vehicle drives at a constant ``speed_m_s``; in steady cornering (side-slip rate
    neglected) its yaw rate is ``r = a_y / v``. Channels: ``speed`` (m/s) = ``v``,
    ``yaw_rate`` (rad/s) = ``a_y / v``; their linear model marks them as input channels
    (``SensorModel.inputs``): designs do not use them as measurements of the state.

    Parameters
    ----------
    speed_m_s : float
        Vehicle speed (positive), m/s.
    """

    names, units, measured_state = ("speed", "yaw_rate"), ("m/s", "rad/s"), (None, None)

    def __init__(self, speed_m_s: float = SPEED_M_S):
        speed_m_s = float(speed_m_s)
        if not (np.isfinite(speed_m_s) and speed_m_s > 0):
            raise ValueError(f"speed_m_s must be a positive speed in m/s, got {speed_m_s}")
        self.speed_m_s = speed_m_s

    def draws_per_sample(self) -> int:
        """0: noise comes from decorators."""
        return 0

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``[v, a_y / v]`` with the ``a_y`` applied over the step, shape (k, 2)."""
        out = np.empty((sample.k, 2))
        out[:, 0] = self.speed_m_s
        np.divide(sample.u[:, 0], self.speed_m_s, out=out[:, 1])
        return out

    def measure_into(self, sample: Sample, noise: Noise, out: np.ndarray) -> None:
        """:meth:`measure` into ``out`` (k, 2) (the same division)."""
        out[:, 0] = self.speed_m_s
        np.divide(sample.u[:, 0], self.speed_m_s, out=out[:, 1])

    def measure_row(self, sample: Sample, noise: Noise) -> list[float]:
        """:meth:`measure` of one member on Python floats (the same division)."""
        return [self.speed_m_s, sample.u.item(0, 0) / self.speed_m_s]

    def linear_model(self) -> SensorModel:
        """``yaw_rate = a_y / v`` (``D``); ``speed`` is constant; both are input channels."""
        return SensorModel(C=np.zeros((2, 2)), D=np.array([[0.0], [1.0 / self.speed_m_s]]),
                           R=np.zeros((2, 2)), Hw=np.zeros((2, 0)),
                           stochastic=np.ones(2, bool), inputs=np.ones(2, bool))


class SpeedChannel(SpeedYawRate):
    """The ``speed`` channel of :class:`SpeedYawRate` alone (m/s)."""

    names, units, measured_state = ("speed",), ("m/s",), (None,)
    _rows = slice(0, 1)

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``v``, shape (k, 1)."""
        out = np.empty((sample.k, 1))
        out.fill(self.speed_m_s)
        return out

    def measure_into(self, sample: Sample, noise: Noise, out: np.ndarray) -> None:
        """``v`` into ``out`` (k, 1)."""
        out.fill(self.speed_m_s)

    def measure_row(self, sample: Sample, noise: Noise) -> list[float]:
        """``[v]``."""
        return [self.speed_m_s]

    def linear_model(self) -> SensorModel:
        """This channel's row of :meth:`SpeedYawRate.linear_model`."""
        m, r = super().linear_model(), self._rows
        return SensorModel(C=m.C[r], D=m.D[r], R=m.R[r, r], Hw=m.Hw[r],
                           stochastic=m.stochastic[r], inputs=m.inputs[r])


class YawRateChannel(SpeedChannel):
    """The ``yaw_rate`` channel of :class:`SpeedYawRate` alone (rad/s): ``a_y / v``."""

    names, units, measured_state = ("yaw_rate",), ("rad/s",), (None,)
    _rows = slice(1, 2)

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``a_y / v``, shape (k, 1)."""
        return sample.u[:, :1] / self.speed_m_s

    def measure_into(self, sample: Sample, noise: Noise, out: np.ndarray) -> None:
        """``a_y / v`` into ``out`` (k, 1) (the same division, on 1-D columns: numpy's
        one loop)."""
        np.divide(sample.u[:, 0], self.speed_m_s, out=out[:, 0])

    def measure_row(self, sample: Sample, noise: Noise) -> list[float]:
        """``[a_y / v]`` of one member on Python floats (the same division)."""
        return [sample.u.item(0, 0) / self.speed_m_s]


def measured_lateral_acceleration(tap: Tap) -> np.ndarray:
    """``a_y = speed x yaw rate`` of the latest sample of every member, shape (num, 1)."""
    if tap.names != SpeedYawRate.names:
        raise ValueError(f"a_y is computed from the channels {SpeedYawRate.names}, got "
                         f"{tap.names}")
    return (tap.last[:, 0] * tap.last[:, 1])[:, None]


def measured_a_y_variance(tap: Tap) -> np.ndarray:
    """Per-sample variance of ``a_y = v r`` from the channels' noise models, shape (1, 1).

    ``var(v r) = v^2 var(r) + r^2 var(v)``, taken at ``r = 0`` (straight driving): at the
    double lane change's peak, ``r = 0.28 rad/s``, the left-out term adds 13 % with the
    default noise levels. Biases, scale errors and delays are not in the channels' linear
    model and not in this variance.
    """
    model = tap.linear_model()
    speed = 1.0 / model.D[1, 0]
    return np.array([[speed**2 * model.R[1, 1]]])


def find_tap(sensors: Sensor) -> Tap | None:
    """The :class:`~testbed.sensors.Tap` of the speed and yaw-rate channels in a suite."""
    parts = sensors.sensors if isinstance(sensors, Suite) else (sensors,)
    for part in parts:
        if isinstance(part, Tap) and part.names == SpeedYawRate.names:
            return part
    return None


def lateral_accel_value(x: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
    """``a_y cos(roll) + g sin(roll)``, shape (M,) for ``x`` (M, 2), ``w`` (M, 1)."""
    return w[:, 0] * np.cos(x[:, 0]) + g * np.sin(x[:, 0])


def lateral_accel_gradient(x: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
    """``d / dx``, shape (M, 2)."""
    return np.stack([-w[:, 0] * np.sin(x[:, 0]) + g * np.cos(x[:, 0]), np.zeros(len(x))],
                    axis=1)


def lateral_accel_input_gradient(x: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
    """``d / dw``, shape (M, 1)."""
    return np.cos(x[:, :1])


class LateralAccelerometer(Sensor):
    """Specific force along the body's lateral axis: ``a_y cos(roll) + g sin(roll)`` (m/s^2).

    Mounted on the roll axis; the tangential term of a lever arm is not modelled. Linear
    model about ``roll = 0``: ``C = [g, 0]``, ``D = [1]``.
    """

    names, units, measured_state = ("lateral_accel",), ("m/s^2",), (None,)

    def draws_per_sample(self) -> int:
        """0: noise comes from decorators."""
        return 0

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``a_y cos(roll) + g sin(roll)``, shape (k, 1)."""
        roll = sample.x[:, :1]
        return sample.u[:, :1] * np.cos(roll) + GRAVITY_M_S2 * np.sin(roll)

    def measure_into(self, sample: Sample, noise: Noise, out: np.ndarray) -> None:
        """:meth:`measure` into ``out`` (k, 1): the cosine and the sine of the same roll
        column into new arrays as there (their inputs and outputs laid out the same: numpy
        may pick another loop for other strides), the products and the sum (exact
        operations) in place."""
        roll = sample.x[:, :1]
        c = np.cos(roll)
        np.multiply(sample.u[:, :1], c, out=c)
        s = np.sin(roll)
        np.multiply(GRAVITY_M_S2, s, out=s)
        np.add(c[:, 0], s[:, 0], out=out[:, 0])  # (1-D columns: numpy's one loop)

    def measure_row(self, sample: Sample, noise: Noise) -> list[float]:
        """:meth:`measure` of one member: numpy's cosine and sine of the roll (the same
        functions), the products and the sum on Python floats (the same operations)."""
        roll = sample.x[:, :1]
        return [sample.u.item(0, 0) * np.cos(roll).item()
                + GRAVITY_M_S2 * np.sin(roll).item()]

    def linear_model(self) -> SensorModel:
        """``y = g roll + a_y``, with the exact nonlinear channel."""
        return SensorModel(C=np.array([[GRAVITY_M_S2, 0.0]]), D=np.ones((1, 1)),
                           R=np.zeros((1, 1)), Hw=np.zeros((1, 0)), stochastic=np.ones(1, bool),
                           nonlinear={"lateral_accel": (lateral_accel_value,
                                                        lateral_accel_gradient,
                                                        lateral_accel_input_gradient)})


def imu(dt_s: float = 0.01, gyro_noise_density: float = GYRO_NOISE_DENSITY,
        gyro_bias_walk: float = GYRO_BIAS_WALK, gyro_bias0_std: float = 0.0,
        accel_noise_density: float = ACCEL_NOISE_DENSITY, accel_bias: float = 0.0,
        roll_sensor: bool = False, roll_noise_std: float = ROLL_NOISE_STD,
        accel_bias0_std: float = 0.0, scale_factor_std: float = 0.0,
        delay_samples: int = 0, speed_yaw_rate: bool = True, speed_m_s: float = SPEED_M_S,
        speed_noise_std: float = SPEED_NOISE_STD, speed_scale_std: float = 0.0,
        speed_hold_samples: int = 1) -> Suite:
    """Roll-rate gyro, lateral accelerometer, optional roll-angle sensor, speed and yaw rate.

    Channels: ``roll_rate`` (rad/s) = ``roll_rate + n_g + b_k`` with a bias random walk;
    ``lateral_accel`` (m/s^2) = :class:`LateralAccelerometer` ``+ b_a + n_a``; ``roll``
    (rad) = ``roll + n_r``; with ``speed_yaw_rate`` the input channels ``speed`` (m/s,
    white noise ``speed_noise_std``, quantized to 0.01 km/h) and ``yaw_rate`` (a gyro like
    the roll-rate one) of :class:`SpeedYawRate`, tapped (:class:`~testbed.sensors.Tap`)
    for the estimator's measured ``a_y``. Defaults are representative of automotive MEMS
    IMUs (Bosch BMI088/SMI, ST ASM330 class): at 100 Hz ``sigma_g = 0.1 deg/s``,
    ``sigma_a = 0.0147 m/s^2`` per sample.

    Hardware effects (off by default; the ``hardware`` preset turns them on): a random
    accelerometer offset ``accel_bias0_std`` per episode, a sensitivity error
    ``scale_factor_std`` per episode on the gyros and the accelerometer, a transport delay
    of ``delay_samples`` samples on every channel (CAN latency), a speed scale error
    ``speed_scale_std`` per episode and the speed held over ``speed_hold_samples``.
    """
    for name, value, low in (("delay_samples", delay_samples, 0),
                             ("speed_hold_samples", speed_hold_samples, 1)):
        if int(value) != value or value < low:
            raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")

    def scaled(channel: Sensor, std: float) -> Sensor:
        return ScaleFactor(channel, initial_std=std) if std else channel

    def delayed(channel: Sensor) -> Sensor:
        return Delay(channel, int(delay_samples)) if delay_samples else channel

    def gyro(channel: Sensor) -> Sensor:
        return BiasRandomWalk(WhiteNoise(scaled(channel, scale_factor_std),
                                         density=gyro_noise_density, dt_s=dt_s),
                              walk=gyro_bias_walk, dt_s=dt_s, initial_std=gyro_bias0_std)

    accel = scaled(LateralAccelerometer(), scale_factor_std)
    if accel_bias:  # a zero offset is no decorator (one fewer per sample)
        accel = Bias(accel, accel_bias)
    if accel_bias0_std:
        accel = BiasRandomWalk(accel, walk=0.0, dt_s=dt_s, initial_std=accel_bias0_std)
    accel = WhiteNoise(accel, density=accel_noise_density, dt_s=dt_s)
    parts: list[Sensor] = [delayed(gyro(StateChannel(1, 2, 1, "roll_rate", "rad/s"))),
                           delayed(accel)]
    if roll_sensor:
        parts.append(WhiteNoise(StateChannel(0, 2, 1, "roll", "rad"), std=roll_noise_std))
    if speed_yaw_rate:
        speed: Sensor = Quantize(WhiteNoise(scaled(SpeedChannel(speed_m_s), speed_scale_std),
                                            std=speed_noise_std), SPEED_RESOLUTION)
        if speed_hold_samples > 1:
            speed = SampleAndHold(speed, int(speed_hold_samples))
        parts.append(Tap(Suite(delayed(speed), delayed(gyro(YawRateChannel(speed_m_s))))))
    return Suite(*parts)


def hardware(dt_s: float = 0.01, **options) -> Suite:
    """The ``hardware`` preset: :func:`imu` with the documented hardware effects on.

    Gyro offsets ``HW_GYRO_BIAS0_STD`` and accelerometer offset ``HW_ACCEL_BIAS0_STD`` per
    episode, sensitivity errors ``HW_SCALE_FACTOR_STD``, CAN latency ``HW_CAN_DELAY_S``
    (whole samples, at least one), speed scale error ``HW_SPEED_SCALE_STD`` and the speed
    held over ``HW_SPEED_PERIOD_S``. ``options`` override any :func:`imu` argument.
    """
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be a positive sampling period in s, got {dt_s}")
    defaults = {"gyro_bias0_std": HW_GYRO_BIAS0_STD, "accel_bias0_std": HW_ACCEL_BIAS0_STD,
                "scale_factor_std": HW_SCALE_FACTOR_STD,
                "delay_samples": max(1, int(round(HW_CAN_DELAY_S / dt_s))),
                "speed_scale_std": HW_SPEED_SCALE_STD,
                "speed_hold_samples": max(1, int(round(HW_SPEED_PERIOD_S / dt_s)))}
    return imu(dt_s=dt_s, **{**defaults, **options})


class PaperRollChannel(Sensor):
    """Zhang et al.'s measurement ``y_k = H x_k + L v_k`` (52), optionally with white noise.

    ``v_k = 0.01 * 0.9^k`` is the paper's disturbance at the sample time
    (:class:`testbed.rigs.vehicle_roll.manoeuvres.PaperDecay`), unless the scenario's disturbance
    ``w``
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

    def draws_per_sample(self) -> int:
        """Two normals with ``noise_std > 0``, else none."""
        return 2 if self.noise_std else 0

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
