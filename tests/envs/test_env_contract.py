"""One contract for every registered environment (like dm_control's suite-wide test)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import testbed

IDS = list(testbed.ENV_IDS)
#: Keyword arguments that make each environment random (where its defaults are not): none,
#: every rig env draws its initial state and has an ambient disturbance by default.
RANDOM: dict[str, dict] = {}
#: Environments with no randomness at all (a fixed plant and x0, no noise).
DETERMINISTIC = {"testbed/PolynomialCubic-v0"}
#: The MuJoCo rig environments.
RIG_IDS = ["testbed/Helicopter2DOF-v0", "testbed/VehicleRoll-v0", "testbed/Aero2DOF-v0"]


def _rollout(env, seed, steps=20):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    zero = np.zeros(env.action_space.shape)
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(zero)
        assert np.all(np.isfinite(obs)) and np.isfinite(reward)
        out.append(obs)
        if terminated:
            break
    return np.array(out)


@pytest.mark.parametrize("env_id", IDS)
def test_check_env(env_id):
    env = gym.make(env_id).unwrapped
    check_env(env, skip_render_check=True)


@pytest.mark.parametrize("env_id", IDS)
def test_same_seed_same_rollout_other_seed_differs(env_id):
    env = gym.make(env_id, **RANDOM.get(env_id, {}))
    a, b, c = _rollout(env, 5), _rollout(env, 5), _rollout(env, 6)
    assert np.array_equal(a, b)
    assert np.array_equal(a, c) == (env_id in DETERMINISTIC)


@pytest.mark.parametrize("env_id", RIG_IDS)
def test_default_rig_env_seed_changes_the_outcome(env_id):
    """With default arguments the seed changes the initial state and the whole run."""
    env = gym.make(env_id)
    x0 = {seed: env.reset(seed=seed)[1]["state"] for seed in (0, 1, 7)}
    assert not np.array_equal(x0[0], x0[1]) and not np.array_equal(x0[1], x0[7])
    np.testing.assert_array_equal(env.reset(seed=1)[1]["state"], x0[1])
    runs = {seed: _rollout(env, seed, steps=30) for seed in (0, 1)}
    assert not np.array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(_rollout(env, 1, steps=30), runs[1])
    # the spread is off with reset_noise_scale=0 and ambient_noise=0: the fixed default state
    quiet = gym.make(env_id, reset_noise_scale=0.0, ambient_noise=0.0).unwrapped
    a, b = quiet.reset(seed=0)[1]["state"], quiet.reset(seed=1)[1]["state"]
    np.testing.assert_array_equal(a, quiet.rig.default_x0())
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("env_id", IDS)
def test_bad_actions_rejected_with_state_unchanged(env_id):
    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    before = _rollout_state(env)
    shape = env.action_space.shape
    for bad in (np.full(shape, np.nan), np.zeros((shape[0] + 1,)), "x"):
        with pytest.raises(ValueError):
            env.step(bad)
    assert np.array_equal(_rollout_state(env), before)


def _rollout_state(env):
    sim = getattr(env, "sim", None)
    if sim is not None:
        return sim.physics.state.copy()
    return np.array(env.step.__self__.__dict__.get("_x", np.zeros(0)), copy=True)


@pytest.mark.parametrize("env_id", RIG_IDS)
def test_vector_env_equals_single_envs_bitwise(env_id):
    kwargs = RANDOM.get(env_id, {})
    venv = gym.make_vec(env_id, num_envs=3, vectorization_mode="vector_entry_point", **kwargs)
    obs, _ = venv.reset(seed=10)
    rows = [obs]
    for _ in range(15):
        obs, *_ = venv.step(np.zeros(venv.action_space.shape))
        rows.append(obs)
    venv.close()
    batched = np.array(rows)
    for i in range(3):
        single = _rollout(gym.make(env_id, **kwargs), 10 + i, steps=15)
        assert np.array_equal(single, batched[:, i])


@pytest.mark.parametrize("env_id", IDS)
def test_every_env_has_a_vector_entry_point(env_id):
    assert gym.spec(env_id).vector_entry_point is not None


@pytest.mark.parametrize("env_id", [i for i in IDS if i not in RIG_IDS])
def test_plant_vector_entry_point_equals_sync_bitwise(env_id):
    """A plain plant's vector entry point is the sync vector env of its copies: the same
    observations, rewards and ends step for step, truncation at the registration's length
    included (a short one here)."""
    def roll(mode):
        venv = gym.make_vec(env_id, num_envs=2, vectorization_mode=mode, max_episode_steps=7)
        out = [venv.reset(seed=3)[0]]
        for _ in range(9):  # past the truncation: NEXT_STEP autoreset in both
            obs, reward, terminated, truncated, _ = venv.step(np.zeros(venv.action_space.shape))
            out += [obs, reward, terminated, truncated]
        venv.close()
        return out

    ours, sync = roll("vector_entry_point"), roll("sync")
    assert any(np.any(row) for row in ours[4::4])  # truncated within the rollout
    assert len(ours) == len(sync)
    for a, b in zip(ours, sync, strict=True):
        assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="num_envs"):
        gym.make_vec(env_id, num_envs=0, vectorization_mode="vector_entry_point")
