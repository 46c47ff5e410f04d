"""Continuous-time :class:`filters.KalmanBucyFilter` and :func:`filters.check_covariance`."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from filters import (
    Estimator,
    FilterError,
    FiniteEscapeError,
    KalmanBucyFilter,
    KalmanFilter,
    LinearSystem,
    LossOfDefinitenessError,
    check_covariance,
)


def random_system(seed: int, n: int = 3, m: int = 2, k: int = 1) -> LinearSystem:
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((n, n))
    L = rng.standard_normal((m, m))
    return LinearSystem(
        A=rng.standard_normal((n, n)),
        B=rng.standard_normal((n, k)) if k else None,
        C=rng.standard_normal((m, n)),
        Q=G @ G.T,
        R=L @ L.T + 0.5 * np.eye(m),
    )


def reference_solution(
    system: LinearSystem,
    x0: np.ndarray,
    P0: np.ndarray,
    ys: np.ndarray,
    us: np.ndarray,
    dt: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman-Bucy ODE with ZOH data, integrated by DOP853 at rtol 1e-13."""
    n = system.n
    A, B, C, Q = system.A, system.B, system.C, system.Q
    Rinv = np.linalg.inv(system.R)
    z = np.concatenate([x0, P0.ravel()])
    for y, u in zip(ys, us, strict=True):

        def rhs(_t: float, z: np.ndarray, y: np.ndarray = y, u: np.ndarray = u) -> np.ndarray:
            m, P = z[:n], z[n:].reshape(n, n)
            dm = A @ m + B @ u + P @ C.T @ Rinv @ (y - C @ m)
            dP = A @ P + P @ A.T + Q - P @ C.T @ Rinv @ C @ P
            return np.concatenate([dm, dP.ravel()])

        z = solve_ivp(rhs, (0.0, dt), z, method="DOP853", rtol=1e-13, atol=1e-14).y[:, -1]
    return z[:n], z[n:].reshape(n, n)


def test_rk4_convergence_order() -> None:
    system = random_system(0)
    rng = np.random.default_rng(100)
    dt, intervals = 0.5, 4
    ys = rng.standard_normal((intervals, system.m))
    us = rng.standard_normal((intervals, system.k))
    x0, P0 = rng.standard_normal(system.n), np.eye(system.n)
    x_ref, P_ref = reference_solution(system, x0, P0, ys, us, dt)
    errors = []
    for substeps in (32, 64, 128):  # step sizes h, h/2, h/4
        kb = KalmanBucyFilter(system, x0, P0, dt, substeps=substeps)
        for y, u in zip(ys, us, strict=True):
            kb.step(y, u)
        errors.append(max(np.abs(kb.x - x_ref).max(), np.abs(kb.P - P_ref).max()))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[-1] < 1e-8
    assert np.all((orders > 3.5) & (orders < 4.5)), (errors, orders)


def test_scalar_riccati_closed_form() -> None:
    """dP/dt = 2 a P + q - P^2 c^2 / r has a tanh closed form; RK4 error ~ h^4."""
    a, c, q, r, p0, T = -0.3, 2.0, 1.5, 0.4, 3.0, 1.0
    system = LinearSystem(A=[[a]], B=None, C=[[c]], Q=[[q]], R=[[r]])
    s = c * c / r
    lam = np.sqrt(a * a + q * s)
    p_inf, p_neg = (a + lam) / s, (a - lam) / s  # roots of s p^2 - 2 a p - q

    def exact(t: float) -> float:
        g = (p0 - p_inf) / (p0 - p_neg) * np.exp(-2.0 * lam * t)
        return (p_inf - p_neg * g) / (1.0 - g)

    kb = KalmanBucyFilter(system, [0.0], [[p0]], dt_s=T, substeps=400)
    kb.step([0.0])
    assert kb.P[0, 0] == pytest.approx(exact(T), rel=1e-9)
    assert kb.steady_state_covariance()[0, 0] == pytest.approx(p_inf, rel=1e-12)


def test_steady_state_matches_care() -> None:
    system = random_system(1)
    kb = KalmanBucyFilter(system, np.zeros(3), 5.0 * np.eye(3), dt_s=0.02, substeps=1)
    P_inf = kb.steady_state_covariance()
    for _ in range(3000):
        kb.step(np.zeros(2))
    np.testing.assert_allclose(kb.P, P_inf, rtol=1e-9, atol=1e-12)
    assert kb.t_s == pytest.approx(60.0)


