"""Gymnasium environments: every rig through :class:`RigEnv` / :class:`RigVectorEnv`, and
the papers' plain (non-MuJoCo) plants."""

from testbed.envs.rig_env import RigEnv, RigVectorEnv, build_simulator

__all__ = ["RigEnv", "RigVectorEnv", "build_simulator"]
