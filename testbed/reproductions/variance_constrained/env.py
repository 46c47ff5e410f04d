"""``testbed/UncertainLinear-v0``: a linear plant with norm-bounded uncertainty as a Gymnasium
environment (the examples of Wang & Fang (2006) and Liu, Deng & Wang (n.d.); see
docs/references.md)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from filters.analysis import UncertainPlant
from testbed.envs.common import action_array, check_seed, initial_state, reset_options
from testbed.reproductions.variance_constrained.plant import (
    UncertainLinearPlant,
    UncertainLinearSensors,
)

RESET_OPTION_KEYS = ("x0", "F")
#: Bound of the (optional, normalized) input, clipped; scale it through ``B``.
INPUT_LIMIT = 1.0
#: Default sample period of a continuous-time scenario, s.
CONTINUOUS_DT_S = 0.01
#: State magnitude (plant units) beyond which the episode terminates: an unstable plant
#: (or an absurd ``x0``) would otherwise overflow to inf and NaN.
ESCAPE_BOUND = 1e10


#: The named scenarios (``scenario=``): the paper examples, continuous and discrete.
SCENARIOS = ("wang-variance-constrained-parabolic", "liu-variance-constrained-discrete")


def _scenario_model(name: str) -> UncertainPlant:
    if name == "wang-variance-constrained-parabolic":
        from testbed.reproductions.variance_constrained.scenario_wang import (
            VarianceConstrainedContinuousScenario,
        )

        return VarianceConstrainedContinuousScenario().plant
    if name == "liu-variance-constrained-discrete":
        from testbed.reproductions.variance_constrained.scenario_liu import (
            VarianceConstrainedDiscreteScenario,
        )

        return VarianceConstrainedDiscreteScenario().plant
    raise ValueError(f"scenario must be one of {list(SCENARIOS)} (or pass plant=...), got "
                     f"{name!r}")


class UncertainLinearEnv(gym.Env):
    """A linear plant with norm-bounded uncertainty ``[dA; dC] = [M1; M2] F N``, ``F^T F <= I``.

    The example of Wang & Fang (2006) (continuous,
    ``scenario="wang-variance-constrained-parabolic"``) or of Liu, Deng & Wang (n.d.)
    (discrete, ``"liu-variance-constrained-discrete"``), or any
    :class:`~filters.analysis.UncertainPlant` (``plant=``)::

        continuous: x' = (A + M1 F N) x + B u + D1 w,   y = (C + M2 F N) x + D2 w
        discrete:   x(k+1) = (A + M1 F N) x(k) + B u(k) + D1 w(k),
                    y(k) = (C + M2 F N) x(k) + D2 w(k)

    ``w`` is white noise of unit intensity (continuous) or unit covariance (discrete), the same
    in state and measurement. ``F`` is drawn per episode from the env's generator (entries
    uniform in [-1, 1], scaled to spectral norm <= 1; uniform on [-1, 1] for a scalar ``F``)
    unless fixed by the constructor or ``reset(options={"F": ...})``. Simulation:
    :class:`~testbed.reproductions.variance_constrained.plant.UncertainLinearPlant` (exact for the
    continuous
    plant: ``x`` and ``int y dt`` by Van Loan).

    ## Action space

    ``Box(-1, 1, (k,), float64)``: the normalized input ``u`` through ``B`` (default
    ``B = 0``, shape (n, 1): the papers' plants have no input; the action then has no
    effect). Values outside
    are clipped (``info["action_clipped"]``); NaN, inf or a wrong shape raise ``ValueError``
    and leave the state (and the generator) unchanged.

    | Num | Action | Min | Max | Unit |
    |-----|--------|-----|-----|------|
    | 0..k-1 | input ``u`` (held over the step) | -1 | 1 | - (scaled by ``B``) |

    ## Observation space

    ``Box(-inf, inf, (p,), float64)``:

    | Num | Observation | Unit |
    |-----|-------------|------|
    | 0..p-1 | measurement ``y`` of the last step | plant units |

    After a step ``k -> k+1`` the observation is the measurement that belongs to that step:
    discrete ``y(k)`` (it shares ``w(k)`` with ``x(k+1)``, as in (1)-(2) of
    Liu, Deng & Wang (n.d.));
    continuous the average of ``y(t)`` over the step (noise covariance ``D2 D2^T / dt``). A
    filter ``xhat(k+1) = G xhat(k) + K y(k)`` stepped on it estimates ``info["state"] =
    x(k+1)``, so :class:`~testbed.envs.wrappers.FilterInLoop` with
    :class:`~filters.variance_constrained.LinearFilter` is aligned. ``reset`` returns zeros
    (no measurement yet).

    ## Info

    | key | content | unit |
    |-----|---------|------|
    | `state` | true ``x`` after the step, shape (n,) | plant units |
    | `t` | time after the step | s |
    | `disturbance` | noise draw of the step (see below) | - |
    | `F` | the episode's uncertainty, shape (i, j) | - |
    | `setpoint` | no reference: shape (0,) | |
    | `action_applied` | clipped ``u``, shape (k,) | |
    | `action_clipped` | bool, shape (k,) | |

    ``disturbance`` is ``w(k)`` (shape (r,)) for a discrete plant; for a continuous plant it is
    the standard normal ``xi`` of the exact step (``S xi`` is the noise of ``[x(k+1); y]``,
    :class:`~testbed.reproductions.variance_constrained.plant.Transition`).

    ## Reward

    0 (an estimation testbed; there is nothing to control).

    ## Episode end

    Truncated after ``max_episode_steps`` (registration default 1000). Terminates only if a
    step would take the state beyond :data:`ESCAPE_BOUND` in magnitude (an unstable plant):
    the state and measurement then stay those of the last step within the bound (never NaN
    or inf) and further steps return them unchanged with ``terminated=True``.

    ## Arguments

    ``scenario`` (``"wang-variance-constrained-parabolic"``,
    ``"liu-variance-constrained-discrete"``) or ``plant`` (an ``UncertainPlant``);
    ``dt_s`` (continuous: sample period, default 0.01 s; discrete: time label, default 1);
    ``F`` (fixed uncertainty, default None: drawn per episode); ``B`` (n, k) input matrix.

    ``reset(seed=..., options={"x0": (n,), "F": scalar or (i, j)})``: ``x0`` defaults to 0
    (and must lie within the escape bound);
    ``F`` overrides the uncertainty for this episode. Unknown keys raise ``ValueError``.
    """

    metadata = {"render_modes": [], "render_fps": 100}

    def __init__(self, scenario: str = "wang-variance-constrained-parabolic",
                 plant: UncertainPlant | None = None, dt_s: float | None = None,
                 F: Any = None, B: Any = None, render_mode: str | None = None):
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (no rendering), got {render_mode!r}")
        if plant is not None and not isinstance(plant, UncertainPlant):
            raise ValueError(f"plant must be a filters.analysis.UncertainPlant, got "
                             f"{type(plant).__name__}")
        model = plant if plant is not None else _scenario_model(scenario)
        if dt_s is None:
            dt_s = 1.0 if model.discrete else CONTINUOUS_DT_S
        if not (isinstance(dt_s, (int, float)) and np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be a positive finite float (s), got {dt_s!r}")
        self.model = model
        self.plant = UncertainLinearPlant(model, float(dt_s), B)
        self.dt_s = float(dt_s)
        self._fixed_F = None if F is None else model.uncertainty(F)
        self.sensors = UncertainLinearSensors(model)
        n, p, k = model.n, model.p, self.plant.B.shape[1]
        self.action_space = spaces.Box(-INPUT_LIMIT, INPUT_LIMIT, (k,), np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, (p,), np.float64)
        self.state_names = [f"x{i + 1}" for i in range(n)]
        self.action_names = [f"u{i + 1} [-]" for i in range(k)]
        self._x = np.zeros(n)
        self._x0 = np.zeros(n)
        self._F = np.zeros(model.f_shape)
        self._steps = 0
        self._y = np.zeros(p)
        self._escaped = False

    @property
    def t_s(self) -> float:
        """Time in s (steps times ``dt_s``)."""
        return self._steps * self.dt_s

    @property
    def F(self) -> np.ndarray:
        """The current episode's uncertainty, shape (i, j)."""
        return self._F.copy()

    @property
    def x0(self) -> np.ndarray:
        """True initial state of the current episode, shape (n,)."""
        return self._x0.copy()

    def _info(self, xi: np.ndarray, u: np.ndarray, clipped: np.ndarray) -> dict[str, Any]:
        return {"state": self._x.copy(), "t": self.t_s, "disturbance": xi, "F": self._F.copy(),
                "setpoint": np.zeros(0), "action_applied": u, "action_clipped": clipped}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the plant; see the class docstring for ``options``."""
        check_seed(seed)
        options = reset_options(options, RESET_OPTION_KEYS)
        n = self.model.n
        x0 = np.zeros(n)
        if options.get("x0") is not None:
            x0 = initial_state(options["x0"], n, ESCAPE_BOUND, self.state_names)
        F_opt = None
        if options.get("F") is not None:
            try:
                F_opt = self.model.uncertainty(options["F"])
            except ValueError as exc:
                raise ValueError(f"options['F']: {exc}") from None
        super().reset(seed=seed)
        if F_opt is not None:
            self._F = F_opt
        elif self._fixed_F is not None:
            self._F = self._fixed_F.copy()
        else:
            self._F = self.plant.sample_F(self.np_random)
        self._x = x0.copy()
        self._x0 = x0.copy()
        self._steps = 0
        self._y = np.zeros(self.model.p)
        self._escaped = False
        k = self.plant.B.shape[1]
        r = self.plant.transition(self._F).S.shape[1]
        return self._y.copy(), self._info(np.zeros(r), np.zeros(k), np.zeros(k, bool))

    def step(self, action):
        """Advance one sample; see the class docstring."""
        u = action_array(action, self.plant.B.shape[1])
        uc = u.clip(-INPUT_LIMIT, INPUT_LIMIT)
        xi = np.zeros(self.plant.transition(self._F).S.shape[1])
        if not self._escaped:
            with np.errstate(over="ignore", invalid="ignore"):
                x, y, xi = self.plant.step(self._x, self._F, self.np_random, uc)
            if np.all(np.abs(x) <= ESCAPE_BOUND) and np.all(np.isfinite(y)):
                self._x, self._y = x, y
                self._steps += 1
            else:
                self._escaped = True
        return self._y.copy(), 0.0, self._escaped, False, self._info(xi, uc, uc != u)
