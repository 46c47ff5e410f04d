"""The MuJoCo helicopter against Basin et al.'s linear model and its own physics."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from testbed.rigs.helicopter import (
    PITCH_LIMIT_RAD,
    HelicopterParams,
    HelicopterRig,
    gravity_voltage,
    paper_model,
)


def test_joint_names_axes_and_limits():
    rig = HelicopterRig()
    m = rig.model
    yaw = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "yaw")
    pitch = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "pitch")
    assert yaw >= 0 and pitch >= 0
    assert not m.jnt_limited[yaw]
    assert m.jnt_limited[pitch]
    np.testing.assert_allclose(m.jnt_range[pitch], np.deg2rad([-40.5, 40.5]), atol=1e-6)
    np.testing.assert_allclose(m.jnt_axis[yaw], [0, 0, 1])
    assert m.nu == 2
    assert mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, 0) == "pitch_motor"
    assert mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, 1) == "yaw_motor"
    np.testing.assert_allclose(m.actuator_ctrlrange, [[-24, 24], [-24, 24]])
    assert m.body_mass[rig._body_id] == pytest.approx(1.3872)
    np.testing.assert_allclose(m.body_ipos[rig._body_id], [0.186, 0, 0])


def test_linearization_matches_paper_within_one_percent():
    rig = HelicopterRig()
    A, B = rig.linearize()  # level pitch, gravity compensated by u_op
    pm = paper_model()
    nonzero_A = pm.A != 0
    np.testing.assert_allclose(A[nonzero_A], pm.A[nonzero_A], rtol=0.01)
    np.testing.assert_allclose(A[~nonzero_A], 0.0, atol=1e-6)
    np.testing.assert_allclose(B[2:], pm.B[2:], rtol=0.01)
    np.testing.assert_allclose(B[:2], 0.0, atol=1e-9)


def test_linearization_away_from_level_shows_gravity_and_inertia_change():
    rig = HelicopterRig()
    pitch = np.deg2rad(20.0)
    A, B = rig.linearize(np.array([pitch, 0, 0, 0]))
    p = HelicopterParams()
    # d/dth of -m g l cos(th) / J_p = m g l sin(th) / J_p
    expected = p.mass_kg * 9.81 * p.com_m * np.sin(pitch) / p.pitch_inertia
    assert A[2, 0] == pytest.approx(expected, rel=1e-4)
    # yaw inertia grows as the nose rises (I_xx < I_zz + m l^2 ...): the yaw damping term
    # -B_y / J_y(th) differs from the level value
    assert A[3, 3] != pytest.approx(-3.4955, rel=1e-3)


def test_gravity_voltage_is_close_to_papers_constant_input():
    u = gravity_voltage(HelicopterParams(), 0.0)
    np.testing.assert_allclose(u, [12.495, -3.835], rtol=0.01)
    rig = HelicopterRig()
    rig.set_state(np.zeros(4))
    rig.data.ctrl[:] = u
    mujoco.mj_forward(rig.model, rig.data)
    np.testing.assert_allclose(rig.data.qacc, 0.0, atol=1e-9)


def test_positive_pitch_voltage_raises_the_nose():
    rig = HelicopterRig()
    rig.set_state(np.zeros(4))
    rig.data.ctrl[:] = gravity_voltage(rig.params, 0.0) + np.array([1.0, 0.0])
    mujoco.mj_forward(rig.model, rig.data)
    assert rig.data.qacc[rig.dof_index[0]] > 0
    assert rig.data.qacc[rig.dof_index[1]] > 0  # K_yp > 0: reaction torque turns yaw +


def test_rests_on_the_lower_stop_without_power():
    rig = HelicopterRig()
    rig.set_state(np.array([0.0, 0.0, 0.0, 0.0]))
    mujoco.mj_step(rig.model, rig.data, nstep=5000)
    x = rig.get_state()
    assert x[0] == pytest.approx(-PITCH_LIMIT_RAD, abs=np.deg2rad(1.0))
    assert abs(x[2]) < 1e-3


def test_pendulum_free_response_matches_its_ode():
    """Yaw held still: the pitch obeys J th'' = -B th' - m g l cos(th) + torque (scipy ODE)."""
    from scipy.integrate import solve_ivp

    rig = HelicopterRig(physics_dt_s=0.0005)
    p = rig.params
    u = np.array([12.0, 0.0])
    tau = p.K_pp * u[0] + p.K_py * u[1]

    def rhs(_t, s):
        return [s[1], (tau - p.pitch_damping * s[1] - p.mass_kg * 9.81 * p.com_m
                       * np.cos(s[0])) / p.pitch_inertia]

    x0 = np.array([0.1, 0.0, 0.0, 0.0])
    ref = solve_ivp(rhs, (0, 1.0), [0.1, 0.0], rtol=1e-10, atol=1e-12, t_eval=[1.0])
    rig.set_state(x0)
    rig.model.dof_damping[rig.dof_index[1]] = 1e6  # lock yaw (reaction torque would turn it)
    rig.data.ctrl[:] = u
    mujoco.mj_step(rig.model, rig.data, nstep=2000)
    assert rig.get_state()[0] == pytest.approx(ref.y[0, -1], abs=2e-3)


@pytest.mark.parametrize("bad", [{"mass_kg": -1.0}, {"yaw_damping": 0.0},
                                 {"pitch_inertia": 0.01}])
def test_unphysical_parameters_are_rejected_by_name(bad):
    rig = HelicopterRig()
    before = rig.model.body_mass.copy()
    params = HelicopterParams(**{**HelicopterParams().__dict__, **bad})
    with pytest.raises(ValueError, match=next(iter(bad))):
        rig.set_params(params)
    np.testing.assert_array_equal(rig.model.body_mass, before)


def test_scaled_params_validation():
    with pytest.raises(ValueError, match="unknown params key 'mas'"):
        HelicopterParams().scaled({"mas": 1.1})
    with pytest.raises(ValueError, match="mass_kg"):
        HelicopterParams().scaled({"mass_kg": float("nan")})
    assert HelicopterParams().scaled({"mass_kg": 1.5}).mass_kg == pytest.approx(1.5 * 1.3872)
    with pytest.raises(ValueError, match="pitch_inertia must exceed"):
        HelicopterParams().scaled({"mass_kg": 2.0})  # m l^2 would exceed the inertia


def test_paper_model_corrections():
    pm = paper_model()
    assert pm.B.shape == (4, 2)
    np.testing.assert_array_equal(pm.B[:2], 0.0)
    GGt = pm.G @ pm.G.T
    np.testing.assert_array_equal(GGt[:2], 0.0)  # the printed 1 entries are misprints
    np.testing.assert_allclose(GGt[2:, 2:], [[0.8220, 0.1597], [0.1597, 0.7779]], atol=2e-4)
    np.testing.assert_allclose(pm.H @ pm.G.T, 0.0)  # orthogonality condition C4
