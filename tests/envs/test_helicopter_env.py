"""The Gymnasium contract of testbed/Helicopter2DOF-v0 (RigEnv("helicopter"))."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import testbed  # noqa: F401  (registers the environments)
from testbed.envs import RigEnv, RigVectorEnv
from testbed.rigs.disturbances import Disturbance
from testbed.rigs.helicopter import (
    PITCH_LIMIT_RAD,
    basin_helicopter_disturbance,
    basin_helicopter_w,
    gravity_voltage,
)


def make(**kwargs) -> RigEnv:
    return gym.make("testbed/Helicopter2DOF-v0", **kwargs).unwrapped


def _physics_snapshot(env: RigEnv) -> tuple:
    """Everything a failed step must leave unchanged: physics, time, noise streams."""
    noise = env.sim.noise
    return (env.sim.physics.state.copy(), env.t_s, int(env.sim.steps[0]),
            noise.generators[0].bit_generator.state, noise._pos.copy(), noise._buf.copy(),
            env.sim.obs.copy())


@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("sensors", ["encoders", "encoders+gyros", "paper"])
def test_check_env(sensors):
    env = make(sensors=sensors, disturbance="basin-helicopter")
    assert isinstance(env, RigEnv) and env.rig.name == "helicopter"
    check_env(env, skip_render_check=True)


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
    env = make(sensors="encoders+gyros",
               disturbance=basin_helicopter_disturbance(noise_scale=0.3),
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


def test_vector_env_members_equal_single_envs_bitwise():
    kwargs = {"sensors": "encoders+gyros",
              "disturbance": basin_helicopter_disturbance(noise_scale=0.3),
              "sensor_kwargs": {"noise_std_rad": 0.001}}
    seeds = [3, 11, 4]
    vec = RigVectorEnv(len(seeds), rig="helicopter", num_threads=2, **kwargs)
    singles = [RigEnv("helicopter", **kwargs) for _ in seeds]
    obs_v, info_v = vec.reset(seed=seeds)
    for i, (env, seed) in enumerate(zip(singles, seeds, strict=True)):
        obs, info = env.reset(seed=seed)
        np.testing.assert_array_equal(obs_v[i], obs)
        np.testing.assert_array_equal(info_v["state"][i], info["state"])
    rng = np.random.default_rng(0)
    for _ in range(100):
        actions = rng.uniform(-5, 20, (len(seeds), 2))
        obs_v, rew_v, term_v, _, info_v = vec.step(actions)
        for i, env in enumerate(singles):
            obs, reward, terminated, _, info = env.step(actions[i])
            np.testing.assert_array_equal(obs_v[i], obs)
            assert rew_v[i] == reward and term_v[i] == terminated
            for key in ("state", "t", "disturbance", "process_accel", "action_applied",
                        "action_clipped", "setpoint"):
                np.testing.assert_array_equal(info_v[key][i], info[key])
    # the members are different episodes (different seeds)
    assert not np.array_equal(obs_v[0], obs_v[1])
    vec.close()
    for env in singles:
        env.close()


def test_info_contents_and_reset_defaults():
    env = make(disturbance="basin-helicopter", reset_noise_scale=0.0)
    obs, info = env.reset(seed=0)
    np.testing.assert_allclose(info["state"], [-PITCH_LIMIT_RAD, 0, 0, 0])
    np.testing.assert_array_equal(env.x0, [-PITCH_LIMIT_RAD, 0, 0, 0])
    assert info["t"] == 0.0 and env.t_s == 0.0
    np.testing.assert_allclose(info["disturbance"], basin_helicopter_w(0.0))
    _, reward, _, _, info = env.step(np.zeros(2))
    assert info["t"] == pytest.approx(0.01) and env.t_s == pytest.approx(0.01)
    assert reward == pytest.approx(-np.sum((info["state"][:2] - info["setpoint"]) ** 2))
    np.testing.assert_array_equal(info["setpoint"], env.setpoint(info["t"]))
    assert set(info) >= {"state", "t", "disturbance", "setpoint", "action_applied",
                         "action_clipped", "manoeuvre", "process_accel", "step_noise"}
    assert info["step_noise"].shape == (0,)  # the helicopter has no model noise
    np.testing.assert_array_equal(info["manoeuvre"], [0.0, 0.0])
    units = env.units()
    assert units["pitch"] == "rad" and units["yaw_rate"] == "rad/s" and units["V_pitch"] == "V"
    pos, quat = env.body_poses()
    assert pos.shape == (env.rig.model.nbody, 3) and quat.shape == (env.rig.model.nbody, 4)


@pytest.mark.parametrize("action", [[np.nan, 0.0], [0.0, np.inf], [1.0, 2.0, 3.0], [[1.0, 2.0]],
                                    "abc", None])
def test_bad_action_raises_and_leaves_state_unchanged(action):
    env = make(sensors="encoders+gyros", process_noise=0.5)
    env.reset(seed=0)
    env.step(np.array([15.0, 0.0]))
    before = _physics_snapshot(env)
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    for x, y in zip(before, _physics_snapshot(env), strict=True):
        if isinstance(x, dict):
            assert x == y
        else:
            np.testing.assert_array_equal(x, y)


def test_out_of_range_voltage_is_clipped_and_flagged():
    env = make()
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([30.0, -3.0]))
    np.testing.assert_array_equal(info["action_applied"], [24.0, -3.0])
    np.testing.assert_array_equal(info["action_clipped"], [True, False])
    # the rig moved exactly as with the clipped voltage
    ref = make()
    ref.reset(seed=0)
    _, _, _, _, ref_info = ref.step(np.array([24.0, -3.0]))
    np.testing.assert_array_equal(info["state"], ref_info["state"])
    np.testing.assert_array_equal(ref_info["action_clipped"], [False, False])


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
    env = make(disturbance=Disturbance(G=G, w=lambda t: np.array([2.0])), ambient_noise=0.0)
    env.reset(seed=0, options={"x0": np.zeros(4)})
    u = gravity_voltage(env.nominal_params, 0.0)
    _, _, _, _, info = env.step(u)
    np.testing.assert_allclose(info["process_accel"], [0.0, 2.0])
    # yaw_rate after 10 ms with damping: v = a/c (1 - exp(-c t)), c = B_y/J_y
    c = 3.4955
    assert info["state"][3] == pytest.approx(2.0 / c * (1 - np.exp(-c * 0.01)), rel=2e-3)
    with pytest.raises(ValueError, match="position states"):
        Disturbance(G=np.ones((4, 1)), w=lambda t: np.ones(1))
