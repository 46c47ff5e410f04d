"""Sensor suites of the vehicle roll rig: an automotive IMU and seed-002's output channels.

Same interface as :mod:`testbed.sensors` (``names``, ``dim``, ``measured_state_index``,
``measure(x, t_s, rng, w=None)``, ``linear_model(dt_s) -> (C, R)``) plus, because the
lateral accelerometer sees the input:

- ``measure(..., *, a_y=0.0)``: the lateral acceleration (m/s^2) acting on the vehicle;
- ``feedthrough_matrix()``: ``D`` (shape (dim, 1)) of ``y = C x + D a_y + noise`` for filter
  design (``LinearSystem(..., D=...)``);
- ``reset(rng)``: restart the suite's internal state (gyro bias) at an episode's start;
- ``disturbance(t_s)``: the deterministic disturbance entering the measurement, shape (s,)
  (empty for the IMU).

All noise comes from the generator the environment passes in (its seeded ``np_random``).
Samples are taken at the control rate ``1 / dt_s``. A white-noise density ``N`` (unit/sqrt(Hz))
sampled at ``f_s = 1 / dt_s`` has the per-sample standard deviation ``sigma = N sqrt(f_s)``
(the sensor's bandwidth taken as the Nyquist band; a datasheet density over a narrower
filter bandwidth gives less).

State ``x = [roll, roll_rate]`` (rad, rad/s).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from testbed.manoeuvres import PaperDecay
from testbed.rigs.helicopter import GRAVITY_M_S2
from testbed.rigs.vehicle_roll import paper_model

#: Representative automotive MEMS gyro white-noise density: 0.01 deg/s/sqrt(Hz), in rad/s/sqrt(Hz).
GYRO_NOISE_DENSITY = float(np.deg2rad(0.01))
#: Representative gyro bias random walk: 1e-4 deg/s/sqrt(s) (~22 deg/h/sqrt(h)), rad/s/sqrt(s).
GYRO_BIAS_WALK = float(np.deg2rad(1e-4))
#: Representative MEMS accelerometer noise density: 150 micro-g/sqrt(Hz), in m/s^2/sqrt(Hz).
ACCEL_NOISE_DENSITY = 150e-6 * GRAVITY_M_S2
#: Representative roll-angle sensor noise (e.g. from a dual-antenna GNSS/INS), rad per sample.
ROLL_NOISE_STD = float(np.deg2rad(0.1))


def _non_negative(value: float, name: str) -> float:
    value = float(value)
    if not (np.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be finite and non-negative, got {value}")
    return value


def _period(dt_s: float) -> float:
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be a positive sampling period in s, got {dt_s}")
    return float(dt_s)


@dataclass
class ImuSuite:
    """Roll-rate gyro, lateral accelerometer and an optional roll-angle sensor.

    Channels (in order)::

        roll_rate      g_k   = roll_rate + b_k + n_g,           n_g ~ N(0, sigma_g^2)  (rad/s)
        lateral_accel  a_k   = a_y cos(roll) + g sin(roll) + b_a + n_a,
                                                                n_a ~ N(0, sigma_a^2)  (m/s^2)
        roll           r_k   = roll + n_r,                      n_r ~ N(0, sigma_r^2)  (rad)

    The gyro bias is a random walk ``b_{k+1} = b_k + q_b sqrt(dt) xi_k`` starting from
    ``b_0 ~ N(0, gyro_bias0_std^2)`` at :meth:`reset`. The accelerometer sits on the sprung
    mass on the roll axis and measures specific force along the body's lateral axis: the
    vehicle's ``a_y`` projected on the tilted axis (``cos(roll)``) plus the component of
    gravity the roll tilts into it (``g sin(roll)``, ``g = 9.81 m/s^2``), same sign
    convention as ``a_y`` (+ left). Mounted ``h`` above the roll axis it would also see the
    tangential term ``-h roll''`` (and no centripetal term along y); that lever arm is not
    modelled. ``b_a`` is a constant bias.

    Defaults are representative of automotive/industrial MEMS IMUs, not of a specific part:
    datasheets of the Bosch BMI088/SMI-series and ST ASM330-series class list gyro noise
    densities of roughly 0.004-0.014 deg/s/sqrt(Hz) and accelerometer densities of roughly
    60-200 micro-g/sqrt(Hz). Here 0.01 deg/s/sqrt(Hz) and 150 micro-g/sqrt(Hz): at 100 Hz,
    ``sigma_g = 0.1 deg/s`` and ``sigma_a = 0.0147 m/s^2`` per sample.

    Parameters
    ----------
    dt_s : float
        Sampling period (the control period), s.
    gyro_noise_density : float
        Gyro white-noise density, rad/s/sqrt(Hz).
    gyro_bias_walk : float
        Gyro bias random walk ``q_b``, rad/s/sqrt(s).
    gyro_bias0_std : float
        Standard deviation of the initial gyro bias, rad/s (0: calibrated at standstill).
    accel_noise_density : float
        Accelerometer white-noise density, m/s^2/sqrt(Hz).
    accel_bias : float
        Constant accelerometer bias, m/s^2.
    roll_sensor : bool
        Append the roll-angle channel.
    roll_noise_std : float
        Roll-angle noise per sample, rad.
    """

    dt_s: float = 0.01
    gyro_noise_density: float = GYRO_NOISE_DENSITY
    gyro_bias_walk: float = GYRO_BIAS_WALK
    gyro_bias0_std: float = 0.0
    accel_noise_density: float = ACCEL_NOISE_DENSITY
    accel_bias: float = 0.0
    roll_sensor: bool = False
    roll_noise_std: float = ROLL_NOISE_STD
    name: str = field(default="imu", init=False)

    def __post_init__(self) -> None:
        self.dt_s = _period(self.dt_s)
        for key in ("gyro_noise_density", "gyro_bias_walk", "gyro_bias0_std",
                    "accel_noise_density", "roll_noise_std"):
            setattr(self, key, _non_negative(getattr(self, key), key))
        self.accel_bias = float(self.accel_bias)
        if not np.isfinite(self.accel_bias):
            raise ValueError(f"accel_bias must be finite, got {self.accel_bias}")
        self.roll_sensor = bool(self.roll_sensor)
        self._bias = 0.0

    @property
    def names(self) -> list[str]:
        """Channel names: ``roll_rate``, ``lateral_accel`` (and ``roll``)."""
        return ["roll_rate", "lateral_accel"] + (["roll"] if self.roll_sensor else [])

    @property
    def dim(self) -> int:
        """Number of channels (2, or 3 with the roll sensor)."""
        return 3 if self.roll_sensor else 2

    @property
    def measured_state_index(self) -> list[int | None]:
        """State measured directly by each channel (the accelerometer: none)."""
        return [1, None] + ([0] if self.roll_sensor else [])

    @property
    def gyro_bias(self) -> float:
        """Current gyro bias, rad/s."""
        return self._bias

    def sample_std(self, dt_s: float | None = None) -> np.ndarray:
        """Per-sample white-noise standard deviations of the channels, shape (dim,).

        ``[gyro_noise_density, accel_noise_density] * sqrt(1 / dt_s)`` (and
        ``roll_noise_std``); units rad/s, m/s^2, rad.
        """
        rate = 1.0 / _period(self.dt_s if dt_s is None else dt_s)
        std = [self.gyro_noise_density * np.sqrt(rate), self.accel_noise_density * np.sqrt(rate)]
        return np.array(std + ([self.roll_noise_std] if self.roll_sensor else []))

    def reset(self, rng: np.random.Generator) -> None:
        """Draw the initial gyro bias (one normal draw when ``gyro_bias0_std > 0``)."""
        self._bias = self.gyro_bias0_std * rng.standard_normal() if self.gyro_bias0_std else 0.0

    def disturbance(self, t_s: float) -> np.ndarray:
        """No deterministic disturbance: shape (0,)."""
        return np.zeros(0)

    def measure(self, x: np.ndarray, t_s: float, rng: np.random.Generator,
                w: np.ndarray | None = None, *, a_y: float = 0.0) -> np.ndarray:
        """One sample of the IMU; advances the gyro bias by one period.

        Draws, in order: gyro noise, bias increment (when ``gyro_bias_walk > 0``),
        accelerometer noise, roll noise (when ``roll_sensor``).

        Parameters
        ----------
        x : ndarray, shape (2,)
            True ``[roll, roll_rate]``.
        t_s : float
            Time (unused).
        rng : numpy.random.Generator
            Source of all noise.
        w : ndarray, optional
            Unused.
        a_y : float
            Lateral acceleration acting on the vehicle, m/s^2.

        Returns
        -------
        ndarray, shape (dim,)
        """
        std = self.sample_std()
        gyro = x[1] + self._bias + std[0] * rng.standard_normal()
        if self.gyro_bias_walk:
            self._bias += self.gyro_bias_walk * np.sqrt(self.dt_s) * rng.standard_normal()
        roll = x[0]
        accel = (a_y * np.cos(roll) + GRAVITY_M_S2 * np.sin(roll) + self.accel_bias
                 + std[1] * rng.standard_normal())
        if not self.roll_sensor:
            return np.array([gyro, accel])
        return np.array([gyro, accel, roll + std[2] * rng.standard_normal()])

    def linear_model(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Observation matrix (about ``roll = 0``) and per-sample noise covariance.

        The accelerometer is linearized about ``roll = 0``: ``a_y + g roll``, its ``a_y`` part
        is :meth:`feedthrough_matrix`. Biases are not in the model (``R`` is white noise only).

        Returns
        -------
        C : ndarray, shape (dim, 2)
            Rows ``[0, 1]``, ``[g, 0]`` (and ``[1, 0]``).
        R : ndarray, shape (dim, dim)
            ``diag(sample_std(dt_s)^2)``.
        """
        C = np.array([[0.0, 1.0], [GRAVITY_M_S2, 0.0], [1.0, 0.0]])[: self.dim]
        return C, np.diag(self.sample_std(dt_s) ** 2)

    def feedthrough_matrix(self) -> np.ndarray:
        """``D`` of ``y = C x + D a_y``: 1 on the accelerometer row, shape (dim, 1)."""
        D = np.zeros((self.dim, 1))
        D[1, 0] = 1.0
        return D


