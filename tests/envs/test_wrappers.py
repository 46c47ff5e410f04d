"""FilterInLoop, the episode metrics and the closed loop with the LQR controller."""

from __future__ import annotations

import numpy as np
import pytest

from filters import KalmanFilter, LinearSystem
from testbed.envs import RigEnv
from testbed.envs.wrappers import FilterInLoop
from testbed.experiment.control import make_controller
from testbed.experiment.metrics import EpisodeMetrics
from testbed.experiment.runner import run
from testbed.experiment.scenario import Scenario
from testbed.rigs.helicopter import basin_helicopter_w, paper_model


def filter_in_loop(estimator: str = "kalman", **env_kwargs):
    """A helicopter RigEnv wrapped with an estimator built from the rig's design model, and
    the LQR policy acting on the wrapper's observation (the estimate)."""
    env = RigEnv("helicopter", **env_kwargs)
    design = env.rig.design_model(env.sensors, env.dt_s, env.sim.known_disturbance)
    wrapped = FilterInLoop.from_design(env, estimator, design=design)
    ctrl = make_controller("lqr", env.rig, design, env.setpoint)
    ctrl.reset(1)

    def policy(x_hat):
        return ctrl(np.asarray(x_hat)[None], env.t_s)[0]

    return wrapped, policy, design


def helicopter(estimator: str = "kalman", **kwargs) -> Scenario:
    return Scenario(rig="helicopter", estimator=estimator, controller="lqr", **kwargs)


def test_observation_is_the_estimate_and_info_keeps_truth_and_measurement():
    env, policy, design = filter_in_loop()
    x_hat, info = env.reset(seed=0)
    np.testing.assert_array_equal(x_hat, env.estimator.x)
    np.testing.assert_array_equal(x_hat, design.x0)
    for _ in range(5):
        x_hat, _, _, _, info = env.step(policy(x_hat))
    np.testing.assert_array_equal(x_hat, info["estimate"])
    np.testing.assert_array_equal(x_hat, env.estimator.x)
    np.testing.assert_array_equal(info["error"], info["estimate"] - info["state"])
    assert info["measurement"].shape == (2,)
    assert info["covariance"].shape == (4, 4)
    assert env.observation_space.shape == (4,)
    assert env.metrics().count == 5
    # no deterministic disturbance: no noise-output ratio
    assert env.metrics().noise_output_ratio() is None


def test_estimator_prior_from_reset_options():
    env, _, _ = filter_in_loop()
    x0 = np.array([-0.7, 0.1, 0.0, 0.0])
    x_hat, _ = env.reset(seed=0, options={"estimator": {"x0": x0}})
    np.testing.assert_array_equal(x_hat, x0)
    x_hat, _ = env.reset(seed=0)  # back to the prior it had when wrapped
    np.testing.assert_array_equal(x_hat, env.unwrapped.rig.default_x0())
    with pytest.raises(ValueError, match="estimator"):
        env.reset(seed=0, options={"estimator": {"xx": x0}})
    # the other option keys still reach the environment
    _, info = env.reset(seed=0, options={"x0": np.zeros(4), "estimator": {"x0": x0}})
    np.testing.assert_array_equal(info["state"], np.zeros(4))
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(seed=0, options={"bogus": 1})


def test_wrapper_metrics_match_the_runner():
    """The same estimator, controller and seed through the wrapper and through run()."""
    env, policy, _ = filter_in_loop(disturbance="basin-helicopter", process_noise=0.1)
    x_hat, _ = env.reset(seed=2)
    states = []
    for _ in range(100):
        x_hat, _, _, _, info = env.step(policy(x_hat))
        states.append(info["state"])
    traj, summary = run(helicopter(disturbance="basin-helicopter", process_noise=0.1,
                                   duration_s=1.0, seed=2), progress=False)
    np.testing.assert_array_equal(np.array(states), traj.state[1:])  # one code path
    ours = env.metrics().summary()
    for key in ("rmse", "measurement_rmse", "nees_mean", "T_final"):
        assert ours[key] == summary[key]


