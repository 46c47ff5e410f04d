"""The vector entry points of the papers' plain plant environments
(``testbed/PolynomialCubic-v0``, ``testbed/NonlinearDiscrete-v0``,
``testbed/UncertainLinear-v0``).

Their plants are a few numpy operations per step (no physics to batch), so their vector
environment is Gymnasium's :class:`~gymnasium.vector.SyncVectorEnv` over ``num_envs``
``gymnasium.make(env_id)`` copies: ``gymnasium.make_vec(ID, N,
vectorization_mode="vector_entry_point")`` is then the same environment, step for step and
bitwise, as ``vectorization_mode="sync"``, and every registered ``testbed/`` id has a vector
entry point. The rig environments have a batched one (:class:`testbed.envs.RigVectorEnv`: one
``mujoco`` batch).
"""

from __future__ import annotations

from functools import partial
from typing import Any

import gymnasium as gym
from gymnasium.vector import AutoresetMode, SyncVectorEnv


def sync_vector_env(env_id: str, num_envs: int = 1, *, max_episode_steps: int | None = None,
                    autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                    **kwargs: Any) -> SyncVectorEnv:
    """``num_envs`` copies of ``gymnasium.make(env_id, **kwargs)`` stepped in this process.

    Parameters
    ----------
    env_id : str
        A registered id.
    num_envs : int
        Members (>= 1).
    max_episode_steps : int, optional
        Each member's truncation (``make_vec`` passes the registration's).
    autoreset_mode : gymnasium.vector.AutoresetMode or str
    **kwargs
        The environment's own arguments (``render_mode``...).

    Raises
    ------
    ValueError
        ``num_envs`` not a positive integer.
    """
    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
    make = partial(gym.make, env_id, max_episode_steps=max_episode_steps, **kwargs)
    return SyncVectorEnv([make] * num_envs, autoreset_mode=AutoresetMode(autoreset_mode))


#: The vector entry points (``testbed.envs.plant_vector:NAME`` in the registration).
polynomial_cubic = partial(sync_vector_env, "testbed/PolynomialCubic-v0")
nonlinear_discrete = partial(sync_vector_env, "testbed/NonlinearDiscrete-v0")
uncertain_linear = partial(sync_vector_env, "testbed/UncertainLinear-v0")

__all__ = ["nonlinear_discrete", "polynomial_cubic", "sync_vector_env", "uncertain_linear"]
