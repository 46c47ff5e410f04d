"""The discrete noise of held accelerations: the map against MuJoCo's own period, the
covariance against the simulator's one-step residuals, and the helicopter's reference
Kalman filter consistent with it."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.design.held_noise import (
    held_acceleration_map,
    held_noise_covariance,
    implicit_damping,
)
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs.linear_plant.rig import LinearPlantRig


def test_the_map_is_mujocos_period_on_a_linear_plant() -> None:
    # the linear plant's discrete_map differences mj_step itself (exact for a linear plant)
    rig = LinearPlantRig()
    dt_s = 0.01
    A, _ = rig.linearize()
    _, _, E_mujoco = rig.discrete_map(dt_s)
    implicit = implicit_damping(rig.model)
    assert implicit  # MuJoCo's Euler: damping implicit
    E = held_acceleration_map(A, 1, dt_s, rig.model.opt.timestep, implicit=implicit)
    np.testing.assert_allclose(E, E_mujoco, rtol=1e-6, atol=1e-12)


def test_limit_of_one_step_and_bad_periods() -> None:
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    # one explicit physics step: v += h a, p += h v+ = h^2 a
    np.testing.assert_allclose(held_acceleration_map(A, 1, 0.1, 0.1, implicit=False),
                               [[0.01], [0.1]])
    # many steps: p -> dt^2 / 2 (1 + 1/N), v = dt
    E = held_acceleration_map(A, 1, 0.01, 0.001, implicit=False)
    np.testing.assert_allclose(E[:, 0], [0.5 * 0.01**2 * 1.1, 0.01], rtol=1e-12)
    assert held_acceleration_map(A, 1, 0.0105, 0.001) is None
    Q = held_noise_covariance(E, np.diag([0.0, 2.0]), 1, 0.01)
    np.testing.assert_allclose(Q, E @ E.T * 200.0)
    assert np.linalg.matrix_rank(Q) == 1  # positions and velocities move together


def test_helicopter_reference_kalman_is_consistent_and_its_noise_is_the_simulators() -> None:
    scenario = Scenario(rig="helicopter", disturbance="basin-helicopter",
                        sensor_options={"disturbance_channel": True}, process_noise=1.0,
                        duration_s=6.0)
    experiment = runner.build(scenario, 16)
    result = experiment.loop.run(runner.run_seeds(3, 16), scenario.duration_s, {},
                                 record=True)
    rec = result.trajectory
    design = experiment.design
    X, U = rec["state"], rec["action"]
    W = np.stack([X[:, k + 1] - X[:, k] @ design.discrete.F.T
                  - design.input_transform(U[:, k + 1], X[:, k]) @ design.discrete.B.T
                  for k in range(10, X.shape[1] - 1)], axis=1).reshape(-1, 4)
    measured = np.cov(W.T)
    Q = np.asarray(design.discrete.Q)
    # the simulated one-step residual: rates within 10 % of the design's noise, and the
    # position-rate correlation of held noise (near one; 0.87 for continuous white noise)
    np.testing.assert_allclose(np.diag(measured)[2:], np.diag(Q)[2:], rtol=0.1)
    for i in (0, 1):
        corr = measured[i, i + 2] / np.sqrt(measured[i, i] * measured[i + 2, i + 2])
        design_corr = Q[i, i + 2] / np.sqrt(Q[i, i] * Q[i + 2, i + 2])
        assert corr > 0.98 and design_corr > 0.98
    error = rec["estimate"][:, 1:] - rec["state"][:, 1:]
    P = rec["covariance"][:, 1:]
    nees = np.einsum("rti,rtij,rtj->rt", error, np.linalg.inv(P), error).mean()
    assert nees == pytest.approx(4.0, rel=0.1)  # 3.30 with the continuous noise's Q


@pytest.mark.parametrize("rig", ["helicopter", "aero", "vehicle-roll"])
def test_the_process_noise_model_option_chooses_the_papers_q(rig) -> None:
    """``process_noise_model``: "auto" is "held" (bitwise), "continuous" the papers' Van Loan
    Q (another matrix); on the hardware profile the matched design holds the rig's white
    noise (helicopter, Aero: another matrix than "continuous"; the vehicle's damping noise
    is not additive: "auto" is "continuous" there)."""
    def Q(profile: str, model: str | None) -> np.ndarray:
        options = {} if model is None else {"process_noise_model": model}
        scenario = Scenario(rig=rig, profile=profile, duration_s=0.1, design_options=options,
                            process_noise=0.0 if rig == "vehicle-roll" else 1.0)
        experiment = runner.build(scenario)
        try:
            return np.array(experiment.design.discrete.Q)
        finally:
            experiment.close()

    auto = Q("paper", None)
    np.testing.assert_array_equal(auto, Q("paper", "held"))
    assert not np.allclose(auto, Q("paper", "continuous"), rtol=1e-3, atol=0)
    hardware = Q("hardware", None)
    np.testing.assert_array_equal(hardware, Q("hardware", "held"))
    if rig == "vehicle-roll":
        np.testing.assert_array_equal(hardware, Q("hardware", "continuous"))
    else:
        assert not np.allclose(hardware, Q("hardware", "continuous"), rtol=1e-3, atol=0)


def test_the_matched_design_holds_the_rigs_noise_and_integrates_the_rest() -> None:
    """Hardware helicopter, Basin's b dW: the matched design's discrete Q is the held
    covariance of b b^T (as the paper design computes it: the same function on the
    designer's A) plus Van Loan's integral of the rest of the intensity (the floor, the
    rotors' and the biases' noise): checked against a design without b (the Van Loan part
    alone) and the paper design's held Q without the floor."""
    def design(profile: str, process_noise: float, floor: float):
        scenario = Scenario(rig="helicopter", profile=profile, disturbance="basin-helicopter",
                            process_noise=process_noise, duration_s=0.1,
                            design_options={"process_noise_floor": floor})
        experiment = runner.build(scenario)
        try:
            return experiment.design
        finally:
            experiment.close()

    full = np.asarray(design("hardware", 1.0, 0.05).discrete.Q)
    rest = np.asarray(design("hardware", 0.0, 0.05).discrete.Q)
    held = np.asarray(design("paper", 1.0, 0.0).discrete.Q)
    np.testing.assert_allclose(full[4:, 4:], rest[4:, 4:], rtol=1e-12, atol=0)
    # the rig's block: the held part through the matched model's own A (its damping from
    # the MJCF's linearization: the diagonal within 1.1 % of the paper model's), with the
    # held noise's position-rate correlation (near one; 0.87 for continuous white noise)
    part = full[:4, :4] - rest[:4, :4]
    np.testing.assert_allclose(part, held, rtol=2e-2, atol=1e-6 * np.abs(held).max())
    for i in (0, 1):
        assert part[i, i + 2] / np.sqrt(part[i, i] * part[i + 2, i + 2]) > 0.98


def test_hardware_helicopter_kalman_rates_are_consistent_after_the_lift_off() -> None:
    """The suite's hardware helicopter (Basin's disturbance and b dW), 8 runs x 5 s: after
    the lift-off from the stop (t > 2 s) mean(e^2) / mean(P) of each rate within 15 % of 1
    (measured 0.93 and 0.90; 0.73 and 0.59 with the continuous covariance of b b^T, which
    ``process_noise_model=continuous`` still gives)."""
    scenario = Scenario(rig="helicopter", profile="hardware", disturbance="basin-helicopter",
                        sensor_options={"disturbance_channel": True}, process_noise=1.0,
                        duration_s=5.0)
    ratios = {}
    for model in ("auto", "continuous"):
        sc = scenario.replace(design_options={"process_noise_model": model})
        experiment = runner.build(sc, 8)
        try:
            rec = experiment.loop.run(runner.run_seeds(5, 8), sc.duration_s, {},
                                      record=True).trajectory
        finally:
            experiment.close()
        after = slice(201, None)
        error = rec["estimate"][:, after, :4] - rec["state"][:, after, :4]
        P = np.diagonal(rec["covariance"][:, after], axis1=-2, axis2=-1)[..., :4]
        ratios[model] = (error**2).mean(axis=(0, 1)) / P.mean(axis=(0, 1))
    np.testing.assert_allclose(ratios["auto"][2:], 1.0, atol=0.15)
    assert np.all(ratios["continuous"][2:] < 0.8)


def test_an_unknown_process_noise_model_is_one_line_naming_the_option() -> None:
    scenario = Scenario(rig="helicopter", duration_s=0.1,
                        design_options={"process_noise_model": "white"})
    with pytest.raises(ValueError, match=r"process_noise_model must be one of .*'white'"):
        runner.build(scenario)
