"""``testbed/NonlinearDiscrete-v0``: the nonlinear discrete stochastic system (49) of
Zhang, Deng & Zhang (2018), Example 5.1 (see docs/references.md)."""

from __future__ import annotations

from typing import Any

import numpy as np

from testbed.envs.plant_env import PlantEnv, PlantSensors
from testbed.reproductions.zhang_lmi_hinf import plant


class NonlinearDiscreteEnv(PlantEnv):
    """Example 5.1, eq. (49), of Zhang, Deng & Zhang (2018)
    (:class:`~testbed.reproductions.zhang_lmi_hinf.plant.NonlinearDiscretePlant`)::

        x1+ = 0.6 x1^3 / (1 + x1^2 + x2^2) + 0.1 v x1 + 0.5 x2 sin(v) w
        x2+ = 0.65 x2 + 0.1 x2 x1 + 0.5 v sin(x2) w
        y   = 0.5 x + v sin(x)

    ``w_k ~ N(0, 1)`` from the env's generator; ``v_k`` is the paper's ``2 * 0.9999^k``
    (``disturbance="paper"``, default) plus the action, or the action alone
    (``disturbance=None``). Dimensionless; one step is one time unit (``info["t"] = k``).
    The common contract (validation, escape, info) is :class:`PlantEnv`'s.

    ===========  =====  =======================================================
    space        shape  content
    ===========  =====  =======================================================
    action       (1,)   perturbation of ``v_k``, in [-10, 10]
    observation  (2,)   ``y_{k+1} = 0.5 x + v sin(x)`` (schedule's ``v_{k+1}``)
    ===========  =====  =======================================================

    ``info`` adds ``disturbance`` and ``action_applied`` (``[v_k]``), ``noise`` (``w_k``)
    and ``z = 0.1 x1 + 0.1 x2``. Reward ``-z^2``. The episode terminates if the state
    would leave ``1e6`` in magnitude; truncated after 200 steps (registration).
    ``reset(options={"x0": (2,)})``: default ``[1, 1]`` (the paper gives none).
    """

    metadata = {"render_modes": [], "render_fps": 10}
    DEFAULT_X0 = (1.0, 1.0)

    def __init__(self, disturbance: str | None = "paper", render_mode: str | None = None):
        system = plant.NonlinearDiscretePlant(disturbance)
        self._setup(system, PlantSensors(list(plant.MEASUREMENT_NAMES), 0.5 * np.eye(2),
                                         np.zeros((2, 2))),
                    action_limit=10.0, action_names=["v [-]"],
                    state_names=list(plant.STATE_NAMES), x0=np.array(self.DEFAULT_X0),
                    escape_bound=plant.ESCAPE_BOUND, render_mode=render_mode)

    def _first(self, x0: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        v0 = np.array([self.plant.schedule(0)])
        return self.plant.observe(x0, 0), {"disturbance": v0, "action_applied": v0,
                                            "noise": 0.0, "z": float(plant.output(x0))}

    def _reward(self, x: np.ndarray) -> float:
        return -float(plant.output(x)) ** 2
