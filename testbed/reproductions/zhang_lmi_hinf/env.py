"""``testbed/NonlinearDiscrete-v0``: the nonlinear discrete stochastic system (49) of
Zhang, Deng & Zhang (2018), Example 5.1 (see docs/references.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from testbed.envs.common import action_array, check_seed, initial_state, reset_options
from testbed.reproductions.zhang_lmi_hinf import plant

RESET_OPTION_KEYS = ("x0",)
#: Disturbance perturbation limit of the action (dimensionless).
ACTION_LIMIT = 10.0
#: State magnitude beyond which the episode terminates (escape; never reached from |x0| <~ 3).
ESCAPE_BOUND = plant.ESCAPE_BOUND


@dataclass
class NonlinearDiscreteSensors:
    """The measurement of (49): ``y = 0.5 x + v sin(x)`` (componentwise, no additive noise).

    ``v`` is the disturbance of the measurement's step. Same interface as the rigs' suites
    (``names``, ``dim``, ``measured_state_index``, ``measure``, ``linear_model``).
    """

    dt_s: float = 1.0
    name: str = field(default="paper", init=False)

    @property
    def names(self) -> list[str]:
        """Channel names ``y1``, ``y2``."""
        return list(plant.MEASUREMENT_NAMES)

    @property
    def dim(self) -> int:
        """Number of channels (2)."""
        return 2

    @property
    def measured_state_index(self) -> list[int | None]:
        """``y_i = 0.5 x_i + v sin(x_i)`` is not a direct measurement of ``x_i``: None."""
        return [None, None]

    def measure(self, x: np.ndarray, v: float) -> np.ndarray:
        """``0.5 x + v sin(x)``, shape (2,)."""
        return plant.measure(x, v)

    def linear_model(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Linearization about ``x = 0``, ``v = 0``: ``C = 0.5 I`` and ``R = 0`` (no noise).

        Returns
        -------
        C : ndarray, shape (2, 2)
        R : ndarray, shape (2, 2)
        """
        return 0.5 * np.eye(2), np.zeros((2, 2))


