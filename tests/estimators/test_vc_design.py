"""The variance-constrained family on the rigs ('vc-discrete', testbed.estimators.vc).

The uncertainty ``M Fu N`` is checked against rigs rebuilt at the scaled parameters (their
own MuJoCo linearization and an ``expm``, independent of the Frechet derivative used in the
construction) and against the roll model's closed form; the designed predictor against
:func:`verify_design`, the physical (block-diagonal) uncertainty set and a Monte-Carlo
simulation of the linear plant with an input.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.linalg import expm

from filters.analysis import error_covariance, unit_disk
from filters.variance_constrained import LinearFilter, passes, verify_design
from testbed import estimators
from testbed.cli import main
from testbed.estimators import vc as estimators_vc
from testbed.estimators import vc_design
from testbed.estimators.stochastic_system import design_system
from testbed.estimators.vc import (
    VarianceConstrainedPredictor,
    design_vc_discrete,
    mismatch_uncertainty,
    reference_covariance,
)
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs.helicopter.rig import HelicopterRig
from testbed.rigs.linear_plant.rig import LinearPlantRig
from testbed.rigs.vehicle_roll.model import VehicleRollParams
from testbed.rigs.vehicle_roll.rig import VehicleRollRig
from testbed.score.suite import HELICOPTER_MISMATCH_KEYS


def _design(rig, **options):
    experiment = runner.build(Scenario(rig=rig, estimator="kalman", duration_s=0.1,
                                       **options), 1)
    experiment.close()
    return experiment.design


@pytest.fixture(scope="module")
def vehicle():
    return _design("vehicle-roll")


@pytest.fixture(scope="module")
def vehicle_vc(vehicle):
    return design_vc_discrete(vehicle)  # ~2 s; cached in-process for the other tests


def _block(unc, index: int, sign: float) -> np.ndarray:
    """``Fu`` with ``sign I`` on block ``index`` and zero elsewhere (block diagonal)."""
    F = np.zeros((unc.M.shape[1], unc.N.shape[0]))
    start = sum(unc.blocks[:index])
    for j in range(start, start + unc.blocks[index]):
        F[j, j] = sign
    return F


def test_rigs_declare_their_mismatch_range_and_the_suite_uses_it():
    assert tuple(HelicopterRig.mismatch_range) == HELICOPTER_MISMATCH_KEYS
    assert set(VehicleRollRig.mismatch_range) == {"roll_stiffness", "roll_damping"}
    assert LinearPlantRig.mismatch_range == {}

    class Bad(VehicleRollRig):
        xml_path = VehicleRollRig.resolved_xml_path()
        mismatch_range = {"no_such_field": 0.2}

    with pytest.raises(TypeError, match="no_such_field"):
        Bad()
    Bad.mismatch_range = {"roll_damping": 1.5}
    with pytest.raises(TypeError, match="roll_damping"):
        Bad()


def test_mismatch_derivative_matches_the_roll_models_closed_form(vehicle):
    """``A[1, 0] = -(s_K K_R - m g h) / I``, ``A[1, 1] = -s_C C_R / I``: linear in the
    scale factors, so dA/ds is exact."""
    unc = mismatch_uncertainty(vehicle)
    p = VehicleRollParams()
    expected = {"roll_stiffness": np.array([[0.0, 0.0], [-p.roll_stiffness / p.roll_inertia,
                                                          0.0]]),
                "roll_damping": np.array([[0.0, 0.0], [0.0, -p.roll_damping
                                                       / p.roll_inertia]])}
    assert unc.parameters == ("roll_stiffness", "roll_damping")
    assert unc.ranges == (0.2, 0.2)
    for name, dA in zip(unc.parameters, unc.continuous, strict=True):
        np.testing.assert_allclose(dA, expected[name], rtol=1e-6, atol=1e-6)


def test_m_fu_n_reproduces_the_first_order_change_and_covers_the_scaled_rigs(vehicle):
    unc = mismatch_uncertainty(vehicle)
    dt, F0 = vehicle.dt_s, vehicle.discrete.F
    np.testing.assert_allclose(F0, expm(vehicle.continuous.A * dt), rtol=1e-12, atol=1e-14)
    nominal = VehicleRollParams()
    assert unc.dropped < 1e-3
    for i, (name, r) in enumerate(zip(unc.parameters, unc.ranges, strict=True)):
        for sign in (1.0, -1.0):
            # sampled block-diagonal Fu reproduce +-Delta_i (up to the dropped directions)
            change = unc.M @ _block(unc, i, sign) @ unc.N
            scale = np.linalg.norm(unc.deltas[i], 2)
            assert np.linalg.norm(change - sign * unc.deltas[i], 2) <= 1.01e-3 * scale
            # the rig itself at the edge of the range: its own linearization, its own expm
            A_edge, _ = VehicleRollRig(nominal.scaled({name: 1.0 + sign * r})).linearize()
            true_change = expm(A_edge * dt) - F0
            residual = np.linalg.norm(true_change - change, 2)
            # first order: the remainder is small against the change itself ...
            assert residual < 0.05 * np.linalg.norm(true_change, 2)
            # ... and smaller than leaving the uncertainty out or getting its sign wrong
            assert residual < 0.1 * np.linalg.norm(true_change + change, 2)
            # halfway through the range the remainder shrinks quadratically (first order)
            A_half, _ = VehicleRollRig(nominal.scaled({name: 1.0 + sign * r / 2})).linearize()
            half = np.linalg.norm(expm(A_half * dt) - F0 - change / 2, 2)
            assert half < 0.3 * residual + 1e-12


def test_rig_without_a_range_gets_no_uncertainty():
    design = _design(LinearPlantRig, process_noise=1.0)
    unc = mismatch_uncertainty(design)
    assert unc.parameters == () and not np.any(unc.M) and not np.any(unc.N)


def test_vehicle_design_passes_its_verification_and_the_physical_set(vehicle_vc):
    vc = vehicle_vc
    meta = vc.meta()
    assert meta["certified"] and np.all(vc.bound <= vc.sigma2)
    assert vc.gamma == pytest.approx(2.0 * vc.gamma_min)
    check = verify_design(vc.plant, vc.G, vc.K, region=unit_disk(), gamma=vc.gamma,
                          sigma2=vc.sigma2, n_grid=21)
    assert passes(check)
    assert check.hinf_worst <= vc.gamma and np.all(check.variance_worst <= vc.sigma2)
    # the physical set: each parameter anywhere in its range (block-diagonal Fu)
    unc = vc.uncertainty
    for f1 in np.linspace(-1, 1, 5):
        for f2 in np.linspace(-1, 1, 5):
            Fu = f1 * _block(unc, 0, 1.0) + f2 * _block(unc, 1, 1.0)
            P = error_covariance(vc.plant, vc.G, vc.K, Fu)
            assert np.all(np.diag(P) <= vc.bound * (1 + 1e-9))
    # no filter beats the Kalman predictor on the nominal plant: the bound is above it
    P_nominal = error_covariance(vc.plant, vc.G, vc.K)
    assert np.all(np.diag(P_nominal) >= vc.reference * (1 - 1e-9))
    np.testing.assert_allclose(vc.reference, np.diag(reference_covariance(vc.plant)))


def test_predictor_with_an_input_has_the_designed_error_covariance(vehicle, vehicle_vc):
    """Monte Carlo of the nominal linear plant driven by a large known input: the loop
    form's error covariance is the design's (the gains alone, fed y, would be biased)."""
    vc, plant = vehicle_vc, vehicle_vc.plant
    B, D, H = vehicle.discrete.B, vehicle.discrete.D, vehicle.discrete.H
    rng = np.random.default_rng(7)
    N, K = 400, 600
    est = VarianceConstrainedPredictor(vc.G, vc.K, plant.A, B, D, H, np.zeros((N, 2)),
                                       vehicle.dt_s)
    # the designed gains fed y directly, x_hat(k+1) = G x_hat + K (y - D u) + B u
    naive = LinearFilter(vc.G, vc.K, np.zeros((N, 2)), discrete=True, B=B)
    P_design = error_covariance(plant, vc.G, vc.K)
    x = rng.multivariate_normal(np.zeros(2), 4 * P_design, N)  # not the stationary law
    y0 = x @ H.T + rng.standard_normal((N, plant.D2.shape[1])) @ plant.D2.T
    est.reset(np.zeros((N, 2)))
    est.prime(y0)
    errors, naive_errors, y_prev = [], [], y0
    for k in range(K):
        u = np.full((N, 1), 6.0 * np.sin(2 * np.pi * 0.4 * k * vehicle.dt_s))
        w = rng.standard_normal((N, plant.D1.shape[1]))
        x = x @ plant.A.T + u @ B.T + w @ plant.D1.T
        y = x @ H.T + u @ D.T + w @ plant.D2.T
        errors.append(x - est.step(y, u))
        naive_errors.append(x - naive.step(y_prev, u))
        y_prev = y - u @ D.T
    e = np.array(errors[200:]).reshape(-1, 2)
    np.testing.assert_allclose(e.var(axis=0), np.diag(P_design), rtol=0.05)
    # unbiased: the mean within 4 standard errors (from the runs' own time averages: the
    # errors within a run are correlated; a fixed 0.05 sigma was one standard error)
    run_means = np.array(errors[200:]).mean(axis=0)  # (N, 2)
    standard_error = run_means.std(axis=0, ddof=1) / np.sqrt(N)
    assert np.all(np.abs(run_means.mean(axis=0)) < 4 * standard_error)
    # without the input's response the error has a large input-driven part
    e_naive = np.array(naive_errors[200:]).reshape(-1, 2)
    assert np.all(np.mean(e_naive**2, axis=0) > 2.0 * np.diag(P_design))


def test_predictor_rejects_bad_measurements_before_changing_state(vehicle_vc, vehicle):
    vc = vehicle_vc
    est = VarianceConstrainedPredictor(vc.G, vc.K, vc.plant.A, vehicle.discrete.B,
                                       vehicle.discrete.D, vehicle.discrete.H,
                                       np.zeros((3, 2)), vehicle.dt_s)
    before = est.x.copy()
    with pytest.raises(ValueError, match="y must have shape"):
        est.step(np.zeros((3, 5)), np.zeros((3, 1)))
    with pytest.raises(ValueError, match="y"):
        est.step(np.full((3, 2), np.nan), np.zeros((3, 1)))
    np.testing.assert_array_equal(est.x, before)
    # unprimed: the first step uses the measurement the prior predicts (no correction)
    est.reset(np.array([[0.01, 0.0]] * 3))
    x1 = est.step(np.zeros((3, 2)), np.zeros((3, 1)))
    np.testing.assert_allclose(x1, np.array([[0.01, 0.0]] * 3) @ vc.plant.A.T)


@pytest.fixture(scope="module")
def helicopter():
    return _design("helicopter")


@pytest.fixture(scope="module")
def helicopter_vc(helicopter):
    return design_vc_discrete(helicopter)  # ~15 s (five injections); cached in-process


def test_helicopter_without_injection_is_refused_with_the_reason_in_one_line(helicopter):
    with pytest.raises(ValueError) as err:
        estimators.build("vc-discrete", helicopter, output_injection=False)
    message = str(err.value)
    assert "\n" not in message
    assert "Schur-stable" in message and "free integrators" in message


def test_helicopter_is_designed_in_the_output_injection_loop(helicopter, helicopter_vc):
    """Free integrators: the theorem's plant is F - L0 H with y a known input (the same
    uncertainty set), and the design's bounds hold there."""
    vc, d = helicopter_vc, helicopter
    F, H = d.discrete.F, d.discrete.H
    assert np.max(np.abs(np.linalg.eigvals(F))) >= 1.0 - 1e-12
    L0 = vc.injection
    assert L0 is not None and vc.injection_scale in estimators_vc.INJECTION_SCALES
    np.testing.assert_allclose(vc.plant.A, F - L0 @ H)
    assert np.max(np.abs(np.linalg.eigvals(vc.plant.A))) < 1.0
    system, _ = design_system(d, stable=False)
    np.testing.assert_allclose(vc.plant.D1, system.B - L0 @ system.D_y)
    # the chosen injection has the smallest certified bound ratio of the family
    assert vc_design._ratio(vc) <= 2.0
    meta = vc.meta()
    assert meta["certified"] and meta["output_injection"]["rho_F0"] < 1.0
    check = verify_design(vc.plant, vc.G, vc.K, region=unit_disk(), gamma=vc.gamma,
                          sigma2=vc.sigma2, n_grid=5)
    assert passes(check)
    P_nominal = error_covariance(vc.plant, vc.G, vc.K)
    assert np.all(np.diag(P_nominal) <= vc.bound * (1 + 1e-9))
    assert np.all(np.diag(P_nominal) >= vc.reference * (1 - 1e-9))


