"""``testbed/UncertainLinear-v0``: a linear plant with norm-bounded uncertainty as a Gymnasium
environment (the examples of Wang & Fang (2006) and Liu, Deng & Wang (n.d.); see
docs/references.md)."""

from __future__ import annotations

from typing import Any

import numpy as np

from filters.analysis import UncertainPlant
from testbed.envs.plant_env import PlantEnv, PlantSensors
from testbed.reproductions.variance_constrained.plant import ESCAPE_BOUND, UncertainLinearPlant

#: Default sample period of a continuous-time scenario, s.
CONTINUOUS_DT_S = 0.01

#: The named scenarios (``scenario=``): the paper examples, continuous and discrete.
SCENARIOS = ("wang-variance-constrained-parabolic", "liu-variance-constrained-discrete")


def _scenario_model(name: str) -> UncertainPlant:
    from testbed.reproductions.variance_constrained import scenario

    if name == "wang-variance-constrained-parabolic":
        return scenario.VarianceConstrainedContinuousScenario().plant
    if name == "liu-variance-constrained-discrete":
        return scenario.VarianceConstrainedDiscreteScenario().plant
    raise ValueError(f"scenario must be one of {list(SCENARIOS)} (or pass plant=...), got "
                     f"{name!r}")


class UncertainLinearEnv(PlantEnv):
    """A linear plant with norm-bounded uncertainty ``[dA; dC] = [M1; M2] F N``, ``F^T F <= I``
    (the model and its exact sampling: :mod:`testbed.reproductions.variance_constrained.plant`).

    The example of Wang & Fang (2006) (continuous,
    ``scenario="wang-variance-constrained-parabolic"``) or of Liu, Deng & Wang (n.d.)
    (discrete, ``"liu-variance-constrained-discrete"``), or any
    :class:`~filters.analysis.UncertainPlant` (``plant=``). ``F`` is drawn per episode from
    the env's generator (entries uniform in [-1, 1], scaled to spectral norm <= 1) unless
    fixed by the constructor or ``reset(options={"F": ...})``. The common contract
    (validation, escape beyond ``1e10``, info) is :class:`PlantEnv`'s; reward 0; truncated
    after 1000 steps (registration).

    ===========  =====  =================================================================
    space        shape  content
    ===========  =====  =================================================================
    action       (k,)   normalized input ``u`` through ``B`` (default ``B = 0``), [-1, 1]
    observation  (p,)   the measurement of the last step; zeros after ``reset``
    ===========  =====  =================================================================

    After a step ``k -> k+1`` the observation is the measurement of that step (discrete
    ``y(k)``, continuous the average of ``y(t)`` over the step), so a filter ``xhat(k+1) =
    G xhat(k) + K y(k)`` stepped on it estimates ``info["state"] = x(k+1)``. ``info`` adds
    ``F`` (the episode's) and ``disturbance`` (discrete: ``w(k)``; continuous: the standard
    normal ``xi`` of the exact step).

    Arguments: ``scenario`` or ``plant``; ``dt_s`` (continuous: sample period, default
    0.01 s; discrete: time label, default 1); ``F`` (fixed uncertainty, default None: drawn
    per episode); ``B`` (n, k) input matrix. ``reset(options={"x0": (n,), "F": ...})``:
    ``x0`` defaults to 0; ``F`` overrides the uncertainty for this episode.
    """

    RESET_OPTION_KEYS = ("x0", "F")

    def __init__(self, scenario: str = "wang-variance-constrained-parabolic",
                 plant: UncertainPlant | None = None, dt_s: float | None = None,
                 F: Any = None, B: Any = None, render_mode: str | None = None):
        if plant is not None and not isinstance(plant, UncertainPlant):
            raise ValueError(f"plant must be a filters.analysis.UncertainPlant, got "
                             f"{type(plant).__name__}")
        model = plant if plant is not None else _scenario_model(scenario)
        if dt_s is None:
            dt_s = 1.0 if model.discrete else CONTINUOUS_DT_S
        self.model = model
        self._fixed_F = None if F is None else model.uncertainty(F)
        self._F_option: np.ndarray | None = None
        system = UncertainLinearPlant(model, dt_s, B)  # checks dt_s
        sensors = PlantSensors([f"y{i + 1}" for i in range(model.p)], model.C,
                               model.D2 @ model.D2.T, per_sample=model.discrete)
        k = system.B.shape[1]
        self._setup(system, sensors, action_limit=1.0,
                    action_names=[f"u{i + 1} [-]" for i in range(k)],
                    state_names=[f"x{i + 1}" for i in range(model.n)], x0=np.zeros(model.n),
                    escape_bound=ESCAPE_BOUND, render_mode=render_mode)

    @property
    def F(self) -> np.ndarray:
        """The current episode's uncertainty, shape (i, j)."""
        return self.plant.F.copy()

    def _check(self, options: dict[str, Any]) -> None:
        self._F_option = None
        if options.get("F") is not None:
            try:
                self._F_option = self.model.uncertainty(options["F"])
            except ValueError as exc:
                raise ValueError(f"options['F']: {exc}") from None

    def _episode(self, options: dict[str, Any]) -> dict[str, Any]:
        F = self._F_option if self._F_option is not None else self._fixed_F
        self.plant.F = self.plant.sample_F(self.np_random) if F is None else F.copy()
        return {"F": self.plant.F.copy()}

    def _first(self, x0: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        return self.plant.observe(x0, 0), {"disturbance": self.plant.noise(None, ())}
