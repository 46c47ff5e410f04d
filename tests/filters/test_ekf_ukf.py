"""The extended and the unscented Kalman filter (:mod:`filters.ekf`, :mod:`filters.ukf`)."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints
from filterpy.kalman import UnscentedKalmanFilter as FilterpyUKF

from filters import (
    DiscreteLinearSystem,
    Estimator,
    ExtendedKalmanFilter,
    FiniteEscapeError,
    KalmanFilter,
    LossOfDefinitenessError,
    UnscentedKalmanFilter,
)


def random_system(rng: np.random.Generator, n: int, m: int, k: int) -> DiscreteLinearSystem:
    """A random stable system with input, feedthrough and PD noise covariances."""
    F = rng.standard_normal((n, n))
    F *= 0.97 / max(1.0, np.abs(np.linalg.eigvals(F)).max())
    G = rng.standard_normal((n, n))
    L = rng.standard_normal((m, m))
    return DiscreteLinearSystem(F=F, B=rng.standard_normal((n, k)), H=rng.standard_normal((m, n)),
                                Q=0.1 * G @ G.T + 1e-3 * np.eye(n), R=L @ L.T + 0.1 * np.eye(m),
                                dt_s=0.01, D=rng.standard_normal((m, k)))


def linear_callables(s: DiscreteLinearSystem):
    """``f, F, h, H`` of a linear system, batched."""
    N = lambda x: len(x)  # noqa: E731
    return (lambda x, u: x @ s.F.T + u @ s.B.T,
            lambda x, u: np.broadcast_to(s.F, (N(x), s.n, s.n)),
            lambda x, u: x @ s.H.T + u @ s.D.T,
            lambda x, u: np.broadcast_to(s.H, (N(x), s.m, s.n)))


def make_ekf(s: DiscreteLinearSystem, x0, P0) -> ExtendedKalmanFilter:
    f, F, h, H = linear_callables(s)
    return ExtendedKalmanFilter(f, F, h, H, s.Q, s.R, x0, P0, k=s.k, dt_s=s.dt_s)


def make_ukf(s: DiscreteLinearSystem, x0, P0, **kw) -> UnscentedKalmanFilter:
    f, _, h, _ = linear_callables(s)
    return UnscentedKalmanFilter(f, h, s.Q, s.R, x0, P0, k=s.k, dt_s=s.dt_s, **kw)


def linear_data(s: DiscreteLinearSystem, rng: np.random.Generator, steps: int,
                batch: tuple[int, ...] = ()):
    """Inputs and measurements of a simulated run, shapes (steps, *batch, k/m)."""
    x = rng.standard_normal((*batch, s.n))
    us, ys = [], []
    for _ in range(steps):
        u = rng.standard_normal((*batch, s.k))
        x = x @ s.F.T + u @ s.B.T + rng.multivariate_normal(np.zeros(s.n), s.Q, size=batch)
        ys.append(x @ s.H.T + u @ s.D.T + rng.multivariate_normal(np.zeros(s.m), s.R, size=batch))
        us.append(u)
    return np.array(us), np.array(ys)


@pytest.mark.parametrize(("n", "m", "k"), [(1, 1, 1), (2, 1, 1), (4, 2, 2), (6, 3, 2)])
def test_on_a_linear_model_ekf_and_ukf_equal_the_kalman_filter(n, m, k):
    rng = np.random.default_rng(10 * n + m)
    s = random_system(rng, n, m, k)
    x0 = rng.standard_normal(n)
    G = rng.standard_normal((n, n))
    P0 = G @ G.T + 0.1 * np.eye(n)
    kf, ekf, ukf = KalmanFilter(s, x0, P0), make_ekf(s, x0, P0), make_ukf(s, x0, P0)
    us, ys = linear_data(s, rng, 60)
    for u, y in zip(us, ys, strict=True):
        kf.step(y, u)
        ekf.step(y, u)
        ukf.step(y, u)
        scale = 1.0 + np.abs(kf.x).max()
        np.testing.assert_allclose(ekf.x, kf.x, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(ekf.P, kf.P, rtol=0, atol=1e-9 * np.abs(kf.P).max())
        np.testing.assert_allclose(ukf.x, kf.x, rtol=0, atol=1e-6 * scale)
        np.testing.assert_allclose(ukf.P, kf.P, rtol=0, atol=1e-6 * np.abs(kf.P).max())
        for est in (ekf, ukf):
            np.testing.assert_allclose(est.innovation, kf.innovation, atol=1e-6 * scale)
            np.testing.assert_allclose(est.innovation_cov, kf.innovation_cov, rtol=1e-6)
    assert ekf.t_s == ukf.t_s == pytest.approx(kf.t_s)


def test_predict_then_update_equals_step():
    rng = np.random.default_rng(3)
    s = random_system(rng, 3, 2, 1)
    us, ys = linear_data(s, rng, 5)
    for make in (make_ekf, make_ukf):
        a, b = make(s, np.zeros(3), np.eye(3)), make(s, np.zeros(3), np.eye(3))
        for u, y in zip(us, ys, strict=True):
            a.step(y, u)
            b.predict(u)
            b.update(y, u)
            np.testing.assert_allclose(a.x, b.x, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(a.P, b.P, rtol=1e-12, atol=1e-12)
        assert isinstance(a, Estimator)


# ----------------------------------------------------------------------- pendulum vs filterpy
DT = 0.05


def pendulum_f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Damped pendulum (angle, rate), semi-implicit Euler, torque input; batched."""
    theta, omega = x[:, 0], x[:, 1]
    omega_n = omega + DT * (-9.81 * np.sin(theta) - 0.3 * omega + u[:, 0])
    return np.stack([theta + DT * omega_n, omega_n], axis=1)


