"""The helicopter's design models: the paper design (Basin et al.'s ``(A, B)`` with the
sensors' model), the ``hardware`` profile's matched design, the cubic expansion of the
gravity torque, and the input transform both share (the voltage minus the gravity voltage at
the estimated pitch). :class:`~testbed.rigs.helicopter.rig.HelicopterRig` delegates here."""

from __future__ import annotations

import numpy as np

from testbed.rigs.base import GRAVITY_M_S2
from testbed.rigs.helicopter.hardware import current_limited, deadband
from testbed.rigs.helicopter.paper import PAPER_GAMMA, PAPER_INITIAL_WEIGHT, paper_model
from testbed.rigs.helicopter.params import (
    PITCH_LIMIT_RAD,
    HelicopterParams,
    gravity_voltage,
    volts_per_pitch_newton_metre,
)

#: Matched ``hardware`` design: white-noise intensity of the rotor states, as the rms
#: change over one time constant (V): the deadband and current limit are modelled at the
#: estimate, the rotor torque's small nonlinearity is not (assumption).
MOTOR_STATE_NOISE_V = 0.1
#: Matched ``hardware`` design: prior std of the rotor states at rest, V.
MOTOR_PRIOR_STD_V = 0.01
#: Matched ``hardware`` design: a typical rate for the gyros' sensitivity error in ``R``,
#: rad/s (the rig's rates under the default setpoints stay below about 0.5 rad/s).
DESIGN_RATE_RAD_S = 0.3
#: Matched ``hardware`` design: the pitch at which the yaw gyro's ``yaw_rate cos(pitch)`` is
#: linearized, rad (level: where the rig flies its setpoints).
YAW_GYRO_PITCH_RAD = 0.0
#: Matched ``hardware`` design: an estimated pitch within this of the lower stop rests on it
#: (the stop's reaction cancels a downward acceleration), rad (two pitch-encoder counts).
STOP_TOLERANCE_RAD = 2 * 2 * np.pi / 4096


def cubic_model(design, pitch0_rad: float = 0.0):
    """Third-order expansion of the gravity torque in pitch (nominal parameters).

    The design model's ``A, B`` leave gravity out: its input is the voltage minus the
    gravity-compensating voltage at the estimate. The expansion restores the absolute
    voltage (``input_offset`` = :func:`gravity_voltage` at the estimate, so
    ``E u_p = B u + [0, 0, c cos(pitch_hat), 0]``) and models the gravity torque itself::

        pitch'' += -c cos(pitch),   c = m g l / J_p  (29.3 rad/s^2 nominal)
        cos(pitch) ~ cos p0 - sin p0 d - cos p0 d^2 / 2 + sin p0 d^3 / 6,  d = pitch - p0

    about ``p0 = pitch0_rad`` (default 0, the design model's linearization point, where
    the cubic term vanishes: the model is quadratic). The pitch-dependent yaw inertia,
    the ``cos(pitch)`` on the yaw torque and the centrifugal and Coriolis terms stay
    out (as in the design model).

    Parameters
    ----------
    design : testbed.design.DesignModel
    pitch0_rad : float
        Expansion point, rad.

    Returns
    -------
    testbed.design.cubic.CubicExpansion
    """
    from testbed.design.cubic import CubicExpansion

    if not (np.isfinite(pitch0_rad) and abs(pitch0_rad) <= PITCH_LIMIT_RAD):
        raise ValueError(f"pitch0_rad must lie within the stops +-{PITCH_LIMIT_RAD:.4f} "
                         f"rad, got {pitch0_rad!r}")
    nominal = HelicopterParams()
    c = nominal.mass_kg * GRAVITY_M_S2 * nominal.com_m / nominal.pitch_inertia
    s0, c0 = np.sin(pitch0_rad), np.cos(pitch0_rad)
    # -c cos(pitch) as a polynomial in d, then in pitch = d + p0
    in_d = np.polynomial.Polynomial([-c * c0, c * s0, c * c0 / 2.0, -c * s0 / 6.0])
    coef = in_d(np.polynomial.Polynomial([-pitch0_rad, 1.0])).coef
    coef = np.concatenate([coef, np.zeros(4 - len(coef))])
    a0, a1 = np.zeros(4), np.array(design.continuous.A, float)
    a2, a3 = np.zeros((4, 4, 4)), np.zeros((4, 4, 4, 4))
    a0[2] = coef[0]
    a1[2, 0] += coef[1]
    a2[2, 0, 0] = coef[2]
    a3[2, 0, 0, 0] = coef[3]
    return CubicExpansion(
        a0=a0, a1=a1, a2=a2 if np.any(a2) else None, a3=a3 if np.any(a3) else None,
        E=np.array(design.continuous.B, float),
        input_offset=lambda x_hat: gravity_voltage(nominal, x_hat[:, 0]),
        description=f"gravity torque -m g l cos(pitch) / J_p to third order about pitch "
                    f"= {pitch0_rad:g} rad; absolute voltage as input")