def test_agrees_with_discrete_filter_as_dt_shrinks() -> None:
    """KF on ``system.discretize(dt)`` and Kalman-Bucy differ by O(dt).

    Tolerance (relative to the largest entry of the Kalman-Bucy x and P): at dt = 1e-3
    after 1 s both differences are below 2e-3 (observed 7e-4 and 1.3e-3), and shrinking
    dt 4x must shrink both by more than 3.5x (first order).
    """
    system = random_system(0)
    rng = np.random.default_rng(7)
    x0, P0 = rng.standard_normal(3), np.eye(3)
    diffs = []
    for dt in (4e-3, 1e-3):
        steps = round(1.0 / dt)
        t = np.arange(steps) * dt
        ys = np.stack([np.sin(2 * np.pi * t), np.cos(3 * t)], axis=1)
        us = np.sin(t)[:, None]
        kb = KalmanBucyFilter(system, x0, P0, dt_s=dt)
        kf = KalmanFilter(system.discretize(dt), x0, P0)
        for y, u in zip(ys, us, strict=True):
            kb.step(y, u)
            kf.step(y, u)
        assert kb.t_s == pytest.approx(kf.t_s)
        diffs.append(
            (
                np.abs(kb.x - kf.x).max() / np.abs(kb.x).max(),
                np.abs(kb.P - kf.P).max() / np.abs(kb.P).max(),
            )
        )
    (dx1, dP1), (dx2, dP2) = diffs
    assert dx2 < 2e-3 and dP2 < 2e-3, diffs
    assert dx1 / dx2 > 3.5 and dP1 / dP2 > 3.5, diffs


def test_batch_equals_separate_filters() -> None:
    system = random_system(2, n=4, m=2, k=2)
    rng = np.random.default_rng(3)
    batch = 5
    x0 = rng.standard_normal((batch, 4))
    G = rng.standard_normal((batch, 4, 4))
    P0 = G @ np.swapaxes(G, -1, -2) + np.eye(4)
    batched = KalmanBucyFilter(system, x0, P0, dt_s=0.01, substeps=2)
    singles = [KalmanBucyFilter(system, x0[j], P0[j], dt_s=0.01, substeps=2) for j in range(batch)]
    for _ in range(50):
        ys, us = rng.standard_normal((batch, 2)), rng.standard_normal((batch, 2))
        batched.step(ys, us)
        for j, f in enumerate(singles):
            f.step(ys[j], us[j])
    for j, f in enumerate(singles):
        np.testing.assert_allclose(batched.x[j], f.x, rtol=0, atol=1e-14)
        np.testing.assert_allclose(batched.P[j], f.P, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(batched.P, np.swapaxes(batched.P, -1, -2))


def test_bad_y_raises_and_leaves_state_unchanged() -> None:
    kb = KalmanBucyFilter(random_system(4), np.zeros(3), np.eye(3), dt_s=0.1)
    kb.step(np.ones(2))
    x, P = kb.x.copy(), kb.P.copy()
    for y in (np.array([1.0, np.nan]), np.zeros(3)):
        with pytest.raises(ValueError, match=r"^y must"):
            kb.step(y)
    np.testing.assert_array_equal(kb.x, x)
    np.testing.assert_array_equal(kb.P, P)
    assert kb.t_s == pytest.approx(0.1)
    kb.reset(np.ones(3), 2.0 * np.eye(3))
    assert kb.t_s == 0.0 and isinstance(kb, Estimator) and kb.name == "kalman-bucy"
    with pytest.raises(ValueError, match=r"^substeps must be an integer >= 1"):
        KalmanBucyFilter(random_system(4), np.zeros(3), np.eye(3), dt_s=0.1, substeps=0)
    with pytest.raises(ValueError, match=r"^dt_s must be a positive finite float"):
        KalmanBucyFilter(random_system(4), np.zeros(3), np.eye(3), dt_s=float("nan"))


@pytest.mark.parametrize(
    ("r", "error"), [(0.5, LossOfDefinitenessError), (1e-3, FiniteEscapeError)]
)
def test_unstable_rk4_step_raises_typed_error(r: float, error: type[FilterError]) -> None:
    """dP/dt = -P^2 / r, P(0) = 1, RK4 step h = 1: h / r = 2 overshoots to P = -1/3,
    h / r = 1000 to P ~ -4e40 (beyond the escape bound)."""
    system = LinearSystem(A=[[0.0]], B=None, C=[[1.0]], Q=[[0.0]], R=[[r]])
    kb = KalmanBucyFilter(system, [0.0], [[1.0]], dt_s=2.0, substeps=2)
    with pytest.raises(error) as info:
        kb.step([0.0])
    assert info.value.quantity == "P"
    assert info.value.time == pytest.approx(1.0)  # end of the first substep
    assert kb.t_s == 0.0 and kb.P[0, 0] == 1.0


def test_enough_substeps_fix_the_unstable_case() -> None:
    system = LinearSystem(A=[[0.0]], B=None, C=[[1.0]], Q=[[0.0]], R=[[0.5]])
    kb = KalmanBucyFilter(system, [0.0], [[1.0]], dt_s=2.0, substeps=200)
    kb.step([0.0])
    assert kb.P[0, 0] == pytest.approx(1.0 / (1.0 + 2.0 / 0.5), rel=1e-9)  # P = 1/(1 + t/r)


def test_check_covariance_typed_errors() -> None:
    P = np.eye(3)
    P[0, 1] = np.nan
    with pytest.raises(FiniteEscapeError) as esc:
        check_covariance(P, time=1.25, quantity="P_prior")
    assert esc.value.time == 1.25 and esc.value.quantity == "P_prior"
    assert "P_prior" in str(esc.value) and "1.25" in str(esc.value)
    assert isinstance(esc.value, FilterError) and isinstance(esc.value, RuntimeError)
    with pytest.raises(FiniteEscapeError):
        check_covariance(np.diag([1.0, 2e12]), time=0.0)
    with pytest.raises(LossOfDefinitenessError) as lod:
        check_covariance(np.array([[1.0, 2.0], [2.0, 1.0]]), time=3.0)
    assert lod.value.time == 3.0 and lod.value.quantity == "P"
    np.testing.assert_array_equal(lod.value.value, [[1.0, 2.0], [2.0, 1.0]])
    # batch: the failing member is reported
    stack = np.stack([np.eye(2), np.diag([1.0, -1.0])])
    with pytest.raises(LossOfDefinitenessError, match=r"batch index \(1,\)"):
        check_covariance(stack, time=0.0)


def test_check_covariance_accepts_psd_and_symmetrizes() -> None:
    P = np.array([[2.0, 1.0 + 1e-12], [1.0, 0.5]])  # singular PSD, slightly asymmetric
    out = check_covariance(P, time=0.0)
    np.testing.assert_array_equal(out, out.T)
    np.testing.assert_allclose(out, [[2.0, 1.0], [1.0, 0.5]], atol=1e-12)
    assert P[0, 1] == 1.0 + 1e-12  # input untouched
    check_covariance(np.zeros((4, 4)), time=0.0)
    check_covariance(np.diag([1.0, -1e-12]), time=0.0)  # within the 1e-9 relative tolerance
    batch = check_covariance(np.broadcast_to(np.eye(3), (2, 5, 3, 3)), time=0.0)
    assert batch.shape == (2, 5, 3, 3)
    with pytest.raises(ValueError, match="shape"):
        check_covariance(np.ones((2, 3)), time=0.0)


def test_feedthrough_equals_corrected_measurement() -> None:
    base = random_system(5)
    D = np.array([[0.7], [-1.3]])
    with_d = LinearSystem(A=base.A, B=base.B, C=base.C, Q=base.Q, R=base.R, D=D)
    a = KalmanBucyFilter(with_d, np.zeros(3), np.eye(3), dt_s=0.05, substeps=2)
    b = KalmanBucyFilter(base, np.zeros(3), np.eye(3), dt_s=0.05, substeps=2)
    c = KalmanBucyFilter(base, np.zeros(3), np.eye(3), dt_s=0.05, substeps=2)
    rng = np.random.default_rng(1)
    for _ in range(10):
        y, u = rng.standard_normal(2), rng.standard_normal(1)
        a.step(y, u)
        b.step(y - D @ u, u)
        c.step(y, u)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-14)
    np.testing.assert_allclose(a.P, b.P, rtol=0, atol=1e-14)
    assert np.abs(a.x - c.x).max() > 1e-3  # D is not ignored


