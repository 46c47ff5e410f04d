"""Theorem-4 LMI H-infinity design (nonlinear discrete stochastic systems paper): designs,
a-posteriori checks, the filter (45)."""

from __future__ import annotations

import numpy as np
import pytest

from filters.base import Estimator
from filters.lmi_hinf import (
    LMIHInfFilter,
    StochasticLinearSystem,
    balancing,
    certify_gain,
    check_design,
    design_lmi_hinf,
    design_lmi_matrix,
    error_system,
    gari_matrix,
    lmi_gamma_for_solution,
    minimal_gamma,
    minimal_gamma_sdp,
    ms_spectral_radius,
    output_error_moments,
)


def random_system(seed: int, n: int = 3, ny: int = 1, nv: int = 2, rho: float = 0.8,
                  noise: float = 0.1) -> StochasticLinearSystem:
    """A random Schur-stable system with multiplicative noise (no exact decoupling: ny < nv)."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    A *= rho / np.max(np.abs(np.linalg.eigvals(A)))
    return StochasticLinearSystem(
        A=A, B=rng.standard_normal((n, nv)), C_y=rng.standard_normal((ny, n)),
        C_z=rng.standard_normal((1, n)), A_w=noise * rng.standard_normal((n, n)),
        B_w=noise * rng.standard_normal((n, nv)), D_y=rng.standard_normal((ny, nv)),
        D_z=0.1 * rng.standard_normal((1, nv)))


@pytest.fixture(scope="module")
def system() -> StochasticLinearSystem:
    return random_system(1)


@pytest.fixture(scope="module")
def search(system):
    return minimal_gamma(system)


# ------------------------------------------------------------------ the system
def test_system_validation_names_the_argument():
    A = 0.5 * np.eye(2)
    s = StochasticLinearSystem(A=A, B=np.ones((2, 1)), C_y=np.eye(2), C_z=np.eye(1, 2))
    assert s.n == 2 and s.n_v == 1 and s.n_y == 2 and s.n_z == 1
    assert np.all(s.A_w == 0) and s.D_y.shape == (2, 1) and not s.A.flags.writeable
    with pytest.raises(ValueError, match="B must"):
        StochasticLinearSystem(A=A, B=np.ones((3, 1)), C_y=np.eye(2), C_z=np.eye(1, 2))
    with pytest.raises(ValueError, match="C_y must"):
        StochasticLinearSystem(A=A, B=np.ones((2, 1)), C_y=np.eye(3), C_z=np.eye(1, 2))
    with pytest.raises(ValueError, match="D_y must"):
        StochasticLinearSystem(A=A, B=np.ones((2, 1)), C_y=np.eye(2), C_z=np.eye(1, 2),
                               D_y=np.ones((2, 2)))
    with pytest.raises(ValueError, match="A_w must"):
        StochasticLinearSystem(A=A, B=np.ones((2, 1)), C_y=np.eye(2), C_z=np.eye(1, 2),
                               A_w=np.full((2, 2), np.nan))


def test_error_system_is_the_difference_of_plant_and_filter(system, rng):
    K = rng.standard_normal(system.gain_shape())
    At, Bt, Ct, Dt, Gt, Mt = error_system(system, K)
    x, xh, v, w = rng.standard_normal(3), rng.standard_normal(3), rng.standard_normal(2), 0.7
    s = system
    x1 = s.A @ x + s.B @ v + (s.A_w @ x + s.B_w @ v) * w
    xh1 = s.A @ xh + K @ (s.C_y @ x + s.D_y @ v - s.C_y @ xh)  # (45) with A xhat
    eta = np.concatenate([x, x - xh])
    assert np.allclose(At @ eta + Bt @ v + (Ct @ eta + Dt @ v) * w,
                       np.concatenate([x1, x1 - xh1]))
    assert np.allclose(Gt @ eta + Mt @ v, s.C_z @ x + s.D_z @ v - s.C_z @ xh)


def test_ms_spectral_radius_without_noise_is_rho_squared():
    A = np.array([[0.5, 1.0], [0.0, -0.9]])
    assert ms_spectral_radius(A, np.zeros((2, 2))) == pytest.approx(0.81)


# ------------------------------------------------------------------ designs
@pytest.mark.parametrize("objective", ["feasibility", "h2"])
def test_feasible_design_passes_independent_checks(system, search, objective):
    gamma = 1.5 * search.gamma_min
    d = design_lmi_hinf(system, gamma, objective=objective)
    assert d.feasible and d.status == "feasible" and d.solver_status.startswith("optimal")
    assert np.allclose(d.gain, np.linalg.solve(d.P2, d.P_K))
    # GARI matrix of Corollary 5, recomputed from (46), and mean-square stability
    n = system.n
    P = np.block([[d.P1, np.zeros((n, n))], [np.zeros((n, n)), d.P2]])
    assert np.linalg.eigvalsh(gari_matrix(system, d.gain, P, gamma))[-1] < 0
    At, _, Ct, *_ = error_system(system, d.gain)
    assert ms_spectral_radius(At, Ct) < 1
    assert np.linalg.eigvalsh(design_lmi_matrix(system, d.P1, d.P2, d.P_K, gamma))[-1] < 0
    assert lmi_gamma_for_solution(system, d.P1, d.P2, d.P_K) < gamma
    c = d.check
    assert c.ok and c.lmi_balanced_max_eig <= -0.5 * d.margin
    assert c.P_balanced_min_eig >= 0.5 * d.margin


def test_h2_design_minimizes_the_trace(system, search):
    gamma = 2 * search.gamma_min
    h2 = design_lmi_hinf(system, gamma, objective="h2")
    feas = design_lmi_hinf(system, gamma, objective="feasibility")
    assert h2.trace <= feas.trace * (1 + 1e-6)


def test_schur_equivalence_of_48_and_the_gari(system, rng, search):
    """(48) < 0 at P_K = P2 Khat iff PP < 0 (P = diag(P1, P2) > 0): same sign either way."""
    d = design_lmi_hinf(system, 1.5 * search.gamma_min)
    n = system.n
    P = np.block([[d.P1, np.zeros((n, n))], [np.zeros((n, n)), d.P2]])
    for gamma in (0.5 * search.gamma_min, 1.5 * search.gamma_min, 10 * search.gamma_min):
        a = np.linalg.eigvalsh(design_lmi_matrix(system, d.P1, d.P2, d.P2 @ d.gain, gamma))[-1]
        b = np.linalg.eigvalsh(gari_matrix(system, d.gain, P, gamma))[-1]
        assert (a < 0) == (b < 0)


def test_certified_gain_attenuates_every_disturbance(system, search, rng):
    """sum E|ztilde|^2 <= gamma^2 sum |v|^2 from eta_0 = 0, exactly (moment propagation)."""
    gamma = 1.2 * search.gamma_min
    d = design_lmi_hinf(system, gamma, objective="h2")
    zero = np.zeros(system.n)
    for _ in range(5):
        v = rng.standard_normal((60, system.n_v)) * np.exp(-0.05 * np.arange(60))[:, None]
        ez = output_error_moments(system, d.gain, zero, zero, v)
        assert np.all(np.cumsum(ez) <= gamma**2 * np.cumsum(np.sum(v**2, axis=1)) + 1e-12)


def test_infeasible_below_gamma_min_and_for_an_unstable_plant(system, search):
    low = design_lmi_hinf(system, 0.5 * search.lower)
    assert not low.feasible and low.status == "infeasible"
    assert low.gain is None and "infeasible" in low.solver_status
    unstable = StochasticLinearSystem(A=np.diag([1.2, 0.5]), B=np.ones((2, 1)),
                                      C_y=np.eye(1, 2), C_z=np.eye(1, 2), D_y=np.ones((1, 1)))
    d = design_lmi_hinf(unstable, 10.0)
    assert d.status == "infeasible" and d.gain is None and d.check is None
    s = minimal_gamma(unstable, gamma_max=1e3)
    assert s.gamma_min is None and s.status == "infeasible" and s.design is None


def test_unknown_solver_is_a_result_not_a_crash(system):
    d = design_lmi_hinf(system, 10.0, solvers=("NO_SUCH_SOLVER",))
    assert d.status == "solver_error" and "error" in d.solver_status and not d.feasible


def test_scs_alone_also_finds_a_verified_design(system, search):
    d = design_lmi_hinf(system, 3 * search.gamma_min, solvers=("SCS",), margin=1e-5)
    assert d.feasible and d.solver == "SCS"


def test_bisection_brackets_gamma_min_to_the_tolerance(system, search):
    assert search.status == "converged" and search.gamma_min / search.lower - 1 <= 1e-3
    assert search.design.feasible and search.design.gamma == search.gamma_min
    # monotone history: every feasible gamma is above every infeasible one
    feas = [g for g, ok in search.history if ok]
    infeas = [g for g, ok in search.history if not ok]
    assert min(feas) > max(infeas)
    # cross-check with one SDP (min gamma^2, no margin): the infimum is just below
    inf, status = minimal_gamma_sdp(system)
    assert status == "optimal"
    assert inf <= search.gamma_min and search.gamma_min < 1.01 * inf


def test_gamma_min_grows_with_the_margin(system):
    small = minimal_gamma(system, margin=1e-8).gamma_min
    large = minimal_gamma(system, margin=1e-3).gamma_min
    assert small < large


def test_certify_gain(system, search):
    d = design_lmi_hinf(system, 2 * search.gamma_min)
    c = certify_gain(system, d.gain, 2 * search.gamma_min)
    assert c.feasible and c.fixed_gain and np.allclose(c.gain, d.gain)
    bad = certify_gain(system, 100 * np.ones(system.gain_shape()), 1e3)
    assert not bad.feasible
    g = minimal_gamma(system, gain=d.gain)
    assert g.gamma_min <= 2 * search.gamma_min * (1 + 2e-3)


def test_check_design_rejects_a_destabilizing_gain(system, search):
    d = design_lmi_hinf(system, 2 * search.gamma_min)
    chk = check_design(system, 50 * np.ones(system.gain_shape()), d.P1, d.P2, d.gamma)
    assert not chk.ok and not chk.mean_square_stable


def test_balancing_has_unit_blocks_for_a_scaled_problem(system):
    (s1, s2), diag = balancing(system, gamma=0.5)
    n = system.n
    assert s1 > 0 and s2 > 0 and diag.shape == (6 * n + system.n_v + system.n_z,)
    assert diag[2 * n] == pytest.approx(2.0)


def test_design_result_as_dict_is_json_ready(system, search):
    import json

    d = design_lmi_hinf(system, 2 * search.gamma_min)
    json.dumps(d.as_dict(), allow_nan=False)
    json.dumps(search.as_dict(), allow_nan=False)
    json.dumps(design_lmi_hinf(system, 1e-6).as_dict(), allow_nan=False)


def test_decouplable_example_has_gamma_min_set_by_the_margin():
    """n_y >= n_v and the error can be decoupled: the infimum is 0, gamma_min ~ sqrt(margin)."""
    s = StochasticLinearSystem(A=np.array([[0.9, 0.1], [0.0, 0.5]]), B=np.array([[1.0], [0.5]]),
                               C_y=np.eye(2), C_z=np.eye(1, 2), D_y=np.array([[1.0], [0.0]]))
    g1 = minimal_gamma(s, margin=1e-4).gamma_min
    g2 = minimal_gamma(s, margin=1e-6).gamma_min
    assert g2 < g1 / 3


# ------------------------------------------------------------------ moments vs Monte Carlo
def test_moments_match_monte_carlo_of_the_batched_filter(system, search, rng):
    d = design_lmi_hinf(system, 2 * search.gamma_min)
    s = system
    runs, N = 4000, 25
    v = np.exp(-0.1 * np.arange(N))[:, None] * np.ones((N, s.n_v))
    x0, xh0 = np.array([0.3, -0.2, 0.1]), np.zeros(3)
    exact = output_error_moments(s, d.gain, x0, xh0, v)
    f = LMIHInfFilter.from_design(s, d, x0=np.tile(xh0, (runs, 1)))
    x = np.tile(x0, (runs, 1))
    f.prime(x @ s.C_y.T + v[0] @ s.D_y.T)
    z2 = np.empty((runs, N))
    for k in range(N):
        z2[:, k] = np.sum(((x - f.x) @ s.C_z.T + v[k] @ s.D_z.T) ** 2, axis=1)
        w = rng.standard_normal(runs)[:, None]
        x = x @ s.A.T + v[k] @ s.B.T + w * (x @ s.A_w.T + v[k] @ s.B_w.T)
        f.step(x @ s.C_y.T + v[min(k + 1, N - 1)] @ s.D_y.T)
    mc = z2.sum(axis=1)
    se = mc.std(ddof=1) / np.sqrt(runs)
    assert abs(mc.mean() - exact.sum()) < 4 * se


# ------------------------------------------------------------------ the filter (45)
def _system2() -> StochasticLinearSystem:
    return StochasticLinearSystem(A=np.array([[1.0, 0.01], [-0.3, 0.7]]),
                                  B=np.array([[-0.8], [0.4]]), C_y=np.array([[0.4, 0.6],
                                                                            [1.1, 1.5]]),
                                  C_z=np.eye(1, 2), D_y=np.array([[0.8], [-1.4]]))


def test_filter_is_45_with_A_xhat_and_pending_measurement():
    s = _system2()
    K = np.array([[-0.5, 0.2], [0.7, 0.15]])
    f = LMIHInfFilter(s.A, s.C_y, K, C_z=s.C_z, dt_s=0.01)
    assert isinstance(f, Estimator) and f.name == "lmi-hinf" and f.P is None
    ys = np.random.default_rng(0).standard_normal((5, 2))
    f.prime(ys[0])
    xh = np.zeros(2)
    for k in range(1, 5):
        out = f.step(ys[k])
        xh = s.A @ xh + K @ (ys[k - 1] - s.C_y @ xh)
        assert np.allclose(out, xh)
    assert f.t_s == pytest.approx(0.04)
    assert np.allclose(f.z, s.C_z @ xh)
    assert np.allclose(f.pending_measurement, ys[4])


def test_unprimed_first_step_is_a_prediction_and_reset_drops_the_measurement():
    s = _system2()
    K = np.ones((2, 2))
    f = LMIHInfFilter(s.A, s.C_y, K, x0=[1.0, 2.0])
    assert np.allclose(f.step([5.0, 5.0]), s.A @ [1.0, 2.0])
    f.reset([0.0, 0.0], np.array(None))  # P0 is ignored (FilterInLoop passes its prior)
    assert f.pending_measurement is None and f.t_s == 0 and np.all(f.x == 0)


def test_batch_equals_single_filters():
    s = _system2()
    K = np.array([[-0.5, 0.2], [0.7, 0.15]])
    rng = np.random.default_rng(3)
    x0 = rng.standard_normal((4, 2))
    ys = rng.standard_normal((6, 4, 2))
    batch = LMIHInfFilter(s.A, s.C_y, K, x0=x0)
    singles = [LMIHInfFilter(s.A, s.C_y, K, x0=x0[i]) for i in range(4)]
    batch.prime(ys[0])
    for i, f in enumerate(singles):
        f.prime(ys[0, i])
    for k in range(1, 6):
        out = batch.step(ys[k])
        for i, f in enumerate(singles):
            assert np.allclose(out[i], f.step(ys[k, i]), rtol=0, atol=1e-14)
    assert batch.batch_shape == (4,)


def test_known_input_and_feedthrough():
    s = _system2()
    K = np.array([[0.1, 0.0], [0.0, 0.2]])
    Bu, Du = np.array([[0.0], [0.25]]), np.array([[0.0], [1.0]])
    f = LMIHInfFilter(s.A, s.C_y, K, input_matrix=Bu, feedthrough=Du)
    y0, y1, u0 = np.array([0.1, 0.2]), np.array([0.3, 0.4]), np.array([2.0])
    f.prime(y0)
    out = f.step(y1, u0)
    assert np.allclose(out, s.A @ np.zeros(2) + K @ y0 + Bu @ u0)
    assert np.allclose(f.pending_measurement, y1 - Du @ u0)
    # without input_matrix the rig's u is ignored (the filter has no known input)
    g = LMIHInfFilter(s.A, s.C_y, K)
    g.prime(y0)
    assert np.allclose(g.step(y1, np.array([9.0])), K @ y0)


def test_from_state_space_is_the_papers_filter_50():
    f = LMIHInfFilter.from_state_space(0.5 * np.eye(2), 0.5 * np.eye(2), C_z=[[0.1, 0.1]])
    f.prime([1.0, 2.0])
    assert np.allclose(f.step([0.0, 0.0]), [0.5, 1.0])
    assert np.allclose(f.step([0.0, 0.0]), [0.25, 0.5])
    assert np.allclose(f.z, [0.075])


def test_bad_inputs_raise_and_leave_the_state_unchanged():
    s = _system2()
    f = LMIHInfFilter(s.A, s.C_y, np.ones((2, 2)))
    f.prime([1.0, 1.0])
    x = f.x.copy()
    with pytest.raises(ValueError, match="y must"):
        f.step([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="y must be finite"):
        f.step([np.nan, 1.0])
    assert np.array_equal(f.x, x) and f.t_s == 0
    with pytest.raises(ValueError, match="x0 must"):
        f.reset([1.0])
    with pytest.raises(ValueError, match="gain must"):
        LMIHInfFilter(s.A, s.C_y, np.ones((3, 2)))
    with pytest.raises(ValueError, match="feedthrough needs input_matrix"):
        LMIHInfFilter(s.A, s.C_y, np.ones((2, 2)), feedthrough=np.ones((2, 1)))
    with pytest.raises(ValueError, match="design has no gain"):
        LMIHInfFilter.from_design(s, design_lmi_hinf(s, 1e-9))
