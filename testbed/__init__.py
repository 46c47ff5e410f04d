"""testbed: a MuJoCo-backed simulation testbed for robust state estimators.

Importing the package registers the Gymnasium environments::

    import gymnasium as gym
    import testbed  # noqa: F401

    env = gym.make("testbed/Helicopter2DOF-v0")
"""

from __future__ import annotations

import gymnasium as gym

__version__ = "0.1.0"

#: Environment id -> (entry point, max_episode_steps[, vector entry point]). Entry points
#: import lazily; a vector entry point serves ``gym.make_vec(...,
#: vectorization_mode="vector_entry_point")``.
_ENVS = {
    "testbed/Helicopter2DOF-v0": ("testbed.envs.helicopter:Helicopter2DOFEnv", 2000,
                                  "testbed.envs.helicopter_vector:Helicopter2DOFVectorEnv"),
    "testbed/VehicleRoll-v0": ("testbed.envs.vehicle_roll:VehicleRollEnv", 1000),
    "testbed/PolynomialCubic-v0": ("testbed.envs.polynomial:PolynomialCubicEnv", 1400),
    "testbed/NonlinearDiscrete-v0": ("testbed.envs.nonlinear_discrete:NonlinearDiscreteEnv",
                                     200),
    "testbed/UncertainLinear-v0": ("testbed.envs.uncertain_linear:UncertainLinearEnv", 1000),
}
ENV_IDS = tuple(_ENVS)


def _register() -> None:
    for env_id, (entry_point, max_steps, *vector) in _ENVS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, max_episode_steps=max_steps,
                         vector_entry_point=vector[0] if vector else None)


_register()
