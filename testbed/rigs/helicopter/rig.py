"""Quanser-style 2-DOF helicopter rig: MJCF model, physical parameters, paper model.

The rig owns ``models/helicopter_2dof.xml``, its physical parameters
(:class:`HelicopterParams`), the linear model printed in Basin et al. (:func:`paper_model`,
verbatim with the misprints corrected) and a finite-difference linearization of the MuJoCo
model (:meth:`HelicopterRig.linearize`) so the two can be compared.

State convention (everywhere in the testbed): ``x = [pitch, yaw, pitch_rate, yaw_rate]`` in
rad and rad/s; pitch positive nose up, yaw positive counter-clockwise seen from above.
Input ``u = [V_pitch, V_yaw]`` in volts (front/pitch motor, back/yaw motor).

Physics of the MuJoCo rig (nonlinear)::

    J_p th''                      = K_pp V_p + K_py V_y - B_p th' - m g l cos(th) - (centrifugal)
    J_y(th) psi''                 = cos(th) (K_yp V_p + K_yy V_y) - B_y psi' - (Coriolis)
    J_y(th) = J_stage + I_zz cos^2 th + I_xx sin^2 th + m l^2 cos^2 th

Basin et al.'s ``A``, ``B`` are its linearization about level pitch with gravity left out
(``-9.2751 = -B_p/J_p``, ``2.3667 = K_pp/J_p``...). At level pitch the gravity torque has zero
slope, so the linearization with gravity compensated by the input (``u_op`` from
:meth:`HelicopterRig.gravity_voltage`) equals the paper's matrices.
"""

from __future__ import annotations

import mujoco
import numpy as np

from testbed.rigs.base import GRAVITY_M_S2, Rig
from testbed.rigs.helicopter import design as _design
from testbed.rigs.helicopter.design import (
    DESIGN_RATE_RAD_S,
    MOTOR_PRIOR_STD_V,
    MOTOR_STATE_NOISE_V,
    STOP_TOLERANCE_RAD,
    YAW_GYRO_PITCH_RAD,
)
from testbed.rigs.helicopter.hardware import HelicopterHardware, current_limited, deadband
from testbed.rigs.helicopter.paper import (
    PAPER_GAMMA,
    PAPER_INITIAL_WEIGHT,
    LinearModel,
    basin_helicopter_disturbance,
    basin_helicopter_w,
    basin_signal,
    paper_model,
)
from testbed.rigs.helicopter.params import PITCH_LIMIT_RAD, HelicopterParams, gravity_voltage

__all__ = ["ACTION_NAMES", "AMBIENT_NOISE_RAD_S15", "DEFAULT_SETPOINTS", "DESIGN_RATE_RAD_S",
           "ENCODER_COUNTS", "GRAVITY_M_S2", "MOTOR_PRIOR_STD_V", "MOTOR_STATE_NOISE_V",
           "PAPER_GAMMA", "PAPER_INITIAL_WEIGHT", "PITCH_LIMIT_RAD", "SENSOR_PRESETS",
           "STATE_NAMES", "STOP_TOLERANCE_RAD", "VOLTAGE_LIMIT_V", "X0_YAW_RATE_STD_RAD_S",
           "X0_YAW_STD_RAD", "YAW_GYRO_PITCH_RAD", "HelicopterParams", "HelicopterRig",
           "LinearModel", "basin_helicopter_disturbance", "basin_helicopter_w",
           "gravity_voltage", "hardware_imu", "paper_model"]

STATE_NAMES = ("pitch", "yaw", "pitch_rate", "yaw_rate")
ACTION_NAMES = ("V_pitch", "V_yaw")
VOLTAGE_LIMIT_V = 24.0


