"""filters.analysis: H-infinity norms, Lyapunov covariances, pole regions, robustness over F."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.optimize import minimize_scalar

from filters._linalg import van_loan
from filters.analysis import (
    Disk,
    LeftHalfPlane,
    Parabola,
    UncertainPlant,
    UnstableSystemError,
    error_covariance,
    error_system,
    hinf_norm,
    hinf_norm_bounds,
    poles_in_region,
    robust_filter_analysis,
    sigma_max_response,
    steady_state_covariance,
    uncertainty_samples,
    unit_disk,
)


# ------------------------------------------------------------------ random systems
def _random_stable(rng: np.random.Generator, n: int, m: int, p: int, discrete: bool,
                   with_d: bool) -> tuple[np.ndarray, ...]:
    A = rng.standard_normal((n, n))
    if discrete:
        A *= rng.uniform(0.3, 0.97) / max(np.abs(np.linalg.eigvals(A)))
    else:
        A -= (max(np.linalg.eigvals(A).real) + rng.uniform(0.05, 1.0)) * np.eye(n)
    B = rng.standard_normal((n, m))
    C = rng.standard_normal((p, n))
    D = rng.standard_normal((p, m)) * 0.3 if with_d else np.zeros((p, m))
    return A, B, C, D


def _sweep_norm(A, B, C, D, discrete: bool) -> float:
    """Dense sweep plus a local refinement around its best point."""
    if discrete:
        w = np.linspace(0.0, np.pi, 4001)
    else:
        scale = max(np.abs(np.linalg.eigvals(A)).max(), 1e-3)
        w = np.concatenate([[0.0], np.geomspace(1e-4, 1e4, 6000) * scale])
    s = sigma_max_response(A, B, C, D, w, discrete=discrete)
    k = int(np.argmax(s))
    lo, hi = w[max(k - 1, 0)], w[min(k + 1, len(w) - 1)]
    best = float(s[k])
    if hi > lo:
        res = minimize_scalar(lambda x: -sigma_max_response(A, B, C, D, [x],
                                                            discrete=discrete)[0],
                              bounds=(lo, hi), method="bounded",
                              options={"xatol": 1e-12 * max(hi, 1.0)})
        best = max(best, -float(res.fun))
    if not discrete:
        best = max(best, float(np.linalg.norm(D, 2)))
    return best


@pytest.mark.parametrize("discrete", [False, True])
def test_hinf_norm_matches_dense_sweep_on_random_systems(discrete):
    rng = np.random.default_rng(7 if discrete else 3)
    for trial in range(12):
        n, m, p = rng.integers(1, 6), rng.integers(1, 4), rng.integers(1, 4)
        A, B, C, D = _random_stable(rng, int(n), int(m), int(p), discrete, trial % 2 == 1)
        r = hinf_norm_bounds(A, B, C, D, discrete=discrete, rtol=1e-7)
        sweep = _sweep_norm(A, B, C, D, discrete)
        assert r.stable and r.lower <= r.value <= r.upper
        assert r.upper - r.lower <= 1e-7 * r.lower
        # the sweep is a lower bound; the bisection must not exceed the true peak
        assert sweep <= r.upper * (1 + 1e-9), (trial, sweep, r)
        assert r.lower <= sweep * (1 + 1e-6), (trial, sweep, r)
        assert abs(r.value - sweep) <= 2e-6 * sweep, (trial, sweep, r)


def test_hinf_norm_closed_forms():
    # 1 / (s + a): peak 1/a at w = 0
    assert hinf_norm([[-2.0]], [[1.0]], [[1.0]]) == pytest.approx(0.5, rel=1e-6)
    # lightly damped second order: peak 1 / (2 zeta sqrt(1 - zeta^2)) / wn^2
    wn, zeta = 3.0, 0.05
    A = [[0.0, 1.0], [-wn**2, -2 * zeta * wn]]
    r = hinf_norm_bounds(A, [[0.0], [1.0]], [[1.0, 0.0]], rtol=1e-9)
    exact = 1.0 / (2 * zeta * math.sqrt(1 - zeta**2)) / wn**2
    assert r.value == pytest.approx(exact, rel=1e-8)
    assert r.peak_frequency == pytest.approx(wn * math.sqrt(1 - 2 * zeta**2), rel=1e-4)
    # discrete 1 / (z - 0.5): peak at z = 1, value 2; 1 / (z + 0.5): peak at z = -1
    assert hinf_norm([[0.5]], [[1.0]], [[1.0]], discrete=True) == pytest.approx(2.0, rel=1e-6)
    r = hinf_norm_bounds([[-0.5]], [[1.0]], [[1.0]], discrete=True)
    assert r.value == pytest.approx(2.0, rel=1e-6) and r.peak_frequency == pytest.approx(np.pi)
    # feedthrough only / zero system
    assert hinf_norm([[-1.0]], [[0.0]], [[1.0]], [[0.7]]) == pytest.approx(0.7)
    assert hinf_norm([[-1.0]], [[1.0]], [[0.0]]) == 0.0


def test_hinf_norm_unstable_is_inf_and_validation():
    assert hinf_norm([[0.1]], [[1.0]], [[1.0]]) == math.inf
    assert hinf_norm([[1.2]], [[1.0]], [[1.0]], discrete=True) == math.inf
    assert hinf_norm_bounds([[0.0]], [[1.0]], [[1.0]]).stable is False
    with pytest.raises(ValueError, match="B must"):
        hinf_norm([[-1.0]], [[1.0, 2.0], [3.0, 4.0]], [[1.0]])
    with pytest.raises(ValueError, match="rtol"):
        hinf_norm([[-1.0]], [[1.0]], [[1.0]], rtol=0.0)


def test_hinf_norm_against_python_control():
    control = pytest.importorskip("control", reason="python-control not installed")
    pytest.importorskip("slycot", reason="slycot (python-control's H-infinity backend) "
                                         "not installed")
    rng = np.random.default_rng(11)
    for discrete in (False, True):
        A, B, C, D = _random_stable(rng, 4, 2, 3, discrete, True)
        sys = control.ss(A, B, C, D, 1.0 if discrete else 0)
        ref = control.linfnorm(sys)[0]
        assert hinf_norm(A, B, C, D, discrete=discrete, rtol=1e-8) == pytest.approx(ref,
                                                                                   rel=1e-6)


# ------------------------------------------------------------------ Lyapunov / Monte Carlo
def test_steady_state_covariance_against_monte_carlo():
    rng = np.random.default_rng(5)
    A = np.array([[-1.0, 2.0], [-0.5, -1.5]])
    B = np.array([[1.0, 0.0], [0.3, 0.5]])
    X = steady_state_covariance(A, B)
    np.testing.assert_allclose(A @ X + X @ A.T + B @ B.T, 0, atol=1e-12)
    # exact sampling of dx = A x dt + B dW, independent chains from 0
    dt, steps, N = 0.05, 300, 20000
    Ad, Qd = expm(A * dt), van_loan(A, B @ B.T, dt)
    S = np.linalg.cholesky(Qd)
    x = np.zeros((N, 2))
    for _ in range(steps):
        x = x @ Ad.T + rng.standard_normal((N, 2)) @ S.T
    emp = x.T @ x / N
    se = np.sqrt((np.outer(np.diag(X), np.diag(X)) + X**2) / N)
    assert np.all(np.abs(emp - X) < 5 * se), (emp, X, se)

    Ad = np.array([[0.8, 0.3], [-0.2, 0.5]])
    Bd = np.array([[0.2, 0.1], [0.0, 0.3]])
    Xd = steady_state_covariance(Ad, Bd, discrete=True)
    np.testing.assert_allclose(Ad @ Xd @ Ad.T + Bd @ Bd.T, Xd, atol=1e-14)
    x = np.zeros((N, 2))
    for _ in range(150):
        x = x @ Ad.T + rng.standard_normal((N, 2)) @ Bd.T
    emp = x.T @ x / N
    se = np.sqrt((np.outer(np.diag(Xd), np.diag(Xd)) + Xd**2) / N)
    assert np.all(np.abs(emp - Xd) < 5 * se)


def test_steady_state_covariance_unstable_raises():
    with pytest.raises(UnstableSystemError, match="Hurwitz") as info:
        steady_state_covariance([[0.5]], [[1.0]])
    assert info.value.eigenvalues[0] == pytest.approx(0.5)
    with pytest.raises(UnstableSystemError, match="Schur"):
        steady_state_covariance([[1.0]], [[1.0]], discrete=True)


# ------------------------------------------------------------------ regions
def test_parabola_region_fact1():
    P = Parabola(0.5, 0.5)
    # vertex at -a, boundary Im^2 = -(2/b)(Re + a) included (closed)
    assert P.contains([-0.5 + 0j])
    assert P.contains([-1.5 + 2j])  # 4 <= -4 (-1) = 4: on the boundary
    assert not P.contains([-1.5 + 2.01j])
    assert not P.contains([-0.4 + 0j])
    assert not P.contains([-3 + 5j])
    assert P.margin([-2.5 + 1j]) == pytest.approx(4 * 2.0 - 1.0)
    # (28)'s disk lies inside the parabola
    disk = P.proof_disk()
    assert complex(disk.center) == -2.0 and disk.radius == pytest.approx(math.sqrt(2.0))
    th = np.linspace(0, 2 * np.pi, 400)
    rim = -2.0 + 0.999 * disk.radius * np.exp(1j * th)
    assert disk.contains(rim) and P.contains(rim)
    with pytest.raises(ValueError, match="a must"):
        Parabola(0.0, 1.0)


def test_half_plane_and_disks():
    lhp = LeftHalfPlane()
    assert lhp.contains([-1e-9, -3 + 4j]) and not lhp.contains([0.0])  # open
    assert LeftHalfPlane(shift=1.0).contains([-1.5]) and not LeftHalfPlane(1.0).contains([-1])
    ud = unit_disk()
    assert ud.contains([0.99j, -0.5]) and not ud.contains([1.0]) and not ud.contains([1j])
    d = Disk(-2.0, 1.0)
    assert d.contains([-2.5 + 0.5j]) and not d.contains([-0.9])
    assert d.margin([-2.0]) == pytest.approx(1.0)
    assert Disk(0.0, 1.0, closed=True).contains([1.0])
    assert poles_in_region(np.diag([-1.0, -2.0]), lhp)
    assert not poles_in_region(np.diag([0.5, 1.2]), ud)
    with pytest.raises(ValueError, match="radius"):
        Disk(0.0, -1.0)
    for region in (Parabola(1, 1), lhp, ud, d):
        assert isinstance(region.describe(), str)


# ------------------------------------------------------------------ filters on uncertain plants
def _plant(discrete: bool = False) -> UncertainPlant:
    if discrete:
        return UncertainPlant([[0.8, 0.05], [-0.08, -0.5]], [[1.0, 0.0]], 0.1 * np.eye(2),
                              [[0.1, 0.08]], [[0.1], [0.08]], [[0.1]], [[0.5, 0.5]],
                              [[0.01, 0.01]], discrete=True)
    return UncertainPlant([[-2.5, 0.3], [0.4, -1.5]], [[0.1, 0.1]], 0.1 * np.eye(2),
                          [[0.6, 0.2]], [[0.8], [0.8]], [[0.8]], [[0.1, 0.1]], [[0.1, 0.1]])


def test_uncertain_plant_validation_and_perturbation():
    pl = _plant()
    assert (pl.n, pl.p, pl.f_shape) == (2, 1, (1, 1))
    A_F, C_F = pl.perturbed(0.5)
    np.testing.assert_allclose(A_F, pl.A + 0.5 * pl.M1 @ pl.N)
    np.testing.assert_allclose(C_F, pl.C + 0.5 * pl.M2 @ pl.N)
    with pytest.raises(ValueError, match="F must satisfy"):
        pl.uncertainty(1.5)
    with pytest.raises(ValueError, match="D2 must"):
        UncertainPlant(pl.A, pl.C, pl.D1, [[1.0]], pl.M1, pl.M2, pl.N, pl.L)
    with pytest.raises(ValueError, match="M2 must"):
        UncertainPlant(pl.A, pl.C, pl.D1, pl.D2, pl.M1, [[1.0, 2.0]], pl.N, pl.L)


def test_error_system_structure_and_covariance():
    pl = _plant()
    G = np.array([[-2.2816, 0.1753], [0.7458, -1.4981]])
    K = np.array([[0.3868], [0.3025]])
    Af, Df, Cf = error_system(pl, G, K, 1.0)
    lam = np.sort_complex(np.linalg.eigvals(Af))
    expect = np.sort_complex(np.concatenate([np.linalg.eigvals(pl.perturbed(1.0)[0]),
                                             np.linalg.eigvals(G)]))
    np.testing.assert_allclose(lam, expect, atol=1e-12)
    np.testing.assert_allclose(Df[2:], pl.D1 - K @ pl.D2)
    np.testing.assert_allclose(Cf, [[0, 0, 0.1, 0.1]])
    P = error_covariance(pl, G, K, 0.0)
    X = steady_state_covariance(*error_system(pl, G, K, 0.0)[:2])
    np.testing.assert_allclose(P, X[2:, 2:])


def test_uncertainty_samples():
    s = uncertainty_samples((1, 1), n_grid=5)
    assert [k for k, _ in s].count("vertex") == 2 and len(s) == 7
    assert sorted(F[0, 0] for k, F in s if k == "vertex") == [-1.0, 1.0]
    m = uncertainty_samples((2, 3), n_grid=3, n_directions=3, seed=1)
    assert sum(k == "vertex" for k, _ in m) == 4
    assert all(np.linalg.norm(F, 2) <= 1 + 1e-12 and F.shape == (2, 3) for _, F in m)
    assert max(np.linalg.norm(F, 2) for _, F in m) == pytest.approx(1.0)


def test_robust_analysis_worst_case_and_json():
    pl = _plant()
    G = np.array([[-2.2816, 0.1753], [0.7458, -1.4981]])
    K = np.array([[0.3868], [0.3025]])
    ra = robust_filter_analysis(pl, G, K, region=Parabola(0.5, 0.5), gamma=0.1,
                                sigma2=[0.3, 0.7], n_grid=11)
    assert ra.all_stable and ra.poles_in_region
    direct = [hinf_norm(*error_system(pl, G, K, F)) for F in np.linspace(-1, 1, 11)]
    assert ra.hinf_worst == pytest.approx(max(direct), rel=1e-5)
    k = int(np.argmax(ra.hinf))
    np.testing.assert_array_equal(ra.hinf_worst_F, ra.F[k])
    assert ra.meets() == {"poles_in_region": True, "hinf": True, "variance": True}
    d = ra.to_dict()
    assert set(d["worst_F"]) == {"hinf", "variance", "poles"}
    assert isinstance(d["worst_F"]["hinf"], float) and len(d["variance_worst"]) == 2

    # an unstable filter: no steady state, inf norm, reported as None in JSON
    bad = robust_filter_analysis(pl, np.diag([0.1, -1.0]), K, n_grid=3)
    assert not bad.all_stable and bad.hinf_worst == math.inf
    assert bad.to_dict()["hinf_worst"] is None and bad.meets()["poles_in_region"] is False


def test_robust_analysis_discrete_default_region():
    pl = _plant(discrete=True)
    G = np.array([[-0.17795, 0.09257], [-0.01529, -0.58288]])
    K = np.array([[0.9764], [-0.0882]])
    ra = robust_filter_analysis(pl, G, K, gamma=0.012, n_grid=5)
    assert "disk" in ra.region.describe() and ra.poles_in_region
    assert ra.hinf_worst < 0.012
