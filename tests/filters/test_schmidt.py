"""Schmidt-Kalman filter: the Kalman filter without constants, an independent loop with
them, and consistency on runs whose sensitivity error is a random constant."""

from __future__ import annotations

import numpy as np
import pytest

from filters import DiscreteLinearSystem, KalmanFilter
from filters.schmidt import ConsiderParameter, SchmidtKalmanFilter

DT_S = 0.05
F = np.array([[1.0, DT_S], [-0.2 * DT_S, 0.98]])
B = np.array([[0.0], [DT_S]])
H = np.array([[1.0, 0.0], [0.0, 1.0]])
D = np.array([[0.0], [0.1]])
SYSTEM = DiscreteLinearSystem(F=F, B=B, H=H, D=D, Q=np.diag([1e-6, 1e-3]),
                              R=np.diag([1e-4, 4e-4]), dt_s=DT_S)
X0, P0 = np.zeros(2), np.diag([0.01, 0.04])


def _inputs(steps: int) -> np.ndarray:
    return np.sin(0.3 * np.arange(steps))[:, None]


def test_without_constants_it_is_the_kalman_filter() -> None:
    rng = np.random.default_rng(0)
    ys = rng.normal(size=(40, 3, 2))
    us = _inputs(40)
    kf = KalmanFilter(SYSTEM, np.zeros((3, 2)), P0)
    sk = SchmidtKalmanFilter(SYSTEM, np.zeros((3, 2)), P0,
                             [ConsiderParameter(0.0, measurement_state=np.eye(2))])
    for y, u in zip(ys, us, strict=True):
        np.testing.assert_allclose(sk.step(y, u), kf.step(y, u), rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(sk.P, kf.P, rtol=1e-10, atol=1e-16)
        np.testing.assert_allclose(sk.innovation_cov, kf.innovation_cov, rtol=1e-10)


def _reference_step(x, Pa, y, u, params):
    """The Schmidt recursion written out for one filter (Simon 2006, section 7.5)."""
    n = 2
    p = len(params)

    def z(value, shape):
        return np.zeros(shape) if value is None else np.asarray(value)

    T = np.column_stack([z(c.transition_state, (2, 2)) @ x + z(c.transition_input, (2, 1)) @ u
                         for c in params])
    Fa = np.block([[F, T], [np.zeros((p, n)), np.eye(p)]])
    xp = F @ x + B @ u
    Pa = Fa @ Pa @ Fa.T + np.block([[SYSTEM.Q, np.zeros((n, p))],
                                    [np.zeros((p, n)), np.zeros((p, p))]])
    Hs = np.column_stack([z(c.measurement_state, (2, 2)) @ xp
                          + z(c.measurement_input, (2, 1)) @ u for c in params])
    Ha = np.hstack([H, Hs])
    S = Ha @ Pa @ Ha.T + SYSTEM.R
    K = Pa @ Ha.T @ np.linalg.inv(S)
    K[n:] = 0.0
    x_new = xp + K[:n] @ (y - H @ xp - D @ u)
    A = np.eye(n + p) - K @ Ha
    return x_new, A @ Pa @ A.T + K @ SYSTEM.R @ K.T


def test_an_independent_recursion_with_constants() -> None:
    params = [ConsiderParameter(0.05, "gyro scale", measurement_state=np.diag([0.0, 1.0]),
                                measurement_input=np.array([[0.0], [0.1]])),
              ConsiderParameter(0.02, "input scale", transition_input=-B,
                                measurement_input=-D, transition_state=0.1 * np.eye(2))]
    sk = SchmidtKalmanFilter(SYSTEM, X0, P0, params)
    x, Pa = X0.copy(), np.diag([0.01, 0.04, 0.05**2, 0.02**2])
    rng = np.random.default_rng(1)
    for u in _inputs(50):
        y = rng.normal(size=2) * 0.1
        x, Pa = _reference_step(x, Pa, y, u, params)
        sk.step(y, u)
        np.testing.assert_allclose(sk.x, x, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(sk.joint_covariance, Pa, rtol=1e-9, atol=1e-16)
    assert np.allclose(sk.joint_covariance, sk.joint_covariance.swapaxes(-1, -2))


def test_consistent_where_white_noise_for_the_constant_is_not() -> None:
    # the rate channel's sensitivity error is drawn once per run (std 10 %)
    runs, steps, std = 400, 200, 0.1
    rng = np.random.default_rng(2)
    scale = std * rng.standard_normal(runs)
    us = 10.0 * _inputs(steps)
    x = rng.multivariate_normal(X0, P0, size=runs)
    params = [ConsiderParameter(std, measurement_state=np.diag([0.0, 1.0]),
                                measurement_input=np.array([[0.0], [0.1]]))]
    sk = SchmidtKalmanFilter(SYSTEM, np.zeros((runs, 2)), P0, params)
    # the white-noise stand-in: the constant's variance at the signal's RMS in R
    rate_rms = 0.5
    white = DiscreteLinearSystem(F=F, B=B, H=H, D=D, Q=SYSTEM.Q,
                                 R=SYSTEM.R + np.diag([0.0, (std * rate_rms) ** 2]), dt_s=DT_S)
    kf = KalmanFilter(white, np.zeros((runs, 2)), P0)
    nees_sk, nees_kf = [], []
    chol_q, chol_r = np.linalg.cholesky(SYSTEM.Q), np.linalg.cholesky(SYSTEM.R)
    for u in us:
        x = x @ F.T + u @ B.T + rng.standard_normal((runs, 2)) @ chol_q.T
        signal = x @ H.T + u @ D.T
        y = signal + np.column_stack([np.zeros(runs), scale * signal[:, 1]]) \
            + rng.standard_normal((runs, 2)) @ chol_r.T
        for est, out in ((sk, nees_sk), (kf, nees_kf)):
            est.step(y, u)
            e = est.x - x
            out.append(np.einsum("ri,rij,rj->r", e, np.linalg.inv(est.P), e))
    anees_sk = np.mean(nees_sk[50:])
    anees_kf = np.mean(nees_kf[50:])
    assert anees_sk == pytest.approx(2.0, rel=0.1)
    assert anees_kf > 1.3 * anees_sk  # overconfident: the error does not average out


def test_bad_input_is_named() -> None:
    with pytest.raises(ValueError, match=r"parameters\[0\] \(g\): std must be finite"):
        SchmidtKalmanFilter(SYSTEM, X0, P0, [ConsiderParameter(-1.0, "g")])
    with pytest.raises(ValueError, match=r"parameters\[0\] \(g\)"):
        SchmidtKalmanFilter(SYSTEM, X0, P0, [ConsiderParameter(0.1, "g",
                                                               measurement_state=np.eye(3))])
    with pytest.raises(ValueError, match="parameters\\[0\\] must be a ConsiderParameter"):
        SchmidtKalmanFilter(SYSTEM, X0, P0, [0.1])
    with pytest.raises(ValueError, match="system must be a DiscreteLinearSystem"):
        SchmidtKalmanFilter("kalman", X0, P0, [])
    sk = SchmidtKalmanFilter(SYSTEM, X0, P0, [])
    with pytest.raises(ValueError, match="y must have shape"):
        sk.step(np.zeros(3))


def test_a_failed_step_leaves_the_filter_unchanged() -> None:
    sk = SchmidtKalmanFilter(SYSTEM, X0, P0, [ConsiderParameter(0.1, measurement_state=H)])
    with pytest.raises(ValueError, match="y must be finite"):
        sk.step(np.array([np.nan, 0.0]))
    assert sk.t_s == 0.0 and sk.innovation is None
