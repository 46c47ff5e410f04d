"""The nonlinear design model (:mod:`testbed.estimators.nonlinear`) and the ``ekf``/``ukf``
filters."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from testbed.estimators.nonlinear import (
    AbsoluteInput,
    MeasurementModel,
    MujocoProcessModel,
    nonlinear_models,
)
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs.helicopter.imu import HelicopterIMU
from testbed.rigs.helicopter.rig import HelicopterParams, HelicopterRig, gravity_voltage
from testbed.rigs.linear_plant.rig import LinearPlantRig
from testbed.rigs.vehicle_roll.rig import VehicleRollRig
from testbed.rigs.vehicle_roll.sensors import LateralAccelerometer
from testbed.sensors import Sample


def central_differences(f, x: np.ndarray, u: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """``df/dx`` of a batched ``f`` at each row of ``x`` (M, n): (M, d, n)."""
    n = x.shape[1]
    columns = []
    for i in range(n):
        dx = np.zeros(n)
        dx[i] = eps
        columns.append((f(x + dx, u) - f(x - dx, u)) / (2 * eps))
    return np.stack(columns, axis=-1)


@pytest.mark.parametrize(("rig_type", "x", "u"), [
    (HelicopterRig, [[-0.3, 0.1, 0.5, -0.2], [0.2, -1.0, -0.4, 0.8], [0.0, 0.0, 0.0, 0.0]],
     [[12.0, -3.0], [14.0, 2.0], [12.5, -3.8]]),
    (VehicleRollRig, [[0.05, -0.1], [-0.02, 0.3]], [[2.0], [-4.0]]),
    (LinearPlantRig, [[0.1, -0.2], [0.0, 1.0]], [[3.0], [-1.0]]),
])
@pytest.mark.parametrize("centered", [True, False])
def test_jacobian_equals_central_differences_of_f(rig_type, x, u, centered):
    rig = rig_type()
    process = MujocoProcessModel(rig, 0.01, centered=centered)
    x, u = np.array(x, float), np.array(u, float)
    J = process.jacobian(x, u)
    fx = process(x, u)  # from the cache of jacobian()
    cache = process._cache
    process._cache = None
    np.testing.assert_array_equal(fx, process(x, u))  # rollout = the mjd trajectory, bitwise
    assert cache is not None
    J_fd = central_differences(process, x, u)
    tol = 1e-6 if centered else 1e-5  # forward differences: first order in eps
    np.testing.assert_allclose(J, J_fd, rtol=0, atol=tol * max(1.0, np.abs(J_fd).max()))
    assert J.shape == (len(x), rig.n_states, rig.n_states)


def test_f_is_the_rig_stepped_over_one_control_period():
    rig = HelicopterRig()
    process = MujocoProcessModel(rig, 0.01)
    assert process.frame_skip == 10
    x, u = np.array([0.2, 0.5, -0.3, 0.4]), np.array([13.0, -1.0])
    data = mujoco.MjData(rig.model)
    rig.set_state(x, data)
    data.ctrl[:] = u
    mujoco.mj_step(rig.model, data, 10)
    np.testing.assert_array_equal(process(x[None], u[None])[0], rig.get_state(data))
    # vehicle roll: the input is the d'Alembert force in xfrc_applied
    vr = VehicleRollRig()
    vp = MujocoProcessModel(vr, 0.02)
    data = mujoco.MjData(vr.model)
    vr.set_state(np.array([0.01, 0.02]), data)
    data.xfrc_applied[:] = vr.actuation(np.array([[3.0]]), vr.member_constants(vr.params)[None])[
        "xfrc"][0]
    mujoco.mj_step(vr.model, data, 20)
    np.testing.assert_array_equal(vp(np.array([[0.01, 0.02]]), np.array([[3.0]]))[0],
                                  vr.get_state(data))


def test_process_model_refuses_a_period_that_is_not_whole_physics_steps():
    with pytest.raises(ValueError, match="whole number"):
        MujocoProcessModel(HelicopterRig(), 0.0105)
    with pytest.raises(ValueError, match="nq = nv"):
        MujocoProcessModel(HelicopterRig(profile="hardware"), 0.01)  # motor lag: na = 2


def _design(rig, profile="paper", **kw):
    experiment = runner.build(Scenario(rig=rig, profile=profile, duration_s=0.1, **kw), 1,
                              num_threads=1)
    experiment.close()
    return experiment.design


def test_helicopter_imu_channels_are_nonlinear_and_match_the_sensor():
    design = _design("helicopter", "hardware", design_profile="paper")  # the rig's states
    _, _, measure = nonlinear_models(design)
    assert measure.nonlinear == ("gyro_yaw", "accel_x")
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.6, 0.6, (6, 4))
    u = rng.uniform(-5, 5, (6, 2))
    y = measure(x, u)
    imu = HelicopterIMU().measure(Sample(x, np.zeros(6), u, np.zeros((6, 0)), np.arange(6)),
                                  None)
    cols = [measure.names.index(c) for c in HelicopterIMU.names]
    np.testing.assert_allclose(y[:, cols], imu, rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(measure.jacobian(x, u), central_differences(measure, x, u),
                               atol=1e-8)


def test_vehicle_lateral_accelerometer_is_nonlinear_with_its_feedthrough():
    design = _design("vehicle-roll")
    _, _, measure = nonlinear_models(design)
    assert "lateral_accel" in measure.nonlinear
    x = np.array([[0.1, 0.2], [-0.3, 0.0]])
    u = np.array([[2.0], [-1.0]])
    row = measure.names.index("lateral_accel")
    sample = Sample(x, np.zeros(2), u, np.zeros((2, 0)), np.arange(2))
    np.testing.assert_allclose(measure(x, u)[:, row],
                               LateralAccelerometer().measure(sample, None)[:, 0], rtol=1e-15)
    np.testing.assert_allclose(measure.jacobian(x, u), central_differences(measure, x, u),
                               atol=1e-8)


def test_linear_channels_are_the_design_rows():
    design = _design("helicopter")  # encoders: linear
    measure = MeasurementModel(design, "helicopter")
    assert measure.nonlinear == ()
    x = np.random.default_rng(1).standard_normal((3, 4))
    np.testing.assert_array_equal(measure(x, np.zeros((3, 2))), x @ design.discrete.H.T)


def test_absolute_input_adds_the_operating_input_at_the_estimate_before_the_step():
    seen = []

    class Inner:
        x = np.array([[0.3, 0.0, 0.0, 0.0]])

        def step(self, y, u):
            seen.append(u)
            return self.x

    nominal = HelicopterParams()
    est = AbsoluteInput(Inner(), lambda x: gravity_voltage(nominal, x[:, 0]), 2)
    transform = _design("helicopter").input_transform
    u_applied = np.array([[14.0, -2.0]])
    est.step(np.zeros((1, 2)), transform(u_applied, Inner.x))
    np.testing.assert_allclose(seen[0], u_applied, rtol=1e-14)


def test_the_design_state_must_be_the_rigs():
    import dataclasses

    design = dataclasses.replace(_design("helicopter"),
                                 state_names=("pitch", "yaw", "pitch_rate", "yaw_rate", "b"))
    with pytest.raises(ValueError, match="state"):
        nonlinear_models(design)


# ------------------------------------------------------------------------ in the runner
def test_on_the_calibration_plant_ekf_and_ukf_match_kalman_and_are_consistent():
    rmse, nees = {}, {}
    for name in ("kalman", "ekf", "ukf"):
        sc = Scenario(rig=LinearPlantRig, estimator=name, process_noise=1.0, duration_s=20.0,
                      seed=3)
        _, summary = runner.run(sc, record=False, progress=False)
        rmse[name] = np.array(list(summary["rmse"].values()))
        nees[name] = summary["nees_mean"]
    for name in ("ekf", "ukf"):
        # within 2 % asked; the MuJoCo map of this plant is linear, so they agree to rounding
        np.testing.assert_allclose(rmse[name], rmse["kalman"], rtol=1e-6)
        assert 1.0 <= nees[name] <= 4.0  # n = 2: within a factor 2


@pytest.mark.parametrize("rig", ["helicopter", "vehicle-roll"])
@pytest.mark.parametrize("profile", ["paper", "hardware"])
@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_ekf_and_ukf_run_on_every_rig_and_profile(rig, profile, name):
    sc = Scenario(rig=rig, profile=profile, estimator=name, duration_s=1.0, seed=0)
    _, summary = runner.run(sc, record=False, progress=False)
    assert np.isfinite(summary["nees_mean"])
    assert all(np.isfinite(v) for v in summary["rmse"].values())


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_cli_runs_the_helicopter(name, capsys):
    from testbed.cli import main

    assert main(["run", "helicopter", "--filter", name, "--duration", "2", "--seed", "0"]) == 0
    assert "pitch" in capsys.readouterr().out


def test_a_batch_of_runs_equals_the_single_runs():
    """``mc`` steps one batched filter; member i equals its single run (bitwise)."""
    sc = Scenario(rig="helicopter", estimator="ukf", duration_s=0.3, seed=0)
    result = runner.monte_carlo(sc, runs=2, progress=False)
    for i, seed in enumerate(result["seeds"]):
        _, single = runner.run(sc.replace(seed=int(seed)), record=False, progress=False)
        for k, v in single["rmse"].items():
            assert result["rmse_per_run"][k][i] == v


@pytest.mark.parametrize("name", ["ekf", "ukf"])
def test_from_design_in_a_gymnasium_loop_equals_the_runner(name):
    from testbed.envs import RigEnv
    from testbed.envs.wrappers import FilterInLoop

    env = RigEnv("vehicle-roll", manoeuvre="double-lane-change")  # the runner's default
    wrapped = FilterInLoop.from_design(env, name)
    wrapped.reset(seed=4)
    estimates = [wrapped.step(np.zeros(env.action_space.shape))[0] for _ in range(20)]
    traj, _ = runner.run(Scenario(rig="vehicle-roll", estimator=name, duration_s=0.2, seed=4),
                         progress=False)
    np.testing.assert_array_equal(np.array(estimates), traj.estimate[1:])
