"""Discrete-time :class:`filters.KalmanFilter`."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF
from scipy.stats import chi2

from filters import (
    DiscreteLinearSystem,
    Estimator,
    FiniteEscapeError,
    KalmanFilter,
    LossOfDefinitenessError,
)


def random_system(
    rng: np.random.Generator, n: int, m: int, k: int, dt_s: float | None = 0.01
) -> DiscreteLinearSystem:
    """Random stable-ish system with PD noise covariances."""
    F = rng.standard_normal((n, n))
    F *= 0.97 / max(1.0, np.abs(np.linalg.eigvals(F)).max())
    G = rng.standard_normal((n, n))
    L = rng.standard_normal((m, m))
    return DiscreteLinearSystem(
        F=F,
        B=rng.standard_normal((n, k)) if k else None,
        H=rng.standard_normal((m, n)),
        Q=0.1 * G @ G.T + 1e-3 * np.eye(n),
        R=L @ L.T + 0.1 * np.eye(m),
        dt_s=dt_s,
    )


def simulate(
    system: DiscreteLinearSystem, x0: np.ndarray, steps: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample the model; returns states (steps+1, ..., n), inputs (steps, k), outputs."""
    n, m, k = system.n, system.m, system.k
    batch = x0.shape[:-1]
    xs = [x0]
    us = rng.standard_normal((steps, k))
    ys = []
    Lq = np.linalg.cholesky(system.Q)
    Lr = np.linalg.cholesky(system.R)
    for i in range(steps):
        w = rng.standard_normal((*batch, n)) @ Lq.T
        x = xs[-1] @ system.F.T + us[i] @ system.B.T + w
        ys.append(x @ system.H.T + rng.standard_normal((*batch, m)) @ Lr.T)
        xs.append(x)
    return np.array(xs), us, np.array(ys)


@pytest.mark.parametrize(
    ("seed", "n", "m", "k"),
    [(0, 2, 1, 0), (1, 3, 2, 1), (2, 4, 2, 2), (3, 5, 3, 1), (4, 6, 1, 3), (5, 6, 3, 2)],
)
def test_matches_filterpy(seed: int, n: int, m: int, k: int) -> None:
    rng = np.random.default_rng(seed)
    system = random_system(rng, n, m, k)
    x0 = rng.standard_normal(n)
    G = rng.standard_normal((n, n))
    P0 = G @ G.T + np.eye(n)
    _, us, ys = simulate(system, x0, 50, rng)

    ref = FilterpyKF(dim_x=n, dim_z=m, dim_u=k)
    ref.F, ref.H, ref.Q, ref.R = system.F, system.H, system.Q, system.R
    if k:
        ref.B = system.B
    ref.x, ref.P = x0.reshape(n, 1).copy(), P0.copy()
    kf = KalmanFilter(system, x0, P0)
    for i in range(50):
        u = us[i] if k else None
        ref.predict(u=u.reshape(k, 1) if k else None)
        ref.update(ys[i].reshape(m, 1))
        kf.step(ys[i], u)
        np.testing.assert_allclose(kf.x, ref.x[:, 0], rtol=0, atol=1e-10)
        np.testing.assert_allclose(kf.P, ref.P, rtol=0, atol=1e-10)
        np.testing.assert_allclose(kf.gain, ref.K, rtol=0, atol=1e-10)
        np.testing.assert_allclose(kf.innovation, ref.y[:, 0], rtol=0, atol=1e-10)
        np.testing.assert_allclose(kf.innovation_cov, ref.S, rtol=0, atol=1e-10)
        assert np.array_equal(kf.P, kf.P.T)
    assert kf.t_s == pytest.approx(50 * 0.01)


