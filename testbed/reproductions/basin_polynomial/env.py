"""``testbed/PolynomialCubic-v0``: the cubic polynomial system of Basin, Shi &
Calderon-Alvarez (n.d.) as a Gymnasium environment (see docs/references.md).

A plain ODE plant (no MuJoCo) under the same contract as the MuJoCo rigs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from filters import real_array
from filters.errors import FiniteEscapeError
from filters.polynomial_model import EscapeTest
from testbed.envs.common import action_array, check_seed, initial_state, reset_options
from testbed.reproductions.basin_polynomial.plant import PolynomialPlant
from testbed.reproductions.basin_polynomial.scenario import paper_model, paper_w

STATE_NAMES = ("x1", "x2")
ACTION_LIMIT = 10.0
RESET_OPTION_KEYS = ("x0",)
DISTURBANCES = ("paper", "white", "none")


@dataclass
class OutputSensor:
    """The observation ``y = x1 + w2`` (23), averaged over each control period.

    Parameters
    ----------
    noise_intensity : float
        Intensity ``q2`` of ``w2`` when it is white noise (0 for a deterministic ``w2``);
        a sample then has variance ``q2 / dt_s``.

    Attributes
    ----------
    names : list of str
        ``["y"]``.
    dim : int
        1.
    measured_state_index : list of int
        ``[0]``: ``y`` measures ``x1``.
    """

    noise_intensity: float = 0.0
    name: str = field(default="output", init=False)

    @property
    def names(self) -> list[str]:
        """Measurement channel names."""
        return ["y"]

    @property
    def dim(self) -> int:
        """Number of measurement channels."""
        return 1

    @property
    def measured_state_index(self) -> list[int | None]:
        """Index of the state each channel measures."""
        return [0]

    def linear_model(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Observation matrix and per-sample noise covariance for filter design.

        Returns
        -------
        C : ndarray, shape (1, 2)
            ``[1, 0]``.
        R : ndarray, shape (1, 1)
            ``q2 / dt_s`` for white ``w2``; for a deterministic ``w2`` the nominal unit
            intensity ``1 / dt_s`` (``D D^T = 1``, what the H-infinity filters use).
        """
        q = self.noise_intensity if self.noise_intensity > 0 else 1.0
        return np.array([[1.0, 0.0]]), np.array([[q / dt_s]])


