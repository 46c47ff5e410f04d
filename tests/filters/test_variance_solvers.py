"""Structured solvers of the variance-constrained designs (Riccati mappings, monotone Newton,
continuation) on random systems of dimension 2-8, and the optimizer-based design search on the
parabolic-region example of Wang & Fang (2006), verified independently."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import solve_continuous_lyapunov, solve_discrete_are, solve_discrete_lyapunov

from filters.analysis import Parabola, UncertainPlant, unit_disk
from filters.matrix_equations import (
    continuation,
    newton_solve,
    solve_filter_dare,
    solve_linear_matrix_equation,
)
from filters.variance_constrained import is_positive_definite, passes, verify_design
from filters.variance_continuous import (
    ParabolicDesignParameters,
    design_parabolic,
    error_bound_residual,
    hat_terms,
    search_parabolic_design,
    solve_error_bound,
    solve_state_bound,
    state_bound_residual,
)
from filters.variance_discrete import (
    DiscreteDesignParameters,
    design_discrete,
    error_bound_residual_discrete,
    hat_terms_discrete,
    least_state_bound_discrete,
    solve_error_bound_discrete,
    solve_state_bound_discrete,
    state_bound_residual_discrete,
)

DIMS = (2, 4, 6, 8)
SYSTEMS_PER_DIM = 3


def random_plant(n: int, rng: np.random.Generator, *, discrete: bool) -> UncertainPlant:
    """Random plant with ``p = max(1, n // 2)`` measurements and a scalar uncertainty.

    Continuous: eigenvalues in [-2, -1] (inside the disk of (28) for a = 0.5, b = 0.2);
    discrete: magnitudes in [0.75, 0.95] (slow modes, for which ``Phi = Gamma A^T`` is well
    conditioned). Independent process and measurement noise, ``D2`` of full row rank.
    """
    p = max(1, n // 2)
    if discrete:
        lam = rng.choice([-1.0, 1.0], n) * rng.uniform(0.75, 0.95, n)
    else:
        lam = rng.uniform(-2.0, -1.0, n)
    V = np.linalg.qr(rng.standard_normal((n, n)))[0] + 0.2 * rng.standard_normal((n, n)) / n
    A = V @ np.diag(lam) @ np.linalg.inv(V)
    C = rng.standard_normal((p, n)) / math.sqrt(n)
    D1 = np.hstack([0.3 * rng.standard_normal((n, n)) / math.sqrt(n), np.zeros((n, p))])
    D2 = np.hstack([np.zeros((p, n)), 0.3 * np.eye(p)])
    M1 = 0.1 * rng.standard_normal((n, 1)) / math.sqrt(n)
    M2 = 0.1 * rng.standard_normal((p, 1))
    N = 0.1 * rng.standard_normal((1, n)) / math.sqrt(n)
    L = rng.standard_normal((1, n)) / math.sqrt(n)
    return UncertainPlant(A, C, D1, D2, M1, M2, N, L, discrete=discrete)


def _systems(discrete: bool):
    out = []
    for n in DIMS:
        rng = np.random.default_rng(1000 * n + int(discrete))
        out += [(n, k, random_plant(n, rng, discrete=discrete)) for k in range(SYSTEMS_PER_DIM)]
    return out


# ============================================================== building blocks
def test_linear_matrix_equation_matches_lyapunov():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((4, 4)) - 3 * np.eye(4)
    Q = rng.standard_normal((4, 4))
    Q = Q @ Q.T
    X = solve_linear_matrix_equation([(A, np.eye(4)), (np.eye(4), A)], -Q)
    np.testing.assert_allclose(X, solve_continuous_lyapunov(A, -Q), rtol=1e-10, atol=1e-12)
    B = 0.5 * rng.standard_normal((4, 4)) / 2
    Y = solve_linear_matrix_equation([(B, B), (-np.eye(4), np.eye(4))], -Q)
    np.testing.assert_allclose(Y, solve_discrete_lyapunov(B, Q), rtol=1e-9, atol=1e-12)


def test_filter_dare_with_indefinite_weight_matches_monotone_newton():
    """(11) as a DARE with R = -eps I equals the limit of the monotone Newton iteration."""
    rng = np.random.default_rng(1)
    A = 0.8 * np.linalg.qr(rng.standard_normal((3, 3)))[0]
    N = 0.4 * rng.standard_normal((1, 3))
    c = 0.1 * np.eye(3)
    eps = 1.0
    X = solve_filter_dare(A, N, c, -eps * np.eye(1))

    def fun(P):
        W = eps * np.eye(1) - N @ P @ N.T
        Xw = np.linalg.solve(W, N @ P)
        AT = A @ (np.eye(3) + Xw.T @ N)
        return A @ (P + (N @ P).T @ Xw) @ A.T - P + c, [(AT, AT), (-np.eye(3), np.eye(3))]

    out = newton_solve(fun, np.zeros((3, 3)), admissible=lambda P: True, tol=1e-13,
                       monotone=True)
    assert out.converged
    np.testing.assert_allclose(out.X, X, rtol=1e-9, atol=1e-12)


def test_continuation_reports_where_the_branch_ends():
    # x^2 theta - 2 x + 1 = 0 (scalar): solution from x = 1/2 at theta = 0, fold at theta = 1
    def fun(X, theta):
        x = X[0, 0]
        return (np.array([[theta * x * x - 2 * x + 1]]), [(np.array([[2 * theta * x - 2]]),
                                                            np.eye(1))], np.array([[x * x]]))

    ok = continuation(fun, [[0.5]], 0.5, admissible=lambda X: X[0, 0] > 0, tol=1e-13)
    assert ok.reached_target
    assert ok.X[0, 0] == pytest.approx((1 - math.sqrt(0.5)) / 0.5, rel=1e-10)
    end = continuation(fun, [[0.5]], 2.0, admissible=lambda X: X[0, 0] > 0, tol=1e-13)
    assert not end.reached_target and end.status == "branch_ended"
    assert 0.99 < end.theta_reached <= 1.0


# ============================================================== random systems
@pytest.mark.parametrize("n,k,plant", _systems(False), ids=lambda v: str(v)[:12])
def test_parabolic_design_on_random_systems(n, k, plant):
    """(16) and (17) solved; (17) at large gamma is the DARE of the disk mapping; Theorem 1's
    three claims verified for all F."""
    p = plant.p
    gamma = 1e3
    prm = ParabolicDesignParameters(0.5, 0.2, gamma, 0.5, 0.5, 1e-3, 1e-3, np.zeros((n, p)))
    d = design_parabolic(plant, prm, method="riccati")
    assert d.solved, d.message
    scale1, scale2 = max(1.0, np.linalg.norm(d.Q1)), max(1.0, np.linalg.norm(d.Q2))
    assert np.linalg.norm(state_bound_residual(d.Q1, plant, prm)) <= 1e-9 * scale1
    t = hat_terms(d.Q1, plant, prm)
    assert np.linalg.norm(error_bound_residual(d.Q2, plant, prm, t)) <= 1e-9 * scale2
    assert is_positive_definite(d.Q1) and is_positive_definite(d.Q2)
    # the mapping of (17) at gamma = inf onto scipy's DARE, written out here independently
    b, a, s = prm.b, prm.a, prm.s
    c = 1 / b - 2 * a
    Ab = math.sqrt(b) * t.A_hat + np.eye(n) / math.sqrt(b)
    Cb = math.sqrt(b) * t.C_hat
    dA, dC = plant.A - t.A_hat, plant.C - t.C_hat
    S = b * dA @ t.Gamma @ dC.T + s * plant.M1 @ plant.M2.T + plant.D1 @ plant.D2.T
    R = b * dC @ t.Gamma @ dC.T + s * plant.M2 @ plant.M2.T + plant.D2 @ plant.D2.T
    Q = (b * dA @ t.Gamma @ dA.T + s * plant.M1 @ plant.M1.T + plant.D1 @ plant.D1.T
         + prm.delta2 * np.eye(n))
    X = solve_discrete_are(Ab.T / math.sqrt(c), Cb.T / math.sqrt(c), Q / c, R / c, s=S / c)
    prm_inf = replace(prm, gamma=1e150)
    assert np.linalg.norm(error_bound_residual(X, plant, prm_inf, t)) <= 1e-8 * scale2
    # gamma = 1e3 only perturbs it by O(gamma^-2 ||Q2||^2 ||L||^2)
    np.testing.assert_allclose(d.Q2, X, atol=1e-4 * scale2 * (1 + np.linalg.norm(X)))
    ra = verify_design(plant, d.G, d.K, region=Parabola(prm.a, prm.b), gamma=gamma,
                       sigma2=np.diag(d.Q2), n_grid=5)
    assert passes(ra)
    for P in ra.covariances:  # P < Q2 for every F
        assert np.linalg.eigvalsh(d.Q2 - P).min() > 0


@pytest.mark.parametrize("n,k,plant", _systems(True), ids=lambda v: str(v)[:12])
def test_discrete_design_on_random_systems(n, k, plant):
    """(11) and (12r) solved and equal to scipy's DARE of their mappings (written out here);
    the three requirements verified for all F."""
    p, q = plant.p, plant.L.shape[0]
    prm = DiscreteDesignParameters(100.0, 5.0, 1e-3, 1e-3, np.zeros((n, p)))
    d = design_discrete(plant, prm, method="riccati")
    assert d.solved, d.message
    scale = max(1.0, np.linalg.norm(d.Q2))
    # (11): DARE with C = N, R = -eps I
    c11 = (prm.eps * plant.M1 @ plant.M1.T + plant.D1 @ plant.D1.T + prm.delta1 * np.eye(n))
    P1 = solve_discrete_are(plant.A.T, plant.N.T, c11, -prm.eps * np.eye(1))
    np.testing.assert_allclose(d.Q1, P1, rtol=1e-8, atol=1e-10)
    residual = np.linalg.norm(state_bound_residual_discrete(d.Q1, plant, prm))
    assert residual <= 1e-9 * max(1.0, np.linalg.norm(P1))
    # (12r): DARE with C = [L; C_hat], R = diag(-gamma^2 I, R0), S = [0, S0]
    t = hat_terms_discrete(d.Q1, plant, prm)
    dA, dC, e = plant.A - t.A_hat, plant.C - t.C_hat, prm.eps
    S0 = dA @ t.Gamma @ dC.T + e * plant.M1 @ plant.M2.T + plant.D1 @ plant.D2.T
    R0 = dC @ t.Gamma @ dC.T + e * plant.M2 @ plant.M2.T + plant.D2 @ plant.D2.T
    Q0 = (dA @ t.Gamma @ dA.T + e * plant.M1 @ plant.M1.T + plant.D1 @ plant.D1.T
          + prm.delta2 * np.eye(n))
    W = np.vstack([plant.L, t.C_hat])
    Rw = np.block([[-prm.gamma**2 * np.eye(q), np.zeros((q, p))], [np.zeros((p, q)), R0]])
    P2 = solve_discrete_are(t.A_hat.T, W.T, Q0, Rw, s=np.hstack([np.zeros((n, q)), S0]))
    np.testing.assert_allclose(d.Q2, P2, rtol=1e-7, atol=1e-9 * scale)
    assert np.linalg.norm(error_bound_residual_discrete(d.Q2, plant, prm, t)) <= 1e-9 * scale
    ra = verify_design(plant, d.G, d.K, region=unit_disk(), gamma=prm.gamma,
                       sigma2=np.diag(d.Q2), n_grid=5)
    assert passes(ra)
    for P in ra.covariances:
        assert np.linalg.eigvalsh(d.Q2 - P).min() > 0


def _design_random(n: int, k: int, discrete: bool):
    """Plant ``k`` of the seeded sequence of dimension ``n`` (as :func:`_systems` draws them)
    and its design with the parameters of the two tests above."""
    rng = np.random.default_rng(1000 * n + int(discrete))
    for _ in range(k + 1):
        plant = random_plant(n, rng, discrete=discrete)
    p = plant.p
    if discrete:
        prm = DiscreteDesignParameters(100.0, 5.0, 1e-3, 1e-3, np.zeros((n, p)))
        return plant, prm, design_discrete(plant, prm, method="riccati")
    prm = ParabolicDesignParameters(0.5, 0.2, 1e3, 0.5, 0.5, 1e-3, 1e-3, np.zeros((n, p)))
    return plant, prm, design_parabolic(plant, prm, method="riccati")


@pytest.mark.parametrize("n,k,discrete,reason", [
    (3, 3, False, "branch from gamma = inf ends"),
    (3, 4, False, "continuation reached gamma = 1000 but the residual is"),
    (2, 7, True, "the stabilizing solution is not admissible"),
])
def test_random_draws_without_a_design_say_why(n, k, discrete, reason):
    """Draws outside the three per even dimension above (found by the all-dimension sweep
    below): no design, and the reason, never a silent or unverified one."""
    _, _, d = _design_random(n, k, discrete)
    assert not d.solved and reason in d.message, d.message


@pytest.mark.slow
@pytest.mark.parametrize("discrete", [False, True], ids=["parabolic", "discrete"])
def test_random_systems_of_every_dimension(discrete):
    """30 plants per dimension 2-8: every solved design passes the three requirements for
    all F, every failure is a result with its reason, and at least 90 % are solved (199 and
    198 of 210 when this was written)."""
    solved = 0
    for n in range(2, 9):
        for k in range(30):
            plant, prm, d = _design_random(n, k, discrete)
            if not d.solved:
                assert d.message and ("(17)" in d.message or "(12r)" in d.message), d.message
                continue
            solved += 1
            region = unit_disk() if discrete else Parabola(prm.a, prm.b)
            ra = verify_design(plant, d.G, d.K, region=region, gamma=prm.gamma,
                               sigma2=np.diag(d.Q2), n_grid=5)
            assert passes(ra), (n, k)
    assert solved >= 189, solved


def test_solver_failures_are_results_with_reasons():
    rng = np.random.default_rng(7)
    plant = random_plant(3, rng, discrete=False)
    prm = ParabolicDesignParameters(0.5, 0.2, 1e-4, 0.5, 0.5, 1e-3, 1e-3, np.zeros((3, 1)))
    eq1 = solve_state_bound(plant, prm)
    assert eq1.solved and eq1.method == "monotone-newton"
    eq2 = solve_error_bound(plant, prm, hat_terms(eq1.X, plant, prm))
    assert not eq2.solved and eq2.status == "branch_ended" and "ends" in eq2.message
    # A outside the disk of (28): no Q1 > 0, said so
    fast = replace(plant, A=plant.A - 20 * np.eye(3))
    bad = solve_state_bound(fast, prm)
    assert not bad.solved and bad.status == "unstable_derivative"
    # (11) without solution (eps too small for N): the monotone iteration decides
    dplant = random_plant(3, rng, discrete=True)
    dprm = DiscreteDesignParameters(1.0, 1e-6, 1e-3, 1e-3, np.zeros((3, 1)))
    out = solve_state_bound_discrete(dplant, dprm)
    assert not out.solved and out.status in ("left_admissible_set", "unstable_derivative")
    assert least_state_bound_discrete(dplant, dprm)[0] is None
    ok = solve_state_bound_discrete(dplant, replace(dprm, eps=1.0))
    assert ok.solved and ok.method == "dare"
    t = hat_terms_discrete(ok.X, dplant, replace(dprm, eps=1.0))
    tight = solve_error_bound_discrete(dplant, replace(dprm, eps=1.0, gamma=1e-4), t,
                              find_gamma_reached=True)
    assert not tight.solved and tight.details["gamma_reached"] > 1e-4
    at = solve_error_bound_discrete(dplant, replace(dprm, eps=1.0,
                                           gamma=1.01 * tight.details["gamma_reached"]), t)
    assert at.solved


# ============================================================== parabolic example
def _example():
    plant = UncertainPlant([[-2.5, 0.3], [0.4, -1.5]], [[0.1, 0.1]], 0.1 * np.eye(2),
                           [[0.6, 0.2]], [[0.8], [0.8]], [[0.8]], [[0.1, 0.1]], [[0.1, 0.1]])
    prm = ParabolicDesignParameters(0.5, 0.5, 0.1, 0.58, 0.58, 0.01, 0.01, [[0.1], [0.1]])
    return plant, prm, np.array([0.3, 0.7])


def _independent_check(plant, G, K, a, b, gamma, sigma2):
    """Eigenvalues over a grid of F in P(a, b), Lyapunov variances, H-infinity norm by a dense
    frequency sweep; all written here without the analysis toolkit."""
    n = plant.n
    worst_h, worst_var, margin = 0.0, np.zeros(n), math.inf
    for F in np.linspace(-1.0, 1.0, 41):
        A = plant.A + plant.M1 @ [[F]] @ plant.N
        C = plant.C + plant.M2 @ [[F]] @ plant.N
        Af = np.block([[A, np.zeros((n, n))], [A - G - K @ C, G]])
        Df = np.vstack([plant.D1, plant.D1 - K @ plant.D2])
        Cf = np.hstack([np.zeros((1, n)), plant.L])
        lam = np.linalg.eigvals(Af)
        # P(a, b): Im^2 <= -(2 / b)(Re + a)
        margin = min(margin, float(np.min(-(2 / b) * (lam.real + a) - lam.imag**2)))
        X = solve_continuous_lyapunov(Af, -Df @ Df.T)
        worst_var = np.maximum(worst_var, np.diag(X[n:, n:]))
        w = np.concatenate([[0.0], np.geomspace(1e-3, 1e3, 3000)])
        resp = [np.linalg.norm(Cf @ np.linalg.solve(1j * wi * np.eye(2 * n) - Af, Df), 2)
                for wi in w]
        worst_h = max(worst_h, float(np.max(resp)))
    return margin, worst_h, worst_var


def test_parabolic_example_search_finds_a_verified_design():
    plant, prm, s2 = _example()
    rec = search_parabolic_design(plant, prm, s2, n_starts=3, seed=0, max_evaluations=150,
                                  n_grid=11)
    assert rec.candidates[0].start == 0 and rec.candidates[0].parameters["eps1"] == 0.58
    assert not rec.candidates[0].solved  # the printed eps: (17) has no solution on the branch
    assert rec.found and rec.verification is not None
    d = rec.design
    assert d.solved and d.residual_1 < 1e-9 and d.residual_2 < 1e-9
    margin, h, var = _independent_check(plant, d.G, d.K, prm.a, prm.b, prm.gamma, s2)
    assert margin > 0
    assert h <= prm.gamma
    assert np.all(var <= s2)
    # the analysis toolkit and the independent computation agree
    assert h == pytest.approx(rec.verification.hinf_worst, rel=1e-3)
    np.testing.assert_allclose(var, rec.verification.variance_worst, rtol=1e-6)
    js = rec.to_dict()
    assert js["found"] and len(js["candidates"]) == len(rec.candidates)


@pytest.mark.slow
def test_parabolic_example_full_search():
    plant, prm, s2 = _example()
    rec = search_parabolic_design(plant, prm, s2, n_starts=8, seed=0)
    assert rec.found and sum(c.verified for c in rec.candidates) >= 2
    d = rec.design
    margin, h, var = _independent_check(plant, d.G, d.K, prm.a, prm.b, prm.gamma, s2)
    assert margin > 0 and h <= prm.gamma and np.all(var <= s2)
