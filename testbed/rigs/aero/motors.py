"""The Aero's rotor speeds and motor currents: channels of the ``hardware`` profile.

Each rotor is a permanent-magnet DC motor driving a propeller. With the armature resistance
``R``, the motor constant ``k`` (back-EMF V s/rad = torque N m/A), the rotor's inertia ``J_r``
and a viscous load ``b`` (the propeller's drag, linearized), and the armature inductance left
out (its time constant ``L / R`` is a fraction of a millisecond)::

    i = (V - k w) / R,        J_r w' = k i - b w = (k / R) V - (b + k^2 / R) w

a first-order lag: ``w`` follows ``G V`` with

    G = k / (R b + k^2)          (rad/s per V, the steady-state speed per volt)
    tau = J_r R / (R b + k^2)    (the rotor time constant)

This is the MuJoCo rotor lag of the ``hardware`` profile (``dyntype="filterexact"``, its
state ``act`` in volts of steady-state command, the time constants
``AeroParams.rotor_time_constant_*_s``): the rotor speed is ``G act`` and the current
``(V - k G act) / R``, ``V`` the voltage applied over the last control step. At a voltage step
from rest the current jumps to ``V / R`` and decays with ``tau`` to the steady
``V b / (R b + k^2)``; the ratio of the steady current to the peak, ``R b / (R b + k^2)``,
does not depend on ``V`` or ``tau``. ``b`` is chosen to give the ratio of a real unit's
recording (about 0.09 A steady after a 1.6 A peak): ``b = rho k^2 / (R (1 - rho))`` with
``rho = 0.09 / 1.6``. ``R`` and ``k`` are assumptions (docs/aero.md, "Hardware profile").

In the ``paper`` profile (no lag) the channels read the steady state of the voltage.
The channels are no measurements of the rig's physical state: their linear model marks them
as channels an input is computed from (``SensorModel.inputs``), which the designs leave out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.records import field_items
from testbed.sensors import Noise, Sample, Sensor, SensorModel

#: Channel names: rotor speeds (rad/s) and motor currents (A), pitch (front) motor first.
MOTOR_CHANNELS = ("rotor_speed_pitch", "rotor_speed_yaw", "current_pitch", "current_yaw")
MOTOR_UNITS = ("rad/s", "rad/s", "A", "A")
#: Steady-state current over the peak current of a voltage step in a real unit's recording
#: (about 0.09 A after 1.6 A): ``R b / (R b + k^2)``.
STEADY_TO_PEAK_CURRENT = 0.09 / 1.6


@dataclass(frozen=True)
class AeroMotor:
    """The DC motor of each rotor (both alike).

    Attributes
    ----------
    resistance_ohm : float
        Armature resistance ``R``, ohm (an assumption).
    motor_constant : float
        Back-EMF and torque constant ``k``, V s/rad = N m/A (an assumption).
    load_damping_Nms : float
        The propeller's linearized viscous load ``b``, N m s/rad: by default the one giving
        a real unit's steady-to-peak current ratio (:data:`STEADY_TO_PEAK_CURRENT`).
    """

    resistance_ohm: float = 8.4
    motor_constant: float = 0.042
    load_damping_Nms: float = (STEADY_TO_PEAK_CURRENT * 0.042**2
                               / (8.4 * (1.0 - STEADY_TO_PEAK_CURRENT)))

    def __post_init__(self) -> None:
        for f, value in field_items(self):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"AeroMotor.{f.name} must be finite and positive, got "
                                 f"{value!r}")

    @property
    def speed_per_volt(self) -> float:
        """``G = k / (R b + k^2)``: steady-state rotor speed per volt, rad/s/V."""
        k = self.motor_constant
        return k / (self.resistance_ohm * self.load_damping_Nms + k * k)

    def rotor_inertia(self, time_constant_s: float) -> float:
        """``J_r = tau (R b + k^2) / R``: the rotor inertia of a time constant, kg m^2."""
        k = self.motor_constant
        return (time_constant_s * (self.resistance_ohm * self.load_damping_Nms + k * k)
                / self.resistance_ohm)


class AeroMotors(Sensor):
    """Rotor speeds and motor currents from MuJoCo's actuator states (noise-free core).

    Reads ``Sample.act`` (the rotor lag's states, volts; ``reads_act``) and ``Sample.u`` (the
    voltages applied over the last step); without actuator states (the ``paper`` profile,
    no lag) the rotor speed is the steady state of the voltage.

    Parameters
    ----------
    motor : AeroMotor, optional
    n_states : int
        The rig's state dimension (zero rows of the linear model).
    """

    reads_act = True

    def __init__(self, motor: AeroMotor | None = None, n_states: int = 4):
        if motor is not None and not isinstance(motor, AeroMotor):
            raise ValueError(f"motor must be an AeroMotor, got {motor!r}")
        self.motor = motor or AeroMotor()
        self.n_states = int(n_states)
        self.names, self.units = MOTOR_CHANNELS, MOTOR_UNITS
        self.measured_state = (None,) * 4

    def draws_per_sample(self) -> int:
        """0: noise comes from decorators."""
        return 0

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``[G act_p, G act_y, (V_p - k G act_p) / R, (V_y - k G act_y) / R]``: (k, 4)."""
        m = self.motor
        u = np.asarray(sample.u, float)[:, :2]
        act = sample.act if sample.act is not None and sample.act.shape[1] >= 2 else u
        speed = m.speed_per_volt * np.asarray(act, float)[:, :2]
        current = (u - m.motor_constant * speed) / m.resistance_ohm
        return np.concatenate([speed, current], axis=1)

    def linear_model(self) -> SensorModel:
        """No rows on the physical state: marked as input channels (the designs leave
        them out), noise-free."""
        return SensorModel(C=np.zeros((4, self.n_states)), D=np.zeros((4, 2)),
                           R=np.zeros((4, 4)), Hw=np.zeros((4, 0)),
                           stochastic=np.zeros(4, bool), inputs=np.ones(4, bool))


def hardware_motors(hardware, n_states: int) -> Sensor:
    """The motor channels of the ``hardware`` preset: :class:`AeroMotors` with white noise
    and quantization (``hardware``: :class:`~testbed.rigs.aero.hardware.AeroHardware`), drawing
    from streams of their own (:class:`~testbed.sensors.streams.OwnStream`: the other
    channels' numbers do not change with them)."""
    from testbed.sensors import Quantize, WhiteNoise
    from testbed.sensors.streams import OwnStream

    hw = hardware
    core = AeroMotors(hw.motor, n_states)
    noisy = WhiteNoise(core, std=[hw.rotor_speed_noise_std] * 2 + [hw.current_noise_std] * 2)
    return OwnStream(Quantize(noisy, [hw.rotor_speed_step] * 2 + [hw.current_step] * 2),
                     key=MOTOR_STREAM_KEY)


#: The motor channels' stream key (:class:`~testbed.sensors.streams.OwnStream`).
MOTOR_STREAM_KEY = 38
