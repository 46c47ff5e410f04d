"""The vehicle estimator's input a_y: measured speed x yaw rate by default, or the oracle."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.cli import main
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs.vehicle_roll.sensors import (
    GYRO_NOISE_DENSITY,
    SPEED_M_S,
    SpeedYawRate,
    find_tap,
    imu,
    measured_a_y_variance,
)
from testbed.sensors import Sample


def test_speed_yaw_rate_channels_are_inputs_not_measurements():
    channel = SpeedYawRate(20.0)
    a_y = np.array([[2.0], [-4.0]])
    y = channel.measure(Sample(np.zeros((2, 2)), np.zeros(2), a_y, np.zeros((2, 0))), None)
    np.testing.assert_allclose(y, [[20.0, 0.1], [20.0, -0.2]])
    suite = imu(dt_s=0.01, roll_sensor=True)
    model = suite.linear_model()
    assert suite.names == ("roll_rate", "lateral_accel", "roll", "speed", "yaw_rate")
    np.testing.assert_array_equal(model.inputs, [False, False, False, True, True])
    np.testing.assert_allclose(model.D[4], [1 / SPEED_M_S])
    design = runner.build(Scenario(rig="vehicle-roll", sensors="imu",
                                   sensor_options={"roll_sensor": True})).design
    np.testing.assert_array_equal(design.measurement_index, [0, 1, 2])
    assert len(design.deterministic_index) == 0
    with pytest.raises(ValueError, match="speed_m_s"):
        SpeedYawRate(0.0)


def test_estimator_input_is_speed_times_yaw_rate_of_the_same_sample():
    experiment = runner.build(Scenario(rig="vehicle-roll"), 3)
    sim, design = experiment.loop.sim, experiment.design
    assert design.extras["a_y_source"] == "measured"
    sim.reset(None, [1, 2, 3])
    names = list(sim.sensors.names)
    v, r = names.index("speed"), names.index("yaw_rate")
    errors = []
    for _ in range(300):
        sim.step(np.zeros((3, 1)))
        u = design.input_transform(sim.info["action_applied"], np.zeros((3, 2)))
        np.testing.assert_array_equal(u[:, 0], sim.obs[:, v] * sim.obs[:, r])
        errors.append(u[:, 0] - sim.info["action_applied"][:, 0])
    experiment.close()
    errors = np.array(errors)
    # white part of the error: the yaw gyro's noise times the speed (bias walks slowly)
    sigma = np.sqrt(measured_a_y_variance(find_tap(sim.sensors))[0, 0])
    assert sigma == pytest.approx(SPEED_M_S * GYRO_NOISE_DENSITY * 10, rel=1e-3)
    np.testing.assert_allclose(np.diff(errors, axis=0).std() / np.sqrt(2), sigma, rtol=0.1)
    with pytest.raises(ValueError, match="simulator's own sensors"):
        design.input_transform(np.zeros((2, 1)), np.zeros((2, 2)))


def test_oracle_and_auto():
    oracle = runner.build(Scenario(rig="vehicle-roll",
                                   design_options={"a_y_source": "oracle"})).design
    assert oracle.input_transform is None and oracle.extras["a_y_source"] == "oracle"
    paper = runner.build(Scenario(rig="vehicle-roll", sensors="paper")).design
    assert paper.extras["a_y_source"] == "oracle"  # auto: no speed/yaw-rate channels
    with pytest.raises(ValueError, match="needs the speed and yaw_rate channels"):
        runner.build(Scenario(rig="vehicle-roll", sensors="paper",
                              design_options={"a_y_source": "measured"}))
    with pytest.raises(ValueError, match="a_y_source must be one of"):
        runner.build(Scenario(rig="vehicle-roll", design_options={"a_y_source": "truth"}))
    # R of the accelerometer grows by var(a_y) (the measured input enters its model)
    measured = runner.build(Scenario(rig="vehicle-roll")).design
    dR = measured.discrete.R - oracle.discrete.R
    var = measured_a_y_variance(find_tap(imu()))[0, 0]
    np.testing.assert_allclose(dR, [[0, 0], [0, var]], atol=1e-15)


def test_measured_input_costs_accuracy_and_stays_consistent():
    base = Scenario(rig="vehicle-roll", duration_s=5.0)
    measured = runner.monte_carlo(base, 8, progress=False)
    oracle = runner.monte_carlo(base.replace(design_options={"a_y_source": "oracle"}), 8,
                                progress=False)
    roll_m, roll_o = measured["rmse"]["roll"]["mean"], oracle["rmse"]["roll"]["mean"]
    print(f"roll RMSE measured a_y {np.rad2deg(roll_m):.4f} deg, oracle "
          f"{np.rad2deg(roll_o):.4f} deg; NEES {measured['nees_mean']:.2f} / "
          f"{oracle['nees_mean']:.2f}")
    assert roll_m > 1.3 * roll_o
    assert 1.0 < measured["nees_mean"] < 3.5


def test_cli_a_y_source(capsys):
    assert main(["run", "vehicle-roll", "--design-option", "a_y_source=oracle", "--duration",
                 "0.2", "--no-progress"]) == 0
    assert main(["run", "helicopter", "--design-option", "a_y_source=oracle", "--duration",
                 "0.2"]) == 2
    err = capsys.readouterr().err
    assert "--design-option" in err and "a_y_source" in err and "do not apply" in err