#: Default setpoint schedule: (start time s, pitch rad, yaw rad).
DEFAULT_SETPOINTS: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.0, 0.0),
    (5.0, float(np.deg2rad(10.0)), float(np.deg2rad(30.0))),
    (10.0, float(np.deg2rad(-5.0)), float(np.deg2rad(-20.0))),
    (15.0, float(np.deg2rad(5.0)), 0.0),
)
#: Initial-state spread of the default scenario: yaw and yaw rate standard deviations
#: (rad, rad/s), the design prior's (``P0 = 1e-4 I``); pitch rests on its stop, still.
X0_YAW_STD_RAD = 0.01
X0_YAW_RATE_STD_RAD_S = 0.01
#: Ambient disturbance of the default scenario ("air turbulence on the rotors"): white-noise
#: angular accelerations on pitch and yaw, rad/s^(3/2). From a thrust-torque fluctuation of
#: 1 % of the hover torque m g l (0.293 rad/s^2 rms) with a 0.05 s correlation time:
#: intensity 2 sigma^2 tau_c = 0.0086 rad^2/s^3, b = 0.093 (assumption, docs/helicopter.md).
AMBIENT_NOISE_RAD_S15 = 0.093
#: Encoder resolutions (pitch, yaw), counts per revolution (Quanser's).
ENCODER_COUNTS = (4096, 8192)
SENSOR_PRESETS = ("encoders", "encoders+gyros", "paper", "hardware")


