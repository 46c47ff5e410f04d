"""Quanser-style 2-DOF helicopter rig: MJCF model, physical parameters, paper model.

The rig owns ``models/helicopter_2dof.xml``, its physical parameters
(:class:`HelicopterParams`), the linear model printed in seed-000 (:func:`paper_model`,
verbatim with the misprints corrected) and a finite-difference linearization of the MuJoCo
model (:meth:`HelicopterRig.linearize`) so the two can be compared.

State convention (everywhere in the testbed): ``x = [pitch, yaw, pitch_rate, yaw_rate]`` in
rad and rad/s; pitch positive nose up, yaw positive counter-clockwise seen from above.
Input ``u = [V_pitch, V_yaw]`` in volts (front/pitch motor, back/yaw motor).

Physics of the MuJoCo rig (nonlinear)::

    J_p th''                      = K_pp V_p + K_py V_y - B_p th' - m g l cos(th) - (centrifugal)
    J_y(th) psi''                 = cos(th) (K_yp V_p + K_yy V_y) - B_y psi' - (Coriolis)
    J_y(th) = J_stage + I_zz cos^2 th + I_xx sin^2 th + m l^2 cos^2 th

seed-000's ``A``, ``B`` are its linearization about level pitch with gravity left out
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

from testbed.rigs.assets import model_path
from testbed.rigs.params import scaled_copy

GRAVITY_M_S2 = 9.81
PITCH_LIMIT_RAD = float(np.deg2rad(40.5))
STATE_NAMES = ("pitch", "yaw", "pitch_rate", "yaw_rate")
ACTION_NAMES = ("V_pitch", "V_yaw")
VOLTAGE_LIMIT_V = 24.0


@dataclass(frozen=True)
class HelicopterParams:
    """Physical parameters of the Quanser 2-DOF helicopter (SI units).

    The inertias are not printed in seed-000; they are the values for which the damping and
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

    def scaled(self, scales: dict[str, float]) -> HelicopterParams:
        """Copy with some parameters multiplied by factors (model mismatch studies).

        Parameters
        ----------
        scales : dict
            ``{field_name: factor}``; factors must be finite and non-negative.

        Raises
        ------
        ValueError
            Unknown field name, a bad factor, or an unphysical result (e.g. ``m l^2`` above
            the pitch inertia), named in the message.
        """
        return scaled_copy(self, scales)

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
                             f"({self.mass_kg * self.com_m ** 2:.6f}), got {self.pitch_inertia}")
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
        Observation, output and noise matrices of seed-000 (12)-(15).
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
    """The linear helicopter model of seed-000, eqs. (12)-(15), as printed.

    Corrected misprints (PAPER_NOTES):

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
        close to the constant ``u = [12.495, -3.835]`` V of seed-000's example.
    """
    torque = params.mass_kg * GRAVITY_M_S2 * params.com_m * np.cos(np.asarray(pitch_rad, float))
    return torque[..., None] * _volts_per_pitch_newton_metre(params)


@functools.lru_cache(maxsize=32)
def _volts_per_pitch_newton_metre(params: HelicopterParams) -> np.ndarray:
    """Voltages giving 1 N m of pitch torque and no yaw torque, shape (2,), read-only."""
    volts = np.linalg.solve(params.torque_gains, np.array([1.0, 0.0]))
    volts.flags.writeable = False
    return volts