def test_helicopter_predictor_in_a_feedback_loop_has_the_designed_error_covariance(
        helicopter, helicopter_vc):
    """Monte Carlo of the design model with its free integrators (F, not F - L0 H) under a
    state-feedback controller plus a known excitation: the error is stationary with the
    covariance of the design's error system (computed on the injection loop)."""
    from scipy.linalg import solve_discrete_are

    vc, d = helicopter_vc, helicopter
    F, B, H = d.discrete.F, d.discrete.B, d.discrete.H
    system, _ = design_system(d, stable=False)
    D1, D2 = system.B, system.D_y
    n = F.shape[0]
    X = solve_discrete_are(F, B, np.eye(n), np.eye(B.shape[1]))
    Kc = np.linalg.solve(B.T @ X @ B + np.eye(B.shape[1]), B.T @ X @ F)
    rng = np.random.default_rng(11)
    N, K = 300, 700
    P_design = error_covariance(vc.plant, vc.G, vc.K)
    est = VarianceConstrainedPredictor(vc.G, vc.K, F, B, d.discrete.D, H, np.zeros((N, n)),
                                       d.dt_s, injection=vc.injection)
    x = rng.multivariate_normal(np.zeros(n), 4 * P_design, N)
    est.reset(np.zeros((N, n)))
    est.prime(x @ H.T + rng.standard_normal((N, D2.shape[1])) @ D2.T)
    errors = []
    for k in range(K):
        u = -x @ Kc.T + 2.0 * np.sin(2 * np.pi * 0.3 * k * d.dt_s)
        w = rng.standard_normal((N, D1.shape[1]))
        x = x @ F.T + u @ B.T + w @ D1.T
        y = x @ H.T + w @ D2.T
        errors.append(x - est.step(y, u))
    e = np.array(errors[300:]).reshape(-1, n)
    np.testing.assert_allclose(e.var(axis=0), np.diag(P_design), rtol=0.05)
    assert np.all(np.abs(e.mean(axis=0)) < 0.05 * np.sqrt(np.diag(P_design)))


