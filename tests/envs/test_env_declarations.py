"""What the wrappers read from the environment they wrap (:func:`env_declarations`): the
sensors' and the rig's declared contract (names, measured state, description; name and
profile), and nothing from an environment that declares none."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from testbed.envs import RigEnv
from testbed.envs.common import env_declarations
from testbed.envs.plant_env import PlantSensors
from testbed.reproductions.basin_polynomial.env import PolynomialCubicEnv


def test_a_rig_env_declares_its_suite_and_rig():
    env = RigEnv("helicopter", profile="hardware")
    declared = env_declarations(env.unwrapped)
    suite = env.unwrapped.sensors
    assert declared.channel_names == tuple(suite.names) and declared.channel_names
    assert declared.measured == list(suite.measured_state)
    assert declared.sensors_text == suite.describe() != ""
    assert (declared.rig_name, declared.profile) == ("helicopter", "hardware")
    assert declared.dt_s == env.unwrapped.dt_s
    env.close()


def test_a_plant_env_declares_its_measurement_without_a_rig():
    env = PolynomialCubicEnv()
    declared = env_declarations(env.unwrapped)
    assert declared.channel_names == ("y",)
    assert declared.measured == [0] == env.unwrapped.sensors.measured_state_index
    assert (declared.sensors_text, declared.rig_name, declared.profile) == ("", "", "")
    assert declared.rig is None


def test_plant_sensors_measured_state_is_the_unit_rows_of_c():
    sensors = PlantSensors(["a", "b", "c"], np.array([[0.0, 1.0], [2.0, 0.0], [0.5, 0.5]]),
                           np.eye(3))
    assert sensors.measured_state == [1, None, None]
    assert sensors.describe() == ""


class _Bare(gym.Env):
    observation_space = gym.spaces.Box(-1.0, 1.0, (1,))
    action_space = gym.spaces.Box(-1.0, 1.0, (1,))


def test_an_env_that_declares_nothing():
    declared = env_declarations(_Bare())
    assert (declared.sensors, declared.rig, declared.state_names) == (None, None, None)
    assert (declared.measured, declared.channel_names, declared.sensors_text) == ([], (), "")
    assert (declared.rig_name, declared.profile) == ("", "")