def test_suggested_substeps_for_a_stiff_accurate_sensor() -> None:
    """Accurate sensor (R intensity 2e-8) at dt = 5 ms: one RK4 step is unstable."""
    A = np.array(
        [[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0], [-2.0, 0.0, -0.5, 0.0], [0, 0, 0, -0.3]]
    )
    system = LinearSystem(
        A=A, B=None, C=np.eye(2, 4), Q=np.diag([0, 0, 1e-3, 1e-3]), R=2e-8 * np.eye(2)
    )
    P0 = 1e-4 * np.eye(4)
    with pytest.raises(FilterError):
        KalmanBucyFilter(system, np.zeros(4), P0, dt_s=0.005).step(np.zeros(2))
    substeps = KalmanBucyFilter(system, np.zeros(4), P0, dt_s=0.005).suggested_substeps()
    assert 10 <= substeps <= 40
    kb = KalmanBucyFilter(system, np.zeros(4), P0, dt_s=0.005, substeps=substeps)
    rng = np.random.default_rng(0)
    for _ in range(400):
        kb.step(1e-3 * rng.standard_normal(2))
    np.testing.assert_allclose(kb.P, kb.steady_state_covariance(), rtol=1e-6, atol=1e-14)


def test_auto_substeps_survive_a_stiff_riccati_equation():
    """An accurate sensor (tiny R) makes fixed coarse RK4 blow up; 'auto' stays stable."""
    from filters import FilterError, KalmanBucyFilter, LinearSystem

    A = np.array([[0.0, 1.0], [0.0, -1.0]])
    system = LinearSystem(A=A, B=np.zeros((2, 1)), C=np.array([[1.0, 0.0]]),
                          Q=np.diag([0.0, 0.1]), R=np.array([[1e-9]]))
    P0 = np.eye(2) * 1e-3  # 'auto' asks for 8,000 substeps at first (cap 10,000)
    coarse = KalmanBucyFilter(system, np.zeros(2), P0, dt_s=0.01, substeps=1)
    with pytest.raises(FilterError):
        for _ in range(5):
            coarse.step(np.zeros(1))
    auto = KalmanBucyFilter(system, np.zeros(2), P0, dt_s=0.01, substeps="auto")
    for _ in range(200):
        auto.step(np.zeros(1))
    assert auto.substeps >= 1
    np.testing.assert_allclose(auto.P, auto.steady_state_covariance(), rtol=1e-6)