def pendulum_h(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Horizontal bob position and the rate; batched."""
    return np.stack([np.sin(x[:, 0]), x[:, 1]], axis=1)


@pytest.mark.parametrize(("alpha", "beta", "kappa"), [(1e-3, 2.0, 0.0), (0.5, 2.0, 1.0),
                                                      (1.0, 0.0, 0.0)])
def test_ukf_equals_filterpy_on_a_pendulum(alpha, beta, kappa):
    rng = np.random.default_rng(7)
    Q = np.diag([1e-5, 1e-3])
    R = np.diag([0.05**2, 0.1**2])
    x0, P0 = np.array([1.0, 0.0]), np.diag([0.2, 0.5])
    ours = UnscentedKalmanFilter(pendulum_f, pendulum_h, Q, R, x0, P0, alpha=alpha, beta=beta,
                                 kappa=kappa, k=1, dt_s=DT)
    points = MerweScaledSigmaPoints(2, alpha=alpha, beta=beta, kappa=kappa)
    ref = FilterpyUKF(dim_x=2, dim_z=2, dt=DT, points=points,
                      fx=lambda x, dt, u: pendulum_f(x[None], u[None])[0],
                      hx=lambda x: pendulum_h(x[None], np.zeros((1, 1)))[0])
    ref.x, ref.P, ref.Q, ref.R = x0.copy(), P0.copy(), Q, R
    x = np.array([1.3, 0.0])
    for k in range(100):
        u = np.array([0.5 * np.sin(0.1 * k)])
        x = pendulum_f(x[None], u[None])[0] + rng.multivariate_normal(np.zeros(2), Q)
        y = pendulum_h(x[None], u[None])[0] + rng.multivariate_normal(np.zeros(2), R)
        ours.step(y, u)
        ref.predict(u=u)
        ref.update(y)
        np.testing.assert_allclose(ours.x, ref.x, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(ours.P, ref.P, rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(ours.innovation, ref.y, rtol=1e-8, atol=1e-9)
        np.testing.assert_allclose(ours.innovation_cov, ref.S, rtol=1e-8,
                                   atol=1e-9 * np.abs(ref.S).max())
    np.testing.assert_allclose(ours.Wm, points.Wm)
    np.testing.assert_allclose(ours.Wc, points.Wc)


def test_ukf_calls_f_and_h_once_per_step_on_stacked_points():
    calls = []

    def f(x, u):
        calls.append(("f", x.shape, u.shape))
        return pendulum_f(x, u)

    def h(x, u):
        calls.append(("h", x.shape, u.shape))
        return pendulum_h(x, u)

    ukf = UnscentedKalmanFilter(f, h, 1e-3 * np.eye(2), 1e-2 * np.eye(2),
                                np.zeros((3, 2)), np.eye(2), k=1)
    ukf.step(np.zeros((3, 2)), np.ones(1))
    assert calls == [("f", (15, 2), (15, 1)), ("h", (15, 2), (15, 1))]


# ----------------------------------------------------------------------------- batching
@pytest.mark.parametrize("which", ["ekf", "ukf"])
def test_batch_equals_a_loop_over_members_bitwise(which):
    rng = np.random.default_rng(11)
    N = 5
    x0 = rng.standard_normal((N, 2))
    G = rng.standard_normal((N, 2, 2))
    P0 = G @ np.swapaxes(G, -1, -2) + 0.1 * np.eye(2)
    us = rng.standard_normal((30, N, 1))
    ys = rng.standard_normal((30, N, 2))
    Q, R = np.diag([1e-4, 1e-3]), np.diag([0.01, 0.02])

    def pend_F(x, u):
        J = np.zeros((len(x), 2, 2))
        c = DT * (-9.81 * np.cos(x[:, 0]))
        J[:, 1, 0], J[:, 1, 1] = c, 1.0 - 0.3 * DT
        J[:, 0, 0], J[:, 0, 1] = 1.0 + DT * c, DT * (1.0 - 0.3 * DT)
        return J

    def pend_H(x, u):
        J = np.zeros((len(x), 2, 2))
        J[:, 0, 0], J[:, 1, 1] = np.cos(x[:, 0]), 1.0
        return J

    def make(x, P):
        if which == "ekf":
            return ExtendedKalmanFilter(pendulum_f, pend_F, pendulum_h, pend_H, Q, R, x, P, k=1)
        return UnscentedKalmanFilter(pendulum_f, pendulum_h, Q, R, x, P, alpha=0.3, k=1)

    batch = make(x0, P0)
    singles = [make(x0[i], P0[i]) for i in range(N)]
    for u, y in zip(us, ys, strict=True):
        batch.step(y, u)
        for i, s in enumerate(singles):
            s.step(y[i], u[i])
    assert batch.x.shape == (N, 2) and batch.P.shape == (N, 2, 2)
    for i, s in enumerate(singles):
        assert s.x.shape == (2,)
        assert np.array_equal(batch.x[i], s.x)
        assert np.array_equal(batch.P[i], s.P)
        assert np.array_equal(batch.innovation[i], s.innovation)
        assert np.array_equal(batch.innovation_cov[i], s.innovation_cov)


def test_shared_input_and_prior_broadcast_over_the_batch():
    rng = np.random.default_rng(2)
    s = random_system(rng, 3, 2, 1)
    ekf = make_ekf(s, np.zeros((4, 3)), np.eye(3))
    assert ekf.P.shape == (4, 3, 3)
    ekf.step(np.zeros(2), np.ones(1))
    assert ekf.x.shape == (4, 3) and ekf.innovation.shape == (4, 2)
    assert ekf.innovation_cov.shape == (4, 2, 2) and ekf.gain.shape == (4, 3, 2)


# ------------------------------------------------------------------------- typed errors
def test_non_finite_prediction_raises_finite_escape_with_time_and_quantity():
    s = random_system(np.random.default_rng(0), 2, 1, 1)
    f, F, h, H = linear_callables(s)

    def bad_f(x, u):
        out = f(x, u)
        return out * np.inf if bad_f.armed else out

    bad_f.armed = False
    for est in (ExtendedKalmanFilter(bad_f, F, h, H, s.Q, s.R, np.zeros(2), np.eye(2), k=1,
                                     dt_s=0.01),
                UnscentedKalmanFilter(bad_f, h, s.Q, s.R, np.zeros(2), np.eye(2), k=1,
                                      dt_s=0.01)):
        bad_f.armed = False
        est.step(np.zeros(1), np.ones(1))
        est.step(np.zeros(1), np.ones(1))
        x_before, P_before = est.x.copy(), est.P.copy()
        bad_f.armed = True
        with pytest.raises(FiniteEscapeError) as info:
            est.step(np.zeros(1), np.ones(1))
        assert info.value.quantity == "x"
        assert info.value.time == pytest.approx(0.03)
        np.testing.assert_array_equal(est.x, x_before)  # unchanged
        np.testing.assert_array_equal(est.P, P_before)
        assert est.t_s == pytest.approx(0.02)


def test_non_finite_jacobian_raises_finite_escape_naming_it():
    s = random_system(np.random.default_rng(0), 2, 1, 1)
    f, F, h, H = linear_callables(s)
    ekf = ExtendedKalmanFilter(f, lambda x, u: F(x, u) * np.nan, h, H, s.Q, s.R, np.zeros(2),
                               np.eye(2), k=1)
    with pytest.raises(FiniteEscapeError) as info:
        ekf.step(np.zeros(1), np.ones(1))
    assert info.value.quantity == "F"
    assert info.value.time == 1.0  # steps without dt_s


def test_indefinite_innovation_covariance_raises_loss_of_definiteness():
    s = random_system(np.random.default_rng(0), 2, 1, 1)
    f, F, h, H = linear_callables(s)
    # S = H P H^T + R is PD for a checked P and a validated R: test the typed path directly
    ekf = ExtendedKalmanFilter(f, F, h, H, s.Q, s.R, np.zeros(2), np.eye(2), k=1, dt_s=0.5)
    with pytest.raises(LossOfDefinitenessError) as info:
        ekf._innovation_factor(-np.eye(1)[None], 3)
    assert info.value.quantity == "innovation_cov" and info.value.time == 1.5
    with pytest.raises(FiniteEscapeError) as info:
        ekf._innovation_factor(np.full((1, 1, 1), np.nan), 3)
    assert info.value.quantity == "innovation_cov"


@pytest.mark.parametrize("which", ["ekf", "ukf"])
def test_a_covariance_that_is_not_psd_raises_loss_of_definiteness(which):
    s = random_system(np.random.default_rng(0), 2, 1, 1)
    est = (make_ekf if which == "ekf" else make_ukf)(s, np.zeros(2), np.eye(2))
    est.step(np.zeros(1), np.ones(1))
    # a covariance that is not PSD cannot enter through the API: corrupt the internals
    est._P = np.array([[1.0, 0.0], [0.0, -100.0]])
    x_before = est.x.copy()
    with pytest.raises(LossOfDefinitenessError) as info:
        est.step(np.zeros(1), np.ones(1))
    assert info.value.quantity in ("P", "innovation_cov")
    assert info.value.time == pytest.approx(0.02)
    np.testing.assert_array_equal(est.x, x_before)


def test_wrong_shape_from_a_model_function_is_a_value_error_naming_it():
    s = random_system(np.random.default_rng(0), 2, 1, 1)
    f, F, h, H = linear_callables(s)
    ekf = ExtendedKalmanFilter(f, F, lambda x, u: np.zeros((len(x), 3)), H, s.Q, s.R,
                               np.zeros(2), np.eye(2), k=1)
    with pytest.raises(ValueError, match=r"h\(x, u\) must return shape \(1, 1\)"):
        ekf.step(np.zeros(1), np.ones(1))
    assert ekf.t_s == 0
    ukf = UnscentedKalmanFilter(lambda x, u: x[:, :1], h, s.Q, s.R, np.zeros(2), np.eye(2), k=1)
    with pytest.raises(ValueError, match=r"f\(x, u\) must return shape \(5, 2\)"):
        ukf.step(np.zeros(1), np.ones(1))


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("which", ["ekf", "ukf"])
def test_bad_arguments_raise_value_errors_naming_them(which):
    s = random_system(np.random.default_rng(0), 2, 1, 1)
    f, F, h, H = linear_callables(s)

    def make(Q=s.Q, R=s.R, x0=None, P0=None, k=1, **kw):
        x0 = np.zeros(2) if x0 is None else x0
        P0 = np.eye(2) if P0 is None else P0
        if which == "ekf":
            return ExtendedKalmanFilter(f, F, h, H, Q, R, x0, P0, k=k, **kw)
        return UnscentedKalmanFilter(f, h, Q, R, x0, P0, k=k, **kw)

    with pytest.raises(ValueError, match="^Q must"):
        make(Q=-np.eye(2))
    with pytest.raises(ValueError, match="^Q must"):
        make(Q=np.ones(3))
    with pytest.raises(ValueError, match="^R must"):
        make(R=np.zeros((1, 1)))
    with pytest.raises(ValueError, match="^x0 must"):
        make(x0=np.zeros(3))
    with pytest.raises(ValueError, match="^x0 must"):
        make(x0=np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match="^P0 must"):
        make(P0=np.array([[1.0, 0.0], [0.0, -1.0]]))
    with pytest.raises(ValueError, match="^k "):
        make(k=-1)
    with pytest.raises(ValueError, match="^dt_s"):
        make(dt_s=0.0)
    est = make()
    with pytest.raises(ValueError, match="^y must"):
        est.step(np.zeros(2), np.ones(1))
    with pytest.raises(ValueError, match="^y must"):
        est.step(np.array([np.nan]), np.ones(1))
    with pytest.raises(ValueError, match="^u must"):
        est.step(np.zeros(1), np.ones(2))
    with pytest.raises(ValueError, match="^u must"):
        est.step(np.zeros(1), np.array([1j]))
    assert est.t_s == 0
    with pytest.raises(TypeError, match="^h must be callable"):
        if which == "ekf":
            ExtendedKalmanFilter(f, F, None, H, s.Q, s.R, np.zeros(2), np.eye(2))
        else:
            UnscentedKalmanFilter(f, None, s.Q, s.R, np.zeros(2), np.eye(2))


def test_ukf_parameters_are_validated():
    s = random_system(np.random.default_rng(0), 2, 1, 1)
    f, _, h, _ = linear_callables(s)
    for kw, word in (({"alpha": 0.0}, "alpha"), ({"alpha": 1.5}, "alpha"),
                     ({"beta": -1.0}, "beta"), ({"kappa": -2.0}, "kappa"),
                     ({"alpha": "x"}, "alpha"), ({"kappa": np.nan}, "kappa")):
        with pytest.raises(ValueError, match=f"^{word} must"):
            UnscentedKalmanFilter(f, h, s.Q, s.R, np.zeros(2), np.eye(2), k=1, **kw)


def test_no_input_model_accepts_none_and_rejects_an_input():
    Q, R = 1e-3 * np.eye(2), 1e-2 * np.eye(1)
    h = lambda x, u: x[:, :1]  # noqa: E731
    ukf = UnscentedKalmanFilter(lambda x, u: x, h, Q, R, np.zeros(2), np.eye(2))
    ukf.step(np.ones(1))
    assert ukf.x[0] > 0
    with pytest.raises(ValueError, match="^u must be None"):
        ukf.step(np.ones(1), np.ones(1))
