"""A paper's own numpy plant as a Gymnasium environment: :class:`PlantEnv`, the base of
``testbed/NonlinearDiscrete-v0``, ``testbed/UncertainLinear-v0`` and
``testbed/PolynomialCubic-v0`` (each a small subclass beside its plant in
``testbed/reproductions/<family>/env.py``), and :class:`PlantSensors`, their measurement
for designs."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from filters.errors import FiniteEscapeError
from testbed.envs.common import action_array, check_seed, initial_state, reset_options
from testbed.experiment.numpy_plant import NumpyPlant


@dataclass
class PlantSensors:
    """The measurement of a numpy plant, for environments and filter designs.

    Attributes
    ----------
    names : list of str
        Channel names, ``p`` of them.
    C : ndarray, shape (p, n)
        Nominal observation matrix (the linearization at 0 for a nonlinear plant).
    R : ndarray, shape (p, p)
        Noise covariance per sample (``per_sample``) or intensity (divided by the period).
    per_sample : bool
    """

    names: list[str]
    C: np.ndarray
    R: np.ndarray
    per_sample: bool = True
    name: str = field(default="paper")

    @property
    def dim(self) -> int:
        """Number of channels ``p``."""
        return len(self.names)

    @property
    def measured_state_index(self) -> list[int | None]:
        """The state a channel measures directly (a unit row of ``C``), else None."""
        out: list[int | None] = []
        for row in self.C:
            nz = np.flatnonzero(row)
            out.append(int(nz[0]) if nz.size == 1 and row[nz[0]] == 1.0 else None)
        return out

    @property
    def measured_state(self) -> list[int | None]:
        """:attr:`measured_state_index` under the sensors' contract's name
        (:class:`testbed.envs.common.EnvSensors`)."""
        return self.measured_state_index

    def describe(self) -> str:
        """A description for outputs: empty (a plant's measurement is its ``C`` and ``R``)."""
        return ""

    def linear_model(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``C`` (p, n) and the per-sample noise covariance ``R`` (p, p) for a filter design."""
        return self.C.copy(), self.R.copy() if self.per_sample else self.R / dt_s


class PlantEnv(gym.Env):
    """A numpy plant as a Gymnasium environment (the contract every testbed env keeps).

    One episode steps :attr:`plant` with its noise drawn from the env's seeded generator
    (``reset(seed=...)``): the same seed gives the same episode bitwise. The action is
    clipped to ``[-action_limit, action_limit]`` (``info["action_clipped"]``); NaN, inf or a
    wrong shape raise ``ValueError`` and leave the state and the generator unchanged, as do
    unknown reset options. ``reset(options={"x0": (n,)})`` sets the initial state (it must
    lie within the escape bound).

    ``info``: ``state`` (truth after the step), ``t`` (steps times ``dt_s``), ``setpoint``
    (none: shape (0,)), ``action_applied``, ``action_clipped``, ``escape`` (None, or
    ``{"quantity", "time"}``) and the plant's extras (e.g. ``disturbance``).

    Episode end: when a step would make the plant escape (a
    :class:`~filters.errors.FiniteEscapeError` of its ``step``) the episode terminates; the
    state and observation stay the last ones within the bound (never NaN or inf) and further
    steps return them unchanged with ``terminated=True``. Truncation comes from the
    registration's ``max_episode_steps``.

    Subclasses set the plant, sensors and spaces (:meth:`_setup`) and may override
    :meth:`_episode` (per-episode draws), :meth:`_reward` and :meth:`_first`.
    """

    metadata: dict[str, Any] = {"render_modes": [], "render_fps": 100}
    RESET_OPTION_KEYS: tuple[str, ...] = ("x0",)

    def _setup(self, plant: NumpyPlant, sensors: PlantSensors, *, action_limit: float,
               action_names: list[str], state_names: list[str], x0: np.ndarray,
               escape_bound: float, render_mode: str | None) -> None:
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (no rendering), got {render_mode!r}")
        self.plant, self.sensors = plant, sensors
        self.dt_s = float(plant.dt_s)
        self.action_limit, self.escape_bound = float(action_limit), float(escape_bound)
        self.action_space = spaces.Box(-action_limit, action_limit, (len(action_names),),
                                       np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, (sensors.dim,), np.float64)
        self.state_names, self.action_names = list(state_names), list(action_names)
        self._default_x0 = np.array(x0, dtype=float)
        self._x, self._x0 = self._default_x0.copy(), self._default_x0.copy()
        self._y = np.zeros(sensors.dim)
        self._steps = 0
        self._escape: dict[str, Any] | None = None
        self._extras: dict[str, Any] = {}

    @property
    def t_s(self) -> float:
        """Time after the last step (steps times ``dt_s``)."""
        return self._steps * self.dt_s

    @property
    def x0(self) -> np.ndarray:
        """True initial state of the current episode, shape (n,)."""
        return self._x0.copy()

    @property
    def state(self) -> np.ndarray:
        """True state, shape (n,) (a copy)."""
        return self._x.copy()

    def _episode(self, options: dict[str, Any]) -> dict[str, Any]:
        """Per-episode draws after the generator is seeded; returns the info extras."""
        return {}

    def _check(self, options: dict[str, Any]) -> None:
        """Check the subclass's own reset options (before anything changes)."""

    def _reward(self, x: np.ndarray) -> float:
        return 0.0

    def _first(self, x0: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        """The observation at reset and its info extras."""
        return self.plant.observe(x0, 0), {}

    def _info(self, applied: np.ndarray, clipped: np.ndarray) -> dict[str, Any]:
        return {"state": self._x.copy(), "t": self.t_s, "setpoint": np.zeros(0),
                "action_applied": applied, "action_clipped": clipped,
                "escape": None if self._escape is None else dict(self._escape),
                **{k: v.copy() if isinstance(v, np.ndarray) else v
                   for k, v in self._extras.items()}}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode; see the class docstring for ``options``."""
        check_seed(seed)
        options = reset_options(options, self.RESET_OPTION_KEYS)
        x0 = self._default_x0.copy()
        if options.get("x0") is not None:
            x0 = initial_state(options["x0"], x0.size, self.escape_bound, self.state_names)
        self._check(options)
        super().reset(seed=seed)
        episode = self._episode(options)
        self._x, self._x0 = x0.copy(), x0.copy()
        self._steps = 0
        self._escape = None
        self._y, first = self._first(x0)
        self._extras = {**episode, **first}
        k = self.action_space.shape[0]
        return self._y.copy(), self._info(np.zeros(k), np.zeros(k, bool))

    def step(self, action):
        """Advance one step; see the class docstring."""
        u = action_array(action, self.action_space.shape[0])
        applied = u.clip(-self.action_limit, self.action_limit)
        if self._escape is None:
            try:
                with np.errstate(over="ignore", invalid="ignore"):
                    x, y, extras = self.plant.step(self._x, self._steps, applied,
                                                   self.plant.noise(self.np_random, ()))
            except FiniteEscapeError as exc:
                self._escape = {"quantity": exc.quantity, "time": exc.time}
            else:
                self._x, self._y = x, y
                self._extras.update(extras)
                self._steps += 1
        return (self._y.copy(), self._reward(self._x), self._escape is not None, False,
                self._info(applied, applied != u))
