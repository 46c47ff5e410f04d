"""The 2-DOF helicopter's physical parameters and the gravity-compensating voltage."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from testbed.records import field_items
from testbed.rigs.base import GRAVITY_M_S2, Params

PITCH_LIMIT_RAD = float(np.deg2rad(40.5))


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
        for f, value in field_items(self):
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
    return torque[..., None] * volts_per_pitch_newton_metre(params)


@functools.lru_cache(maxsize=32)
def volts_per_pitch_newton_metre(params: HelicopterParams) -> np.ndarray:
    """Voltages giving 1 N m of pitch torque and no yaw torque, shape (2,), read-only."""
    volts = np.linalg.solve(params.torque_gains, np.array([1.0, 0.0]))
    volts.flags.writeable = False
    return volts
