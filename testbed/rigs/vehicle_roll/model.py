"""Vehicle roll rig: MJCF model, physical parameters, Zhang et al.'s model and the physical one.

The rig owns ``models/vehicle_roll.xml``: the sprung mass of a light commercial vehicle
rolling about its roll axis (Zhang et al. Example 5.2, eq. (51), Table 1). It provides the
parameters (:class:`VehicleRollParams`), the discrete model printed in the paper
(:func:`paper_model`, verbatim), the physical continuous-time linearization
(:func:`physical_model`, analytic, and :meth:`VehicleRollRig.linearize`, by finite
differences of MuJoCo) so the two can be compared.

State convention: ``x = [roll, roll_rate]`` in rad and rad/s (the paper's ``eta`` and
``Delta eta``); positive roll lowers the right side (ISO 8855: x forward, y left, z up).
Input: lateral acceleration ``a_y`` of the vehicle in m/s^2, positive to the left (a left
turn), which rolls the body positively (outwards).

Physics of the MuJoCo rig (nonlinear)::

    I_xx eta'' + (C_R + D_n w_k) eta' + K_R eta = m_s h_cr a_y cos(eta) + m_s g h_cr sin(eta)

This is eq. (51) except for ``cos(eta)``: ``a_y`` is applied as the d'Alembert force
``-m_s a_y`` (world y) at the centre of mass, whose lever arm about the roll axis is
``h_cr cos(eta)``. The difference is ``m_s h_cr a_y (1 - cos eta) ~ m_s h_cr a_y eta^2 / 2``:
0.2 % of the input torque at 4 deg of roll (about the largest roll at the +-8 m/s^2 limit),
below 2e-4 rad of roll angle. A base accelerated laterally through a slide joint gives the
same ``cos(eta)`` (the rig and eq. (51) differ only there). ``w_k`` is standard white noise
drawn once per control step (the joint damping is ``C_R + D_n w_k`` for that step).

Paper model vs physics
----------------------
Zhang et al.'s (52) is the forward-Euler discretization (``T = 0.01`` s) of (51) with two
departures from it (docs/references.md):

- its ``A[1, 0] = (m_s h_cr - K_R) T / I_xx`` lacks ``g`` in the gravity term: the
  destabilizing stiffness is ``m_s h_cr = 425`` (kg m, printed as if N m/rad) instead of
  ``m_s g h_cr = 4169.25 N m/rad``. Net roll stiffness: paper ``54889``, physics
  ``51144.75 N m/rad`` (7 % softer); ``A[1, 0]``: paper ``-0.32288``, Euler-discretized
  physics ``-0.30085``, continuous physics ``-30.085 1/s^2``.
- ``a_y`` does not appear; the disturbance ``v_k`` enters through the printed ``B``, ``L``.

``K_R`` is printed with the unit "N ms/rad"; it is a stiffness (N m/rad).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.records import field_items
from testbed.rigs.base import GRAVITY_M_S2, Params

STATE_NAMES = ("roll", "roll_rate")
ACTION_NAMES = ("a_y",)
#: Lateral-acceleration limit of the action, m/s^2 (about 0.8 g: tyre friction).
A_Y_LIMIT_M_S2 = 8.0
#: Sampling period of Zhang et al.'s discrete model (52), s.
PAPER_PERIOD_S = 0.01


@dataclass(frozen=True)
class VehicleRollParams(Params):
    """Physical parameters of the roll model (Zhang et al. Table 1, SI units).

    Attributes
    ----------
    sprung_mass_kg : float
        Sprung mass ``m_s``.
    com_height_m : float
        Height ``h_cr`` of the sprung mass's centre of mass above the roll axis.
    roll_inertia : float
        Inertia ``I_xx`` of the sprung mass about the ROLL AXIS, kg m^2 (includes
        ``m_s h_cr^2``; the inertia about the centre of mass is ``I_xx - m_s h_cr^2``).
    roll_stiffness : float
        Torsional stiffness ``K_R``, N m/rad (printed "N ms/rad" in the paper).
    roll_damping : float
        Torsional damping ``C_R``, N m s/rad.
    damping_noise : float
        ``D_n``: the damping is ``C_R + D_n w_k`` with ``w_k ~ N(0, 1)`` per control step,
        N m s/rad.
    """

    sprung_mass_kg: float = 1700.0
    com_height_m: float = 0.25
    roll_inertia: float = 1700.0
    roll_stiffness: float = 55314.0
    roll_damping: float = 53071.0
    damping_noise: float = 20.0

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first unphysical parameter."""
        for f, value in field_items(self):
            if not np.isfinite(value):
                raise ValueError(f"VehicleRollParams.{f.name} must be finite, got {value}")
            strict = f.name in ("sprung_mass_kg", "com_height_m", "roll_inertia")
            if value < 0 or (strict and value == 0):
                kind = "positive" if strict else "non-negative"
                raise ValueError(f"VehicleRollParams.{f.name} must be {kind}, got {value}")
        ml2 = self.sprung_mass_kg * self.com_height_m**2
        if self.roll_inertia <= ml2:
            raise ValueError("VehicleRollParams.roll_inertia (about the roll axis) must exceed "
                             f"sprung_mass_kg * com_height_m**2 = {ml2}, got {self.roll_inertia}")

    @property
    def inertia_com(self) -> float:
        """Roll inertia about the centre of mass, ``I_xx - m_s h_cr^2``, kg m^2."""
        return self.roll_inertia - self.sprung_mass_kg * self.com_height_m**2

    @property
    def gravity_stiffness(self) -> float:
        """Destabilizing stiffness ``m_s g h_cr`` of the gravity torque at ``eta = 0``, N m/rad."""
        return self.sprung_mass_kg * GRAVITY_M_S2 * self.com_height_m