def test_predict_update_equals_step_and_time_counting() -> None:
    rng = np.random.default_rng(7)
    system = random_system(rng, 4, 2, 1, dt_s=None)
    a = KalmanFilter(system, np.zeros(4), np.eye(4))
    b = KalmanFilter(system, np.zeros(4), np.eye(4))
    for _ in range(5):
        y, u = rng.standard_normal(2), rng.standard_normal(1)
        a.step(y, u)
        b.predict(u)
        b.update(y)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
    assert a.t_s == b.t_s == 5.0
    a.reset(np.ones(4), 2 * np.eye(4))
    assert a.t_s == 0.0
    np.testing.assert_array_equal(a.x, np.ones(4))


def test_steady_state_matches_dare() -> None:
    rng = np.random.default_rng(11)
    system = random_system(rng, 4, 2, 1)
    P_inf, K_inf = KalmanFilter(system, np.zeros(4), np.eye(4)).steady_state()
    kf = KalmanFilter(system, np.zeros(4), 10.0 * np.eye(4))
    for _ in range(2000):
        kf.step(rng.standard_normal(2))
    kf.predict()
    np.testing.assert_allclose(kf.P, P_inf, rtol=1e-8, atol=1e-12)
    kf.update(np.zeros(2))
    np.testing.assert_allclose(kf.gain, K_inf, rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("k", [0, 2])
def test_batch_equals_separate_filters(k: int) -> None:
    rng = np.random.default_rng(3)
    n, m, batch = 4, 2, 5
    system = random_system(rng, n, m, k)
    x0 = rng.standard_normal((batch, n))
    G = rng.standard_normal((batch, n, n))
    P0 = G @ np.swapaxes(G, -1, -2) + np.eye(n)
    ys = rng.standard_normal((30, batch, m))
    us = rng.standard_normal((30, batch, k))
    batched = KalmanFilter(system, x0, P0)
    singles = [KalmanFilter(system, x0[j], P0[j]) for j in range(batch)]
    ones = [KalmanFilter(system, x0[j:j + 1], P0[j:j + 1]) for j in range(batch)]
    assert batched.batch_shape == (batch,)
    for i in range(30):
        batched.step(ys[i], us[i] if k else None)
        for j, f in enumerate(singles):
            f.step(ys[i, j], us[i, j] if k else None)
            ones[j].step(ys[i, j:j + 1], us[i, j:j + 1] if k else None)
    for j, f in enumerate(ones):  # row-wise arithmetic: a row does not see the batch size
        np.testing.assert_array_equal(batched.x[j], f.x[0])
        np.testing.assert_array_equal(batched.P[j], f.P[0])
    for j, f in enumerate(singles):
        np.testing.assert_allclose(batched.x[j], f.x, rtol=0, atol=1e-14)
        np.testing.assert_allclose(batched.P[j], f.P, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(batched.P, np.swapaxes(batched.P, -1, -2))


def test_batch_broadcasts_P0_and_shared_measurement() -> None:
    rng = np.random.default_rng(4)
    system = random_system(rng, 3, 1, 0)
    kf = KalmanFilter(system, np.zeros((2, 3)), np.eye(3))
    assert kf.x.shape == (2, 3) and kf.P.shape == (2, 3, 3)
    kf.step(np.array([0.5]))  # shape (m,) is broadcast over the batch
    np.testing.assert_array_equal(kf.x[0], kf.x[1])
    with pytest.raises(ValueError, match=r"^y must have shape"):
        kf.step(np.zeros((3, 1)))


@pytest.mark.parametrize(
    ("y", "fragment"),
    [
        (np.zeros(3), r"^y must have shape \(2,\), got shape \(3,\)"),
        (np.zeros((2, 1)), r"^y must have shape \(2,\)"),
        (np.array([0.0, np.nan]), r"^y must be finite"),
        (np.array([np.inf, 0.0]), r"^y must be finite"),
        ([1.0, "a"], r"^y must be a real numeric array"),
    ],
)
def test_bad_y_raises_and_leaves_state_unchanged(y: object, fragment: str) -> None:
    rng = np.random.default_rng(5)
    kf = KalmanFilter(random_system(rng, 4, 2, 1), rng.standard_normal(4), np.eye(4))
    kf.step(rng.standard_normal(2))
    x, P, t = kf.x.copy(), kf.P.copy(), kf.t_s
    for call in (kf.step, kf.update):
        with pytest.raises(ValueError, match=fragment):
            call(y)  # type: ignore[operator]
        np.testing.assert_array_equal(kf.x, x)
        np.testing.assert_array_equal(kf.P, P)
        assert kf.t_s == t


def test_bad_u_and_initial_conditions() -> None:
    rng = np.random.default_rng(6)
    system = random_system(rng, 4, 2, 1)
    kf = KalmanFilter(system, np.zeros(4), np.eye(4))
    with pytest.raises(ValueError, match=r"^u must have shape \(1,\)"):
        kf.step(np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match=r"^u must be finite"):
        kf.predict(np.array([np.nan]))
    assert kf.t_s == 0.0
    no_input = KalmanFilter(random_system(rng, 4, 2, 0), np.zeros(4), np.eye(4))
    with pytest.raises(ValueError, match=r"^u must be None"):
        no_input.step(np.zeros(2), np.ones(1))
    with pytest.raises(ValueError, match=r"^x0 must have shape \(4,\)"):
        KalmanFilter(system, np.zeros(3), np.eye(4))
    with pytest.raises(ValueError, match=r"^P0 must be symmetric positive semidefinite"):
        KalmanFilter(system, np.zeros(4), -np.eye(4))
    with pytest.raises(ValueError, match=r"do not broadcast"):
        KalmanFilter(system, np.zeros((2, 4)), np.stack([np.eye(4)] * 3))
    with pytest.raises(ValueError, match="read-only"):
        kf.x[0] = 1.0


def test_singular_prior_uses_explicit_joseph_path() -> None:
    """P0 = 0 (exactly known state) is PSD but has no Cholesky factor."""
    rng = np.random.default_rng(8)
    system = random_system(rng, 3, 1, 0)
    system = DiscreteLinearSystem(F=system.F, B=None, H=system.H, Q=np.zeros((3, 3)), R=system.R)
    kf = KalmanFilter(system, np.ones(3), np.zeros((3, 3)))
    kf.step(np.array([1.0]))
    np.testing.assert_allclose(kf.P, 0.0, atol=1e-300)
    np.testing.assert_allclose(kf.x, system.F @ np.ones(3), rtol=1e-15)


def test_unstable_prediction_raises_finite_escape() -> None:
    system = DiscreteLinearSystem(F=[[10.0]], B=None, H=[[1.0]], Q=[[1.0]], R=[[1.0]], dt_s=0.5)
    kf = KalmanFilter(system, [0.0], [[1.0]])
    with pytest.raises(FiniteEscapeError) as info:
        for _ in range(20):
            kf.predict()
    err = info.value
    # P_k = 100^k + (100^k - 1) / 99 first exceeds 1e12 at k = 6, i.e. t = 3 s
    assert err.quantity == "P" and err.time == pytest.approx(3.0)
    assert "t = 3 s" in str(err) and "'P'" in str(err)
    assert kf.t_s == pytest.approx(2.5)  # state left at the last good step
    assert kf.P[0, 0] < 1e12
    clone = pickle.loads(pickle.dumps(err))
    assert isinstance(clone, FiniteEscapeError) and clone.time == err.time


def test_nees_consistency_monte_carlo() -> None:
    """500 Monte-Carlo runs of the true model: mean NEES within the chi-square 99% interval."""
    rng = np.random.default_rng(2024)
    n, runs, steps = 4, 500, 40
    system = random_system(rng, n, 2, 1)
    P0 = np.diag([1.0, 2.0, 0.5, 1.5])
    x_true0 = rng.standard_normal((runs, n)) @ np.linalg.cholesky(P0).T
    xs, us, ys = simulate(system, x_true0, steps, rng)
    kf = KalmanFilter(system, np.zeros((runs, n)), P0)
    nees = []
    for i in range(steps):
        kf.step(ys[i], us[i])
        e = xs[i + 1] - kf.x
        nees.append(np.einsum("ri,rij,rj->r", e, np.linalg.inv(kf.P), e))
    nees_arr = np.array(nees)  # (steps, runs)
    lo, hi = chi2.ppf([0.005, 0.995], runs * n) / runs
    for i in (9, 19, 39):  # a few fixed times: each mean NEES ~ chi2(runs * n) / runs
        assert lo < nees_arr[i].mean() < hi, (i, nees_arr[i].mean(), lo, hi)
    # the test has power: a filter that under-states Q by 3x is flagged as inconsistent
    wrong = DiscreteLinearSystem(system.F, system.B, system.H, system.Q / 3.0, system.R)
    kf_wrong = KalmanFilter(wrong, np.zeros((runs, n)), P0)
    for i in range(steps):
        kf_wrong.step(ys[i], us[i])
    e = xs[-1] - kf_wrong.x
    assert np.einsum("ri,rij,rj->r", e, np.linalg.inv(kf_wrong.P), e).mean() > hi
    # and the empirical error covariance at the end matches P (same for all runs)
    e = xs[-1] - kf.x
    emp = e.T @ e / runs
    se = np.sqrt((kf.P[0] ** 2 + np.outer(np.diag(kf.P[0]), np.diag(kf.P[0]))) / runs)
    assert np.all(np.abs(emp - kf.P[0]) < 4.0 * se)


def test_protocol_and_name() -> None:
    rng = np.random.default_rng(9)
    kf = KalmanFilter(random_system(rng, 2, 1, 0), np.zeros(2), np.eye(2))
    assert isinstance(kf, Estimator)
    assert KalmanFilter.name == "kalman"


def test_innovation_covariance_failure_is_typed() -> None:
    rng = np.random.default_rng(10)
    kf = KalmanFilter(random_system(rng, 2, 1, 0), np.zeros(2), np.eye(2))
    kf._R = np.array([[-1e6]])  # corrupt the model to force an indefinite H P H^T + R
    with pytest.raises(LossOfDefinitenessError) as info:
        kf.update(np.zeros(1))
    assert info.value.quantity == "innovation_cov"


def test_feedthrough_matches_filterpy_on_corrected_measurement() -> None:
    """With ``y = H x + D u + v`` the filter equals filterpy fed ``y - D u``."""
    rng = np.random.default_rng(12)
    base = random_system(rng, 3, 2, 1)
    D = rng.standard_normal((2, 1))
    system = DiscreteLinearSystem(base.F, base.B, base.H, base.Q, base.R, dt_s=0.1, D=D)
    ref = FilterpyKF(dim_x=3, dim_z=2, dim_u=1)
    ref.F, ref.B, ref.H, ref.Q, ref.R = system.F, system.B, system.H, system.Q, system.R
    ref.x, ref.P = np.zeros((3, 1)), np.eye(3)
    kf = KalmanFilter(system, np.zeros(3), np.eye(3))
    for _ in range(20):
        y, u = rng.standard_normal(2), rng.standard_normal(1)
        kf.step(y, u)
        ref.predict(u=u.reshape(1, 1))
        ref.update((y - D @ u).reshape(2, 1))
        np.testing.assert_allclose(kf.x, ref.x[:, 0], rtol=0, atol=1e-10)
        np.testing.assert_allclose(kf.P, ref.P, rtol=0, atol=1e-10)


def test_a_strided_batch_gives_the_members_of_a_contiguous_one_bitwise():
    # numpy's vecmat takes another kernel for a strided batch of vectors (a Fortran-ordered
    # y differed in the last bit in 82 of 200 draws before the filters made it contiguous)
    from filters import LinearFilter

    rng = np.random.default_rng(4)
    G, K = 0.5 * rng.normal(size=(4, 4)), rng.normal(size=(4, 2))
    batch, single = (LinearFilter(G, K, np.ones((r, 4)), discrete=True) for r in (4, 1))
    for _ in range(50):
        y = np.asfortranarray(rng.normal(size=(4, 2)))
        batch.step(y)
        single.step(np.ascontiguousarray(y[2:3]))
        np.testing.assert_array_equal(batch.x[2], single.x[0])