def test_bad_options_are_refused(vehicle):
    with pytest.raises(ValueError, match="gamma_factor"):
        estimators.build("vc-discrete", vehicle, gamma_factor=0.5)
    with pytest.raises(ValueError, match="sigma_factor"):
        estimators.build("vc-discrete", vehicle, sigma_factor=-1.0)
    with pytest.raises(ValueError, match="bound ratio"):  # below the reachable bound
        estimators.build("vc-discrete", vehicle, sigma_factor=1.0)


def test_cli_run_on_the_vehicle(tmp_path, vehicle_vc):
    path = tmp_path / "vc.json"
    assert main(["run", "vehicle-roll", "--filter", "vc-discrete", "--duration", "2",
                 "--no-progress", "--json", str(path)]) == 0
    out = json.loads(path.read_text())
    assert out["filter"] == "vc-discrete" and out["nees_mean"] is None
    assert all(np.isfinite(v) for v in out["rmse"].values())
    assert out["meta"]["design"]["gamma"] == pytest.approx(vehicle_vc.gamma)
    assert out["meta"]["design"]["certified"] is True


def test_member_of_a_batch_equals_the_single_run_bitwise(vehicle_vc):
    sc = Scenario(rig="vehicle-roll", estimator="vc-discrete", duration_s=1.0)
    seeds = runner.run_seeds(0, 4)
    results = []
    for num, members in ((4, seeds), (1, seeds[2:3])):
        experiment = runner.build(sc, num)
        try:
            assert type(experiment.loop.stage.estimator).__name__ != "PerMember"
            results.append(experiment.loop.run(members, sc.duration_s, record=True))
        finally:
            experiment.close()
    batch, single = (r.trajectory for r in results)
    for key in ("state", "estimate", "measurement"):
        np.testing.assert_array_equal(batch[key][2], single[key][0], err_msg=key)
    assert "covariance" not in single
