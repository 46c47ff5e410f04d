"""The UKF's spherical simplex sigma points (Julier 2003; :func:`filters.ukf.simplex_points`)."""

from __future__ import annotations

import numpy as np
import pytest

from filters import KalmanFilter, UnscentedKalmanFilter
from filters.ukf import SIGMA_POINT_SETS, simplex_points
from tests.filters.test_ekf_ukf import (
    linear_callables,
    linear_data,
    make_ukf,
    pendulum_f,
    pendulum_h,
    random_system,
)


def julier_recursion(n: int, w0: float) -> tuple[np.ndarray, np.ndarray]:
    """The spherical simplex points as Julier (2003) builds them, one dimension at a time.

    Step 3: ``sigma^1 = [0], [-1/sqrt(2 W1)], [1/sqrt(2 W1)]``; step 4, for ``j = 2 .. n``:
    ``sigma_0^j = [sigma_0^{j-1}; 0]``, ``sigma_i^j = [sigma_i^{j-1}; -1/sqrt(j (j+1) W1)]``
    (``i = 1 .. j``), ``sigma_{j+1}^j = [0_{j-1}; j/sqrt(j (j+1) W1)]``.
    """
    W1 = (1.0 - w0) / (n + 1)
    pts = [[0.0], [-1.0 / np.sqrt(2.0 * W1)], [1.0 / np.sqrt(2.0 * W1)]]
    for j in range(2, n + 1):
        c = 1.0 / np.sqrt(j * (j + 1) * W1)
        new = [pts[0] + [0.0]]
        new += [pts[i] + [-c] for i in range(1, j + 1)]
        new.append([0.0] * (j - 1) + [j * c])
        pts = new
    return np.array(pts), np.array([w0] + [W1] * (n + 1))


