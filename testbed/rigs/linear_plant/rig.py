"""The calibration plant of the scoring harness: a linear-Gaussian rig on which the Kalman
filter is exactly optimal.

One mass on a horizontal slide with a spring and a damper (``linear_plant.xml``), driven by a
force, disturbed by white acceleration noise and measured by a noisy position sensor. MuJoCo's
discrete map of this model is linear, so the design model carries it exactly: ``F``, ``B`` and
the disturbance input are finite differences of the simulator's own control step (not the
ZOH of the continuous model), ``Q`` is the covariance of the held acceleration noise the
simulator draws, and the prior is the distribution the harness draws the initial state from.
The Kalman filter on this design is then the minimum-variance estimator of what is simulated:
its ANEES must lie within the chi-square bounds, which is how the harness checks itself.

State ``x = [position, velocity]`` (m, m/s); input ``u = [force]`` (N).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from filters import DiscreteLinearSystem
from testbed.records import field_items
from testbed.rigs.base import Params, Rig

#: White acceleration noise input ``b`` (velocity row), m/s^2 per sqrt(Hz) at process_noise 1.
NOISE_INPUT = np.array([[0.0], [0.5]])
#: Position sensor noise, m per sample.
POSITION_NOISE_STD_M = 0.01
#: Prior standard deviations of position and velocity (m, m/s).
PRIOR_STD = (0.05, 0.05)


@dataclass(frozen=True)
class LinearPlantParams(Params):
    """Mass, spring and damper of the calibration plant (SI units).

    The defaults give a lightly damped mode at 0.5 Hz (damping ratio 0.05).

    Attributes
    ----------
    mass_kg : float
    stiffness_n_m : float
        Spring constant, N/m.
    damping_n_s_m : float
        Viscous damping, N s/m.
    """

    mass_kg: float = 1.0
    stiffness_n_m: float = float((2 * np.pi * 0.5) ** 2)
    damping_n_s_m: float = float(2 * 0.05 * 2 * np.pi * 0.5)

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first unphysical parameter."""
        for f, value in field_items(self):
            if not np.isfinite(value) or value < 0 or (f.name == "mass_kg" and value == 0):
                raise ValueError(f"LinearPlantParams.{f.name} must be finite and "
                                 f"{'positive' if f.name == 'mass_kg' else 'non-negative'}, "
                                 f"got {value}")