class HelicopterRig(Rig):
    """Quanser-style 2-DOF helicopter: pitch and yaw hinges, two voltage-driven rotors.

    The rig rests on its lower pitch stop at -40.5 deg. Motor voltages are clipped at
    +-24 V like the real amplifier. Design model: Basin et al.'s linear model (the MuJoCo
    linearization about level pitch with gravity compensated by the input), the sensors'
    linear model, and as input the voltage minus the gravity-compensating voltage at the
    estimated pitch (nominal parameters).

    Profiles: ``"paper"`` (torque proportional to voltage at every instant, ideal encoders
    by default) and ``"hardware"`` (:mod:`testbed.rigs.helicopter.hardware`: rotor lag,
    amplifier voltage and current limits, deadband; default sensors ``"hardware"`` with an
    IMU). The design model follows the profile (:meth:`design_model`; the runner's
    ``design_profile="paper"`` keeps the paper's on the hardware rig).

    Parameters
    ----------
    params : HelicopterParams, optional
    physics_dt_s : float
    profile : {"paper", "hardware"}
    hardware : HelicopterHardware, optional
        Parameters of the ``hardware`` profile (default: the documented ones).
    """

    name = "helicopter"
    sensor_presets = SENSOR_PRESETS
    xml_path = "models/helicopter_2dof.xml"
    params_type = HelicopterParams
    joints = ("pitch", "yaw")
    state_names = STATE_NAMES
    state_units = ("rad", "rad", "rad/s", "rad/s")
    action_names = ACTION_NAMES
    action_units = ("V", "V")
    action_low = (-VOLTAGE_LIMIT_V, -VOLTAGE_LIMIT_V)
    action_high = (VOLTAGE_LIMIT_V, VOLTAGE_LIMIT_V)
    tracked_states = ("pitch", "yaw")
    default_setpoints = DEFAULT_SETPOINTS
    disturbance_signals = {"basin-helicopter": lambda: basin_signal()}
    scenario_options = {"process_noise_floor": 0.05, "process_noise_model": "auto"}
    #: +-20 %: the moving mass (the gravity torque the designer compensates is off) and the
    #: viscous dampings. Scaling the torque gains or the inertias with the mass would cancel
    #: in the hover voltage and in ``m g l / J``. The scoring suite's mismatch entries scale
    #: these fields together.
    mismatch_range = {"mass_kg": 0.2, "pitch_damping": 0.2, "yaw_damping": 0.2}
    #: What a recording identifies (``testbed identify``), bounds as factors of nominal: the
    #: dampings, total inertias and the four torque gains. The moving mass and the centre of
    #: mass are weighed and measured (the gravity torque ``m g l`` fixes the pitch axis's
    #: scale); the pitch inertia stays above ``m l^2`` (0.56 of nominal) and the yaw inertia
    #: above ``m l^2 + stage`` (0.55). The yaw axis's scale is seen through the pitch
    #: coupling only (``J_y(pitch)``, the centrifugal torque): a recording with little
    #: pitch motion leaves ``yaw_inertia`` to the identifiability check.
    identifiable = {"pitch_damping": (0.2, 5.0), "yaw_damping": (0.2, 5.0),
                    "pitch_inertia": (0.6, 3.0), "yaw_inertia": (0.6, 3.0),
                    "K_pp": (0.2, 5.0), "K_py": (0.2, 5.0), "K_yp": (0.2, 5.0),
                    "K_yy": (0.2, 5.0)}
    profiles = ("paper", "hardware")
    render_camera = "overview"
    #: Pitch past 90 deg would put the body through the base (the stops are at 40.5 deg);
    #: yaw turns freely; saturated motors reach about 3.3 rad/s of pitch rate and 7.3 rad/s
    #: of yaw rate, so 100 rad/s is far outside anything the rig does.
    state_envelope = (np.pi / 2, np.inf, 100.0, 100.0)

    def __init__(self, params: HelicopterParams | None = None, physics_dt_s: float = 0.001,
                 profile: str = "paper", hardware: HelicopterHardware | None = None,
                 options: dict | None = None):
        if hardware is not None and not isinstance(hardware, HelicopterHardware):
            raise ValueError(f"hardware must be a HelicopterHardware, got {hardware!r}")
        if hardware is not None and profile != "hardware":
            raise ValueError(f"hardware parameters apply to profile 'hardware', not {profile!r}")
        #: Parameters of the ``hardware`` profile (None in the ``paper`` profile).
        self.hardware = (hardware or HelicopterHardware()) if profile == "hardware" else None
        if self.hardware is not None:
            limits = tuple(float(v) for v in self.hardware.voltage_limit_v)
            self.action_low, self.action_high = tuple(-v for v in limits), limits
        super().__init__(params, physics_dt_s, profile, options)
        ids = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_ACTUATOR, n)
               for n in ("pitch_motor", "yaw_motor")]
        self._act_pitch, self._act_yaw = ids
        self._body_id = self.body_id("helicopter")
        self._stage_id = self.body_id("yaw_stage")
        self._mass_matrix = np.zeros((self.model.nv, self.model.nv))

    def apply_params(self, model: mujoco.MjModel, params: HelicopterParams) -> None:
        """Masses, inertias, damping, rotor arms and gears from ``params``."""
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "helicopter")
        stage = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "yaw_stage")
        act_p = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "pitch_motor")
        act_y = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, "yaw_motor")
        model.body_mass[body] = params.mass_kg
        model.body_ipos[body] = [params.com_m, 0.0, 0.0]
        model.body_inertia[body] = params.body_inertia_com
        model.body_inertia[stage] = [params.stage_inertia] * 3
        model.dof_damping[self.dof_adr[0]] = params.pitch_damping
        model.dof_damping[self.dof_adr[1]] = params.yaw_damping
        model.site_pos[model.actuator_trnid[act_p, 0], 0] = params.r_pitch_rotor_m
        model.site_pos[model.actuator_trnid[act_y, 0], 0] = -params.r_yaw_rotor_m
        gear = np.zeros((2, 6))
        gear[0, 2] = params.K_pp / params.r_pitch_rotor_m   # thrust N/V along rotor axis
        gear[0, 5] = params.K_yp                            # reaction torque about rotor axis
        gear[1, 1] = -params.K_yy / params.r_yaw_rotor_m    # thrust along -y (yaw +)
        gear[1, 4] = -params.K_py                           # reaction torque, pitch +
        model.actuator_gear[act_p] = gear[0]
        model.actuator_gear[act_y] = gear[1]

    # ------------------------------------------------------------------ hardware profile
    def edit_spec(self, spec: mujoco.MjSpec) -> None:
        """``hardware``: first-order rotor lag (``filterexact``) and the amplifier limits."""
        hw = self.hardware
        for i, name in enumerate(("pitch_motor", "yaw_motor")):
            act = spec.actuator(name)
            act.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
            act.dynprm[0] = hw.motor_time_constant_s[i]
            act.ctrlrange = [-hw.voltage_limit_v[i], hw.voltage_limit_v[i]]
        # the simulator's C current limit keeps its command and constants here
        # (testbed.sim.native: [flag, command, back-EMF share, R I_max])
        spec.nuserdata = 1 + 3 * len(spec.actuators)

    def member_constants(self, params: HelicopterParams) -> np.ndarray:
        """``hardware``: :meth:`HelicopterHardware.constants` (deadband, back-EMF share,
        ``R I_max``); none in the ``paper`` profile."""
        return np.zeros(0) if self.hardware is None else self.hardware.constants()

    def actuation(self, u: np.ndarray, constants: np.ndarray) -> dict[str, np.ndarray]:
        """``ctrl = u`` (paper) or the voltages past the motors' deadband (hardware)."""
        if self.hardware is None:
            return {"ctrl": u}
        return {"ctrl": deadband(u, constants[:, :2])}

    @property
    def needs_substep(self) -> bool:
        """The current limit depends on the rotor speed: evaluated every physics step."""
        return self.hardware is not None

    def substep_ctrl(self, command: np.ndarray, act: np.ndarray,
                     constants: np.ndarray) -> np.ndarray:
        """The voltage within the amplifier's current limit (:func:`current_limited`)."""
        return current_limited(command, act, constants[..., 2:4], constants[..., 4:6])

    def act_window(self, constants: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``hardware``: the current limit is ``c act +- R I_max``: run in C by the simulator."""
        if self.hardware is None:
            return None
        return constants[..., 2:4], constants[..., 4:6]

    def process_noise_matrix(self) -> np.ndarray:
        """Basin et al.'s white-noise matrix ``b`` (4, 2) (velocity rows)."""
        return paper_model().b

    @property
    def dof_index(self) -> np.ndarray:
        """MuJoCo dof indices of ``[pitch, yaw]``, shape (2,)."""
        return self.dof_adr

    def default_x0(self) -> np.ndarray:
        """Resting on the lower pitch stop: ``[-40.5 deg, 0, 0, 0]``."""
        return np.array([-PITCH_LIMIT_RAD, 0.0, 0.0, 0.0])

    x0_draws = 2

    def random_x0(self, xi: np.ndarray) -> np.ndarray:
        """On the lower stop, still in pitch; yaw ``~ N(0, 0.01^2)`` rad, yaw rate
        ``~ N(0, 0.01^2)`` rad/s (the design prior): shape (k, 4) from ``xi`` (k, 2)."""
        x = np.tile(self.default_x0(), (len(xi), 1))
        x[:, 1] = X0_YAW_STD_RAD * xi[:, 0]
        x[:, 3] = X0_YAW_RATE_STD_RAD_S * xi[:, 1]
        return x

    def ambient_noise_matrix(self) -> np.ndarray:
        """Air turbulence on the rotors: ``b = diag(0.093, 0.093)`` on the acceleration rows."""
        b = np.zeros((4, 2))
        b[2, 0] = b[3, 1] = AMBIENT_NOISE_RAD_S15
        return b

    def validate_x0(self, x0) -> np.ndarray:
        """Shape (4,), finite, pitch within the stops."""
        x = super().validate_x0(x0)
        if abs(x[0]) > PITCH_LIMIT_RAD + 1e-9:
            raise ValueError(f"options['x0'] pitch {x[0]:.4f} rad is outside the stops "
                             f"+-{PITCH_LIMIT_RAD:.4f} rad")
        return x

    def validate_setpoints(self, setpoints) -> np.ndarray:
        """Rows ``(t_s, pitch_rad, yaw_rad)``; pitch within the stops."""
        table = super().validate_setpoints(setpoints)
        if np.any(np.abs(table[:, 1]) > PITCH_LIMIT_RAD):
            raise ValueError(f"setpoint pitch must lie within +-{np.rad2deg(PITCH_LIMIT_RAD)} deg")
        return table

    def operating_input(self, params: HelicopterParams, x: np.ndarray) -> np.ndarray:
        """Voltages cancelling gravity at each state's pitch, shape (k, 2)."""
        return gravity_voltage(params, x[:, 0])

    def gravity_voltage(self, pitch_rad: float | np.ndarray) -> np.ndarray:
        """Voltages cancelling gravity at ``pitch_rad`` with this rig's current parameters."""
        return gravity_voltage(self.params, pitch_rad)

    def joint_accel_to_force(self, accel: np.ndarray) -> np.ndarray:
        """Generalized forces ``M(q) a`` (nv,) producing joint accelerations ``accel`` (2,)."""
        a = np.zeros(self.model.nv)
        a[self.dof_adr] = accel
        mujoco.mj_fullM(self.model, self.data, self._mass_matrix)
        return self._mass_matrix @ a

    # ------------------------------------------------------------------ sensors, design
    def sensors(self, preset: str | None = None, *, dt_s: float = 0.01,
                noise_std_rad: float = 0.0, gyro_noise_std_rad_s: float = 0.005,
                counts_per_rev: tuple[int, int] = ENCODER_COUNTS,
                intensity: np.ndarray | None = None, disturbance_channel: bool = False):
        """A sensor suite built from the rig's channels.

        Parameters
        ----------
        preset : {"encoders", "encoders+gyros", "paper", "hardware"}, optional
            ``encoders``: quantized pitch and yaw encoders (``2 pi / counts``) with optional
            white noise ``noise_std_rad``; ``encoders+gyros`` adds rate gyros (white noise
            ``gyro_noise_std_rad_s``); ``paper``: Basin et al.'s ``y1 = C1 x + e`` with
            ``cov(e) = intensity / dt_s`` (default intensity ``h h^T = I``); ``hardware``:
            the encoders plus an IMU (:func:`hardware_imu`). Default: ``encoders`` in the
            ``paper`` profile, ``hardware`` in the ``hardware`` profile.
        dt_s : float
            Sampling period, s.
        disturbance_channel : bool
            Append the deterministic channel ``y2 = C2 x + H w`` of the mean-square
            H-infinity example (needs the scenario's disturbance ``w``).
        """
        from testbed.sensors import LinearChannel, Quantize, StateChannel, Suite, WhiteNoise

        preset = preset or ("encoders" if self.hardware is None else "hardware")
        if preset not in SENSOR_PRESETS:
            raise ValueError(f"unknown helicopter sensor preset {preset!r}; expected one of "
                             f"{SENSOR_PRESETS}")
        counts = np.asarray(counts_per_rev)
        if counts.shape != (2,) or np.any(counts < 1) or np.any(counts != np.round(counts)):
            raise ValueError("counts_per_rev must be two positive integers (pitch, yaw), "
                             f"got {counts_per_rev}")

        def state(i: int):
            return StateChannel(i, 4, 2, STATE_NAMES[i], self.state_units[i])

        paper = paper_model()
        if preset == "paper":
            S = np.eye(2) if intensity is None else intensity
            parts = [WhiteNoise(LinearChannel(paper.C1, ("pitch", "yaw"), ("rad", "rad"),
                                              n_inputs=2), intensity=S, dt_s=dt_s)]
        else:
            if intensity is not None:
                raise ValueError("intensity applies to the 'paper' preset only")
            angles = Quantize(Suite(state(0), state(1)), 2 * np.pi / counts.astype(float))
            if np.any(np.asarray(noise_std_rad) != 0):
                angles = WhiteNoise(angles, std=noise_std_rad)
            parts = [angles]
            if preset == "encoders+gyros":
                parts.append(WhiteNoise(Suite(state(2), state(3)), std=gyro_noise_std_rad_s))
            elif preset == "hardware":
                parts.append(hardware_imu(self.hardware or HelicopterHardware(), dt_s))
        if disturbance_channel:
            parts.append(LinearChannel(paper.C2, ("y2_pitch", "y2_yaw"), ("rad", "rad"),
                                       Hw=paper.H, n_inputs=2))
        return Suite(*parts)

    @classmethod
    def cubic_model(cls, design, pitch0_rad: float = 0.0):
        """Third-order expansion of the gravity torque in pitch (nominal parameters):
        :func:`testbed.rigs.helicopter.design.cubic_model`."""
        return _design.cubic_model(design, pitch0_rad)

    def design_model(self, sensors, dt_s: float, disturbance=None, *,
                     process_noise_floor: float = 0.05, process_noise_model: str = "auto"):
        """Basin et al.'s ``(A, B)``, the sensors' model, ``Q`` = disturbance + floor; in the
        ``hardware`` profile augmented with what it declares (:meth:`_matched_design`):
        :func:`testbed.rigs.helicopter.design.design_model`."""
        return _design.design_model(self, sensors, dt_s, disturbance,
                                    process_noise_floor=process_noise_floor,
                                    process_noise_model=process_noise_model)

    def _matched_design(self, paper, sensors, dt_s: float, Q: np.ndarray, G):
        """The ``hardware`` profile's design, the paper design plus what the rig declares:
        :func:`testbed.rigs.helicopter.design.matched_design`."""
        return _design.matched_design(self, paper, sensors, dt_s, Q, G)


def hardware_imu(hardware: HelicopterHardware, dt_s: float):
    """The IMU of the ``hardware`` preset: :class:`HelicopterIMU` with its imperfections.

    ``Delay(SampleAndHold(WhiteNoise(BiasRandomWalk(ScaleFactor(imu)))))``: a sensitivity
    error per episode, a bias (calibration residual at reset, then a random walk on the
    gyros), white noise of the datasheet's density, held at the IMU's output rate when the
    loop samples faster, and the low-pass filter's group delay in whole samples (>= 1).
    """
    from testbed.rigs.helicopter.imu import HelicopterIMU
    from testbed.sensors import BiasRandomWalk, Delay, SampleAndHold, ScaleFactor, WhiteNoise

    if not (np.isfinite(dt_s) and dt_s > 0):
        raise ValueError(f"dt_s must be a positive sampling period in s, got {dt_s}")
    hw = hardware
    # control periods per IMU sample (a loop faster than the IMU holds its sample; one
    # slower reads its latest sample every period); the IMU's own period, rounded to whole
    # control periods, is what its noise and bias walk are per sample
    hold = max(1, int(round(1.0 / (hw.imu_rate_hz * dt_s))))
    imu_dt_s = hold * dt_s if hold > 1 else dt_s
    imu = ScaleFactor(HelicopterIMU(), initial_std=hw.scale_factor_std)
    imu = BiasRandomWalk(imu, walk=[hw.gyro_bias_walk, hw.gyro_bias_walk, 0.0], dt_s=imu_dt_s,
                         initial_std=[hw.gyro_bias0_std, hw.gyro_bias0_std, hw.accel_bias0_std])
    imu = WhiteNoise(imu, density=[hw.gyro_noise_density, hw.gyro_noise_density,
                                   hw.accel_noise_density], dt_s=imu_dt_s)
    if hold > 1:
        imu = SampleAndHold(imu, hold)
    return Delay(imu, max(1, int(round(hw.imu_delay_s / dt_s))))
