"""FilterInLoop, the episode metrics and the closed loop with the LQR controller."""

from __future__ import annotations

import numpy as np
import pytest

from filters import KalmanFilter, LinearSystem
from testbed.envs.helicopter import Helicopter2DOFEnv
from testbed.experiment import build_helicopter, run_episode
from testbed.metrics import EpisodeMetrics
from testbed.rigs.helicopter import paper_model
from testbed.wrappers import FilterInLoop


def test_observation_is_the_estimate_and_info_keeps_truth_and_measurement():
    exp = build_helicopter("kalman", "lqr")
    x_hat, info = exp.env.reset(seed=0)
    np.testing.assert_array_equal(x_hat, exp.env.estimator.x)
    for _ in range(5):
        x_hat, _, _, _, info = exp.env.step(exp.policy(x_hat))
    np.testing.assert_array_equal(x_hat, info["estimate"])
    np.testing.assert_array_equal(info["error"], info["estimate"] - info["state"])
    assert info["measurement"].shape == (2,)
    assert info["covariance"].shape == (4, 4)
    assert exp.env.observation_space.shape == (4,)


def test_estimator_prior_from_reset_options():
    exp = build_helicopter("kalman", "lqr")
    x0 = np.array([-0.7, 0.1, 0.0, 0.0])
    x_hat, _ = exp.env.reset(seed=0, options={"estimator": {"x0": x0}})
    np.testing.assert_array_equal(x_hat, x0)
    with pytest.raises(ValueError, match="estimator"):
        exp.env.reset(seed=0, options={"estimator": {"xx": x0}})


def test_metrics_match_a_recomputation_from_the_trajectory():
    exp = build_helicopter("kalman", "lqr", disturbance="seed000", process_noise_scale=0.1)
    traj, summary = run_episode(exp, 3.0, seed=2)
    err = traj.estimate[1:] - traj.state[1:]
    rmse = np.sqrt(np.mean(err**2, axis=0))
    np.testing.assert_allclose(list(summary["rmse"].values()), rmse, rtol=1e-12)
    meas = np.sqrt(np.mean((traj.measurement[1:] - traj.state[1:, :2]) ** 2, axis=0))
    np.testing.assert_allclose([summary["measurement_rmse"]["pitch"],
                                summary["measurement_rmse"]["yaw"]], meas, rtol=1e-12)
    nees = np.mean([e @ np.linalg.solve(P, e) for e, P in zip(err, traj.covariance[1:],
                                                               strict=True)])
    assert summary["nees_mean"] == pytest.approx(nees, rel=1e-12)
    # T ratio by hand: w held over each step [t_{k-1}, t_k), error at t_k
    from testbed.disturbances import seed000_w

    dt = 0.01
    w_sq = sum(float(seed000_w(t) @ seed000_w(t)) for t in traj.t_s[:-1]) * dt
    z_sq = float(np.sum(err[:, :2] ** 2)) * dt
    x0 = traj.state[0]
    assert summary["T_final"] == pytest.approx(np.sqrt(z_sq / (w_sq + x0 @ x0)), rel=1e-10)


def test_no_ratio_without_deterministic_disturbance():
    m = EpisodeMetrics(["a", "b"], 0.1, [0])
    m.update(np.zeros(2), np.ones(2), None, np.zeros(1), None)
    assert m.noise_output_ratio() is None
    assert m.nees_mean() is None
    assert m.rmse() == {"a": 1.0, "b": 1.0}


def test_closed_loop_runs_are_bitwise_reproducible():
    a, _ = run_episode(build_helicopter(process_noise_scale=0.2), 2.0, seed=5)
    b, _ = run_episode(build_helicopter(process_noise_scale=0.2), 2.0, seed=5)
    c, _ = run_episode(build_helicopter(process_noise_scale=0.2), 2.0, seed=6)
    for field in ("state", "estimate", "measurement", "action", "covariance"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(a.state, c.state)


def test_lqr_tracks_the_setpoints_on_the_nonlinear_rig():
    traj, summary = run_episode(build_helicopter("kalman", "lqr"), 15.0, seed=0)
    k = np.searchsorted(traj.t_s, 9.9)  # end of the second setpoint (10 deg, 30 deg)
    np.testing.assert_allclose(traj.state[k, :2], np.deg2rad([10.0, 30.0]), atol=np.deg2rad(1))
    assert summary["clipped_fraction"] < 0.2


def test_kalman_filter_beats_the_raw_measurement():
    exp = build_helicopter("kalman", "lqr", sensor_kwargs={"noise_std_rad": 0.002},
                           process_noise_scale=0.1)
    _, s = run_episode(exp, 8.0, seed=1)
    for angle in ("pitch", "yaw"):
        assert s["rmse"][angle] < 0.8 * s["measurement_rmse"][angle]
    assert 1.0 < s["nees_mean"] < 8.0


def test_kalman_bucy_in_the_loop_is_stable_and_consistent():
    """Kalman-Bucy on 100 Hz samples: its bandwidth is close to the sample rate here, so
    holding each sample over the interval costs accuracy against the exact discrete filter
    (a documented limitation); it must stay stable and consistent."""
    exp = build_helicopter("kalman-bucy", "lqr", sensor_kwargs={"noise_std_rad": 0.002},
                           process_noise_scale=0.1)
    _, s = run_episode(exp, 8.0, seed=1)
    _, s_kf = run_episode(build_helicopter("kalman", "lqr",
                                           sensor_kwargs={"noise_std_rad": 0.002},
                                           process_noise_scale=0.1), 8.0, seed=1)
    for angle in ("pitch", "yaw"):
        assert s["rmse"][angle] < 1.3 * s["measurement_rmse"][angle]
        assert s_kf["rmse"][angle] < s["rmse"][angle]
    assert 1.0 < s["nees_mean"] < 8.0


def test_wrapper_uses_the_applied_action_and_input_transform():
    env = Helicopter2DOFEnv()
    pm = paper_model()
    sysd = LinearSystem(A=pm.A, B=pm.B, C=np.eye(2, 4), Q=np.eye(4) * 1e-3,
                        R=np.eye(2) * 1e-6).discretize(env.dt_s)
    kf = KalmanFilter(sysd, np.zeros(4), np.eye(4) * 1e-2)
    seen = []

    def transform(u, x_hat):
        seen.append(u.copy())
        return np.zeros(2)

    wrapped = FilterInLoop(env, kf, input_transform=transform)
    wrapped.reset(seed=0)
    wrapped.step(np.array([30.0, -1.0]))
    np.testing.assert_array_equal(seen[0], [24.0, -1.0])


def test_ms_hinf_flies_the_rig_with_the_y2_channel():
    exp = build_helicopter("ms-hinf", "lqr", disturbance="seed000")
    inner = exp.env.unwrapped
    assert inner.sensors.dim == 4 and inner.sensors.names[2:] == ["y2_0", "y2_1"]
    traj, s = run_episode(exp, 3.0, seed=0)
    # y2 = C2 x + H w: pitch + w3, yaw + w4 exactly (no noise on the deterministic channel)
    from testbed.disturbances import seed000_w

    k = 100
    w = seed000_w(traj.t_s[k])
    np.testing.assert_allclose(traj.measurement[k, 2:], traj.state[k, :2] + w[2:], atol=1e-12)
    assert s["T_final"] is not None and s["T_final"] < 1.1
    assert s["rmse"]["pitch"] < np.deg2rad(1.0)
    with pytest.raises(ValueError, match="seed000"):
        build_helicopter("ms-hinf", "lqr", disturbance="none")
