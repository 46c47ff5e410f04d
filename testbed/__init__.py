"""testbed: a MuJoCo-backed simulation testbed for robust state estimators.

Importing the package registers the Gymnasium environments::

    import gymnasium as gym
    import testbed  # noqa: F401

    env = gym.make("testbed/Helicopter2DOF-v0")
"""

from __future__ import annotations

from testbed import _startup  # first: start-up Ctrl-C and MUJOCO_GL

__version__ = "0.1.0"



#: Environment id -> (entry point, max_episode_steps[, vector entry point]). Entry points
#: import lazily; a vector entry point serves ``gym.make_vec(...,
#: vectorization_mode="vector_entry_point")``.
_RIG = "testbed.envs.rig_env:RigEnv"
_RIG_VECTOR = "testbed.envs.rig_env:RigVectorEnv"
_PLANT_VECTOR = "testbed.envs.plant_vector:"  # SyncVectorEnv: nothing to batch in numpy
_ENVS = {
    "testbed/Helicopter2DOF-v0": (_RIG, 2000, _RIG_VECTOR, {"rig": "helicopter"}),
    "testbed/VehicleRoll-v0": (_RIG, 1000, _RIG_VECTOR, {"rig": "vehicle-roll"}),
    "testbed/Aero2DOF-v0": (_RIG, 2000, _RIG_VECTOR, {"rig": "aero"}),
    "testbed/PolynomialCubic-v0": (
        "testbed.reproductions.basin_polynomial.env:PolynomialCubicEnv", 1400,
        _PLANT_VECTOR + "polynomial_cubic"),
    "testbed/NonlinearDiscrete-v0": (
        "testbed.reproductions.zhang_lmi_hinf.env:NonlinearDiscreteEnv", 200,
        _PLANT_VECTOR + "nonlinear_discrete"),
    "testbed/UncertainLinear-v0": (
        "testbed.reproductions.variance_constrained.env:UncertainLinearEnv", 1000,
        _PLANT_VECTOR + "uncertain_linear"),
}
ENV_IDS = tuple(_ENVS)


def register() -> None:
    """Register the Gymnasium ids (:data:`ENV_IDS`); importing the package does, except in
    the ``testbed`` command's own process, whose commands call it once parsed (so that
    ``testbed --version`` does not import Gymnasium)."""
    import gymnasium as gym

    for env_id, (entry_point, max_steps, *rest) in _ENVS.items():
        vector, kwargs = (rest + [None, None])[:2]
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, max_episode_steps=max_steps,
                         vector_entry_point=vector, kwargs=kwargs or {})


if not _startup.CLI_PROCESS:
    register()
