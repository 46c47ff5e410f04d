"""PolynomialPlant (RK4 integration, observation averages, white noise, escape) and the
Gymnasium contract of testbed/PolynomialCubic-v0."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from scipy.integrate import solve_ivp

import testbed  # noqa: F401  (registers the environments)
from filters.hinf_polynomial import PolynomialHInfFilter
from filters.polynomial_model import PolynomialModel
from testbed.envs.wrappers import FilterInLoop
from testbed.experiment.numpy_plant import rollout
from testbed.reproductions.basin_polynomial.env import PolynomialCubicEnv
from testbed.reproductions.basin_polynomial.plant import PolynomialPlant
from testbed.reproductions.basin_polynomial.scenario import PolynomialHinfScenario, paper_w


def paper_rhs(t, x):
    """(22) with the printed disturbance, written out."""
    c = 0.1 + 0.1 * np.sin(50 * t)
    return [x[1], 0.1 * x[1] ** 2 + c * x[1] ** 3 + 1 / (1 + t) ** 2]


def test_plant_matches_solve_ivp_and_averages_y():
    s = PolynomialHinfScenario()
    plant = PolynomialPlant(s.model, dt_s=1e-3, w=s.w, substeps=4)
    run = rollout(plant, s.x0, 1400)
    assert run.escape is None and run.x.shape == (1401, 2) and run.y.shape == (1400, 1)
    ref = solve_ivp(paper_rhs, (0, run.t_s[-1]), s.x0, t_eval=run.t_s, rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(run.x, ref.y.T, rtol=1e-8, atol=1e-9)
    # y = x1 + w2 averaged over each interval, w likewise
    y_trap = 0.5 * ((run.x[:-1, 0] + run.x[1:, 0]) + np.array(
        [paper_w(t)[1] for t in run.t_s[:-1]]) + np.array([paper_w(t)[1] for t in run.t_s[1:]]))
    np.testing.assert_allclose(run.y[:, 0], y_trap, atol=1e-5)
    w1_avg = [(1 / (1 + a) - 1 / (1 + b)) / (b - a) for a, b in zip(run.t_s[:-1], run.t_s[1:],
                                                                  strict=True)]
    w = [plant.step(run.x[k], k, None, None)[2]["disturbance"][0] for k in range(1400)]
    np.testing.assert_allclose(w, w1_avg, rtol=1e-10)


def test_plant_escape_is_reported_and_the_run_truncated():
    """x' = x^3 from 1 escapes at t = 1/2; from x0 = [1, 1] the paper's plant near 1.785 s."""
    model = PolynomialModel(a3=np.ones((1, 1, 1, 1)), B=[[0.0]], C=[[1.0]], D=[[1.0]],
                            L=[[1.0]])
    run = rollout(PolynomialPlant(model, dt_s=1e-4), np.array([1.0]), 10_000)
    assert run.escape is not None and run.escape.quantity == "state"
    assert 0.499 < run.escape.time <= 0.5
    assert np.isfinite(run.x).all() and len(run.t_s) == len(run.x) == len(run.y) + 1
    assert run.t_s[-1] < run.escape.time


def test_plant_white_noise_intensity_and_reproducibility():
    model = PolynomialModel(B=[[1.0, 0.0]], C=[[0.0]], D=[[0.0, 1.0]], L=[[1.0]], n=1)
    q, dt = np.array([4.0, 9.0]), 1e-3
    plant = PolynomialPlant(model, dt_s=dt, noise_intensity=q)
    a = rollout(plant, np.zeros(1), 5000, noise=np.random.default_rng(1))
    b = rollout(plant, np.zeros(1), 5000, noise=np.random.default_rng(1))
    np.testing.assert_array_equal(a.x, b.x)
    # sample variances of 5000 draws: relative standard error 2 %
    assert np.var(np.diff(a.x[:, 0])) == pytest.approx(q[0] * dt, rel=0.1)
    assert np.var(a.y[:, 0]) == pytest.approx(q[1] / dt, rel=0.1)


def test_plant_input_validation():
    model = PolynomialHinfScenario().model
    with pytest.raises(ValueError, match="dt_s"):
        PolynomialPlant(model, dt_s=0.0)
    with pytest.raises(ValueError, match="w must"):
        PolynomialPlant(model, w=np.ones(3))
    with pytest.raises(ValueError, match="noise_intensity"):
        PolynomialPlant(model, noise_intensity=-1.0)
    with pytest.raises(ValueError, match="w must have shape"):
        rollout(PolynomialPlant(model, w=lambda t: np.ones(3)), np.ones(2), 2)
    with pytest.raises(TypeError, match="PolynomialModel"):
        PolynomialPlant("model")


# ------------------------------------------------------------------ the env
def make(**kwargs) -> PolynomialCubicEnv:
    return gym.make("testbed/PolynomialCubic-v0", **kwargs).unwrapped


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("disturbance", ["paper", "white", "none"])
def test_check_env(disturbance):
    check_env(make(disturbance=disturbance), skip_render_check=True)


def test_registered_with_time_limit_and_matches_the_plant():
    env = gym.make("testbed/PolynomialCubic-v0", substeps=2)  # 0.5 ms RK4 steps: faster
    assert env.spec.max_episode_steps == 1400
    obs, info = env.reset(seed=0)
    np.testing.assert_array_equal(info["state"], [1.0, 1.0])
    assert obs[0] == pytest.approx(1.5)  # x1(0) + w2(0) = 1 + 2 / 2^2
    states, ys = [info["state"]], []
    truncated = terminated = False
    while not truncated:
        obs, _, terminated, truncated, info = env.step(np.zeros(1))
        states.append(info["state"])
        ys.append(obs)
        assert not terminated
    assert len(ys) == 1400 and info["t"] == pytest.approx(1.4)
    s = PolynomialHinfScenario()
    run = rollout(PolynomialPlant(s.model, dt_s=1e-3, w=s.w, substeps=2), s.x0, 1400)
    np.testing.assert_allclose(np.array(states), run.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.array(ys), run.y, rtol=0, atol=1e-12)


def test_escape_terminates_without_nan():
    env = make(substeps=2)
    env.reset(seed=0)
    for _ in range(3000):
        obs, reward, terminated, truncated, info = env.step(np.zeros(1))
        if terminated:
            break
    assert terminated and info["escape"]["quantity"] == "state"
    assert 1.77 < info["escape"]["time"] < 1.79
    assert np.isfinite(info["state"]).all() and np.isfinite(obs).all() and math.isfinite(reward)
    again = env.step(np.zeros(1))
    assert again[2] and np.array_equal(again[4]["state"], info["state"])
    env.reset(seed=0)  # a reset starts a fresh episode
    assert env.step(np.zeros(1))[4]["escape"] is None


def env_rollout(seed: int, n: int = 40):
    env = make(disturbance="white", noise_intensity=(0.5, 0.01))
    obs, info = env.reset(seed=seed)
    out = [obs, info["state"]]
    rng = np.random.default_rng(seed)
    for _ in range(n):
        obs, reward, _, _, info = env.step(rng.uniform(-1, 1, 1))
        out += [obs, info["state"], np.array([reward, info["t"]]), info["disturbance"]]
    return out


def test_same_seed_is_bitwise_identical_and_other_seed_differs():
    a, b, c = env_rollout(3), env_rollout(3), env_rollout(4)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(a, c, strict=True))


@pytest.mark.parametrize("action", [[np.nan], [np.inf], [1.0, 2.0], [[1.0]], "abc", None])
def test_bad_action_raises_and_leaves_state_unchanged(action):
    env = make(disturbance="white")
    env.reset(seed=0)
    env.step(np.array([0.5]))
    before = (env.state, env.t_s, env.np_random.bit_generator.state)
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    assert np.array_equal(env.state, before[0]) and env.t_s == before[1]
    assert env.np_random.bit_generator.state == before[2]


def test_action_clipping_info_and_arguments():
    env = make()
    env.reset(seed=0, options={"x0": [0.0, 0.0]})
    _, _, _, _, info = env.step(np.array([50.0]))
    assert info["action_applied"][0] == 10.0 and info["action_clipped"][0]
    assert info["state"][1] > 0  # u pushes x2
    assert set(info) >= {"state", "t", "disturbance", "action_applied", "action_clipped",
                         "escape"}
    np.testing.assert_allclose(info["disturbance"], paper_w(0.0005), rtol=1e-3)
    assert env.state_names == ["x1", "x2"] and env.dt_s == 0.001
    assert env.sensors.names == ["y"] and env.sensors.measured_state_index == [0]
    C, R = env.sensors.linear_model(env.dt_s)
    assert C.shape == (1, 2) and R.shape == (1, 1)
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"x00": [0, 0]})
    with pytest.raises(ValueError, match="x0"):
        env.reset(options={"x0": [0.0]})
    for kwargs, name in (({"dt_s": -1.0}, "dt_s"), ({"substeps": 0}, "substeps"),
                         ({"disturbance": "loud"}, "disturbance"),
                         ({"noise_intensity": (1.0, -1.0)}, "noise_intensity"),
                         ({"render_mode": "human"}, "render_mode")):
        with pytest.raises(ValueError, match=name):
            PolynomialCubicEnv(**kwargs)
    custom = make(disturbance=lambda t: np.array([0.0, 0.1]))
    obs, _ = custom.reset(seed=0)
    assert obs[0] == pytest.approx(1.1)


def test_polynomial_filter_in_the_loop():
    env = gym.make("testbed/PolynomialCubic-v0")
    model = env.unwrapped.model
    filt = PolynomialHInfFilter(model, 1.05, np.eye(2), env.unwrapped.dt_s)
    wrapped = FilterInLoop(env, filt, output_matrix=np.eye(2), ratio_weight=np.eye(2))
    est, info = wrapped.reset(seed=0)
    np.testing.assert_array_equal(est, [0.0, 0.0])
    for _ in range(300):
        est, _, terminated, _, info = wrapped.step(np.zeros(1))
    assert not terminated and filt.t_s == pytest.approx(0.3)
    assert np.linalg.norm(info["error"]) < 1.6  # initial error sqrt(2), estimate moving in
