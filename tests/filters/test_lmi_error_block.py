"""The error block of LMI (48) (``plant_block=False``): without multiplicative noise the
plant block only certifies the plant's stability. Checked against computations that do not
use the LMI: a frequency sweep of the error system (numpy only) and the symplectic-pencil
H-infinity norm (:func:`filters.analysis.hinf_norm`), on random systems of several
dimensions, stable and not."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from filters.lmi_hinf import (
    StochasticLinearSystem,
    balancing,
    certify_gain,
    check_design,
    design_lmi_hinf,
    design_on_grid,
    error_block_matrix,
    error_gari_matrix,
    error_hinf_norm,
    minimal_gamma,
)

#: (seed, n, n_v, n_y, n_z, spectral radius of A): stable, marginal (an eigenvalue on the
#: unit circle, like a free integrator) and unstable plants.
CASES = [(1, 2, 2, 1, 1, 0.9), (2, 3, 3, 2, 2, 0.8), (3, 4, 3, 1, 2, 0.95),
         (4, 3, 2, 1, 1, 1.3), (5, 4, 4, 2, 2, 1.0), (6, 5, 3, 2, 1, 1.0)]


def random_system(seed: int, n: int, nv: int, ny: int, nz: int,
                  rho: float) -> StochasticLinearSystem:
    """A random system without multiplicative noise, ``rho(A) = rho``."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    A *= rho / np.max(np.abs(np.linalg.eigvals(A)))
    return StochasticLinearSystem(A=A, B=rng.standard_normal((n, nv)),
                                  C_y=rng.standard_normal((ny, n)),
                                  C_z=rng.standard_normal((nz, n)),
                                  D_y=rng.standard_normal((ny, nv)),
                                  D_z=0.1 * rng.standard_normal((nz, nv)))


def sweep_norm(s: StochasticLinearSystem, K: np.ndarray, points: int = 4001) -> float:
    """max over a frequency grid of sigma_max(C_z (zI - Ae)^-1 Be + D_z): a lower bound of
    the H-infinity norm, numpy only."""
    Ae, Be = s.A - K @ s.C_y, s.B - K @ s.D_y
    eye = np.eye(s.n)
    best = 0.0
    for w in np.linspace(0.0, np.pi, points):
        T = s.C_z @ np.linalg.solve(np.exp(1j * w) * eye - Ae, Be) + s.D_z
        best = max(best, float(np.linalg.svd(T, compute_uv=False)[0]))
    return best


def kalman_gain(s: StochasticLinearSystem) -> np.ndarray:
    """Steady-state Kalman predictor gain for the noise ``[B; D_y] v`` (scipy)."""
    Q, R, S = s.B @ s.B.T, s.D_y @ s.D_y.T, s.B @ s.D_y.T
    X = solve_discrete_are(s.A.T, s.C_y.T, Q, R, s=S)
    return np.linalg.solve(s.C_y @ X @ s.C_y.T + R, (s.A @ X @ s.C_y.T + S).T).T


@pytest.fixture(scope="module", params=CASES, ids=lambda c: f"n{c[1]}-rho{c[5]}")
def case(request):
    s = random_system(*request.param)
    search = minimal_gamma(s, plant_block=False)
    return request.param, s, search


def test_the_design_bounds_the_error_system_norm_computed_without_the_lmi(case):
    (_, n, *_), s, search = case
    assert search.status == "converged"
    design, _ = design_on_grid(s, 2.0 * search.gamma_min, plant_block=False)
    assert design.feasible and design.P1 is None and not design.plant_block
    K = design.gain
    assert np.max(np.abs(np.linalg.eigvals(s.A - K @ s.C_y))) < 1.0
    sweep = sweep_norm(s, K)
    norm = error_hinf_norm(s, K)
    assert sweep <= norm * (1 + 1e-6)  # the sweep is a lower bound of the true norm
    assert norm <= sweep * (1 + 1e-2)  # and close to it on this grid
    assert norm < design.gamma
    assert design.check.error_hinf_norm == pytest.approx(norm, rel=1e-6)
    assert design.check.ok and design.check.P_min_eig > 0
    # the LMI, evaluated with numpy at the returned (P2, P_K), is negative definite
    assert np.linalg.eigvalsh(error_block_matrix(s, design.P2, design.P_K, design.gamma))[-1] < 0
    assert design.P2.shape == (n, n) and np.allclose(design.P2, design.P2.T)


