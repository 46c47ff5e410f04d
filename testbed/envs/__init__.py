"""The Gymnasium face: every rig through :class:`RigEnv` / :class:`RigVectorEnv`, the
estimator in the loop as a wrapper (:mod:`testbed.envs.wrappers`), and the base of the
papers' plain (non-MuJoCo) plant environments (:mod:`testbed.envs.plant_env`, with the checks
of :mod:`testbed.envs.common`; the plants themselves live with their reproductions)."""

from testbed.envs.rig_env import RigEnv, RigVectorEnv

__all__ = ["RigEnv", "RigVectorEnv"]