class LinearPlantRig(Rig):
    """Mass-spring-damper on a slide: the linear-Gaussian calibration plant.

    Sensors: preset ``"position"`` (position plus white noise ``noise_std_m``, default
    :data:`POSITION_NOISE_STD_M`). Process noise: ``b`` = :data:`NOISE_INPUT` times the
    scenario's ``process_noise``. Design model: the exact discrete map of the simulator (see
    the module docstring).
    """

    name = "linear-plant"
    xml_path = "models/linear_plant.xml"
    params_type = LinearPlantParams
    joints = ("position",)
    state_names = ("position", "velocity")
    state_units = ("m", "m/s")
    action_names = ("force",)
    action_units = ("N",)
    action_low = (-100.0,)
    action_high = (100.0,)
    tracked_states = ("position",)
    scenario_defaults = {"controller": "open-loop"}

    def apply_params(self, model: mujoco.MjModel, params: LinearPlantParams) -> None:
        """Mass, spring and damper from ``params``."""
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "cart")
        joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "position")
        model.body_mass[body] = params.mass_kg
        model.jnt_stiffness[joint] = params.stiffness_n_m
        model.qpos_spring[self.qpos_adr[0]] = 0.0
        model.dof_damping[self.dof_adr[0]] = params.damping_n_s_m

    def process_noise_matrix(self) -> np.ndarray:
        """:data:`NOISE_INPUT` (2, 1)."""
        return NOISE_INPUT.copy()

    def sensors(self, preset: str | None = "position", *, dt_s: float = 0.01,
                noise_std_m: float = POSITION_NOISE_STD_M):
        """``position``: the position with white noise of ``noise_std_m`` per sample."""
        from testbed.sensors import StateChannel, WhiteNoise

        preset = preset or "position"
        if preset != "position":
            raise ValueError(f"unknown linear-plant sensor preset {preset!r}; expected "
                             "'position'")
        if not (np.isfinite(noise_std_m) and noise_std_m > 0):
            raise ValueError(f"noise_std_m must be positive and finite, got {noise_std_m}")
        return WhiteNoise(StateChannel(0, 2, 1, "position", "m"), std=noise_std_m)

    def discrete_map(self, dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The simulator's control step as ``x+ = F x + B u + E a`` (exact for this plant).

        ``a`` is a joint acceleration held over the period (applied as the generalized force
        ``M a``, as the simulator applies disturbances). Finite differences of ``mj_step``
        with unit steps; the map is linear, so they are exact to rounding.

        Parameters
        ----------
        dt_s : float
            Control period, a whole number of physics steps.

        Returns
        -------
        F : ndarray, shape (2, 2)
        B : ndarray, shape (2, 1)
        E : ndarray, shape (2, 1)
        """
        model = self.model
        frame_skip = int(round(dt_s / model.opt.timestep))
        if frame_skip < 1 or not np.isclose(frame_skip * model.opt.timestep, dt_s):
            raise ValueError(f"dt_s must be a whole number of physics steps "
                             f"({model.opt.timestep} s), got {dt_s}")
        data = mujoco.MjData(model)
        mass = np.zeros((model.nv, model.nv))

        def step(x: np.ndarray, u: float, a: float) -> np.ndarray:
            mujoco.mj_resetData(model, data)
            self.set_state(x, data)
            mujoco.mj_fullM(model, data, mass)
            data.ctrl[:] = u
            data.qfrc_applied[:] = mass @ np.full(model.nv, a)
            mujoco.mj_step(model, data, frame_skip)
            return self.get_state(data)

        zero = step(np.zeros(2), 0.0, 0.0)
        F = np.column_stack([step(e, 0.0, 0.0) - zero for e in np.eye(2)])
        B = (step(np.zeros(2), 1.0, 0.0) - zero)[:, None]
        E = (step(np.zeros(2), 0.0, 1.0) - zero)[:, None]
        return F, B, E

    @classmethod
    def cubic_model(cls, design):
        """The exact third-order expansion of a linear plant: ``a0 = 0``, ``a1 = A``,
        ``E = B`` and no quadratic or cubic terms.

        With ``a2 = a3 = 0`` Basin et al.'s central polynomial filter (Theorem 1) is the
        central H-infinity filter of the linear system, so ``poly-hinf`` applies here too.

        Parameters
        ----------
        design : testbed.design.DesignModel

        Returns
        -------
        testbed.design.cubic.CubicExpansion
        """
        from testbed.design.cubic import CubicExpansion

        plant = design.continuous
        return CubicExpansion(a0=np.zeros(plant.A.shape[0]), a1=np.array(plant.A),
                              a2=None, a3=None, E=np.array(plant.B),
                              description="linear plant: the expansion is exact (no "
                                          "quadratic or cubic terms)")

    def design_model(self, sensors, dt_s: float, disturbance=None):
        """The exact discrete model of the simulated plant, its noise and the harness prior.

        ``discrete``: :meth:`discrete_map`, ``Q = E (b_v b_v^T / dt_s) E^T`` (the simulator
        holds ``a = b_v xi / sqrt(dt_s)`` over the period), ``R`` of the sensors.
        ``continuous``: MuJoCo's linearization with intensity ``b b^T``. Prior ``0``,
        ``diag(PRIOR_STD)^2``; the truth is drawn from it when the harness asks
        (``x0_from_prior``).
        """
        from testbed.design import build_design
        from testbed.design.held_noise import held_noise_covariance

        A, B = self.linearize()
        b = None if disturbance is None else disturbance.b
        Q = np.zeros((2, 2)) if b is None else b @ b.T
        G = None if disturbance is None else disturbance.G
        design = build_design(self, sensors, dt_s, A, B, Q, np.zeros(2),
                              np.diag(np.square(PRIOR_STD)), disturbance_matrix=G)
        F, Bd, E = self.discrete_map(dt_s)
        Qd = np.zeros((2, 2)) if b is None else held_noise_covariance(E, Q, 1, dt_s)
        plant = design.discrete
        design.discrete = DiscreteLinearSystem(F=F, B=Bd, H=plant.H, Q=Qd,
                                               R=plant.R, dt_s=dt_s, D=plant.D)
        design.extras["exact_discrete"] = True
        return design