@pytest.mark.parametrize("n", [1, 2, 3, 6, 10])
@pytest.mark.parametrize("w0", [0.0, 0.4])
def test_simplex_points_equal_julier_recursion_and_have_unit_moments(n, w0):
    Z, W = simplex_points(n, w0)
    Zr, Wr = julier_recursion(n, w0)
    assert Z.shape == (n + 2, n) and W.shape == (n + 2,)
    np.testing.assert_allclose(Z, Zr, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(W, Wr, rtol=1e-15)
    np.testing.assert_allclose(W.sum(), 1.0, rtol=1e-14)
    np.testing.assert_allclose(W @ Z, np.zeros(n), atol=1e-13)
    np.testing.assert_allclose((Z.T * W) @ Z, np.eye(n), atol=1e-13)
    radii = np.linalg.norm(Z[1:], axis=1)  # on a sphere (the set's name)
    np.testing.assert_allclose(radii, np.sqrt(n / (n + 1) / W[1]), rtol=1e-13)
    for i in range(2, n + 2):  # z_i is zero before coordinate i - 1 (1-based)
        assert not Z[i, :i - 2].any()


def unscented_prior(f, x, P, **kw):
    """The UKF's prior mean and covariance of one prediction through ``f`` (``Q = 0``)."""
    n = len(x)
    ukf = UnscentedKalmanFilter(f, lambda x, u: x[:, :1], np.zeros((n, n)), np.eye(1), x, P,
                                **kw)
    ukf.predict()
    return ukf.x, ukf.P


def random_gaussian(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    G = rng.standard_normal((n, n))
    return rng.standard_normal(n), G @ G.T + 0.1 * np.eye(n)


@pytest.mark.parametrize("alpha", [1e-3, 0.5, 1.0])
@pytest.mark.parametrize("n", [1, 3, 7])
def test_both_sets_propagate_a_linear_map_exactly(alpha, n):
    rng = np.random.default_rng(n)
    x, P = random_gaussian(rng, n)
    A, b = rng.standard_normal((n, n)), rng.standard_normal(n)
    f = lambda X, u: X @ A.T + b  # noqa: E731
    mean, cov = A @ x + b, A @ P @ A.T  # closed form
    for points in SIGMA_POINT_SETS:
        xp, Pp = unscented_prior(f, x, P, alpha=alpha, sigma_points=points, w0=0.2)
        tol = 1e-7 if alpha < 1e-2 else 1e-11  # alpha = 1e-3: weights of order 1e6
        np.testing.assert_allclose(xp, mean, rtol=0, atol=tol * np.abs(mean).max())
        np.testing.assert_allclose(Pp, cov, rtol=0, atol=tol * np.abs(cov).max())


@pytest.mark.parametrize("points", SIGMA_POINT_SETS)
def test_mean_of_a_quadratic_is_exact(points):
    rng = np.random.default_rng(4)
    x, P = random_gaussian(rng, 4)
    f = lambda X, u: X * X  # noqa: E731  E[x_i^2] = mu_i^2 + P_ii
    xp, _ = unscented_prior(f, x, P, alpha=1.0, sigma_points=points, w0=0.3)
    np.testing.assert_allclose(xp, x * x + np.diag(P), rtol=1e-12)


def test_simplex_with_w0_two_thirds_gives_the_exact_variance_of_a_square():
    # 1-D: the simplex set is symmetric with weights [w0, W1, W1]; w0 = 2/3 matches the
    # Gaussian's fourth moment (Julier's kappa = 3 - n), so y = x^2 has its exact moments
    # E y = mu^2 + s^2, Var y = 4 mu^2 s^2 + 2 s^4
    mu, s2 = 0.7, 0.3
    xp, Pp = unscented_prior(lambda X, u: X * X, np.array([mu]), np.array([[s2]]), alpha=1.0,
                             beta=0.0, sigma_points="simplex", w0=2.0 / 3.0)
    np.testing.assert_allclose(xp, [mu * mu + s2], rtol=1e-13)
    np.testing.assert_allclose(Pp, [[4 * mu * mu * s2 + 2 * s2 * s2]], rtol=1e-13)


@pytest.mark.parametrize("points", SIGMA_POINT_SETS)
def test_polar_to_cartesian_mean_to_second_order(points):
    # r ~ N(1, s_r^2), theta ~ N(t, s_t^2) independent: E[r cos theta] = cos(t) exp(-s_t^2/2),
    # E[r sin theta] = sin(t) exp(-s_t^2/2) (closed form); the unscented mean is the
    # second-order one, cos(t) (1 - s_t^2 / 2), an error O(s_t^4), far below the
    # linearization's O(s_t^2); the simplex set's third moments add a term of order alpha s^3
    t, s_r2, s_t2 = 0.6, 0.02, 0.04
    x, P = np.array([1.0, t]), np.diag([s_r2, s_t2])

    def f(X, u):
        return np.stack([X[:, 0] * np.cos(X[:, 1]), X[:, 0] * np.sin(X[:, 1])], axis=1)

    exact = np.array([np.cos(t), np.sin(t)]) * np.exp(-s_t2 / 2)
    second = np.array([np.cos(t), np.sin(t)]) * (1 - s_t2 / 2)
    xp, _ = unscented_prior(f, x, P, alpha=1e-3, sigma_points=points)
    np.testing.assert_allclose(xp, second, atol=1e-8 if points == "scaled" else 1e-5)
    linear_error = np.abs(f(x[None], None)[0] - exact).max()
    assert np.abs(xp - exact).max() < 0.02 * linear_error


@pytest.mark.parametrize(("n", "m", "k"), [(1, 1, 1), (4, 2, 2), (6, 3, 2)])
def test_simplex_ukf_equals_the_kalman_filter_on_a_linear_model(n, m, k):
    rng = np.random.default_rng(100 + n)
    s = random_system(rng, n, m, k)
    x0, P0 = random_gaussian(rng, n)
    kf, ukf = KalmanFilter(s, x0, P0), make_ukf(s, x0, P0, sigma_points="simplex", w0=0.5)
    assert ukf.Wm.shape == (n + 2,) and ukf.sigma_point_set == "simplex"
    for u, y in zip(*linear_data(s, rng, 60), strict=True):
        kf.step(y, u)
        ukf.step(y, u)
        scale = 1.0 + np.abs(kf.x).max()
        np.testing.assert_allclose(ukf.x, kf.x, rtol=0, atol=1e-6 * scale)
        np.testing.assert_allclose(ukf.P, kf.P, rtol=0, atol=1e-6 * np.abs(kf.P).max())


def test_simplex_ukf_calls_f_and_h_once_on_n_plus_2_points_per_member():
    calls = []

    def f(x, u):
        calls.append(("f", x.shape))
        return pendulum_f(x, u)

    def h(x, u):
        calls.append(("h", x.shape))
        return pendulum_h(x, u)

    ukf = UnscentedKalmanFilter(f, h, 1e-3 * np.eye(2), 1e-2 * np.eye(2), np.zeros((3, 2)),
                                np.eye(2), k=1, sigma_points="simplex")
    ukf.step(np.zeros((3, 2)), np.ones(1))
    assert calls == [("f", (12, 2)), ("h", (12, 2))]
    X = ukf.sigma_points()
    assert X.shape == (3, 4, 2)
    np.testing.assert_array_equal(X[:, 0], ukf.x)


def test_simplex_batch_equals_a_loop_over_members_bitwise():
    rng = np.random.default_rng(12)
    N = 5
    x0 = rng.standard_normal((N, 2))
    G = rng.standard_normal((N, 2, 2))
    P0 = G @ np.swapaxes(G, -1, -2) + 0.1 * np.eye(2)
    Q, R = np.diag([1e-4, 1e-3]), np.diag([0.01, 0.02])

    def make(x, P):
        return UnscentedKalmanFilter(pendulum_f, pendulum_h, Q, R, x, P, alpha=0.3, k=1,
                                     sigma_points="simplex", w0=0.1)

    batch, singles = make(x0, P0), [make(x0[i], P0[i]) for i in range(N)]
    for u, y in zip(rng.standard_normal((30, N, 1)), rng.standard_normal((30, N, 2)),
                    strict=True):
        batch.step(y, u)
        for i, one in enumerate(singles):
            one.step(y[i], u[i])
    for i, one in enumerate(singles):
        assert np.array_equal(batch.x[i], one.x)
        assert np.array_equal(batch.P[i], one.P)


def test_the_default_set_is_unchanged_by_the_option():
    rng = np.random.default_rng(5)
    s = random_system(rng, 3, 2, 1)
    a, b = make_ukf(s, np.zeros(3), np.eye(3)), make_ukf(s, np.zeros(3), np.eye(3),
                                                         sigma_points="scaled", w0=0.7)
    for u, y in zip(*linear_data(s, rng, 10), strict=True):
        a.step(y, u)
        b.step(y, u)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)


def test_simplex_options_are_validated():
    s = random_system(np.random.default_rng(0), 2, 1, 1)
    f, _, h, _ = linear_callables(s)
    for kw, word in (({"sigma_points": "cubature"}, "sigma_points"), ({"w0": 1.0}, "w0"),
                     ({"w0": -0.1}, "w0"), ({"w0": "x"}, "w0"), ({"w0": np.inf}, "w0")):
        with pytest.raises(ValueError, match=f"^{word} must"):
            UnscentedKalmanFilter(f, h, s.Q, s.R, np.zeros(2), np.eye(2), k=1, **kw)
    for bad, word in ((0, "n"), (2.5, "n"), (True, "n")):
        with pytest.raises(ValueError, match=f"^{word} must"):
            simplex_points(bad)
    with pytest.raises(ValueError, match="^w0 must"):
        simplex_points(2, 1.0)
