"""The control-period Jacobian from one-physics-step derivatives
(:mod:`testbed.estimators.jacobians`) against MuJoCo's own derivatives and the whole-period
finite differences, and the EKF on it against the EKF on the old method."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from testbed.estimators.jacobians import linearization_steps, step_derivatives
from testbed.estimators.nonlinear import MujocoProcessModel, nonlinear_models
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs.helicopter.rig import HelicopterRig
from testbed.rigs.linear_plant.rig import LinearPlantRig

X_HELI = np.array([[-0.3, 0.1, 0.5, -0.2], [0.2, -1.0, -0.4, 0.8], [0.0, 0.0, 0.0, 0.0]])
U_HELI = np.array([[12.0, -3.0], [14.0, 2.0], [12.5, -3.8]])


def _relative_error(J: np.ndarray, J_ref: np.ndarray) -> float:
    """Largest ``||J - J_ref|| / ||J_ref - I||`` over the rows (Frobenius): the error
    relative to what the period changes."""
    eye = np.eye(J.shape[-1])
    return float(np.max(np.linalg.norm(J - J_ref, axis=(1, 2))
                        / np.linalg.norm(J_ref - eye, axis=(1, 2))))


def test_linearization_steps_are_the_segments_midpoints():
    # step s stands for the interval [s, s + 1]: its midpoint s + 1/2 is the segment's
    assert linearization_steps(10, 1).tolist() == [4]
    assert linearization_steps(10, 2).tolist() == [2, 7]
    assert linearization_steps(10, 10).tolist() == list(range(10))
    assert linearization_steps(9, 3).tolist() == [1, 4, 7]
    assert linearization_steps(10, 2.0).tolist() == [2, 7]  # the CLI's numbers are floats
    for bad in (0, 11, 1.5, True, "2"):
        with pytest.raises(ValueError, match="jacobian_points"):
            linearization_steps(10, bad)
    with pytest.raises(ValueError, match="jacobian_points"):
        MujocoProcessModel(HelicopterRig(), 0.01, jacobian_points=0)


@pytest.mark.parametrize("centered", [False, True])
def test_step_derivatives_are_mujocos_transition_derivatives(centered):
    """``A`` of one physics step (one batched rollout) equals :func:`mujoco.mjd_transitionFD`
    at the same states (its tangent rows of the rig's joints), within the rounding of the
    differences."""
    rig = HelicopterRig()
    process = MujocoProcessModel(rig, 0.01, centered=centered)
    model = process.model
    states = np.tile(process._template, (len(X_HELI), 1))
    states[:, process._gather] = X_HELI
    A, B = step_derivatives(process, states, U_HELI)
    assert A.shape == (3, 4, 4) and B.shape == (3, 4, 2)
    data = mujoco.MjData(model)
    ref = np.zeros((2 * model.nv, 2 * model.nv))
    rows = process._tangent
    for i, (x, u) in enumerate(zip(X_HELI, U_HELI, strict=True)):
        mujoco.mj_resetData(model, data)
        data.qpos[rig.qpos_adr], data.qvel[rig.dof_adr] = x[:2], x[2:]
        data.ctrl[:] = process.controls(u[None])["ctrl"][0]
        mujoco.mjd_transitionFD(model, data, process.eps, centered, ref, None, None, None)
        tol = 1e-8 if centered else 1e-6
        np.testing.assert_allclose(A[i], ref[np.ix_(rows, rows)], rtol=0, atol=tol)
    # B against differences of the period map of one physics step in the input
    one = MujocoProcessModel(rig, float(model.opt.timestep), jacobian="rollout")
    for j in range(2):
        du = np.zeros(2)
        du[j] = 1e-4
        col = (one(X_HELI, U_HELI + du) - one(X_HELI, U_HELI - du)) / 2e-4
        np.testing.assert_allclose(B[:, :, j], col, rtol=0, atol=1e-8)


def test_held_linearization_error_on_the_helicopter():
    """``jacobian_points = 1`` (the default: one linearization per period) against the
    whole-period central differences: measured 8.2e-4 of ``||J - I||`` on these rows (fast
    rates, pitch off level); two points 1.4e-5 (second order: the segments' midpoints); all
    ten the exact product (1e-8)."""
    rig = HelicopterRig()
    J_ref = MujocoProcessModel(rig, 0.01, jacobian="rollout", centered=True).jacobian(
        X_HELI, U_HELI)
    errors = {}
    for points in (1, 2, 10):
        process = MujocoProcessModel(rig, 0.01, jacobian_points=points, centered=True)
        J = process.jacobian(X_HELI, U_HELI)
        errors[points] = _relative_error(J, J_ref)
        # f is the rollout's, bitwise, whatever the Jacobian
        np.testing.assert_array_equal(process(X_HELI, U_HELI), process.rollout(X_HELI, U_HELI))
    assert errors[1] <= 2e-3
    assert errors[2] <= 0.05 * errors[1]
    assert errors[10] <= 1e-7


def test_on_a_linear_plant_one_linearization_is_exact():
    """The calibration plant's MuJoCo map is linear: ``A^N`` is its period map for any
    number of points (to the rounding of the differences)."""
    rig = LinearPlantRig()
    x = np.array([[0.1, -0.2], [0.0, 1.0]])
    u = np.array([[3.0], [-1.0]])
    J_ref = MujocoProcessModel(rig, 0.01, jacobian="rollout", centered=True).jacobian(x, u)
    J = MujocoProcessModel(rig, 0.01).jacobian(x, u)
    np.testing.assert_allclose(J, J_ref, rtol=0, atol=1e-9)


def test_hardware_design_jacobian_close_to_the_whole_period_differences():
    """The matched hardware helicopter design (rotor lags, biases, delays): the default
    against the whole-period central differences, measured 5.2e-5 of ``||J - I||``."""
    from testbed.rigs.helicopter.rig import HelicopterRig as Rig

    rig = Rig(profile="hardware")
    design = rig.design_model(rig.sensors(dt_s=0.01), 0.01)
    rng = np.random.default_rng(7)
    x = np.array(design.x0, float) + 0.05 * rng.standard_normal((3, design.n))
    x[:, 0] = [-0.3, 0.1, 0.4]
    u = rng.uniform(-3, 3, (3, len(design.input_names)))
    u[:, 2] = 0.0
    _, ref, _ = nonlinear_models(design, jacobian="rollout", centered=True)
    _, new, _ = nonlinear_models(design)
    assert _relative_error(new.jacobian(x, u), ref.jacobian(x, u)) <= 2e-4


def test_ekf_on_the_step_jacobian_follows_the_old_path():
    """4 hardware helicopter runs x 2 s (seed 0): the default Jacobian and the whole-period
    differences (``jacobian="rollout"``) give the same mean RMSE within 3 % and NEES within
    3 % (measured 1.1 % and 0.05 %; the lift-off from the stop, the least smooth part of the
    period map, is where they differ most: 2-3 % over the first second; over 32 runs x 10 s
    0.5 %, docs/performance.md)."""
    base = Scenario(rig="helicopter", profile="hardware", estimator="ekf", duration_s=2.0,
                    seed=0)
    new = runner.monte_carlo(base, 4, progress=False)
    old = runner.monte_carlo(base.replace(estimator_options={"jacobian": "rollout"}), 4,
                             progress=False)
    for k, v in old["rmse"].items():
        assert new["rmse"][k]["mean"] == pytest.approx(v["mean"], rel=3e-2)
    assert new["nees_mean"] == pytest.approx(old["nees_mean"], rel=3e-2)
    assert new["rmse_per_run"] != old["rmse_per_run"]  # a different Jacobian ran


def test_powers_by_doubling_are_the_matrix_powers():
    from testbed.estimators.jacobians import _powers

    A = np.random.default_rng(3).normal(0, 0.5, (4, 3, 3))
    for count in (1, 2, 3, 7, 10):
        P = _powers(A, count)
        for k in range(count):
            np.testing.assert_allclose(P[:, k], np.linalg.matrix_power(A, k), rtol=1e-12,
                                       atol=1e-12)


@pytest.mark.parametrize(("rig", "options"), [
    ("helicopter", {}), ("vehicle-roll", {"a_y_source": "measured"}),
    ("vehicle-roll", {"a_y_source": "oracle"}), ("aero", {})])
def test_every_matched_design_every_step_linearized_is_the_period_differences(rig, options):
    """The chain rule through the inputs (operating input, actuator and bias states, input
    memory, nonlinear delay rows) with a linearization at every physics step equals the
    whole-period central differences, on each rig's matched hardware design."""
    experiment = runner.build(Scenario(rig=rig, profile="hardware", duration_s=0.1,
                                       design_options=options), 1, num_threads=1)
    experiment.close()
    design = experiment.design
    rng = np.random.default_rng(5)
    x = np.array(design.x0, float) + 0.02 * rng.standard_normal((3, design.n))
    u = 0.5 * rng.standard_normal((3, len(design.input_names)))
    _, ref, _ = nonlinear_models(design, jacobian="rollout", centered=True)
    _, new, _ = nonlinear_models(design, jacobian_points=new_points(design))
    J_ref, J = ref.jacobian(x, u), new.jacobian(x, u)
    np.testing.assert_allclose(J, J_ref, rtol=0, atol=2e-6 * max(1.0, np.abs(J_ref).max()))
    np.testing.assert_array_equal(new(x, u), ref(x, u))  # the same f, bitwise


def new_points(design) -> int:
    """Every physics step of the design's control period."""
    from testbed.estimators.nonlinear import nominal_rig

    return int(round(design.dt_s / float(nominal_rig(design).model.opt.timestep)))