class NonlinearDiscreteEnv(gym.Env):
    """Example 5.1, eq. (49), of Zhang, Deng & Zhang (2018): a plain (non-MuJoCo) stochastic plant.

    ::

        x1+ = 0.6 x1^3 / (1 + x1^2 + x2^2) + 0.1 v x1 + 0.5 x2 sin(v) w
        x2+ = 0.65 x2 + 0.1 x2 x1 + 0.5 v sin(x2) w
        y   = 0.5 x + v sin(x)

    ``w_k ~ N(0, 1)`` is drawn once per step from the environment's generator; ``v_k`` is the
    paper's disturbance ``2 * 0.9999^k`` (``disturbance="paper"``, default) plus the action,
    or the action alone (``disturbance=None``). Everything is dimensionless; one step is one
    time unit (``dt_s = 1``, ``info["t"] = k``). See
    :mod:`testbed.reproductions.zhang_lmi_hinf.plant`.

    ## Action space

    ``Box(-10, 10, (1,), float64)``

    | Num | Action                                                  | Min | Max | Unit |
    |-----|---------------------------------------------------------|-----|-----|------|
    | 0   | perturbation of the disturbance ``v_k`` (or ``v_k``)    | -10 | 10  | -    |

    Over step ``k`` the plant feels ``v_k = schedule(k) + clip(action, -10, 10)``; clipping
    sets ``info["action_clipped"]``. NaN, inf or a wrong shape raise ``ValueError`` and leave
    the state and the random generator unchanged.

    ## Observation space

    ``Box(-inf, inf, (2,), float64)``

    | Num | Observation                              | Unit |
    |-----|------------------------------------------|------|
    | 0   | ``y1 = 0.5 x1 + v sin(x1)``              | -    |
    | 1   | ``y2 = 0.5 x2 + v sin(x2)``              | -    |

    The observation after step ``k`` is ``y_{k+1}`` with the schedule's ``v_{k+1}`` (the
    next action, which the paper's ``y_{k+1} = g(x_{k+1}, v_{k+1})`` would include, is not
    known yet); after ``reset`` it is ``y_0`` with ``v_0``.

    ## Info

    | key              | content                                                   | unit |
    |------------------|-----------------------------------------------------------|------|
    | `state`          | true ``[x1, x2]`` after the step, shape (2,)              | -    |
    | `t`              | step count ``k`` after the step (float)                   | step |
    | `disturbance`    | ``[v_k]`` applied over the step (after reset: ``[v_0]``)   | -    |
    | `noise`          | ``w_k`` of the step (0 after reset)                       | -    |
    | `z`              | ``z = 0.1 x1 + 0.1 x2`` after the step                    | -    |
    | `setpoint`       | no reference: shape (0,)                                  |      |
    | `action_applied` | ``[v_k]``, the disturbance applied over the step, (1,)     | -    |
    | `action_clipped` | bool, shape (1,)                                          |      |
    | `escape`         | None, or ``{"quantity": "state", "time": k}`` once escaped |     |

    ## Reward

    ``-z^2`` after each step; estimator studies can ignore it. Always finite.

    ## Episode end

    Terminates when a step would take the state beyond ``1e6`` in magnitude (or make it
    non-finite): the state then stays the last one within the bound (observations and rewards
    are never NaN or inf), ``info["escape"]`` records the step, and further steps return it
    unchanged with ``terminated=True``. Truncated after ``max_episode_steps`` (registration
    default 200).

    ## Arguments

    ``disturbance``: ``"paper"`` (default) or None. ``reset(seed=..., options={"x0": (2,)})``:
    ``x0`` defaults to ``[1, 1]`` (the paper gives none; with ``x0 = 0`` the state stays 0) and
    must lie within the escape bound. Unknown keys raise ``ValueError``.
    """

    metadata = {"render_modes": [], "render_fps": 10}
    DEFAULT_X0 = (1.0, 1.0)

    def __init__(self, disturbance: str | None = "paper", render_mode: str | None = None):
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (no rendering), got {render_mode!r}")
        if disturbance not in ("paper", None):
            raise ValueError(f"disturbance must be 'paper' or None, got {disturbance!r}")
        self.disturbance_name = disturbance
        self.dt_s = 1.0
        self.sensors = NonlinearDiscreteSensors(dt_s=self.dt_s)
        self.action_space = spaces.Box(-ACTION_LIMIT, ACTION_LIMIT, (1,), np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, (2,), np.float64)
        self.state_names = list(plant.STATE_NAMES)
        self.action_names = ["v [-]"]
        self._x = np.array(self.DEFAULT_X0)
        self._x0 = self._x.copy()
        self._steps = 0
        self._escape: dict[str, Any] | None = None

    # ------------------------------------------------------------------ helpers
    @property
    def t_s(self) -> float:
        """Time in steps (one step = one time unit)."""
        return float(self._steps)

    @property
    def x0(self) -> np.ndarray:
        """True initial state of the current episode, shape (2,)."""
        return self._x0.copy()

    def schedule(self, k: int) -> float:
        """Scheduled disturbance ``v_k`` (``2 * 0.9999^k`` or 0)."""
        return float(plant.paper_disturbance(k)) if self.disturbance_name == "paper" else 0.0

    def _info(self, x: np.ndarray, v: float, w: float, clipped: bool) -> dict[str, Any]:
        return {
            "state": x.copy(),
            "t": self.t_s,
            "disturbance": np.array([v]),
            "noise": w,
            "z": float(plant.output(x)),
            "setpoint": np.zeros(0),
            "action_applied": np.array([v]),
            "action_clipped": np.array([clipped]),
            "escape": None if self._escape is None else dict(self._escape),
        }

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset to ``x0`` (``options={"x0": ...}``, default ``[1, 1]``)."""
        check_seed(seed)
        options = reset_options(options, RESET_OPTION_KEYS)
        x0 = np.array(self.DEFAULT_X0)
        if options.get("x0") is not None:
            x0 = initial_state(options["x0"], 2, ESCAPE_BOUND, self.state_names)
        super().reset(seed=seed)
        self._steps = 0
        self._escape = None
        self._x = x0.copy()
        self._x0 = x0.copy()
        v0 = self.schedule(0)
        return self.sensors.measure(self._x, v0), self._info(self._x, v0, 0.0, False)

    def step(self, action):
        """Apply ``v_k`` for one step; see the class docstring."""
        u = action_array(action, 1)
        perturbation = float(np.clip(u[0], -ACTION_LIMIT, ACTION_LIMIT))
        v = self.schedule(self._steps) + perturbation
        w = 0.0
        if self._escape is None:
            w = float(self.np_random.standard_normal())
            with np.errstate(over="ignore", invalid="ignore"):
                x = plant.step(self._x, v, w)
            if np.all(np.abs(x) <= ESCAPE_BOUND):  # NaN compares False
                self._x = x
                self._steps += 1
            else:
                self._escape = {"quantity": "state", "time": float(self._steps + 1)}
        x = self._x
        y = self.sensors.measure(x, self.schedule(self._steps))
        z = float(plant.output(x))
        return (y, -z * z, self._escape is not None, False,
                self._info(x, v, w, perturbation != u[0]))