class HelicopterRig:
    """The MuJoCo helicopter: model, parameters, state access and linearization.

    Parameters
    ----------
    params : HelicopterParams, optional
        Physical parameters; the MJCF's masses, inertias, damping and gears are rewritten
        from them.
    physics_dt_s : float
        MuJoCo time step in seconds.

    Attributes
    ----------
    model : mujoco.MjModel
    data : mujoco.MjData
    """

    XML_FILE = "helicopter_2dof.xml"

    def __init__(self, params: HelicopterParams | None = None, physics_dt_s: float = 0.001):
        if not (np.isfinite(physics_dt_s) and physics_dt_s > 0):
            raise ValueError(f"physics_dt_s must be a positive finite time in s, "
                             f"got {physics_dt_s}")
        self.model = mujoco.MjModel.from_xml_path(str(model_path(self.XML_FILE)))
        self.model.opt.timestep = physics_dt_s
        self.data = mujoco.MjData(self.model)
        self._qpos_adr = np.array([self.model.jnt_qposadr[self._joint_id(n)]
                                   for n in ("pitch", "yaw")])
        self._dof_adr = np.array([self.model.jnt_dofadr[self._joint_id(n)]
                                  for n in ("pitch", "yaw")])
        self._body_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "helicopter")
        self._stage_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "yaw_stage")
        self._act_pitch = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_ACTUATOR,
                                            "pitch_motor")
        self._act_yaw = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_ACTUATOR, "yaw_motor")
        self._mass_matrix = np.zeros((self.model.nv, self.model.nv))
        # [pitch, yaw, pitch_rate, yaw_rate] as one gather from concatenate(qpos, qvel)
        self._state_gather = np.concatenate([self._qpos_adr, self.model.nq + self._dof_adr])
        self.params = HelicopterParams()
        self.set_params(params or HelicopterParams())

    def _joint_id(self, name: str) -> int:
        return mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, name)

    # ------------------------------------------------------------------ parameters
    def set_params(self, params: HelicopterParams) -> None:
        """Write physical parameters into the MuJoCo model (masses, inertias, damping, gears).

        Raises
        ------
        ValueError
            If a parameter is unphysical (named in the message); the model is unchanged.
        """
        params.validate()
        m = self.model
        m.body_mass[self._body_id] = params.mass_kg
        m.body_ipos[self._body_id] = [params.com_m, 0.0, 0.0]
        m.body_inertia[self._body_id] = params.body_inertia_com
        m.body_inertia[self._stage_id] = [params.stage_inertia] * 3
        m.dof_damping[self._dof_adr[0]] = params.pitch_damping
        m.dof_damping[self._dof_adr[1]] = params.yaw_damping
        m.site_pos[m.actuator_trnid[self._act_pitch, 0], 0] = params.r_pitch_rotor_m
        m.site_pos[m.actuator_trnid[self._act_yaw, 0], 0] = -params.r_yaw_rotor_m
        gear = np.zeros((2, 6))
        gear[0, 2] = params.K_pp / params.r_pitch_rotor_m   # thrust N/V along rotor axis
        gear[0, 5] = params.K_yp                            # reaction torque about rotor axis
        gear[1, 1] = -params.K_yy / params.r_yaw_rotor_m    # thrust along -y (yaw +)
        gear[1, 4] = -params.K_py                           # reaction torque, pitch +
        m.actuator_gear[self._act_pitch] = gear[0]
        m.actuator_gear[self._act_yaw] = gear[1]
        mujoco.mj_setConst(m, self.data)
        self.params = params

    # ------------------------------------------------------------------ state
    def get_state(self) -> np.ndarray:
        """True state ``[pitch, yaw, pitch_rate, yaw_rate]``, shape (4,), rad and rad/s."""
        return np.concatenate((self.data.qpos, self.data.qvel))[self._state_gather]

    def set_state(self, x: np.ndarray) -> None:
        """Set the MuJoCo state from ``x`` (shape (4,)) and recompute derived quantities."""
        self.data.qpos[self._qpos_adr] = x[:2]
        self.data.qvel[self._dof_adr] = x[2:]
        mujoco.mj_forward(self.model, self.data)

    def joint_accel_to_force(self, accel: np.ndarray) -> np.ndarray:
        """Generalized forces producing joint accelerations ``accel`` at the current pose.

        Parameters
        ----------
        accel : ndarray, shape (2,)
            ``[pitch_accel, yaw_accel]`` in rad/s^2 (the paper's disturbance units).

        Returns
        -------
        ndarray, shape (nv,)
            ``M(q) a`` in MuJoCo dof order, N m.
        """
        a = np.zeros(self.model.nv)
        a[self._dof_adr] = accel
        mujoco.mj_fullM(self.model, self.data, self._mass_matrix)
        return self._mass_matrix @ a

    @property
    def dof_index(self) -> np.ndarray:
        """MuJoCo dof indices of ``[pitch, yaw]``, shape (2,)."""
        return self._dof_adr

    # ------------------------------------------------------------------ models
    def gravity_voltage(self, pitch_rad: float | np.ndarray) -> np.ndarray:
        """Voltages cancelling gravity at ``pitch_rad`` with this rig's current parameters.

        See :func:`gravity_voltage`; returns shape ``(..., 2)`` in V.
        """
        return gravity_voltage(self.params, pitch_rad)

    def linearize(self, x_op: np.ndarray | None = None, u_op: np.ndarray | None = None,
                  eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time linearization ``(A, B)`` of the MuJoCo rig by central differences.

        ``A = d f / d x`` and ``B = d f / d u`` of ``x' = f(x, u)`` with the accelerations
        from ``mj_forward`` (no integrator involved; joint limits inactive inside the range).

        Parameters
        ----------
        x_op : ndarray, shape (4,), optional
            Operating state; default level pitch at rest.
        u_op : ndarray, shape (2,), optional
            Operating voltages; default :meth:`gravity_voltage` at ``x_op``'s pitch.
        eps : float
            Finite-difference step (rad, rad/s, V).

        Returns
        -------
        A : ndarray, shape (4, 4)
        B : ndarray, shape (4, 2)
        """
        x_op = np.zeros(4) if x_op is None else np.asarray(x_op, float)
        if x_op.shape != (4,) or not np.all(np.isfinite(x_op)):
            raise ValueError(f"x_op must be a finite array of shape (4,), got {x_op!r}")
        u_op = self.gravity_voltage(x_op[0]) if u_op is None else np.asarray(u_op, float)
        if u_op.shape != (2,) or not np.all(np.isfinite(u_op)):
            raise ValueError(f"u_op must be a finite array of shape (2,), got {u_op!r}")
        scratch = mujoco.MjData(self.model)

        def f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            scratch.qpos[self._qpos_adr] = x[:2]
            scratch.qvel[self._dof_adr] = x[2:]
            scratch.ctrl[[self._act_pitch, self._act_yaw]] = u
            mujoco.mj_forward(self.model, scratch)
            return np.concatenate([x[2:], scratch.qacc[self._dof_adr]])

        A = np.zeros((4, 4))
        B = np.zeros((4, 2))
        for i in range(4):
            dx = np.zeros(4)
            dx[i] = eps
            A[:, i] = (f(x_op + dx, u_op) - f(x_op - dx, u_op)) / (2 * eps)
        for j in range(2):
            du = np.zeros(2)
            du[j] = eps
            B[:, j] = (f(x_op, u_op + du) - f(x_op, u_op - du)) / (2 * eps)
        return A, B