def test_gamma_min_is_the_optimal_level_of_the_error_system(case):
    """The error block is the bounded-real lemma (necessary and sufficient): no gain does
    better than the bisection's infeasible level, and the design at gamma_min reaches it."""
    _, s, search = case
    at_min = search.design
    norm_min = error_hinf_norm(s, at_min.gain)
    assert search.lower * (1 - 1e-6) <= norm_min <= search.gamma_min
    rng = np.random.default_rng(0)
    gains = [kalman_gain(s)] + [at_min.gain + 0.05 * rng.standard_normal(at_min.gain.shape)
                                * np.abs(at_min.gain).max() for _ in range(10)]
    for K in gains:
        assert error_hinf_norm(s, K) >= search.lower * (1 - 1e-6)


@pytest.mark.filterwarnings("ignore::scipy.linalg.LinAlgWarning")  # full LMI, marginal A
def test_stable_plants_full_and_error_block_give_the_same_gamma_min(case):
    params, s, search = case
    full = minimal_gamma(s)
    if params[-1] < 1.0:
        assert full.status == "converged"
        assert full.gamma_min == pytest.approx(search.gamma_min, rel=2e-3)
    else:  # Theorem 4 as printed: the plant block needs a Schur-stable A
        assert full.gamma_min is None and full.status == "infeasible"


def test_check_rejects_a_gamma_below_the_norm_and_a_destabilizing_gain():
    s = random_system(*CASES[3])
    design, _ = design_on_grid(s, 2.0 * minimal_gamma(s, plant_block=False).gamma_min,
                               plant_block=False)
    norm = design.check.error_hinf_norm
    low = check_design(s, design.gain, None, design.P2, 0.9 * norm, plant_block=False)
    assert not low.ok and not low.gari_negative_definite
    bad = check_design(s, 100 * np.ones(s.gain_shape()), None, design.P2, design.gamma,
                       plant_block=False)
    assert not bad.ok and not bad.mean_square_stable and bad.error_hinf_norm == np.inf
    # error_gari_matrix is the Schur complement of error_block_matrix: same sign
    M = error_block_matrix(s, design.P2, design.P2 @ design.gain, design.gamma)
    G = error_gari_matrix(s, design.gain, design.P2, design.gamma)
    assert np.linalg.eigvalsh(M)[-1] < 0 and np.linalg.eigvalsh(G)[-1] < 0


def test_analysis_of_a_given_gain_and_balancing_sizes():
    s = random_system(*CASES[4])
    K = kalman_gain(s)
    norm = error_hinf_norm(s, K)
    ok = certify_gain(s, K, 1.05 * norm, plant_block=False)
    assert ok.feasible and np.array_equal(ok.gain, K)
    assert not certify_gain(s, K, 0.95 * norm, plant_block=False).feasible
    (s1, s2), diag = balancing(s, 2.0, plant_block=False)
    assert s1 == 1.0 and s2 > 0 and diag.shape == (2 * s.n + s.n_v + s.n_z,)


def test_multiplicative_noise_keeps_the_plant_block():
    rng = np.random.default_rng(3)
    s = StochasticLinearSystem(A=0.5 * np.eye(2), B=np.ones((2, 1)), C_y=np.eye(1, 2),
                               C_z=np.eye(1, 2), A_w=0.1 * rng.standard_normal((2, 2)))
    with pytest.raises(ValueError, match="A_w = B_w = 0"):
        design_lmi_hinf(s, 1.0, plant_block=False)
    with pytest.raises(ValueError, match="A_w = B_w = 0"):
        check_design(s, np.zeros((2, 1)), None, np.eye(2), 1.0, plant_block=False)