@dataclass(frozen=True)
class PaperModel:
    """Zhang et al.'s discrete vehicle-roll model (52).

    The model::

        x_{k+1} = A x_k + C x_k w_k + B v_k
        y_k     = H x_k + L v_k
        z_k     = M x_k

    Attributes
    ----------
    A : ndarray, shape (2, 2)
        ``[[1, T], [(m_s h_cr - K_R) T / I_xx, 1 - C_R T / I_xx]]`` (no ``g``: see module).
    C : ndarray, shape (2, 2)
        Multiplicative-noise matrix ``[[0, 0], [0, -D_n T / I_xx]]`` (not an output matrix).
    B : ndarray, shape (2, 1)
        Disturbance input ``[-0.7916, 0.3652]^T``.
    H : ndarray, shape (2, 2)
        Measurement matrix ``[[0.4048, 0.6405], [1.1213, 1.4616]]``.
    L : ndarray, shape (2, 1)
        Measurement disturbance input ``[0.8248, -1.3774]^T``.
    M : ndarray, shape (1, 2)
        Regulated output ``[1, 0]`` (the roll angle).
    T : float
        Sampling period, s (0.01).
    params : VehicleRollParams
        The Table 1 values used in ``A`` and ``C``.
    """

    A: np.ndarray
    C: np.ndarray
    B: np.ndarray
    H: np.ndarray
    L: np.ndarray
    M: np.ndarray
    T: float
    params: VehicleRollParams


def paper_model(params: VehicleRollParams | None = None) -> PaperModel:
    """The discrete model (52) of Zhang et al. Example 5.2, as printed.

    ``A`` and ``C`` are evaluated from Table 1 (``params``, default the nominal values) with
    the printed formulas, including the missing ``g``; ``B``, ``H``, ``L``, ``M`` are the
    printed numbers.

    Returns
    -------
    PaperModel
        ``A = [[1, 0.01], [-0.322876..., 0.687818...]]``,
        ``C = [[0, 0], [0, -1.17647e-4]]``, ``T = 0.01``.
    """
    p = params or VehicleRollParams()
    T = PAPER_PERIOD_S
    A = np.array([[1.0, T],
                  [(p.sprung_mass_kg * p.com_height_m - p.roll_stiffness) * T / p.roll_inertia,
                   1.0 - p.roll_damping * T / p.roll_inertia]])
    C = np.array([[0.0, 0.0], [0.0, -p.damping_noise * T / p.roll_inertia]])
    H = np.array([[0.4048, 0.6405], [1.1213, 1.4616]])
    B = np.array([[-0.7916], [0.3652]])
    L = np.array([[0.8248], [-1.3774]])
    M = np.array([[1.0, 0.0]])
    return PaperModel(A=A, C=C, B=B, H=H, L=L, M=M, T=T, params=p)


def paper_disturbance(k: int | np.ndarray) -> float | np.ndarray:
    """Zhang et al.'s disturbance ``v_k = 0.01 * 0.9^k`` at step ``k`` (dimensionless)."""
    return 0.01 * 0.9 ** np.asarray(k, dtype=float)


def physical_model(params: VehicleRollParams | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time linearization of the physics about ``eta = 0`` (analytic, with ``g``).

    ``x' = A x + B a_y`` with ``x = [roll, roll_rate]``::

        A = [[0, 1], [(m_s g h_cr - K_R) / I_xx, -C_R / I_xx]],   B = [[0], [m_s h_cr / I_xx]]

    Returns
    -------
    A : ndarray, shape (2, 2)
        1/s and 1/s^2; nominal ``[[0, 1], [-30.0851, -31.2182]]``.
    B : ndarray, shape (2, 1)
        rad s^-2 per m/s^2; nominal ``[[0], [0.25]]``.
    """
    p = params or VehicleRollParams()
    A = np.array([[0.0, 1.0],
                  [(p.gravity_stiffness - p.roll_stiffness) / p.roll_inertia,
                   -p.roll_damping / p.roll_inertia]])
    B = np.array([[0.0], [p.sprung_mass_kg * p.com_height_m / p.roll_inertia]])
    return A, B