def design_model(rig, sensors, dt_s: float, disturbance=None, *,
                 process_noise_floor: float = 0.05, process_noise_model: str = "auto"):
    """Basin et al.'s ``(A, B)``, the sensors' model, ``Q`` = disturbance + floor; in the
    ``hardware`` profile augmented with what it declares (:func:`matched_design`).

    Parameters
    ----------
    sensors : Sensor
    dt_s : float
    disturbance : testbed.rigs.disturbances.Disturbance, optional
        Its white-noise intensity ``b b^T`` enters ``Q``, its ``G`` the design.
    process_noise_floor : float
        Extra intensity (rad^2/s^3) on each acceleration row (unmodelled dynamics).
    process_noise_model : {"auto", "held", "continuous"}
        How ``Q`` is discretized (:func:`testbed.design.held_noise.uses_held_noise`;
        ``"continuous"`` on the paper profile: the papers' ``Q``).
    """
    from testbed.design import build_design, rate_noise
    from testbed.design.held_noise import matched_held_noise, uses_held_noise

    model = paper_model()
    Q, G = rate_noise(4, 2, process_noise_floor, disturbance)
    nominal = rig.params  # what the designer knows (nominal or a twin's): never the truth

    unbalanced_input = UnbalancedInput(nominal)
    paper = build_design(rig, sensors, dt_s, model.A, model.B, Q, rig.default_x0(),
                         np.diag([1e-4, 1e-4, 1e-4, 1e-4]), disturbance_matrix=G,
                         input_transform=unbalanced_input,
                         held_noise=uses_held_noise(process_noise_model,
                                                    rig.hardware is None),
                         extras={"paper_model": model, "gamma": PAPER_GAMMA,
                                 "initial_weight": PAPER_INITIAL_WEIGHT})
    if rig.hardware is None:
        return paper
    return matched_design(rig, paper, sensors, dt_s, Q, G,
                          held_intensity=matched_held_noise(disturbance,
                                                            process_noise_model))


