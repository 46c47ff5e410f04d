"""The nonlinear plug-in contract of docs/extending.md: filterpy's EKF and UKF written from the
docs alone (docs/examples/fp_ekf.py, fp_ukf.py) get the built-in ekf's and ukf's numbers (the
ukf with its standard scaled sigma points, as filterpy's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from testbed.estimators import nonlinear_model
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario

pytest.importorskip("filterpy")
EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples"


@pytest.fixture(autouse=True)
def examples_on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))


def _run(rig, profile, estimator, duration_s=2.0, **options):
    traj, summary = runner.run(Scenario(rig=rig, estimator=estimator, profile=profile,
                                        duration_s=duration_s, seed=1,
                                        estimator_options=options), progress=False)
    return traj, summary


@pytest.mark.parametrize("rig,profile", [("helicopter", "paper"), ("helicopter", "hardware"),
                                         ("vehicle-roll", "paper"),
                                         ("vehicle-roll", "hardware")])
def test_a_filterpy_ekf_from_the_docs_is_the_builtin_ekf(rig, profile):
    built, s_built = _run(rig, profile, "ekf")
    plug, s_plug = _run(rig, profile, str(EXAMPLES / "fp_ekf.py") + ":make")
    # the same filter up to rounding (filterpy inverts S, the built-in solves)
    scale = np.abs(built.estimate).max()
    assert np.abs(plug.estimate - built.estimate).max() < 1e-7 * scale
    for name, value in s_built["rmse"].items():
        assert s_plug["rmse"][name] == pytest.approx(value, rel=1e-6)


@pytest.mark.parametrize("rig,profile", [("helicopter", "hardware"),
                                         ("vehicle-roll", "paper")])
def test_a_filterpy_ukf_from_the_docs_is_the_builtin_ukf(rig, profile):
    # filterpy's MerweScaledSigmaPoints: the built-in's standard set
    built, s_built = _run(rig, profile, "ukf", duration_s=1.0, sigma_points="scaled")
    plug, s_plug = _run(rig, profile, "fp_ukf:make", duration_s=1.0)
    for name, value in s_built["rmse"].items():
        assert s_plug["rmse"][name] == pytest.approx(value, rel=1e-4)


def _design(rig, profile):
    exp = runner.build(Scenario(rig=rig, estimator="kalman", profile=profile, duration_s=1), 1)
    try:
        return exp.design
    finally:
        exp.close()


def test_the_model_adds_the_operating_input_at_x_hat():
    """f in the loop's input = the process model in absolute volts with the gravity
    voltage at x_hat added (an independent computation from the rig)."""
    from testbed.estimators.nonlinear import nonlinear_models

    design = _design("helicopter", "paper")
    model = nonlinear_model(design)
    rig, process, _ = nonlinear_models(design)
    x = np.array([0.1, 0.2, 0.05, -0.1])
    x_hat = np.array([0.3, 0.0, 0.0, 0.0])
    u = np.array([0.5, -0.2])
    volts = u + rig.operating_input(rig.params, x_hat[None])[0]
    assert np.all(np.abs(volts - u) > 0.1)  # the offset matters
    np.testing.assert_array_equal(model.applied_input(u, x_hat)[0], volts)
    np.testing.assert_array_equal(model.f(x, u, x_hat), process(x[None], volts[None])[0])
    # one state in, one out; rows in, rows out (u and x_hat broadcast)
    rows = np.stack([x, x + 0.01, x - 0.01])
    assert model.f(x, u, x_hat).shape == (4,)
    assert model.F(x, u, x_hat).shape == (4, 4)
    assert model.h(x, u, x_hat).shape == (model.m,)
    assert model.H(rows, u, x_hat).shape == (3, model.m, 4)
    np.testing.assert_array_equal(model.f(rows, u, x_hat)[1], model.f(rows[1], u, x_hat))
    # F: the derivative of f at the applied input (central differences, independent)
    eps = 1e-6
    J = np.stack([(model.f(x + eps * e, u, x_hat) - model.f(x - eps * e, u, x_hat)) / (2 * eps)
                  for e in np.eye(4)], axis=1)
    np.testing.assert_allclose(model.F(x, u, x_hat), J, atol=1e-5)
    with pytest.raises(TypeError):
        model.f(x, u)  # x_hat is required: the offset cannot be forgotten
    with pytest.raises(ValueError, match="x must have shape"):
        model.f(np.zeros(3), u, x_hat)


def test_the_hardware_model_states_are_the_documented_ones():
    heli = nonlinear_model(_design("helicopter", "hardware"))
    assert heli.state_names == ("pitch", "yaw", "pitch_rate", "yaw_rate", "dact_pitch",
                                "dact_yaw", "bias_gyro_pitch", "bias_gyro_yaw",
                                "gyro_pitch_delay1", "gyro_yaw_delay1")
    assert heli.input_names == ("V_pitch", "V_yaw", "stop_reaction")
    vr = nonlinear_model(_design("vehicle-roll", "hardware"))
    assert vr.state_names == ("roll", "roll_rate", "bias_a_y", "bias_roll_rate",
                              "bias_lateral_accel", "roll_rate_delay1", "lateral_accel_delay1")
    assert (heli.n, heli.m, vr.n, vr.m) == (10, 4, 7, 2)