def test_metrics_match_a_recomputation_from_the_trajectory():
    traj, summary = run(helicopter(disturbance="basin-helicopter", process_noise=0.1,
                                   duration_s=3.0, seed=2), progress=False)
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
    dt = 0.01
    w_sq = sum(float(basin_helicopter_w(t) @ basin_helicopter_w(t)) for t in traj.t_s[:-1]) * dt
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
    a, _ = run(helicopter(process_noise=0.2, duration_s=2.0, seed=5), progress=False)
    b, _ = run(helicopter(process_noise=0.2, duration_s=2.0, seed=5), progress=False)
    c, _ = run(helicopter(process_noise=0.2, duration_s=2.0, seed=6), progress=False)
    for field in ("state", "estimate", "measurement", "action", "covariance"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(a.state, c.state)


def test_lqr_tracks_the_setpoints_on_the_nonlinear_rig():
    traj, summary = run(helicopter(duration_s=15.0, seed=0), progress=False)
    k = np.searchsorted(traj.t_s, 9.9)  # end of the second setpoint (10 deg, 30 deg)
    np.testing.assert_allclose(traj.state[k, :2], np.deg2rad([10.0, 30.0]), atol=np.deg2rad(1))
    np.testing.assert_allclose(traj.setpoint[k], np.deg2rad([10.0, 30.0]))
    assert summary["clipped_fraction"] < 0.2


def test_kalman_filter_beats_the_raw_measurement():
    _, s = run(helicopter(sensor_options={"noise_std_rad": 0.002}, process_noise=0.1,
                          duration_s=8.0, seed=1), record=False, progress=False)
    for angle in ("pitch", "yaw"):
        assert s["rmse"][angle] < 0.8 * s["measurement_rmse"][angle]
    assert 1.0 < s["nees_mean"] < 8.0


def test_kalman_bucy_in_the_loop_is_stable_and_consistent():
    """Kalman-Bucy on 100 Hz samples: its bandwidth is close to the sample rate here, so
    holding each sample over the interval costs accuracy against the exact discrete filter
    (a documented limitation); it must stay stable and consistent."""
    common = {"sensor_options": {"noise_std_rad": 0.002}, "process_noise": 0.1,
              "duration_s": 8.0, "seed": 1}
    _, s = run(helicopter("kalman-bucy", **common), record=False, progress=False)
    _, s_kf = run(helicopter("kalman", **common), record=False, progress=False)
    for angle in ("pitch", "yaw"):
        assert s["rmse"][angle] < 1.3 * s["measurement_rmse"][angle]
        assert s_kf["rmse"][angle] < s["rmse"][angle]
    assert 1.0 < s["nees_mean"] < 8.0


def test_wrapper_uses_the_applied_action_and_input_transform():
    env = RigEnv("helicopter")
    pm = paper_model()
    sysd = LinearSystem(A=pm.A, B=pm.B, C=np.eye(2, 4), Q=np.eye(4) * 1e-3,
                        R=np.eye(2) * 1e-6).discretize(env.dt_s)
    kf = KalmanFilter(sysd, np.zeros(4), np.eye(4) * 1e-2)
    seen = []

    def transform(u, x_hat):
        seen.append((u.copy(), np.array(x_hat, copy=True)))
        return np.zeros(2)

    wrapped = FilterInLoop(env, kf, input_transform=transform)
    wrapped.reset(seed=0)
    wrapped.step(np.array([30.0, -1.0]))
    np.testing.assert_array_equal(seen[0][0], [24.0, -1.0])
    np.testing.assert_array_equal(seen[0][1], np.zeros(4))  # the estimate before the step


def test_ms_hinf_flies_the_rig_with_the_y2_channel():
    traj, s = run(helicopter("ms-hinf", disturbance="basin-helicopter", duration_s=3.0,
                             seed=0), progress=False)
    names = s["meta"]["units"]
    assert traj.measurement.shape[1] == 4
    assert traj.measurement_names[2:] == ["y2_pitch", "y2_yaw"]
    assert names["measurement:y2_pitch"] == "rad"
    # y2 = C2 x + H w: pitch + w3, yaw + w4 exactly (no noise on the deterministic channel)
    k = 100
    w = basin_helicopter_w(traj.t_s[k])
    np.testing.assert_allclose(traj.measurement[k, 2:], traj.state[k, :2] + w[2:], atol=1e-12)
    assert s["T_final"] is not None and s["T_final"] < 1.1
    assert s["rmse"]["pitch"] < np.deg2rad(1.0)
    # the filter's default disturbance and y2 channel come from the scenario defaults
    traj_default, _ = run(helicopter("ms-hinf", duration_s=3.0, seed=0),
                                  progress=False)
    np.testing.assert_array_equal(traj_default.estimate, traj.estimate)
    with pytest.raises(ValueError, match="basin-helicopter"):
        run(helicopter("ms-hinf", disturbance="none", duration_s=0.1), progress=False)


def test_bad_prior_is_rejected_before_the_env_is_reset():
    env, policy, _ = filter_in_loop()
    x_hat, _ = env.reset(seed=0)
    for _ in range(3):
        x_hat, _, _, _, info = env.step(policy(x_hat))
    state, t = info["state"].copy(), env.unwrapped.t_s
    for bad in ({"x0": np.full(4, np.nan)}, {"x0": np.zeros(3)},
                {"P0": np.ones((4, 4)) + np.triu(np.ones((4, 4)))}):
        with pytest.raises(ValueError, match="options\\['estimator'\\]"):
            env.reset(seed=1, options={"estimator": bad})
        assert env.unwrapped.t_s == t
        np.testing.assert_array_equal(env.unwrapped.sim.info["state"][0], state)
    with pytest.raises(ValueError, match="options must be a dict"):
        env.reset(options=[1, 2])


def test_step_after_an_estimator_failure_asks_for_reset():
    env, policy, _ = filter_in_loop()
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))
    x_hat, _ = env.reset(seed=0)

    def fail(y, u=None):
        raise FloatingPointError("boom")

    env.estimator.step = fail
    with pytest.raises(FloatingPointError):
        env.step(policy(x_hat))
    with pytest.raises(RuntimeError, match="reset"):
        env.step(policy(x_hat))