def matched_design(rig, paper, sensors, dt_s: float, Q: np.ndarray, G,
                   held_intensity: np.ndarray | None = None):
    """The ``hardware`` profile's design: the paper design plus what the rig declares.

    State ``[pitch, yaw, pitch_rate, yaw_rate, dact_pitch, dact_yaw, biases...,
    delays...]`` (:func:`testbed.design.build_matched_design`):

    - rotor lag: ``dact = act - V_g(pitch)``, the volt-equivalent rotor speeds above the
      gravity-compensating voltage, from :meth:`HelicopterRig.linearize` ``(motor_states=True)`` at
      level pitch (poles ``-1/tau``: -16.7 and -40 rad/s); prior: motors at rest;
    - the input: the command past the declared deadband and current limit (at the
      estimated rotor speed) minus ``V_g`` at the estimated pitch, and a third input,
      the pitch stops' reaction: with the estimated pitch on a stop (within
      :data:`STOP_TOLERANCE_RAD`) it cancels the model's pitch acceleration into the
      stop (the rig starts resting on the lower stop, motors at rest);
    - IMU: gyro bias states (declared random walk and reset spread) and delay states
      for each IMU channel's declared whole-sample delay; ``gyro_yaw`` measures
      ``yaw_rate cos(pitch)``, linearized at the operating pitch (level, where the rig
      flies its setpoints; 24 % off only on the stop at the start, at zero yaw rate);
      the sensitivity error's variance at :data:`DESIGN_RATE_RAD_S` is added to ``R``;
      the accelerometer (``g sin(pitch)``: its reset offset of 0.05 m/s^2 is 0.3 deg
      of pitch, 12 times the encoder's resolution noise) is left out;
    - encoders: quantization ``q^2 / 12`` in ``R`` (the sensors' linear model).
    """
    from testbed.design import InputStates, build_matched_design, channel_effects

    hw = rig.hardware
    nominal = rig.params
    A, B = rig.linearize(motor_states=True)
    tau = np.asarray(hw.motor_time_constant_s, float)
    Qm = np.zeros((6, 6))
    Qm[:4, :4] = Q
    Qm[4:, 4:] = np.diag((MOTOR_STATE_NOISE_V * np.ones(2)) ** 2 / tau)
    x0 = np.concatenate([rig.default_x0(),
                         -gravity_voltage(nominal, rig.default_x0()[0])])
    P0 = np.diag([1e-4] * 4 + [MOTOR_PRIOR_STD_V**2] * 2)
    consts = hw.constants()
    names = tuple(sensors.names)
    effects = channel_effects(sensors)
    channels = [i for i in np.flatnonzero(sensors.linear_model().stochastic
                                          & ~sensors.linear_model().inputs)
                if names[i] != "accel_x"]
    extra_R = {i: (effects[i].scale_std * DESIGN_RATE_RAD_S) ** 2
               for i in channels if names[i].startswith("gyro_")}
    rows = {}
    if "gyro_yaw" in names:  # yaw_rate cos(pitch) at the operating pitch
        rows[names.index("gyro_yaw")] = np.array([0.0, 0.0, 0.0,
                                                  np.cos(YAW_GYRO_PITCH_RAD)])

    B = np.hstack([B, np.eye(6)[:, 2:3]])  # the pitch stops' reaction, rad/s^2
    accel_row = A[2].copy()
    resting = PITCH_LIMIT_RAD - STOP_TOLERANCE_RAD

    gravity = UnbalancedInput(nominal).voltage

    def matched_input(u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
        pitch = x_hat[:, 0]
        v_g = gravity(pitch)
        volts = current_limited(deadband(u, consts[:2]), x_hat[:, 4:6] + v_g,
                                consts[2:4], consts[4:6])
        accel = x_hat[:, :6] @ accel_row  # the model's pitch acceleration now
        into_stop = ((pitch <= -resting) & (accel < 0)) | ((pitch >= resting) & (accel > 0))
        return np.column_stack([volts - v_g, np.where(into_stop, -accel, 0.0)])

    return build_matched_design(
        rig, sensors, dt_s, A, B, Qm, x0, P0, held_intensity=held_intensity,
        extra_states=(("dact_pitch", "V"), ("dact_yaw", "V")), channels=np.array(channels),
        rows=rows, scale_R=extra_R, effects=effects, paper_design=paper,
        input_transform=matched_input, disturbance_matrix=G,
        extra_inputs=(("stop_reaction", "rad/s^2"),),
        extras={"paper_model": paper.extras["paper_model"],
                # the nonlinear filters: the rotor states drive the motors in place of the
                # voltages, relative to the gravity voltage like the input
                "input_states": InputStates(from_input=np.zeros((2, 3)),
                                            from_states=np.eye(2), relative=np.eye(2))})


class UnbalancedInput:
    """The design's input transform: the applied voltages minus :func:`gravity_voltage` at
    the estimated pitch, with the parameters' constants (``m g l`` and the volts per N m)
    computed once instead of on every step (the same operations on the same numbers: the
    same values bitwise); picklable.

    Parameters
    ----------
    nominal : HelicopterParams
        The designer's parameters.
    """

    def __init__(self, nominal: HelicopterParams):
        self.nominal = nominal
        self._torque_n_m = nominal.mass_kg * GRAVITY_M_S2 * nominal.com_m  # times cos(pitch)
        self._volts_per_n_m = volts_per_pitch_newton_metre(nominal)

    def voltage(self, pitch_rad: np.ndarray) -> np.ndarray:
        """:func:`gravity_voltage` ``(nominal, pitch_rad)``, shape (..., 2), V."""
        torque = self._torque_n_m * np.cos(np.asarray(pitch_rad, float))
        return torque[..., None] * self._volts_per_n_m

    def __call__(self, u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
        """``u`` (N, 2) V minus the gravity voltage at ``x_hat[:, 0]`` (N,) rad (the
        operations of :meth:`voltage`, inline: this runs every step)."""
        torque = self._torque_n_m * np.cos(np.asarray(x_hat[:, 0], float))
        return u - torque[..., None] * self._volts_per_n_m