@dataclass
class PaperRollSuite:
    """seed-002's measurement ``y_k = H x_k + L v_k`` (52), optionally with white noise.

    ``v_k = 0.01 * 0.9^k`` is the paper's disturbance, evaluated at the sample time as
    ``0.01 * 0.9^(t / 0.01 s)`` (:class:`testbed.manoeuvres.PaperDecay`) unless the caller
    passes it as ``w``. ``H`` and ``L`` are the printed matrices; the channels mix both
    states (``measured_state_index`` is ``[None, None]``).

    Parameters
    ----------
    dt_s : float
        Sampling period, s.
    noise_std : float
        Extra white noise per sample on each channel (0: the paper's noiseless channel).
    """

    dt_s: float = 0.01
    noise_std: float = 0.0
    name: str = field(default="paper", init=False)

    #: Floor on the design noise std so ``R`` is positive definite with ``noise_std = 0``.
    DESIGN_STD_FLOOR = 1e-4

    def __post_init__(self) -> None:
        self.dt_s = _period(self.dt_s)
        self.noise_std = _non_negative(self.noise_std, "noise_std")
        model = paper_model()
        self.H = model.H
        self.L = model.L
        self._v = PaperDecay()

    @property
    def names(self) -> list[str]:
        """Channel names ``y1``, ``y2``."""
        return ["y1", "y2"]

    @property
    def dim(self) -> int:
        """Number of channels (2)."""
        return 2

    @property
    def measured_state_index(self) -> list[int | None]:
        """No channel measures a single state."""
        return [None, None]

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing to reset (stateless); draws nothing."""

    def disturbance(self, t_s: float) -> np.ndarray:
        """The paper's ``v`` at time ``t_s``, shape (1,)."""
        return np.array([self._v(float(t_s))])

    def measure(self, x: np.ndarray, t_s: float, rng: np.random.Generator,
                w: np.ndarray | None = None, *, a_y: float = 0.0) -> np.ndarray:
        """One sample ``H x + L v (+ noise)``, shape (2,).

        Parameters
        ----------
        x : ndarray, shape (2,)
        t_s : float
            Sample time, s (gives ``v`` when ``w`` is not passed).
        rng : numpy.random.Generator
            Draws two normals only when ``noise_std > 0``.
        w : ndarray, shape (1,), optional
            ``v`` at this sample.
        a_y : float
            Unused.
        """
        v = self.disturbance(t_s) if w is None or len(w) == 0 else np.asarray(w, float)
        if v.shape != (1,):
            raise ValueError(f"w must have shape (1,) (the paper's v), got {v.shape}")
        y = self.H @ x + self.L @ v
        if self.noise_std:
            y = y + self.noise_std * rng.standard_normal(2)
        return y

    def linear_model(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``H`` and a design covariance treating ``L v`` as white noise.

        ``R = L L^T v_0^2 + s^2 I`` with ``v_0 = 0.01`` (the largest ``v``) and
        ``s = max(noise_std, 1e-4)``.

        Returns
        -------
        C : ndarray, shape (2, 2)
        R : ndarray, shape (2, 2)
        """
        v0 = self._v.amplitude_m_s2
        s = max(self.noise_std, self.DESIGN_STD_FLOOR)
        return self.H.copy(), self.L @ self.L.T * v0**2 + s**2 * np.eye(2)

    def feedthrough_matrix(self) -> np.ndarray:
        """``a_y`` does not reach these channels: zeros, shape (2, 1)."""
        return np.zeros((2, 1))


VEHICLE_SENSOR_SUITES = ("imu", "paper")


def make_vehicle_sensor_suite(name: str, dt_s: float, **kwargs) -> ImuSuite | PaperRollSuite:
    """Build a vehicle sensor suite by name.

    Parameters
    ----------
    name : {"imu", "paper"}
    dt_s : float
        Sampling (control) period, s.
    **kwargs
        Passed to the suite's constructor (e.g. ``roll_sensor=True``).

    Raises
    ------
    ValueError
        Unknown name (the valid ones are listed) or bad keyword.
    """
    classes = {"imu": ImuSuite, "paper": PaperRollSuite}
    if name not in classes:
        raise ValueError(f"unknown vehicle sensor suite {name!r}; expected one of "
                         f"{VEHICLE_SENSOR_SUITES}")
    try:
        return classes[name](dt_s=dt_s, **kwargs)
    except TypeError as err:
        raise ValueError(f"bad arguments for sensor suite {name!r}: {err}") from None
