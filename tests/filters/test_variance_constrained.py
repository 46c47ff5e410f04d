"""Variance-constrained designs: equation solvers, Wang & Fang Theorem 1, Liu, Deng & Wang
(reconstructed), the constant-gain filter."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import expm, solve_continuous_are, solve_discrete_are

from filters import zoh
from filters.analysis import (
    Parabola,
    UncertainPlant,
    error_system,
    robust_filter_analysis,
    unit_disk,
)
from filters.errors import FiniteEscapeError
from filters.variance_constrained import (
    LinearFilter,
    is_positive_definite,
    solve_symmetric_equation,
    verify_design,
)
from filters.variance_continuous import (
    ParabolicDesignParameters,
    design_parabolic,
    error_bound_margin,
    error_bound_residual,
    hat_terms,
    search_parabolic,
    state_bound_residual,
)
from filters.variance_discrete import (
    DiscreteDesignParameters,
    delta1_threshold,
    design_discrete,
    least_state_bound_discrete,
    p_gamma,
    state_bound_residual_discrete,
)


# ============================================================== the generic solver
def test_solver_finds_the_care_solution():
    A = np.array([[0.0, 1.0], [-2.0, -0.5]])
    B = np.array([[0.0], [1.0]])
    Q = np.diag([1.0, 0.5])
    R = np.array([[0.3]])
    X_ref = solve_continuous_are(A, B, Q, R)

    def care(X):
        return A.T @ X + X @ A - X @ B @ np.linalg.solve(R, B.T) @ X + Q

    sol = solve_symmetric_equation(care, 2, tol=1e-11)
    assert sol.solved and sol.residual <= 1e-11
    # the stabilizing solution is the only positive definite one
    np.testing.assert_allclose(sol.X, X_ref, rtol=1e-9)


def test_solver_finds_the_dare_solution():
    A = np.array([[1.1, 0.3], [0.0, 0.7]])
    C = np.array([[1.0, 0.0]])
    Q = 0.1 * np.eye(2)
    R = np.array([[0.2]])
    P_ref = solve_discrete_are(A.T, C.T, Q, R)

    def dare(P):
        S = C @ P @ C.T + R
        return A @ P @ A.T - P - A @ P @ C.T @ np.linalg.solve(S, C @ P @ A.T) + Q

    sol = solve_symmetric_equation(dare, 2)
    assert sol.solved
    assert any(np.allclose(S, P_ref, rtol=1e-8) for S in sol.solutions)


def test_solver_reports_smallest_residual_without_solution():
    # X^2 + I = 0 has no real solution: the smallest residual over X > 0 is ||I|| = sqrt(2)
    sol = solve_symmetric_equation(lambda X: X @ X + np.eye(2), 2)
    assert not sol.solved
    assert np.isfinite(sol.residual) and sol.residual == pytest.approx(np.sqrt(2), rel=1e-3)
    assert sol.X is not None and is_positive_definite(sol.X)
    assert "smallest residual" in sol.message
    assert sol.to_dict()["solved"] is False


def test_solver_respects_admissible_set():
    # X^2 - diag(1, 4) = 0 has PD solution diag(1, 2); restricting to X < 1.5 I excludes it
    def f(X):
        return X @ X - np.diag([1.0, 4.0])

    assert solve_symmetric_equation(f, 2).solved

    def adm(X):
        return is_positive_definite(X) and is_positive_definite(1.5 * np.eye(2) - X)

    sol = solve_symmetric_equation(f, 2, admissible=adm)
    assert not sol.solved and adm(sol.X)


# ============================================================== Wang & Fang (2006)
def _p2_plant() -> UncertainPlant:
    """A two-measurement plant (p = n = 2) so that any H H^T can be realized."""
    A = np.array([[-3.0, 0.5], [0.2, -2.5]])
    C = np.array([[1.0, 0.0], [0.3, 1.0]])
    return UncertainPlant(A, C, np.eye(2), [[0.2, 0.0], [0.0, 0.2]], [[0.1], [0.05]],
                          [[0.1], [0.0]], [[0.2, 0.1]], [[1.0, 0.0]])


def test_parabolic_equations_with_a_known_solution():
    """Build D1 and H so that chosen Q1*, Q2* solve (16), (17); the solvers must find them."""
    base = _p2_plant()
    prm = ParabolicDesignParameters(0.5, 0.1, 2.0, 1.0, 1.0, 0.01, 0.01, np.zeros((2, 2)))
    Q1 = np.array([[0.2, 0.02], [0.02, 0.3]])
    rest = state_bound_residual(Q1, replace_D1(base, np.zeros((2, 2))), prm)
    D1 = np.linalg.cholesky(-rest)  # -(rest) must be PD for this construction
    plant = replace_D1(base, D1)
    np.testing.assert_allclose(state_bound_residual(Q1, plant, prm), 0, atol=1e-13)
    Q2 = np.diag([0.05, 0.08])
    t = hat_terms(Q1, plant, prm)
    S = error_bound_residual(Q2, plant, prm, t)  # H = 0
    H = np.linalg.cholesky(-S)
    prm_h = replace(prm, H=H)
    np.testing.assert_allclose(error_bound_residual(Q2, plant, prm_h, t), 0, atol=1e-13)

    d = design_parabolic(plant, prm_h, n_random=10)
    assert any(np.allclose(S1, Q1, atol=1e-9) for S1 in d.equation_1.solutions)
    assert d.solved
    if np.allclose(d.Q1, Q1, atol=1e-9):
        np.testing.assert_allclose(d.Q2, Q2, atol=1e-9)


def replace_D1(plant: UncertainPlant, D1: np.ndarray) -> UncertainPlant:
    return UncertainPlant(plant.A, plant.C, D1, plant.D2, plant.M1, plant.M2, plant.N,
                          plant.L)


def _feasible_continuous():
    plant = UncertainPlant([[-3.0, 0.5], [0.0, -2.0]], [[1.0, 0.5]], 0.1 * np.eye(2),
                           [[0.2, 0.1]], [[0.1], [0.1]], [[0.1]], [[0.2, 0.2]], [[1.0, 0.0]])
    prm = ParabolicDesignParameters(0.5, 0.1, 0.2, 1.0, 1.0, 0.01, 0.01,
                                    0.01 * np.ones((2, 1)))
    return plant, prm


def _psi_continuous(plant, prm, d):
    """Psi of (21)-(24) computed from its definition with the designed K, G."""
    n = plant.n
    Q = np.zeros((2 * n, 2 * n))
    Q[:n, :n], Q[n:, n:] = d.Q1, d.Q2
    Af, Df, Cf = error_system(plant, d.G, d.K, None)
    Mf = np.vstack([plant.M1, plant.M1 - d.K @ plant.M2])
    Nf = np.hstack([plant.N, np.zeros_like(plant.N)])
    Gam = np.linalg.inv(np.linalg.inv(d.Q1) - plant.N.T @ plant.N / prm.eps1)
    blk = np.zeros_like(Q)
    blk[:n, :n], blk[n:, n:] = Gam, d.Q2
    Aa = Af + prm.a * np.eye(2 * n)
    return (prm.b * Af @ blk @ Af.T + prm.s * Mf @ Mf.T + Aa @ Q + Q @ Aa.T
            + Q @ Nf.T @ Nf @ Q / prm.eps2 + Q @ Cf.T @ Cf @ Q / prm.gamma**2 + Df @ Df.T)


@pytest.mark.parametrize("U", [1.0, -1.0])
def test_parabolic_theorem1_guarantees_hold(U):
    plant, prm = _feasible_continuous()
    prm = replace(prm, U=np.array([[U]]))
    d = design_parabolic(plant, prm, sigma2=[0.1, 0.1])
    assert d.solved and d.variance_bounds_met
    assert d.residual_1 < 1e-10 and d.residual_2 < 1e-10
    # the corrected derivation: Psi = diag(-delta1 I, -delta2 I) exactly
    np.testing.assert_allclose(_psi_continuous(plant, prm, d),
                               np.diag([-prm.delta1] * 2 + [-prm.delta2] * 2), atol=1e-10)
    ra = robust_filter_analysis(plant, d.G, d.K, region=Parabola(prm.a, prm.b),
                                gamma=prm.gamma, sigma2=np.diag(d.Q2), n_grid=11)
    assert ra.poles_in_region and ra.hinf_worst <= prm.gamma
    # P < Q2 for every F (the theorem's third claim)
    for P in ra.covariances:
        assert np.linalg.eigvalsh(d.Q2 - P).min() > 0
    # the poles even lie in the disk of (28)
    disk = Parabola(prm.a, prm.b).proof_disk()
    for F in (-1.0, 0.0, 1.0):
        assert disk.contains(np.linalg.eigvals(error_system(plant, d.G, d.K, F)[0]))
    d_dict = d.to_dict()
    assert {"solved", "Q1", "Q2", "residual_16", "residual_17", "K", "G"} <= set(d_dict)


def test_parabolic_printed_example_is_a_result_not_a_crash():
    plant = UncertainPlant([[-2.5, 0.3], [0.4, -1.5]], [[0.1, 0.1]], 0.1 * np.eye(2),
                           [[0.6, 0.2]], [[0.8], [0.8]], [[0.8]], [[0.1, 0.1]], [[0.1, 0.1]])
    prm = ParabolicDesignParameters(0.5, 0.5, 0.1, 0.58, 0.58, 0.01, 0.01, [[0.1], [0.1]])
    d = design_parabolic(plant, prm, sigma2=[0.3, 0.7], n_random=2)
    assert d.equation_1.solved  # (16) is solvable
    np.testing.assert_allclose(d.Q1, [[0.72311779, 0.59709297], [0.59709297, 0.94123361]],
                               atol=1e-7)
    assert not d.solved and d.K is None and d.G is None
    assert 0.4 < d.residual_2 < 0.5  # smallest residual reached, finite
    margin, _ = error_bound_margin(plant, prm, d.Q1)
    assert margin > 0.4  # no H can make (17) solvable for this Q1
    js = d.to_dict()
    assert js["K"] is None and np.isfinite(js["residual_17"])


def test_parabolic_search_finds_the_feasible_design():
    plant, prm = _feasible_continuous()
    s = search_parabolic(plant, prm, [0.1, 0.1], eps1_values=[0.3, 1.0],
                         eps2_values=[1.0], h_scales=[0.0, 1.0], n_grid=5)
    assert s.found and s.verification is not None and s.tried == 4
    assert s.design.variance_bounds_met
    assert s.to_dict()["design"]["solved"] is True


def test_parabolic_parameter_validation():
    with pytest.raises(ValueError, match="gamma must"):
        ParabolicDesignParameters(0.5, 0.5, -1.0, 1, 1, 0.01, 0.01, [[0.1], [0.1]])
    with pytest.raises(ValueError, match="orthogonal"):
        ParabolicDesignParameters(0.5, 0.5, 1.0, 1, 1, 0.01, 0.01, [[0.1], [0.1]], [[2.0]])
    plant, prm = _feasible_continuous()
    with pytest.raises(ValueError, match="H must have shape"):
        design_parabolic(plant, replace(prm, H=np.zeros((3, 1))))


# ============================================================== Liu, Deng & Wang
def _discrete_plant() -> UncertainPlant:
    return UncertainPlant([[0.8, 0.05], [-0.08, -0.5]], [[1.0, 0.0]], 0.1 * np.eye(2),
                          [[0.1, 0.08]], [[0.1], [0.08]], [[0.1]], [[0.5, 0.5]],
                          [[0.01, 0.01]], discrete=True)


def test_discrete_least_solution_and_threshold():
    plant = _discrete_plant()
    ok = DiscreteDesignParameters(0.012, 1.89, 0.01, 0.01, np.zeros((2, 1)))
    P1, _, msg = least_state_bound_discrete(plant, ok)
    assert P1 is not None and "least solution" in msg
    np.testing.assert_allclose(state_bound_residual_discrete(P1, plant, ok), 0, atol=1e-11)
    bad = replace(ok, delta1=0.31)  # the printed value
    assert least_state_bound_discrete(plant, bad)[0] is None
    thr = delta1_threshold(plant, bad)
    assert 0.29 < thr < 0.31
    assert least_state_bound_discrete(plant, replace(ok, delta1=0.99 * thr))[0] is not None


def test_discrete_reconstructed_theorem_guarantees_hold():
    plant = _discrete_plant()
    prm = DiscreteDesignParameters(0.012, 1.89, 0.01, 0.01, np.zeros((2, 1)))
    d = design_discrete(plant, prm, sigma2=[0.02, 0.076])
    assert d.solved and d.variance_bounds_met
    n = 2
    # Psi = A_f diag(Gamma, P_gamma) A_f^T + eps M_f M_f^T - P + D_f D_f^T = -diag(delta)
    Af, Df, _ = error_system(plant, d.G, d.K, None)
    Mf = np.vstack([plant.M1, plant.M1 - d.K @ plant.M2])
    Gam = np.linalg.inv(np.linalg.inv(d.Q1) - plant.N.T @ plant.N / prm.eps)
    blk = np.zeros((2 * n, 2 * n))
    blk[:n, :n], blk[n:, n:] = Gam, p_gamma(d.Q2, plant.L, prm.gamma)
    P = np.zeros_like(blk)
    P[:n, :n], P[n:, n:] = d.Q1, d.Q2
    Psi = Af @ blk @ Af.T + prm.eps * Mf @ Mf.T - P + Df @ Df.T
    np.testing.assert_allclose(Psi, -0.01 * np.eye(4), atol=1e-10)
    ra = verify_design(plant, d.G, d.K, region=unit_disk(), gamma=prm.gamma,
                       sigma2=[0.02, 0.076], n_grid=11)
    assert ra.all_stable and ra.hinf_worst < prm.gamma
    for Pe in ra.covariances:
        assert np.linalg.eigvalsh(d.Q2 - Pe).min() > 0


def test_discrete_printed_values_report_failure():
    plant = _discrete_plant()
    prm = DiscreteDesignParameters(0.012, 1.89, 0.31, 0.31, np.zeros((2, 1)))
    d = design_discrete(plant, prm, n_random=2)
    assert not d.solved and d.residual_2 is None and np.isfinite(d.residual_1)
    assert "monotone iteration" in d.message
    with pytest.raises(ValueError, match="discrete"):
        design_discrete(UncertainPlant(plant.A, plant.C, plant.D1, plant.D2, plant.M1,
                                       plant.M2, plant.N, plant.L), prm)


# ============================================================== the filter
def test_linear_filter_discrete_and_batch():
    G = np.array([[0.5, 0.1], [0.0, 0.3]])
    K = np.array([[1.0], [0.5]])
    f = LinearFilter(G, K, np.zeros(2), discrete=True)
    assert f.name == "linear-gain" and f.P is None and f.t_s == 0.0
    x1 = f.step([2.0])
    np.testing.assert_allclose(x1, K[:, 0] * 2.0)
    np.testing.assert_allclose(f.step(np.array([1.0])), G @ x1 + K[:, 0])
    assert f.t_s == 2.0
    fb = LinearFilter(G, K, np.zeros((3, 2)), discrete=True, covariance=np.eye(2))
    out = fb.step(np.array([[1.0], [2.0], [3.0]]))
    np.testing.assert_allclose(out[2], 3 * K[:, 0])
    assert fb.P.shape == (3, 2, 2)
    with pytest.raises(ValueError, match="y must"):
        fb.step(np.ones((2, 1)))
    with pytest.raises(ValueError, match="u must be None"):
        f.step([1.0], u=[1.0])
    before = f.x.copy()
    with pytest.raises(ValueError):
        f.step([np.nan])
    np.testing.assert_array_equal(f.x, before)
    f.reset(np.ones(2), P0=2 * np.eye(2))
    np.testing.assert_array_equal(f.x, np.ones(2))
    np.testing.assert_array_equal(f.P, 2 * np.eye(2))


def test_linear_filter_continuous_is_exact_zoh():
    G = np.array([[-2.0, 0.3], [0.1, -1.0]])
    K = np.array([[0.4], [0.2]])
    B = np.array([[1.0], [0.0]])
    dt = 0.1
    f = LinearFilter(G, K, [1.0, -1.0], discrete=False, dt_s=dt, B=B)
    Phi, Gam = zoh(G, np.hstack([K, B]), dt)
    np.testing.assert_allclose(f.step([0.5], u=[2.0]), Phi @ [1.0, -1.0] + Gam @ [0.5, 2.0])
    np.testing.assert_allclose(Phi, expm(G * dt))
    assert f.t_s == pytest.approx(dt)
    with pytest.raises(ValueError, match="dt_s must be given"):
        LinearFilter(G, K, [0.0, 0.0], discrete=False)
    huge = LinearFilter(np.eye(1) * 1e300, np.ones((1, 1)), [1e300], discrete=True)
    with pytest.raises(FiniteEscapeError):
        huge.step([0.0])
