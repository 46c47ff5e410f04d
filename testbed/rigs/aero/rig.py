"""The Quanser Aero 2-DOF helicopter rig: MJCF model, physical parameters, Quanser's model.

The rig owns ``models/aero.xml``, its physical parameters (:class:`AeroParams`, Quanser's Aero
parameter script), Quanser's linear model (:func:`quanser_model`) and the MuJoCo model's
finite-difference linearization (:meth:`AeroRig.linearize`), which a test compares.

State: ``x = [pitch, yaw, pitch_rate, yaw_rate]`` in rad and rad/s (pitch positive nose up,
yaw positive counter-clockwise seen from above); with the rig option ``yaw_locked`` (the
pitch-only lab configuration, the yaw axis clamped) ``x = [pitch, pitch_rate]``. Input
``u = [V_pitch, V_yaw]`` in volts in both configurations (front/pitch rotor, back/yaw rotor;
both push pitch).

Physics of the MuJoCo rig (nonlinear)::

    J_p th''      = -m g d sin(th) - D_p th' - F_p sgn(th') + K_pp V_p + K_py V_y - (centrifugal)
    J_y(th) psi'' = -D_y psi' - F_y sgn(psi') + cos(th) (K_yp V_p + K_yy V_y) - (Coriolis)

with the moving mass ``m`` centred ``d = K_sp / (m g)`` below the pitch axis: the pitch
stiffness ``K_sp`` is gravity's (not a joint spring), ``F_p``, ``F_y`` MuJoCo's joint
``frictionloss`` (Coulomb friction). Quanser's linear model is the linearization about level
pitch with the Coulomb friction left out (it has no derivative at rest):
:meth:`AeroRig.linearize` disables ``frictionloss`` while it differentiates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from testbed.records import field_items
from testbed.rigs.aero.hardware import AeroHardware
from testbed.rigs.base import GRAVITY_M_S2, Params, Rig, RigOption

STATE_NAMES = ("pitch", "yaw", "pitch_rate", "yaw_rate")
LOCKED_STATE_NAMES = ("pitch", "pitch_rate")
ACTION_NAMES = ("V_pitch", "V_yaw")
VOLTAGE_LIMIT_V = 24.0
#: Encoder resolution of both axes, counts per revolution.
ENCODER_COUNTS = 2048
SENSOR_PRESETS = ("encoders", "encoders+gyros", "hardware")

# Quanser's Aero parameter script: the parts of the moving assembly (SI units)
BODY_LENGTH_M = 0.1651
BODY_MASS_KG = 0.094
YOKE_MASS_KG = 0.526
YOKE_RADIUS_M = 0.02
PROP_MASS_KG = 0.43
PROP_ARM_M = 0.15875
_J_BODY = BODY_MASS_KG * BODY_LENGTH_M**2 / 12.0
_J_PROP = PROP_MASS_KG * PROP_ARM_M**2
_J_YOKE = YOKE_MASS_KG * YOKE_RADIUS_M**2 / 2.0

#: Default setpoint schedules: (start time s, pitch rad, yaw rad) and, yaw locked, (t, pitch).
DEFAULT_SETPOINTS: tuple[tuple[float, ...], ...] = (
    (0.0, 0.0, 0.0),
    (5.0, float(np.deg2rad(10.0)), float(np.deg2rad(30.0))),
    (10.0, float(np.deg2rad(-5.0)), float(np.deg2rad(-20.0))),
    (15.0, float(np.deg2rad(5.0)), 0.0),
)
LOCKED_SETPOINTS: tuple[tuple[float, ...], ...] = tuple((row[0], row[1])
                                                         for row in DEFAULT_SETPOINTS)
#: Initial-state spread (each state's standard deviation, rad or rad/s): the design prior's
#: (``P0 = 1e-4 I``) about level rest.
X0_STD = 0.01
#: LQR weights (diagonals; states, inputs, integrators of the tracked states) of the free
#: and the yaw-locked configuration (:attr:`AeroRig.lqr_weights`).
LQR_WEIGHTS = {"state_weight": (200.0, 100.0, 2.0, 5.0), "input_weight": (0.01, 0.01),
               "integral_weight": (50.0, 20.0)}
LOCKED_LQR_WEIGHTS = {"state_weight": (200.0, 2.0), "input_weight": (0.01, 0.01),
                      "integral_weight": (50.0,)}
#: Matched design (``hardware``): white noise on the rotor states, V sqrt(s) (the rotors
#: follow the command within about this), and their prior spread, V (motors at rest).
MOTOR_STATE_NOISE_V = 0.05
MOTOR_PRIOR_STD_V = 0.05


@dataclass(frozen=True)
class AeroParams(Params):
    """Physical parameters of the Quanser Aero (SI units; Quanser's Aero parameter script
    unless said otherwise, docs/aero.md).

    Attributes
    ----------
    pitch_stiffness : float
        ``K_sp``, N m/rad: the restoring gravity torque per radian of pitch at level,
        ``m g d`` (it sets the depth ``d`` of the centre of mass below the pitch axis).
    pitch_damping, yaw_damping : float
        Viscous damping ``D_p``, ``D_y``, N m s/rad.
    pitch_coulomb_Nm, yaw_coulomb_Nm : float
        Coulomb friction (MuJoCo ``frictionloss``), N m. Not in Quanser's script: an
        assumption of 5e-4 N m (the pitch torque of about 0.16 V on both rotors; 0.8 deg of
        pitch against ``K_sp``), which a recording identifies.
    pitch_inertia : float
        ``J_p = J_body + 2 J_prop``, total inertia about the pitch axis, kg m^2.
    yaw_inertia : float
        ``J_y = J_body + 2 J_prop + J_yoke``, total inertia about the yaw axis at level
        pitch, kg m^2.
    yoke_inertia : float
        ``J_yoke = m r^2 / 2`` of the yoke about the yaw axis, kg m^2.
    roll_inertia : float
        Inertia of the moving body about its long axis through the centre of mass, kg m^2.
        Not in the script (point masses give 0): an assumption (only the yaw inertia away
        from level pitch depends on it).
    mass_kg : float
        Moving mass ``m`` (body tube and both rotor assemblies), kg.
    K_pp, K_py, K_yp, K_yy : float
        Thrust-torque constants, N m/V: pitch torque from the pitch (front) rotor, pitch
        torque from the yaw (back) rotor, yaw torque from the pitch rotor, yaw torque from
        the yaw rotor.
    rotor_arm_m : float
        Distance of each rotor from the pitch axis, m.
    rotor_time_constant_pitch_s, rotor_time_constant_yaw_s : float
        Rotor (propeller speed) time constants of the ``hardware`` profile, s (about 40 ms
        in a real unit's tachometer; the yaw rotor's assumed equal). The ``paper`` profile
        has no rotor lag.
    """

    pitch_stiffness: float = 0.037463
    pitch_damping: float = 0.0071116
    yaw_damping: float = 0.0220
    pitch_coulomb_Nm: float = 5e-4
    yaw_coulomb_Nm: float = 5e-4
    pitch_inertia: float = _J_BODY + 2.0 * _J_PROP
    yaw_inertia: float = _J_BODY + 2.0 * _J_PROP + _J_YOKE
    yoke_inertia: float = _J_YOKE
    roll_inertia: float = 5e-4
    mass_kg: float = BODY_MASS_KG + 2.0 * PROP_MASS_KG
    K_pp: float = 0.0011
    K_py: float = 0.0021
    K_yp: float = -0.0027
    K_yy: float = 0.0022
    rotor_arm_m: float = PROP_ARM_M
    rotor_time_constant_pitch_s: float = 0.04
    rotor_time_constant_yaw_s: float = 0.04

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first unphysical parameter."""
        non_negative = ("pitch_stiffness", "pitch_damping", "yaw_damping", "pitch_coulomb_Nm",
                        "yaw_coulomb_Nm")
        for f, value in field_items(self):
            if not np.isfinite(value):
                raise ValueError(f"AeroParams.{f.name} must be finite, got {value}")
            if f.name in ("K_pp", "K_py", "K_yp", "K_yy"):
                continue
            if f.name in non_negative:
                if value < 0:
                    raise ValueError(f"AeroParams.{f.name} must be >= 0, got {value}")
            elif value <= 0:
                raise ValueError(f"AeroParams.{f.name} must be positive, got {value}")
        md2 = self.mass_kg * self.com_depth_m**2
        if self.pitch_inertia <= md2:
            raise ValueError(f"AeroParams.pitch_inertia must exceed mass_kg * d**2 "
                             f"({md2:.6g}, d = pitch_stiffness / (mass_kg g)), got "
                             f"{self.pitch_inertia:.6g}")
        if self.yaw_inertia <= self.yoke_inertia:
            raise ValueError(f"AeroParams.yaw_inertia must exceed yoke_inertia "
                             f"({self.yoke_inertia:.6g}), got {self.yaw_inertia:.6g}")

    @property
    def com_depth_m(self) -> float:
        """``d = K_sp / (m g)``: the centre of mass below the pitch axis, m (4.0 mm nominal)."""
        return self.pitch_stiffness / (self.mass_kg * GRAVITY_M_S2)

    @property
    def body_inertia_com(self) -> np.ndarray:
        """Principal inertias of the moving body about its centre of mass, shape (3,).

        Order: about the long axis (x), the pitch axis (y), the body normal (z), kg m^2. The
        centre of mass lies on the yaw axis at level pitch, so the body's yaw inertia there
        is its ``I_zz``.
        """
        return np.array([self.roll_inertia,
                         self.pitch_inertia - self.mass_kg * self.com_depth_m**2,
                         self.yaw_inertia - self.yoke_inertia])

    @property
    def torque_gains(self) -> np.ndarray:
        """Volts to torques at level pitch, shape (2, 2), N m/V (rows pitch, yaw torque;
        columns V_pitch, V_yaw)."""
        return np.array([[self.K_pp, self.K_py], [self.K_yp, self.K_yy]])


