"""testbed: a MuJoCo-backed simulation testbed for robust state estimators.

Importing the package registers the Gymnasium environments::

    import gymnasium as gym
    import testbed  # noqa: F401

    env = gym.make("testbed/Helicopter2DOF-v0")
"""

from __future__ import annotations

import gymnasium as gym

__version__ = "0.1.0"

ENV_IDS = ("testbed/Helicopter2DOF-v0",)


def _register() -> None:
    if "testbed/Helicopter2DOF-v0" not in gym.registry:
        gym.register(
            id="testbed/Helicopter2DOF-v0",
            entry_point="testbed.envs.helicopter:Helicopter2DOFEnv",
            max_episode_steps=2000,
        )


_register()