class PolynomialCubicEnv(gym.Env):
    """The cubic system of Basin, Shi & Calderon-Alvarez (n.d.), Section IV, integrated with RK4.

    ``dx1/dt = x2``, ``dx2/dt = 0.1 x2^2 + (0.1 + 0.1 sin 50t) x2^3 + w1 + u``,
    ``y = x1 + w2``, ``z = x`` (eqs. (22)-(24); the input ``u`` is an extension, 0 gives the
    paper's system). The cubic term is positive: the state escapes in finite time (about
    1.78 s from the paper's ``x0 = [1, 1]`` with its disturbance). The model, for filters,
    is :attr:`model` (:func:`testbed.reproductions.basin_polynomial.scenario.paper_model` with
    ``E = [0, 1]^T``).

    ## Action space

    ``Box(-10, 10, (1,), float64)``

    | Num | Action                                  | Min | Max | Unit   |
    |-----|-----------------------------------------|-----|-----|--------|
    | 0   | input ``u`` added to ``dx2/dt``         | -10 | 10  | 1/s^2 (x2 per s) |

    Values outside the range are clipped and flagged in ``info["action_clipped"]``. NaN,
    inf or a wrong shape raise ``ValueError`` and leave the simulation unchanged.

    ## Observation space

    ``Box(-inf, inf, (1,), float64)``

    | Num | Observation                                              | Unit          |
    |-----|----------------------------------------------------------|---------------|
    | 0   | ``y = x1 + w2`` averaged over the last control period     | units of x1   |

    After :meth:`reset`: ``x1(0) + w2(0)`` (deterministic part). With white ``w2`` of
    intensity ``q2`` a sample has variance ``q2 / dt_s``.

    ## State (``info["state"]``)

    | Num | State | Unit                          |
    |-----|-------|-------------------------------|
    | 0   | x1    | (dimensionless in the paper)  |
    | 1   | x2    | x1 per s                      |

    ## Info

    ``state``: true ``[x1, x2]``; ``t``: time after the step (s); ``disturbance``:
    ``[w1, w2]`` averaged over the step (deterministic part plus white noise);
    ``action_applied`` and ``action_clipped``; ``escape``: None, or
    ``{"quantity": "state", "time": t}`` once the state has escaped.

    ## Reward

    ``-(x1^2 + x2^2)`` after each step (regulation); estimator studies can ignore it.

    ## Episode end

    Terminates when the state escapes (an :class:`~filters.polynomial_model.EscapeTest` after
    every RK4 substep: a bound, default 1e8, and a growth test, more than +10 % in one
    substep above 100): the state is then the last one before the failing substep (never
    NaN) and further steps return it unchanged with ``terminated=True``. Truncated after
    ``max_episode_steps`` (registration default 1400 control steps = 1.4 s, the paper's
    horizon).

    ## Arguments

    ``dt_s`` (control period, default 0.001 s) and ``substeps`` (RK4 steps per period,
    default 10: a 0.1 ms step, far below the 0.126 s period of ``sin 50t``);
    ``disturbance``: ``"paper"`` (``w1 = 1/(1+t)^2``, ``w2 = 2/(2+t)^2``), ``"white"``
    (white noise of intensities ``noise_intensity = (q1, q2)``, drawn from the env's seeded
    generator), ``"none"``, or a callable ``t_s -> [w1, w2]``; ``escape_bound`` and
    ``growth_rtol`` of the escape test.

    ``reset(seed=..., options={"x0": (2,)})``: ``x0`` defaults to the paper's ``[1, 1]``.
    Unknown keys raise ``ValueError``.
    """

    metadata = {"render_modes": [], "render_fps": 1000}

    def __init__(
        self,
        dt_s: float = 0.001,
        substeps: int = 10,
        disturbance: str | Callable[[float], np.ndarray] = "paper",
        noise_intensity: tuple[float, float] = (1.0, 1.0),
        escape_bound: float = 1e8,
        growth_rtol: float = 0.1,
        render_mode: str | None = None,
    ):
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (no rendering), got {render_mode!r}")
        try:
            dt = float(dt_s)
        except (TypeError, ValueError):
            raise ValueError(f"dt_s must be a positive float (s), got {dt_s!r}") from None
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt_s must be a positive float (s), got {dt_s!r}")
        if isinstance(substeps, bool) or not isinstance(substeps, int | np.integer) \
                or substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
        q = real_array(noise_intensity, "noise_intensity", finite=False)
        if q.shape != (2,) or not np.all(np.isfinite(q)) or np.any(q < 0):
            raise ValueError(f"noise_intensity must be two finite non-negative intensities "
                             f"(q1, q2), got {noise_intensity!r}")
        self._w_raw: Callable[[float], np.ndarray] | None
        self._white = False
        if callable(disturbance):
            self._w_raw = disturbance
            self.disturbance_name = getattr(disturbance, "__name__", "callable")
        elif disturbance in DISTURBANCES:
            self._w_raw = paper_w if disturbance == "paper" else None
            self._white = disturbance == "white"
            self.disturbance_name = disturbance
        else:
            raise ValueError(f"disturbance must be one of {DISTURBANCES} or a callable "
                             f"t_s -> [w1, w2], got {disturbance!r}")
        self._w_fn = None if self._w_raw is None else self._w_det
        self.dt_s = dt
        self.substeps = int(substeps)
        self.noise_intensity = q
        self.model = paper_model(E=np.array([[0.0], [1.0]]))
        self.plant = PolynomialPlant(self.model, EscapeTest(bound=escape_bound,
                                                            growth_rtol=growth_rtol))
        self.sensors = OutputSensor(noise_intensity=float(q[1]) if self._white else 0.0)
        self.action_space = spaces.Box(-ACTION_LIMIT, ACTION_LIMIT, (1,), np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, (1,), np.float64)
        self.state_names = list(STATE_NAMES)
        self.action_names = ["u [1/s^2]"]
        self._x = np.array([1.0, 1.0])
        self._x0 = self._x.copy()
        self._steps = 0
        self._w = np.zeros(2)
        self._y = np.zeros(1)
        self._escape: dict[str, Any] | None = None

    # ------------------------------------------------------------------ helpers
    @property
    def t_s(self) -> float:
        """Simulation time in s (control steps times the control period, no drift)."""
        return self._steps * self.dt_s

    @property
    def x0(self) -> np.ndarray:
        """True initial state of the current episode, shape (2,)."""
        return self._x0.copy()

    @property
    def state(self) -> np.ndarray:
        """True state ``[x1, x2]``, shape (2,) (a copy)."""
        return self._x.copy()

    def _w_det(self, t_s: float) -> np.ndarray:
        if self._w_raw is None:
            return np.zeros(2)
        w = np.asarray(self._w_raw(t_s), dtype=float)
        if w.shape != (2,) or not np.all(np.isfinite(w)):
            raise ValueError(f"the disturbance callable must return a finite array of shape "
                             f"(2,) [w1, w2], got {w!r} at t = {t_s} s")
        return w

    def _info(self, u: np.ndarray, clipped: np.ndarray) -> dict[str, Any]:
        return {
            "state": self._x.copy(),
            "t": self.t_s,
            "disturbance": self._w.copy(),
            "action_applied": u,
            "action_clipped": clipped,
            "escape": None if self._escape is None else dict(self._escape),
        }

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the plant; see the class docstring for ``options``."""
        check_seed(seed)
        options = reset_options(options, RESET_OPTION_KEYS)
        x0 = np.array([1.0, 1.0])
        if options.get("x0") is not None:
            x0 = initial_state(options["x0"], 2, self.plant.escape.bound, STATE_NAMES)
        super().reset(seed=seed)
        self._x = x0.copy()
        self._x0 = x0.copy()
        self._steps = 0
        self._escape = None
        self._w = self._w_det(0.0)
        self._y = self.model.at(0.0).C @ x0 + self.model.at(0.0).D @ self._w
        return self._y.copy(), self._info(np.zeros(1), np.zeros(1, bool))

    def step(self, action):
        """Apply the input for one control period; see the class docstring."""
        u = action_array(action, 1)
        applied = u.clip(-ACTION_LIMIT, ACTION_LIMIT)
        clipped = applied != u
        if self._escape is None:
            dW = self.np_random.standard_normal((self.substeps, 2)) if self._white else None
            try:
                x, y, w = self.plant.advance(
                    self._x, self.t_s, self.dt_s, self.substeps, w=self._w_fn, u=applied,
                    dW=dW, noise_intensity=self.noise_intensity if self._white else None)
            except FiniteEscapeError as exc:
                self._escape = {"quantity": exc.quantity, "time": exc.time}
            else:
                self._x, self._y, self._w = x, y, w
                self._steps += 1
        x = self._x
        reward = -float(x[0] * x[0] + x[1] * x[1])
        return (self._y.copy(), reward, self._escape is not None, False,
                self._info(applied, clipped))
