"""testbed/UncertainLinear-v0 and its plant simulation (the scenarios of
Wang & Fang (2006) and Liu, Deng & Wang (n.d.))."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import testbed  # noqa: F401  (registers the environments)
from filters.analysis import error_covariance, steady_state_covariance
from filters.variance_constrained import LinearFilter
from testbed.envs.wrappers import FilterInLoop
from testbed.experiment.numpy_plant import rollout
from testbed.reproductions.variance_constrained.env import UncertainLinearEnv
from testbed.reproductions.variance_constrained.family import sampled_error_covariance
from testbed.reproductions.variance_constrained.plant import UncertainLinearPlant
from testbed.reproductions.variance_constrained.scenario import (
    VarianceConstrainedContinuousScenario,
    VarianceConstrainedDiscreteScenario,
)

#: The two named scenarios of the environment.
CONTINUOUS, DISCRETE = "wang-variance-constrained-parabolic", "liu-variance-constrained-discrete"


@pytest.mark.parametrize("scenario", [CONTINUOUS, DISCRETE])
def test_env_checker_and_spaces(scenario):
    env = gym.make("testbed/UncertainLinear-v0", scenario=scenario)
    check_env(env.unwrapped, skip_render_check=True)
    u = env.unwrapped
    assert u.observation_space.shape == (1,) and u.action_space.shape == (1,)
    assert u.state_names == ["x1", "x2"] and u.sensors.names == ["y1"]
    assert u.dt_s == (1.0 if scenario == DISCRETE else 0.01)
    y, info = env.reset(seed=0)
    assert np.array_equal(y, [0.0]) and info["t"] == 0.0
    assert {"state", "t", "disturbance", "F", "setpoint", "action_applied",
            "action_clipped"} <= set(info)
    C, R = u.sensors.linear_model(u.dt_s)
    assert C.shape == (1, 2) and R.shape == (1, 1)
    assert u.sensors.measured_state_index == ([0] if scenario == DISCRETE else [None])


def test_same_seed_bitwise_identical_and_F_per_episode():
    def run(seed):
        env = UncertainLinearEnv(CONTINUOUS)
        out = [env.reset(seed=seed)[1]["F"]]
        for _ in range(50):
            y, _, _, _, info = env.step(np.zeros(1))
            out += [y, info["state"]]
        return out

    a, b = run(4), run(4)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    c = run(5)
    assert not np.array_equal(a[0], c[0])
    env = UncertainLinearEnv(DISCRETE)
    Fs = [env.reset(seed=s)[1]["F"][0, 0] for s in range(30)]
    assert min(Fs) >= -1 and max(Fs) <= 1 and np.std(Fs) > 0.3
    _, info = env.reset(seed=0, options={"F": -1.0, "x0": [1.0, 2.0]})
    assert info["F"][0, 0] == -1.0 and np.array_equal(info["state"], [1.0, 2.0])
    fixed = UncertainLinearEnv(DISCRETE, F=0.5)
    assert fixed.reset(seed=1)[1]["F"][0, 0] == 0.5


def test_validation_leaves_state_unchanged():
    env = UncertainLinearEnv(DISCRETE)
    env.reset(seed=0)
    env.step(np.zeros(1))
    x, t = env.unwrapped._x.copy(), env.t_s
    rng_state = env.np_random.bit_generator.state
    for bad in (np.array([np.nan]), np.zeros(2), "x"):
        with pytest.raises(ValueError, match="action"):
            env.step(bad)
    assert np.array_equal(env._x, x) and env.t_s == t
    assert env.np_random.bit_generator.state == rng_state
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"G": 1})
    with pytest.raises(ValueError, match="options\\['F'\\]"):
        env.reset(options={"F": 2.0})
    with pytest.raises(ValueError, match="x0"):
        env.reset(options={"x0": [1.0]})
    with pytest.raises(ValueError, match="scenario"):
        UncertainLinearEnv("no-such-scenario")
    with pytest.raises(ValueError, match="dt_s"):
        UncertainLinearEnv(CONTINUOUS, dt_s=-1.0)
    _, _, _, _, info = env.step(np.array([3.0]))
    assert info["action_clipped"][0] and info["action_applied"][0] == 1.0


def test_discrete_plant_matches_the_paper_model():
    s = VarianceConstrainedDiscreteScenario()
    sim = UncertainLinearPlant(s.plant).at(1.0)
    x = np.array([0.3, -0.2])
    w = sim.noise(np.random.default_rng(0), ())
    x1, y, extras = sim.step(x, 0, None, w)
    assert extras["disturbance"] is w and w.shape == (2,)
    A_F, C_F = s.plant.perturbed(1.0)
    np.testing.assert_allclose(x1, A_F @ x + s.D1 @ w, atol=1e-15)
    np.testing.assert_allclose(y, C_F @ x + s.D2 @ w, atol=1e-15)


def test_continuous_plant_exact_sampling_stationary_covariance():
    """The exactly sampled plant state has the continuous Lyapunov covariance."""
    s = VarianceConstrainedContinuousScenario()
    sim = UncertainLinearPlant(s.plant, dt_s=0.05).at(1.0)
    N = 20000
    run = rollout(sim, np.zeros((N, 2)), 120, noise=np.random.default_rng(1))
    x, y = run.x[:, -1], run.y[:, -1]
    X = steady_state_covariance(s.plant.perturbed(1.0)[0], s.D1)
    emp = x.T @ x / N
    se = np.sqrt((np.outer(np.diag(X), np.diag(X)) + X**2) / N)
    assert np.all(np.abs(emp - X) < 5 * se)
    # interval-averaged measurement: noise variance ~ D2 D2^T / dt dominates
    assert y.var() == pytest.approx((s.D2 @ s.D2.T)[0, 0] / 0.05, rel=0.05)


def test_filter_in_the_loop_is_aligned():
    """FilterInLoop + LinearFilter: the error e(k+1) = x(k+1) - xhat(k+1) has the Lyapunov
    steady state of (9) (discrete), so measurement and state are paired correctly."""
    s = VarianceConstrainedDiscreteScenario()
    P = error_covariance(s.plant, s.paper_G, s.paper_K, 0.0)
    # the sampled-loop covariance of the discrete plant equals (9) exactly
    sim = UncertainLinearPlant(s.plant)
    np.testing.assert_allclose(sampled_error_covariance(sim, s.paper_G, s.paper_K, 0.0), P,
                               atol=1e-15)
    env = FilterInLoop(UncertainLinearEnv(DISCRETE, F=0.0),
                       LinearFilter(s.paper_G, s.paper_K, np.zeros(2), discrete=True,
                                    B=np.zeros((2, 1))))
    env.reset(seed=2)
    errs = []
    for k in range(6000):
        _, _, _, _, info = env.step(np.zeros(1))
        if k >= 50:
            errs.append(info["error"])
    e = np.array(errs)
    emp = e.T @ e / len(e)
    # generous bound: correlated samples (poles <= 0.85)
    np.testing.assert_allclose(np.diag(emp), np.diag(P), rtol=0.12)


def test_unstable_plant_terminates_with_finite_values():
    from filters.analysis import UncertainPlant

    z = np.zeros((1, 1))
    unstable = UncertainPlant(np.array([[3.0]]), np.array([[1.0]]), np.array([[1.0]]),
                              np.array([[1.0]]), z, z, z, np.array([[1.0]]), discrete=True)
    env = UncertainLinearEnv(plant=unstable)
    env.reset(seed=0, options={"x0": [5e9]})
    *_, terminated, _, info = env.step(np.zeros(1))
    assert terminated and info["escape"] == {"quantity": "state", "time": 1.0}
    y, reward, terminated, _, info = env.step(np.zeros(1))
    assert terminated and np.all(np.isfinite(y)) and info["state"][0] == 5e9