@pytest.mark.parametrize("estimator", ["kalman", "lmi-hinf"])
def test_from_design_on_the_vehicle_equals_the_runner(estimator):
    env = RigEnv("vehicle-roll", manoeuvre="double-lane-change")  # the runner's default
    wrapped = FilterInLoop.from_design(env, estimator)
    wrapped.reset(seed=4)
    estimates = [wrapped.step(np.zeros(env.action_space.shape))[0] for _ in range(50)]
    traj, _ = run(Scenario(rig="vehicle-roll", estimator=estimator, duration_s=0.5, seed=4),
                  progress=False)
    np.testing.assert_array_equal(np.array(estimates), traj.estimate[1:])


def test_open_loop_returns_a_read_only_view_of_its_action() -> None:
    """The open-loop controller's (N, nu) input: the action broadcast, read-only, the same
    view while the action and N are, a new one when either changes."""
    from testbed.experiment.control import OpenLoop

    ctrl = OpenLoop(np.array([0.5, -1.0]))
    u = ctrl(np.zeros((3, 4)), 0.0)
    assert u.shape == (3, 2) and not u.flags.writeable
    assert np.array_equal(u, [[0.5, -1.0]] * 3)
    assert ctrl(np.zeros((3, 4)), 0.01) is u
    assert ctrl(np.zeros((5, 4)), 0.02).shape == (5, 2)
    ctrl.action = np.array([2.0, 3.0])
    assert np.array_equal(ctrl(np.zeros((5, 4)), 0.03), [[2.0, 3.0]] * 5)
