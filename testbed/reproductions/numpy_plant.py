"""The papers' own numpy plants: one protocol, one batch-first loop, one Gymnasium env.

A paper whose plant is not a MuJoCo rig (the nonlinear system of Zhang, Deng & Zhang
(2018), the uncertain linear plants of Wang & Fang (2006) and Liu, Deng & Wang (n.d.), the
cubic system of Basin, Shi & Calderon-Alvarez (n.d.), the linear helicopter model of Basin,
Elvira-Ceja & Sanchez (n.d.)) gives it as a :class:`NumpyPlant`:

- ``dt_s``, ``state_names``; ``noise(rng, batch)``: one step's random draws for a batch
  (None for a noise-free plant);
- ``observe(x, k)``: the measurement at step ``k`` before any step (a reset's observation);
- ``step(x, k, u, noise) -> (x_next, y, extras)``: step ``k -> k + 1`` for states of shape
  ``(..., n)``; ``y`` is the measurement delivered at the end of the step (the testbed
  convention: a filter's ``step(y)`` returns ``xhat_{k+1}``), ``extras`` what the env adds to
  its ``info``. A finite escape raises :class:`~filters.errors.FiniteEscapeError` (nothing
  non-finite is returned).

:func:`rollout` runs a plant and any number of the library's estimators together (the
Monte Carlo and the recordings of every reproduction with such a plant); :class:`PlantEnv`
is the Gymnasium face of one plant (``testbed/NonlinearDiscrete-v0``,
``testbed/UncertainLinear-v0``, ``testbed/PolynomialCubic-v0``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from filters.errors import FilterError, FiniteEscapeError
from testbed.envs.common import action_array, check_seed, initial_state, reset_options


class NumpyPlant(Protocol):
    """A paper's own plant, stepped for states of shape ``(..., n)`` (module docstring)."""

    dt_s: float

    def noise(self, rng: np.random.Generator | None, batch: tuple[int, ...]) -> Any:
        """One step's random draws for states of shape ``batch + (n,)`` (None: none)."""

    def observe(self, x: np.ndarray, k: int) -> np.ndarray:
        """The measurement at step ``k`` without a step, shape ``(..., p)``."""

    def step(self, x: np.ndarray, k: int, u: np.ndarray | None, noise: Any
             ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        """Step ``k -> k + 1``: ``(x_next (..., n), y (..., p), extras)``."""


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

    def linear_model(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``C`` (p, n) and the per-sample noise covariance ``R`` (p, p) for a filter design."""
        return self.C.copy(), self.R.copy() if self.per_sample else self.R / dt_s


@dataclass
class Rollout:
    """What :func:`rollout` gathered (rows ``0..N``; ``N`` is shorter after an escape).

    Attributes
    ----------
    t_s : ndarray, shape (N + 1,)
    x : ndarray, shape (..., N + 1, n)
        States, batch axes first.
    y : ndarray, shape (..., N, p)
        ``y[..., k, :]``: the measurement delivered at the end of step ``k``.
    estimates, covariances : dict of ndarray
        Per estimator: ``(..., K + 1, n)`` and ``(..., K + 1, n, n)`` (covariances of the
        estimators that have one); ``K = N`` unless it failed.
    failures : dict
        Estimator name -> ``(k, FilterError)``: step ``k`` raised; the estimator keeps its
        state at step ``k`` and its rows end there.
    escape : FiniteEscapeError or None
        The plant's escape that ended the run.
    """

    t_s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    estimates: dict[str, np.ndarray]
    covariances: dict[str, np.ndarray]
    failures: dict[str, tuple[int, FilterError]]
    escape: FiniteEscapeError | None


def rollout(plant: NumpyPlant, x0: np.ndarray, n_steps: int, *,
            noise: np.random.Generator | Callable[[int], Any] | None = None,
            u: Callable[[int], np.ndarray] | None = None,
            estimators: dict[str, Any] | None = None, record: bool = True,
            on_step: Callable[[int, np.ndarray, dict[str, np.ndarray]], None] | None = None,
            ) -> Rollout:
    """Step a plant for a batch of runs with estimators in the loop.

    Each step ``k``: the plant goes ``x_k -> x_{k+1}`` and delivers ``y``; every estimator
    is stepped on it (``step(y)``, or ``step(y, u_k)`` with ``u``) and holds ``xhat_{k+1}``.
    An estimator with ``prime`` (:class:`filters.LMIHInfFilter`) first gets
    ``plant.observe(x0, 0)``. The arithmetic is the estimators' own: a batch ``x0`` of shape
    ``(R, n)`` uses their batched form, ``(n,)`` their single form.

    Parameters
    ----------
    plant : NumpyPlant
    x0 : ndarray, shape (..., n)
    n_steps : int
    noise : numpy.random.Generator or callable ``k -> draws``, optional
        A generator draws each step's noise through ``plant.noise`` (as the env does); a
        callable gives step ``k``'s draws (e.g. a column of a pre-drawn array); None:
        ``plant.noise(None, batch)``.
    u : callable ``k -> (..., nu)``, optional
        The plant's input over step ``k``, also given to the estimators.
    estimators : dict, optional
        Name -> estimator, or ``(estimator, select)`` with ``select(y)`` the channels it gets.
    record : bool
        Keep the states, measurements, estimates and covariances (False: ``on_step`` only).
    on_step : callable ``(k, x_{k+1}, {name: xhat_{k+1}}) -> None``, optional
        Called after each step (e.g. to accumulate error moments without recording).

    Returns
    -------
    Rollout
    """
    x = np.array(x0, dtype=float)
    batch = x.shape[:-1]
    ests = {name: e if isinstance(e, tuple) else (e, None)
            for name, e in (estimators or {}).items()}
    draw = (noise if callable(noise) and not isinstance(noise, np.random.Generator)
            else lambda _k: plant.noise(noise, batch))
    y0 = None
    xs, ys = [x], []
    hist: dict[str, list] = {}
    covs: dict[str, list] = {}
    for name, (est, select) in ests.items():
        if hasattr(est, "prime"):
            y0 = plant.observe(x, 0) if y0 is None else y0
            est.prime(y0 if select is None else select(y0))
        hist[name] = [np.array(est.x)]
        if est.P is not None:
            covs[name] = [np.array(est.P)]
    failures: dict[str, tuple[int, FilterError]] = {}
    escape = None
    for k in range(n_steps):
        uk = None if u is None else u(k)
        try:
            x, y, _ = plant.step(x, k, uk, draw(k))
        except FiniteEscapeError as exc:
            escape = exc
            break
        now = {}
        for name, (est, select) in ests.items():
            if name in failures:
                continue
            ye = y if select is None else select(y)
            try:
                now[name] = est.step(ye) if uk is None else est.step(ye, uk)
            except FilterError as exc:
                failures[name] = (k, exc)
                continue
            if record:
                hist[name].append(np.array(now[name]))
                if name in covs:
                    covs[name].append(np.array(est.P))
        if record:
            xs.append(x)
            ys.append(y)
        if on_step is not None:
            on_step(k, x, now)
    done = len(ys) if record else 0

    def stack(rows: list, tail: int) -> np.ndarray:
        arr = np.array(rows) if rows else np.empty((0, *batch, tail))
        return np.ascontiguousarray(np.moveaxis(arr, 0, len(batch)))  # batch-first

    return Rollout(
        t_s=np.arange(done + 1) * plant.dt_s,
        x=stack(xs, x.shape[-1]), y=stack(ys, 0),
        estimates={name: stack(rows, x.shape[-1]) for name, rows in hist.items()},
        covariances={name: np.ascontiguousarray(np.moveaxis(np.array(rows), 0, len(batch)))
                     for name, rows in covs.items()},
        failures=failures, escape=escape)


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
