"""Autocovariance least squares: exact on exact autocovariances, consistent on simulated
innovations, and the classical limits (an optimal gain gives white innovations)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from filters import DiscreteLinearSystem
from filters.noise_covariance import (
    autocovariance_least_squares,
    fit_autocovariances,
    innovation_autocovariances,
    predicted_autocovariances,
)

DT_S = 0.1
F = np.array([[1.0, DT_S], [0.0, 1.0]])
H = np.array([[1.0, 0.0]])
Q_TRUE = np.diag([1e-4, 4e-3])
R_TRUE = np.array([[0.05]])


def _model(Q: np.ndarray, R: np.ndarray) -> DiscreteLinearSystem:
    return DiscreteLinearSystem(F=F, B=None, H=H, Q=Q, R=R, dt_s=DT_S)


def _steady_gain(Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    P = scipy.linalg.solve_discrete_are(F.T, H.T, Q, R)
    return P @ H.T @ np.linalg.inv(H @ P @ H.T + R)


WRONG = _model(np.diag([1e-2, 1e-2]), np.array([[1.0]]))
K_WRONG = _steady_gain(WRONG.Q, WRONG.R)


def _innovations(K: np.ndarray, runs: int, steps: int, seed: int) -> np.ndarray:
    """Innovations of the fixed-gain filter on the true system (an independent loop)."""
    rng = np.random.default_rng(seed)
    chol = np.linalg.cholesky(Q_TRUE)
    x, x_hat = np.zeros((runs, 2)), np.zeros((runs, 2))
    out = np.empty((runs, steps, 1))
    for k in range(steps):
        y = x @ H.T + np.sqrt(R_TRUE[0, 0]) * rng.standard_normal((runs, 1))
        r = y - x_hat @ H.T
        out[:, k] = r
        x_hat = (x_hat + r @ K.T) @ F.T
        x = x @ F.T + rng.standard_normal((runs, 2)) @ chol.T
    return out


def test_scalar_closed_form() -> None:
    # x' = a x + w, y = x + v, gain k: abar = a (1 - k), P = (q + a^2 k^2 r) / (1 - abar^2),
    # C_0 = P + r, C_j = abar^(j-1) (abar P - a k r)
    a, k, q, r = 0.9, 0.3, 0.2, 0.5
    system = DiscreteLinearSystem(F=[[a]], B=None, H=[[1.0]], Q=[[q]], R=[[r]], dt_s=1.0)
    abar = a * (1 - k)
    P = (q + a**2 * k**2 * r) / (1 - abar**2)
    expected = [P + r] + [abar ** (j - 1) * (abar * P - a * k * r) for j in range(1, 6)]
    got = predicted_autocovariances(system, [[k]], 6)[:, 0, 0]
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_optimal_gain_gives_white_innovations() -> None:
    C = predicted_autocovariances(_model(Q_TRUE, R_TRUE), _steady_gain(Q_TRUE, R_TRUE), 8)
    assert np.max(np.abs(C[1:])) < 1e-12 * np.abs(C[0]).max()
    C_wrong = predicted_autocovariances(WRONG, K_WRONG, 8, Q_TRUE, R_TRUE)
    assert np.max(np.abs(C_wrong[1:])) > 0.05 * C_wrong[0, 0, 0]  # coloured: K is wrong


def test_exact_autocovariances_give_the_true_covariances() -> None:
    C = predicted_autocovariances(WRONG, K_WRONG, 15, Q_TRUE, R_TRUE)
    est = fit_autocovariances(WRONG, K_WRONG, C)
    assert est.identifiable
    np.testing.assert_allclose(est.Q, Q_TRUE, atol=1e-10)
    np.testing.assert_allclose(est.R, R_TRUE, atol=1e-10)
    assert est.residual < 1e-10


def test_a_full_Q_from_one_channel_is_flagged_as_not_identifiable() -> None:
    # n = 2 states seen through m = 1 channel: a full Q is not unique (Odelson et al. 2006)
    C = predicted_autocovariances(WRONG, K_WRONG, 15, Q_TRUE, R_TRUE)
    est = fit_autocovariances(WRONG, K_WRONG, C, q_basis="full")
    assert not est.identifiable and est.rank == 3
    assert est.residual < 1e-10  # it still explains the autocovariances


def test_full_covariances_from_two_channels() -> None:
    system = DiscreteLinearSystem(F=F, B=None, H=np.eye(2), Q=np.eye(2), R=np.eye(2),
                                  dt_s=DT_S)
    Q = np.array([[2e-3, 5e-4], [5e-4, 4e-3]])
    R = np.array([[0.05, 0.01], [0.01, 0.02]])
    P = scipy.linalg.solve_discrete_are(F.T, np.eye(2), np.eye(2), np.eye(2))
    K = P @ np.linalg.inv(P + np.eye(2))
    C = predicted_autocovariances(system, K, 10, Q, R)
    est = fit_autocovariances(system, K, C, q_basis="full", r_basis="full")
    assert est.identifiable
    np.testing.assert_allclose(est.Q, Q, atol=1e-10)
    np.testing.assert_allclose(est.R, R, atol=1e-10)


def test_known_R_identifies_Q_alone() -> None:
    C = predicted_autocovariances(WRONG, K_WRONG, 10, Q_TRUE, R_TRUE)
    est = fit_autocovariances(WRONG, K_WRONG, C, known_R=R_TRUE)
    np.testing.assert_allclose(est.Q, Q_TRUE, atol=1e-10)
    np.testing.assert_array_equal(est.R, R_TRUE)


def test_user_basis_through_a_known_input_matrix() -> None:
    G = np.array([[0.5 * DT_S**2], [DT_S]])
    Q = 0.3 * G @ G.T
    C = predicted_autocovariances(WRONG, K_WRONG, 10, Q, R_TRUE)
    est = fit_autocovariances(WRONG, K_WRONG, C, q_basis=[G @ G.T], r_basis=[np.eye(1)])
    np.testing.assert_allclose(est.q_coefficients, [0.3], rtol=1e-8)


def test_simulated_innovations_recover_the_noise() -> None:
    innovations = _innovations(K_WRONG, runs=20, steps=5000, seed=1)
    sample = innovation_autocovariances(innovations, 3, burn_in=50)
    exact = predicted_autocovariances(WRONG, K_WRONG, 3, Q_TRUE, R_TRUE)
    np.testing.assert_allclose(sample, exact, atol=0.03 * exact[0, 0, 0])
    est = autocovariance_least_squares(WRONG, K_WRONG, innovations, lags=15, burn_in=50)
    # the well-determined ones within 5 %; the position noise (2.5 % of the velocity's
    # effect on the innovations) within 100 %
    np.testing.assert_allclose(est.R, R_TRUE, rtol=0.05)
    assert est.Q[1, 1] == pytest.approx(Q_TRUE[1, 1], rel=0.05)
    assert 0 <= est.Q[0, 0] < 2 * Q_TRUE[0, 0]
    # a filter redesigned with them has (nearly) white innovations
    tuned_K = _steady_gain(est.Q + 1e-12 * np.eye(2), est.R)
    tuned = predicted_autocovariances(WRONG, tuned_K, 6, Q_TRUE, R_TRUE)
    before = predicted_autocovariances(WRONG, K_WRONG, 6, Q_TRUE, R_TRUE)
    assert np.abs(tuned[1:, 0, 0] / tuned[0, 0, 0]).max() < 0.2 * np.abs(
        before[1:, 0, 0] / before[0, 0, 0]).max()


def test_the_same_innovations_give_the_same_estimate() -> None:
    innovations = _innovations(K_WRONG, runs=4, steps=500, seed=2)
    a = autocovariance_least_squares(WRONG, K_WRONG, innovations, lags=8)
    b = autocovariance_least_squares(WRONG, K_WRONG, innovations.copy(), lags=8)
    np.testing.assert_array_equal(a.Q, b.Q)
    np.testing.assert_array_equal(a.R, b.R)


@pytest.mark.parametrize("call, message", [
    (lambda: autocovariance_least_squares(WRONG, np.zeros((2, 2)), np.zeros((10, 1))),
     "gain must"),
    (lambda: autocovariance_least_squares(WRONG, [[0.0], [0.0]], np.zeros((10, 1))),
     "gain must stabilize"),
    (lambda: autocovariance_least_squares(WRONG, K_WRONG, np.zeros((10, 2)), lags=3),
     "autocovariances must have shape"),
    (lambda: autocovariance_least_squares(WRONG, K_WRONG, np.zeros((10, 1)), lags=10),
     "lags must be an integer"),
    (lambda: autocovariance_least_squares(WRONG, K_WRONG, np.full((10, 1), np.nan), lags=2),
     "innovations must be finite"),
    (lambda: autocovariance_least_squares(WRONG, K_WRONG, np.zeros((10, 1)), lags=2,
                                          q_basis="banded"), "q_basis must be"),
    (lambda: autocovariance_least_squares(WRONG, K_WRONG, np.zeros((10, 1)), lags=2,
                                          q_basis=[[[0.0, 1.0], [0.0, 0.0]]]),
     "must be symmetric"),
])
def test_bad_input_is_named(call, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        call()
