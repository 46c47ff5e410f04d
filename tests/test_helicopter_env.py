"""The Gymnasium contract of testbed/Helicopter2DOF-v0."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import testbed  # noqa: F401  (registers the environments)
from testbed.disturbances import Disturbance, seed000_disturbance, seed000_w
from testbed.envs.helicopter import Helicopter2DOFEnv
from testbed.rigs.helicopter import PITCH_LIMIT_RAD, gravity_voltage


def make(**kwargs) -> Helicopter2DOFEnv:
    return gym.make("testbed/Helicopter2DOF-v0", **kwargs).unwrapped


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("sensors", ["encoders", "encoders+gyros", "paper"])
def test_check_env(sensors):
    check_env(make(sensors=sensors, disturbance="seed000"), skip_render_check=True)


def test_registered_with_time_limit():
    env = gym.make("testbed/Helicopter2DOF-v0")
    assert env.spec.max_episode_steps == 2000
    env.reset(seed=0)
    truncated = False
    steps = 0
    while not truncated:
        _, _, _, truncated, _ = env.step(np.zeros(2))
        steps += 1
    assert steps == 2000


def rollout(seed: int, n: int = 150, **kwargs):
    env = make(sensors="encoders+gyros", disturbance=seed000_disturbance(noise_scale=0.3),
               sensor_kwargs={"noise_std_rad": 0.001}, **kwargs)
    obs, info = env.reset(seed=seed)
    out = [obs, info["state"]]
    rng = np.random.default_rng(seed)
    for _ in range(n):
        obs, reward, _, _, info = env.step(rng.uniform(-5, 20, 2))
        out += [obs, info["state"], np.array([reward, info["t"]]), info["disturbance"],
                info["process_accel"]]
    return out


def test_same_seed_is_bitwise_identical_and_other_seed_differs():
    a, b, c = rollout(3), rollout(3), rollout(4)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(a, c, strict=True))


def test_info_contents_and_reset_defaults():
    env = make(disturbance="seed000")
    obs, info = env.reset(seed=0)
    np.testing.assert_allclose(info["state"], [-PITCH_LIMIT_RAD, 0, 0, 0])
    assert info["t"] == 0.0
    np.testing.assert_allclose(info["disturbance"], seed000_w(0.0))
    _, reward, _, _, info = env.step(np.zeros(2))
    assert info["t"] == pytest.approx(0.01)
    assert reward == pytest.approx(-np.sum((info["state"][:2] - info["setpoint"]) ** 2))
    assert set(info) >= {"state", "t", "disturbance", "setpoint", "action_applied",
                         "action_clipped"}


@pytest.mark.parametrize("action", [[np.nan, 0.0], [0.0, np.inf], [1.0, 2.0, 3.0], [[1.0, 2.0]],
                                    "abc", None])
def test_bad_action_raises_and_leaves_state_unchanged(action):
    env = make()
    env.reset(seed=0)
    env.step(np.array([15.0, 0.0]))
    before = (env.rig.data.qpos.copy(), env.rig.data.qvel.copy(), env.t_s,
              env.np_random.bit_generator.state)
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    np.testing.assert_array_equal(env.rig.data.qpos, before[0])
    np.testing.assert_array_equal(env.rig.data.qvel, before[1])
    assert env.t_s == before[2]
    assert env.np_random.bit_generator.state == before[3]


def test_out_of_range_voltage_is_clipped_and_flagged():
    env = make()
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([30.0, -3.0]))
    np.testing.assert_array_equal(info["action_applied"], [24.0, -3.0])
    np.testing.assert_array_equal(info["action_clipped"], [True, False])
    np.testing.assert_array_equal(env.rig.data.ctrl, [24.0, -3.0])


@pytest.mark.parametrize("options, match", [
    ({"bogus": 1}, "unknown reset options"),
    ({"x0": [0.0, 0.0, 0.0]}, "x0"),
    ({"x0": [np.nan, 0, 0, 0]}, "x0"),
    ({"x0": [1.0, 0, 0, 0]}, "outside the stops"),
    ({"params": {"masss": 1.0}}, "unknown params key"),
    ({"params": {"mass_kg": -1.0}}, "mass_kg"),
])
def test_bad_reset_options(options, match):
    env = make()
    with pytest.raises(ValueError, match=match):
        env.reset(seed=0, options=options)


def test_params_option_changes_physics_and_resets_back():
    env = make()
    u = gravity_voltage(env.nominal_params, 0.0)
    env.reset(seed=0, options={"x0": np.zeros(4)})
    for _ in range(50):
        _, _, _, _, info = env.step(u)
    level = info["state"][0]
    env.reset(seed=0, options={"x0": np.zeros(4), "params": {"mass_kg": 1.2}})
    for _ in range(50):
        _, _, _, _, info = env.step(u)
    assert info["state"][0] < level - 0.01  # heavier: the nose drops
    env.reset(seed=0, options={"x0": np.zeros(4)})
    for _ in range(50):
        _, _, _, _, info = env.step(u)
    assert info["state"][0] == level


def test_encoder_quantization():
    env = make()
    obs, info = env.reset(seed=0, options={"x0": [0.1234567, 0.7654321, 0, 0]})
    q = 2 * np.pi / np.array([4096, 8192])
    np.testing.assert_allclose(obs / q, np.round(obs / q), atol=1e-9)
    assert np.all(np.abs(obs - info["state"][:2]) <= q / 2 + 1e-12)


def test_paper_sensor_noise_has_intensity_over_dt_variance():
    env = make(sensors="paper", sensor_kwargs={"intensity": 0.01 * np.eye(2)})
    env.reset(seed=1, options={"x0": np.zeros(4)})
    errs = []
    for _ in range(2000):
        obs, _, _, _, info = env.step(gravity_voltage(env.nominal_params, 0.0))
        errs.append(obs - info["state"][:2])
    var = np.var(np.array(errs), axis=0)
    np.testing.assert_allclose(var, 0.01 / env.dt_s, rtol=0.1)


def test_deterministic_disturbance_acts_as_paper_acceleration():
    """Free rig at level pitch with gravity balanced: yaw accelerates by (G w)_yaw."""
    G = np.zeros((4, 1))
    G[3, 0] = 1.0
    env = make(disturbance=Disturbance(G=G, w=lambda t: np.array([2.0])))
    env.reset(seed=0, options={"x0": np.zeros(4)})
    u = gravity_voltage(env.nominal_params, 0.0)
    _, _, _, _, info = env.step(u)
    # yaw_rate after 10 ms with damping: v = a/c (1 - exp(-c t)), c = B_y/J_y
    c = 3.4955
    assert info["state"][3] == pytest.approx(2.0 / c * (1 - np.exp(-c * 0.01)), rel=2e-3)
    with pytest.raises(ValueError, match="position states"):
        Disturbance(G=np.ones((4, 1)), w=lambda t: np.ones(1))