def quanser_model(params: AeroParams | None = None,
                  yaw_locked: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Quanser's linear model of the Aero, ``x' = A x + B u``.

    ``J_p pitch'' = -K_sp pitch - D_p pitch' + K_pp V_p + K_py V_y`` and
    ``J_y yaw'' = -D_y yaw' + K_yp V_p + K_yy V_y``; with the yaw axis locked only the first.

    Parameters
    ----------
    params : AeroParams, optional
        Default: nominal.
    yaw_locked : bool

    Returns
    -------
    A : ndarray, shape (4, 4), or (2, 2) with ``yaw_locked``
    B : ndarray, shape (4, 2), or (2, 2)
    """
    p = AeroParams() if params is None else params
    pitch_row = [-p.pitch_stiffness / p.pitch_inertia, -p.pitch_damping / p.pitch_inertia]
    pitch_b = [p.K_pp / p.pitch_inertia, p.K_py / p.pitch_inertia]
    if yaw_locked:
        return np.array([[0.0, 1.0], pitch_row]), np.array([[0.0, 0.0], pitch_b])
    A = np.zeros((4, 4))
    A[0, 2] = A[1, 3] = 1.0
    A[2, 0], A[2, 2] = pitch_row
    A[3, 3] = -p.yaw_damping / p.yaw_inertia
    B = np.zeros((4, 2))
    B[2] = pitch_b
    B[3] = [p.K_yp / p.yaw_inertia, p.K_yy / p.yaw_inertia]
    return A, B


class AeroRig(Rig):
    """Quanser Aero: a body with two rotors on a yoke, pitch and yaw hinges.

    The body rests level (its centre of mass hangs below the pitch axis). Motor voltages are
    clipped at +-24 V. Design model: Quanser's linear model (nominal parameters) and the
    sensors' linear model; in the ``hardware`` profile augmented with the rotor lag and the
    IMU's biases (:meth:`design_model`).

    Profiles: ``"paper"`` (torque proportional to voltage at every instant, quantized
    encoders by default) and ``"hardware"`` (:mod:`testbed.rigs.aero.hardware`: rotor lag,
    amplifier limits; default sensors ``"hardware"``, the encoders and the IMU with a real
    unit's errors).

    Parameters
    ----------
    params : AeroParams, optional
    physics_dt_s : float
    profile : {"paper", "hardware"}
    options : dict, optional
        Rig options (:attr:`rig_options`): ``{"yaw_locked": bool}``.
    hardware : AeroHardware, optional
        Parameters of the ``hardware`` profile (default: the documented ones).
    """

    name = "aero"
    sensor_presets = SENSOR_PRESETS
    xml_path = "models/aero.xml"
    params_type = AeroParams
    joints = ("pitch", "yaw")
    state_names = STATE_NAMES
    state_units = ("rad", "rad", "rad/s", "rad/s")
    action_names = ACTION_NAMES
    action_units = ("V", "V")
    action_low = (-VOLTAGE_LIMIT_V, -VOLTAGE_LIMIT_V)
    action_high = (VOLTAGE_LIMIT_V, VOLTAGE_LIMIT_V)
    tracked_states = ("pitch", "yaw")
    default_setpoints = DEFAULT_SETPOINTS
    scenario_options = {"process_noise_floor": 0.01, "process_noise_model": "auto"}
    #: +-20 % on the pitch stiffness and the viscous dampings, the constants Quanser's script
    #: calls "found experimentally" (a real unit's stiffness is more than twice nominal:
    #: an identification, not a robust design, covers that; see :attr:`identifiable`).
    mismatch_range = {"pitch_stiffness": 0.2, "pitch_damping": 0.2, "yaw_damping": 0.2}
    #: Bounds (factors of nominal) a recording's fit searches; wide, as real units differ.
    identifiable = {"pitch_stiffness": (0.2, 5.0), "pitch_damping": (0.05, 5.0),
                    "yaw_damping": (0.05, 5.0), "pitch_coulomb_Nm": (0.01, 20.0),
                    "yaw_coulomb_Nm": (0.01, 20.0), "pitch_inertia": (0.5, 2.0),
                    "yaw_inertia": (0.5, 2.0), "K_pp": (0.2, 5.0), "K_py": (0.2, 5.0),
                    "K_yp": (0.2, 5.0), "K_yy": (0.2, 5.0),
                    "rotor_time_constant_pitch_s": (0.25, 4.0),
                    "rotor_time_constant_yaw_s": (0.25, 4.0)}
    rig_options = {"yaw_locked": RigOption(False, "clamp the yaw axis: the pitch-only lab "
                                                  "configuration")}
    profiles = ("paper", "hardware")
    render_camera = "overview"
    #: No pitch stops are modelled; upside down is far past anything the rig does (the LQR's
    #: setpoints are within 10 deg); saturated motors give at most about 2 rad/s^2 of yaw
    #: acceleration against ``D_y / J_y = 1 /s``, so 100 rad/s is far out.
    state_envelope = (np.pi, np.inf, 100.0, 100.0)
    x0_draws = 4
    lqr_weights: dict[str, tuple[float, ...]] = LQR_WEIGHTS

    def __init__(self, params: AeroParams | None = None, physics_dt_s: float = 0.001,
                 profile: str = "paper", options: dict[str, Any] | None = None,
                 hardware: AeroHardware | None = None):
        if hardware is not None and not isinstance(hardware, AeroHardware):
            raise ValueError(f"hardware must be an AeroHardware, got {hardware!r}")
        if hardware is not None and profile != "hardware":
            raise ValueError(f"hardware parameters apply to profile 'hardware', not {profile!r}")
        #: Whether the yaw axis is clamped (rig option ``yaw_locked``).
        self.yaw_locked = bool(self.resolve_options(options)["yaw_locked"])
        if self.yaw_locked:  # the instance's declarations: the pitch axis only
            self.joints = ("pitch",)
            self.state_names = LOCKED_STATE_NAMES
            self.state_units = ("rad", "rad/s")
            self.tracked_states = ("pitch",)
            self.default_setpoints = LOCKED_SETPOINTS
            self.state_envelope = (np.pi, 100.0)
            self.x0_draws = 2
            self.lqr_weights = LOCKED_LQR_WEIGHTS
        #: Parameters of the ``hardware`` profile (None in the ``paper`` profile).
        self.hardware = (hardware or AeroHardware()) if profile == "hardware" else None
        if self.hardware is not None:
            limits = tuple(float(v) for v in self.hardware.voltage_limit_v)
            self.action_low, self.action_high = tuple(-v for v in limits), limits
        super().__init__(params, physics_dt_s, profile, options)
        self._body_id = self.body_id("aero")

    # ------------------------------------------------------------------ model
    def edit_spec(self, spec: mujoco.MjSpec) -> None:
        """``yaw_locked``: the yaw hinge removed (the yoke fixed to the post);
        ``hardware``: first-order rotor lag (``filterexact``) and the amplifier limits."""
        if self.options["yaw_locked"]:
            spec.delete(spec.joint("yaw"))
        if self.profile == "hardware":
            hw = self.hardware
            for i, name in enumerate(("pitch_motor", "yaw_motor")):
                act = spec.actuator(name)
                act.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
                act.dynprm[0] = (AeroParams.rotor_time_constant_pitch_s,
                                 AeroParams.rotor_time_constant_yaw_s)[i]
                act.ctrlrange = [-hw.voltage_limit_v[i], hw.voltage_limit_v[i]]

    def apply_params(self, model: mujoco.MjModel, params: AeroParams) -> None:
        """Mass, centre of mass, inertias, damping, friction, rotor gears and lags."""
        def named(kind: mujoco.mjtObj, name: str) -> int:
            return mujoco.mj_name2id(model, kind, name)

        body = named(mujoco.mjtObj.mjOBJ_BODY, "aero")
        yoke = named(mujoco.mjtObj.mjOBJ_BODY, "yoke")
        model.body_mass[body] = params.mass_kg
        model.body_ipos[body] = [0.0, 0.0, -params.com_depth_m]
        model.body_inertia[body] = params.body_inertia_com
        model.body_inertia[yoke] = [params.yoke_inertia] * 3
        for joint, damping, friction in (
                ("pitch", params.pitch_damping, params.pitch_coulomb_Nm),
                ("yaw", params.yaw_damping, params.yaw_coulomb_Nm)):
            jid = named(mujoco.mjtObj.mjOBJ_JOINT, joint)
            if jid < 0:  # yaw locked
                continue
            dof = model.jnt_dofadr[jid]
            model.dof_damping[dof] = damping
            model.dof_frictionloss[dof] = friction
        r = params.rotor_arm_m
        acts = [named(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in ("pitch_motor", "yaw_motor")]
        for act, site_x in zip(acts, (r, -r), strict=True):
            model.site_pos[model.actuator_trnid[act, 0]] = [site_x, 0.0, 0.0]
        gear = np.zeros((2, 6))
        gear[0, 2] = params.K_pp / r     # thrust N/V along the rotor axis (body +z)
        gear[0, 5] = params.K_yp         # reaction torque about it: yaw
        gear[1, 1] = -params.K_yy / r    # thrust along body -y (yaw +)
        gear[1, 4] = -params.K_py        # reaction torque about -y: pitch +
        for act, row, tau in zip(acts, gear, (params.rotor_time_constant_pitch_s,
                                              params.rotor_time_constant_yaw_s), strict=True):
            model.actuator_gear[act] = row
            if model.actuator_dyntype[act] != mujoco.mjtDyn.mjDYN_NONE:
                model.actuator_dynprm[act, 0] = tau

    def linearize(self, x_op: np.ndarray | None = None, u_op: np.ndarray | None = None,
                  eps: float = 1e-6, motor_states: bool = False
                  ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`Rig.linearize` with the Coulomb friction (``frictionloss``) left out: it has
        no derivative at rest, and Quanser's linear model has none."""
        flags = self.model.opt.disableflags
        self.model.opt.disableflags = flags | int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
        try:
            return super().linearize(x_op, u_op, eps, motor_states)
        finally:
            self.model.opt.disableflags = flags

    # ------------------------------------------------------------------ state and noise
    def random_x0(self, xi: np.ndarray) -> np.ndarray:
        """Near level rest: every state ``~ N(0, 0.01^2)`` (rad, rad/s), the design prior;
        shape (k, n) from ``xi`` (k, n)."""
        return X0_STD * np.asarray(xi, float)

    def process_noise_matrix(self) -> np.ndarray:
        """White torque noise of 1 mN m sqrt(s) on each axis (per unit ``process_noise``):
        ``b`` (n, j) with ``1e-3 / J`` on the acceleration rows."""
        p = AeroParams()
        j = len(self.joints)
        b = np.zeros((2 * j, j))
        inertias = (p.pitch_inertia, p.yaw_inertia)[:j]
        b[j:] = np.diag([1e-3 / J for J in inertias])
        return b

    # ------------------------------------------------------------------ sensors, design
    def sensors(self, preset: str | None = None, *, dt_s: float = 0.01,
                noise_std_rad: float = 0.0, gyro_noise_std_rad_s: float = 0.005,
                counts_per_rev: int = ENCODER_COUNTS):
        """A sensor suite built from the rig's channels.

        Parameters
        ----------
        preset : {"encoders", "encoders+gyros", "hardware"}, optional
            ``encoders``: the pitch and yaw encoders (pitch only with the yaw axis locked),
            quantized at ``2 pi / counts_per_rev``, with optional white noise
            ``noise_std_rad``; ``encoders+gyros`` adds the rates (white noise
            ``gyro_noise_std_rad_s``); ``hardware``: the encoders, the IMU with a real
            unit's errors (:func:`hardware_imu`), the rotor speeds and the motor currents
            (:func:`~testbed.rigs.aero.motors.hardware_motors`). Default: ``encoders`` in
            the ``paper`` profile, ``hardware`` in the ``hardware`` profile.
        dt_s : float
            Sampling period, s.
        """
        from testbed.sensors import Quantize, StateChannel, Suite, WhiteNoise

        preset = preset or ("encoders" if self.hardware is None else "hardware")
        if preset not in SENSOR_PRESETS:
            raise ValueError(f"unknown aero sensor preset {preset!r}; expected one of "
                             f"{SENSOR_PRESETS}")
        counts = int(counts_per_rev) if np.isscalar(counts_per_rev) else 0
        if counts < 1 or counts != counts_per_rev:
            raise ValueError(f"counts_per_rev must be a positive integer, got {counts_per_rev!r}")
        n, j = self.n_states, len(self.joints)

        def state(i: int):
            return StateChannel(i, n, 2, self.state_names[i], self.state_units[i])

        angles = Quantize(Suite(*(state(i) for i in range(j))), 2 * np.pi / counts)
        if np.any(np.asarray(noise_std_rad) != 0):
            angles = WhiteNoise(angles, std=noise_std_rad)
        parts = [angles]
        if preset == "encoders+gyros":
            parts.append(WhiteNoise(Suite(*(state(i) for i in range(j, n))),
                                    std=gyro_noise_std_rad_s))
        elif preset == "hardware":
            from testbed.rigs.aero.motors import hardware_motors

            hw = self.hardware or AeroHardware()
            parts.append(hardware_imu(hw, dt_s, self.yaw_locked))
            parts.append(hardware_motors(hw, n))
        return Suite(*parts)

    @classmethod
    def cubic_model(cls, design):
        """Third-order expansion of the gravity torque in pitch (nominal parameters).

        The design model (Quanser's) has the linear restoring term ``-K_sp pitch / J_p``;
        the MuJoCo rig's is ``-K_sp sin(pitch) / J_p`` (the centre of mass ``d`` below the
        axis). To third order about level pitch::

            pitch'' += (K_sp / J_p) pitch^3 / 6        (0.285 rad/s^2 per rad^3 nominal)

        The pitch-dependent yaw inertia, the ``cos(pitch)`` on the yaw torques, the
        centrifugal and Coriolis terms and the Coulomb friction stay out (as in the design
        model). Works for either configuration (the pitch rows found by state name).

        Parameters
        ----------
        design : testbed.design.DesignModel

        Returns
        -------
        testbed.design.cubic.CubicExpansion
        """
        from testbed.design.cubic import CubicExpansion

        names = tuple(design.state_names)
        if "pitch" not in names or "pitch_rate" not in names:
            raise ValueError(f"the aero cubic expansion needs the states pitch and pitch_rate, "
                             f"got {list(names)}")
        p, r = names.index("pitch"), names.index("pitch_rate")
        n = len(names)
        nominal = AeroParams()
        a3 = np.zeros((n, n, n, n))
        a3[r, p, p, p] = nominal.pitch_stiffness / nominal.pitch_inertia / 6.0
        return CubicExpansion(
            a0=np.zeros(n), a1=np.array(design.continuous.A, float), a2=None, a3=a3,
            E=np.array(design.continuous.B, float),
            description="gravity torque -K_sp sin(pitch) / J_p to third order about level "
                        "pitch")

    def design_model(self, sensors, dt_s: float, disturbance=None, *,
                     process_noise_floor: float = 0.01, process_noise_model: str = "auto"):
        """Quanser's ``(A, B)`` at the designer's parameters (this rig's: nominal or a
        twin's, never the simulated truth), the sensors' model, ``Q`` = disturbance + floor;
        in the ``hardware`` profile augmented with the rotor lag and the IMU's biases
        (:meth:`_matched_design`).

        Parameters
        ----------
        sensors : Sensor
        dt_s : float
        disturbance : testbed.rigs.disturbances.Disturbance, optional
            Its white-noise intensity ``b b^T`` enters ``Q``, its ``G`` the design.
        process_noise_floor : float
            Extra intensity (rad^2/s^3) on each acceleration row (unmodelled dynamics: the
            Coulomb friction, the stiffness a real unit shows).
        process_noise_model : {"auto", "held", "continuous"}
            How ``Q`` is discretized (:func:`testbed.design.held_noise.uses_held_noise`).
        """
        from testbed.design import build_design, rate_noise
        from testbed.design.held_noise import matched_held_noise, uses_held_noise

        n = self.n_states
        A, B = quanser_model(self.params, self.yaw_locked)  # the designer's, never the truth
        Q, G = rate_noise(n, len(self.joints), process_noise_floor, disturbance)
        P0 = X0_STD**2 * np.eye(n)
        paper = build_design(self, sensors, dt_s, A, B, Q, self.default_x0(), P0,
                             disturbance_matrix=G, extras={"quanser_model": (A, B)},
                             held_noise=uses_held_noise(process_noise_model,
                                                        self.hardware is None))
        if self.hardware is None:
            return paper
        return self._matched_design(paper, sensors, dt_s, Q, G,
                                    matched_held_noise(disturbance, process_noise_model))

    def _matched_design(self, paper, sensors, dt_s: float, Q: np.ndarray, G,
                        held_intensity: np.ndarray | None = None):
        """The ``hardware`` profile's design: Quanser's model plus the rotor lag and the IMU.

        State ``[physical..., rotor_pitch, rotor_yaw, biases...]``
        (:func:`testbed.design.build_matched_design`): the rotors' volt-equivalent
        speeds (MuJoCo ``act``) from :meth:`linearize` ``(motor_states=True)`` at level
        (poles ``-1/tau``), prior: at rest; a bias state for each IMU channel with a declared
        bias (the standing gyro bias and its walk, the accelerometer's offset); the encoders'
        and the gyros' quantization as ``q^2 / 12`` in ``R`` (the sensors' linear model).
        """
        from scipy.linalg import block_diag

        from testbed.design import InputStates, build_matched_design

        A, B = self.linearize(motor_states=True)
        p = self.params
        tau = np.array([p.rotor_time_constant_pitch_s, p.rotor_time_constant_yaw_s])
        Qm = block_diag(Q, np.diag(MOTOR_STATE_NOISE_V**2 * np.ones(2) / tau))
        x0 = np.concatenate([self.default_x0(), np.zeros(2)])
        P0 = block_diag(np.asarray(paper.P0), MOTOR_PRIOR_STD_V**2 * np.eye(2))
        return build_matched_design(
            self, sensors, dt_s, A, B, Qm, x0, P0, held_intensity=held_intensity,
            extra_states=(("rotor_pitch", "V"), ("rotor_yaw", "V")), paper_design=paper,
            disturbance_matrix=G,
            extras={"quanser_model": paper.extras["quanser_model"],
                    # the nonlinear filters: the rotor states drive the motors in place of
                    # the voltages (absolute: the operating input is zero)
                    "input_states": InputStates(from_input=np.zeros((2, 2)),
                                                from_states=np.eye(2),
                                                relative=np.zeros((2, 2)))})


def hardware_imu(hardware: AeroHardware, dt_s: float, yaw_locked: bool = False):
    """The IMU of the ``hardware`` preset: :class:`~testbed.rigs.aero.imu.AeroIMU` with a
    real unit's errors.

    ``Quantize(WhiteNoise(BiasRandomWalk(imu)))``: a standing bias drawn per episode (gyros:
    then a slow random walk), white noise per sample and the quantization steps.
    """
    from testbed.rigs.aero.imu import AeroIMU
    from testbed.sensors import BiasRandomWalk, Quantize, WhiteNoise

    if not (np.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be a positive sampling period in s, got {dt_s}")
    hw = hardware
    gyros = 1 if yaw_locked else 2
    imu = AeroIMU(yaw_locked)
    imu = BiasRandomWalk(imu, walk=[hw.gyro_bias_walk] * gyros + [0.0], dt_s=dt_s,
                         initial_std=[hw.gyro_bias0_std] * gyros + [hw.accel_bias0_std])
    imu = WhiteNoise(imu, std=[hw.gyro_noise_std] * gyros + [hw.accel_noise_std])
    return Quantize(imu, [hw.gyro_step] * gyros + [hw.accel_step])
