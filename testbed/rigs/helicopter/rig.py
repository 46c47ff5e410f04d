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

import dataclasses
import functools
from dataclasses import dataclass

import mujoco
import numpy as np

from testbed.rigs.base import GRAVITY_M_S2, Params, Rig
from testbed.rigs.disturbances import Disturbance
from testbed.rigs.helicopter.hardware import HelicopterHardware, current_limited, deadband

PITCH_LIMIT_RAD = float(np.deg2rad(40.5))
STATE_NAMES = ("pitch", "yaw", "pitch_rate", "yaw_rate")
ACTION_NAMES = ("V_pitch", "V_yaw")
VOLTAGE_LIMIT_V = 24.0


@dataclass(frozen=True)
class HelicopterParams(Params):
    """Physical parameters of the Quanser 2-DOF helicopter (SI units).

    The inertias are not printed in Basin et al.; they are the values for which the damping and
    torque gains below reproduce its ``A`` and ``B`` exactly: ``J_p = B_p / 9.2751``,
    ``J_y = B_y / 3.4955`` (total inertias at level pitch), and ``K_ij = B_ij J``.

    Attributes
    ----------
    mass_kg : float
        Moving mass (helicopter body, motors, shrouds).
    com_m : float
        Distance of the centre of mass in front of the pitch axis.
    pitch_damping : float
        Viscous damping about the pitch axis, N m s/rad.
    yaw_damping : float
        Viscous damping about the yaw axis, N m s/rad.
    pitch_inertia : float
        Total inertia about the pitch axis, kg m^2 (includes ``m l^2``).
    yaw_inertia : float
        Total inertia about the yaw axis at level pitch, kg m^2.
    roll_inertia_com : float
        Body inertia about its long axis through the centre of mass, kg m^2 (sets how the
        yaw inertia changes with pitch).
    stage_inertia : float
        Inertia of the yaw stage (shaft and yoke) about the vertical axis, kg m^2.
    K_pp, K_py, K_yp, K_yy : float
        Torque gains, N m/V: pitch torque from the pitch motor (thrust), pitch torque from the
        yaw motor (reaction torque), yaw torque from the pitch motor (reaction torque), yaw
        torque from the yaw motor (thrust).
    r_pitch_rotor_m, r_yaw_rotor_m : float
        Arms of the front and back rotors from the pitch axis.
    """

    mass_kg: float = 1.3872
    com_m: float = 0.186
    pitch_damping: float = 0.800
    yaw_damping: float = 0.318
    pitch_inertia: float = 0.800 / 9.2751
    yaw_inertia: float = 0.318 / 3.4955
    roll_inertia_com: float = 0.010
    stage_inertia: float = 0.002
    K_pp: float = 2.3667 * 0.800 / 9.2751
    K_py: float = 0.0790 * 0.800 / 9.2751
    K_yp: float = 0.2410 * 0.318 / 3.4955
    K_yy: float = 0.7913 * 0.318 / 3.4955
    r_pitch_rotor_m: float = 0.157
    r_yaw_rotor_m: float = 0.178

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first unphysical parameter."""
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not np.isfinite(value):
                raise ValueError(f"HelicopterParams.{f.name} must be finite, got {value}")
            if f.name in ("K_pp", "K_py", "K_yp", "K_yy"):
                continue
            if value <= 0:
                raise ValueError(f"HelicopterParams.{f.name} must be positive, got {value}")
        pitch_com = self.pitch_inertia - self.mass_kg * self.com_m**2
        if pitch_com <= 0:
            raise ValueError("HelicopterParams.pitch_inertia must exceed mass_kg * com_m**2 "
                             f"({self.mass_kg * self.com_m ** 2:.6g}), got "
                             f"{self.pitch_inertia:.6g}")
        yaw_com = self.yaw_inertia - self.mass_kg * self.com_m**2 - self.stage_inertia
        if yaw_com <= 0:
            raise ValueError("HelicopterParams.yaw_inertia must exceed mass_kg * com_m**2 + "
                             f"stage_inertia, got {self.yaw_inertia}")

    @property
    def body_inertia_com(self) -> np.ndarray:
        """Principal inertias of the moving body about its centre of mass, shape (3,).

        Order: about the long axis (x), the pitch axis (y), the body normal (z), kg m^2.
        """
        ml2 = self.mass_kg * self.com_m**2
        return np.array([self.roll_inertia_com, self.pitch_inertia - ml2,
                         self.yaw_inertia - ml2 - self.stage_inertia])

    @property
    def torque_gains(self) -> np.ndarray:
        """Matrix mapping volts to torques at level pitch, shape (2, 2), N m/V.

        Rows: pitch torque, yaw torque; columns: V_pitch, V_yaw.
        """
        return np.array([[self.K_pp, self.K_py], [self.K_yp, self.K_yy]])


@dataclass(frozen=True)
class LinearModel:
    """Continuous-time linear model ``x' = A x + B u`` (+ noise/disturbance inputs).

    Attributes
    ----------
    A : ndarray, shape (4, 4)
    B : ndarray, shape (4, 2)
    b : ndarray, shape (4, 2) or None
        White-noise input matrix (``b dW``), intensity ``b b^T``.
    G : ndarray, shape (4, s) or None
        Deterministic disturbance input matrix.
    C1, C2, L, h, H : ndarray or None
        Observation, output and noise matrices of Basin et al. (12)-(15).
    """

    A: np.ndarray
    B: np.ndarray
    b: np.ndarray | None = None
    G: np.ndarray | None = None
    C1: np.ndarray | None = None
    C2: np.ndarray | None = None
    L: np.ndarray | None = None
    h: np.ndarray | None = None
    H: np.ndarray | None = None


def paper_model() -> LinearModel:
    """The linear helicopter model of Basin et al., eqs. (12)-(15), as printed.

    Corrected misprints (docs/references.md):

    - ``B`` is printed with three rows; the missing first row is ``[0, 0]`` (pitch angle
      row), giving ``B = [[0,0],[0,0],[2.3667,0.0790],[0.2410,0.7913]]``.
    - The constant matrix of (17)/(18) is ``G G^T`` (= ``b b^T``) whose first two rows are
      zero; the ``1`` entries printed there are not used (we compute ``G G^T``).

    Returns
    -------
    LinearModel
        ``A`` (4, 4), ``B`` (4, 2), ``b`` (4, 2), ``G`` (4, 4), ``C1 = C2 = L`` (2, 4),
        ``h`` (2, 2), ``H`` (2, 4).
    """
    A = np.array([[0.0, 0.0, 1.0, 0.0],
                  [0.0, 0.0, 0.0, 1.0],
                  [0.0, 0.0, -9.2751, 0.0],
                  [0.0, 0.0, 0.0, -3.4955]])
    B = np.array([[0.0, 0.0], [0.0, 0.0], [2.3667, 0.0790], [0.2410, 0.7913]])
    b = np.array([[0.0, 0.0], [0.0, 0.0], [0.9024, 0.0876], [0.0919, 0.8772]])
    G = np.zeros((4, 4))
    G[2:, :2] = b[2:]
    C = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    H = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    return LinearModel(A=A, B=B, b=b, G=G, C1=C.copy(), C2=C.copy(), L=C.copy(),
                       h=np.eye(2), H=H)


def gravity_voltage(params: HelicopterParams, pitch_rad: float | np.ndarray) -> np.ndarray:
    """Motor voltages whose torques cancel gravity at a pitch angle.

    Solves ``K [V_p, V_y]^T = [m g l cos(pitch), 0]^T`` with the torque-gain matrix ``K``
    (:attr:`HelicopterParams.torque_gains`); the yaw torque is kept zero.

    Parameters
    ----------
    params : HelicopterParams
        Parameters assumed by whoever compensates (a controller or an estimator uses its
        nominal model, not the simulated truth).
    pitch_rad : float or ndarray, shape (...)

    Returns
    -------
    ndarray, shape (..., 2)
        Voltages in V. At level pitch with nominal parameters this is ``[12.53, -3.82]`` V,
        close to the constant ``u = [12.495, -3.835]`` V of Basin et al.'s example: on this
        rig, with gravity, that ``u`` about holds level pitch. The paper's linear model
        leaves gravity out; there the same ``u`` drives pitch without bound (about 250 rad
        after 80 s, ``testbed reproduce basin-ms-hinf-helicopter``), so the example is the
        rig hovering only on the MuJoCo rig.
    """
    torque = params.mass_kg * GRAVITY_M_S2 * params.com_m * np.cos(np.asarray(pitch_rad, float))
    return torque[..., None] * _volts_per_pitch_newton_metre(params)


@functools.lru_cache(maxsize=32)
def _volts_per_pitch_newton_metre(params: HelicopterParams) -> np.ndarray:
    """Voltages giving 1 N m of pitch torque and no yaw torque, shape (2,), read-only."""
    volts = np.linalg.solve(params.torque_gains, np.array([1.0, 0.0]))
    volts.flags.writeable = False
    return volts


#: The mean-square H-infinity example's attenuation level and initial-condition weight ``R``
#: of (6) (``S(0) = R^-1``), as printed.
PAPER_GAMMA = 1.1
PAPER_INITIAL_WEIGHT = np.array([[0.8, 0.5, 0.2, 0.1],
                                 [0.5, 0.8, 0.7, 0.2],
                                 [0.2, 0.7, 0.9, 0.4],
                                 [0.1, 0.2, 0.4, 0.9]])
PAPER_INITIAL_WEIGHT.flags.writeable = False
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


def basin_helicopter_w(t_s: float) -> np.ndarray:
    """Basin et al.'s (helicopter example) deterministic disturbance ``w(t)``, shape (4,).

    ``w1 = 1/(1+t)``, ``w2 = 0.1 (1 - exp(-0.3 t))``, ``w3 = 0.1745/(1+t)``,
    ``w4 = 0.0873 (1 - exp(-0.3 t))``. ``w2`` and ``w4`` do not decay, so ``||w||_2`` grows
    with the horizon (docs/references.md).
    """
    rise = 1.0 - np.exp(-0.3 * t_s)
    return np.array([1.0 / (1.0 + t_s), 0.1 * rise, 0.1745 / (1.0 + t_s), 0.0873 * rise])


def basin_helicopter_disturbance(noise_scale: float = 1.0,
                                 deterministic: bool = True) -> Disturbance:
    """Basin et al.'s helicopter disturbance: printed ``G w(t)`` and ``b dW``.

    Parameters
    ----------
    noise_scale : float
        Multiplies the printed ``b`` (0 removes the white noise).
    deterministic : bool
        Include ``G w(t)``.
    """
    pm = paper_model()
    if not (np.isfinite(noise_scale) and noise_scale >= 0):
        raise ValueError(f"noise_scale must be finite and >= 0, got {noise_scale}")
    return Disturbance(G=pm.G if deterministic else None,
                       w=basin_helicopter_w if deterministic else None,
                       b=pm.b * noise_scale if noise_scale > 0 else None)


def _basin_signal():
    return paper_model().G, basin_helicopter_w


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
    disturbance_signals = {"basin-helicopter": lambda: _basin_signal()}
    scenario_options = {"process_noise_floor": 0.05}
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

    def design_model(self, sensors, dt_s: float, disturbance=None, *,
                     process_noise_floor: float = 0.05):
        """Basin et al.'s ``(A, B)``, the sensors' model, ``Q`` = disturbance + floor; in the
        ``hardware`` profile augmented with what it declares (:meth:`_matched_design`).

        Parameters
        ----------
        sensors : Sensor
        dt_s : float
        disturbance : testbed.rigs.disturbances.Disturbance, optional
            Its white-noise intensity ``b b^T`` enters ``Q``, its ``G`` the design.
        process_noise_floor : float
            Extra intensity (rad^2/s^3) on each acceleration row (unmodelled dynamics).
        """
        from testbed.design import build_design, rate_noise

        if not (np.isfinite(process_noise_floor) and process_noise_floor >= 0):
            raise ValueError(f"process_noise_floor must be finite and >= 0, got "
                             f"{process_noise_floor}")
        model = paper_model()
        Q, G = rate_noise(4, 2, process_noise_floor, disturbance)
        nominal = self.params  # what the designer knows (nominal or a twin's): never the truth

        unbalanced_input = _UnbalancedInput(nominal)
        paper = build_design(self, sensors, dt_s, model.A, model.B, Q, self.default_x0(),
                             np.diag([1e-4, 1e-4, 1e-4, 1e-4]), disturbance_matrix=G,
                             input_transform=unbalanced_input,
                             held_noise=self.hardware is None,
                             extras={"paper_model": model, "gamma": PAPER_GAMMA,
                                     "initial_weight": PAPER_INITIAL_WEIGHT})
        if self.hardware is None:
            return paper
        return self._matched_design(paper, sensors, dt_s, Q, G)

    def _matched_design(self, paper, sensors, dt_s: float, Q: np.ndarray, G):
        """The ``hardware`` profile's design: the paper design plus what the rig declares.

        State ``[pitch, yaw, pitch_rate, yaw_rate, dact_pitch, dact_yaw, biases...,
        delays...]`` (:func:`testbed.design.build_matched_design`):

        - rotor lag: ``dact = act - V_g(pitch)``, the volt-equivalent rotor speeds above the
          gravity-compensating voltage, from :meth:`linearize` ``(motor_states=True)`` at
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

        hw = self.hardware
        nominal = self.params
        A, B = self.linearize(motor_states=True)
        tau = np.asarray(hw.motor_time_constant_s, float)
        Qm = np.zeros((6, 6))
        Qm[:4, :4] = Q
        Qm[4:, 4:] = np.diag((MOTOR_STATE_NOISE_V * np.ones(2)) ** 2 / tau)
        x0 = np.concatenate([self.default_x0(),
                             -gravity_voltage(nominal, self.default_x0()[0])])
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

        gravity = _UnbalancedInput(nominal).voltage

        def matched_input(u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
            pitch = x_hat[:, 0]
            v_g = gravity(pitch)
            volts = current_limited(deadband(u, consts[:2]), x_hat[:, 4:6] + v_g,
                                    consts[2:4], consts[4:6])
            accel = x_hat[:, :6] @ accel_row  # the model's pitch acceleration now
            into_stop = ((pitch <= -resting) & (accel < 0)) | ((pitch >= resting) & (accel > 0))
            return np.column_stack([volts - v_g, np.where(into_stop, -accel, 0.0)])

        return build_matched_design(
            self, sensors, dt_s, A, B, Qm, x0, P0,
            extra_states=(("dact_pitch", "V"), ("dact_yaw", "V")), channels=np.array(channels),
            rows=rows, scale_R=extra_R, effects=effects, paper_design=paper,
            input_transform=matched_input, disturbance_matrix=G,
            extra_inputs=(("stop_reaction", "rad/s^2"),),
            extras={"paper_model": paper.extras["paper_model"],
                    # the nonlinear filters: the rotor states drive the motors in place of the
                    # voltages, relative to the gravity voltage like the input
                    "input_states": InputStates(from_input=np.zeros((2, 3)),
                                                from_states=np.eye(2), relative=np.eye(2))})


class _UnbalancedInput:
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
        self._volts_per_n_m = _volts_per_pitch_newton_metre(nominal)

    def voltage(self, pitch_rad: np.ndarray) -> np.ndarray:
        """:func:`gravity_voltage` ``(nominal, pitch_rad)``, shape (..., 2), V."""
        torque = self._torque_n_m * np.cos(np.asarray(pitch_rad, float))
        return torque[..., None] * self._volts_per_n_m

    def __call__(self, u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
        """``u`` (N, 2) V minus the gravity voltage at ``x_hat[:, 0]`` (N,) rad (the
        operations of :meth:`voltage`, inline: this runs every step)."""
        torque = self._torque_n_m * np.cos(np.asarray(x_hat[:, 0], float))
        return u - torque[..., None] * self._volts_per_n_m


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
