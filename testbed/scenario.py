"""A scenario is data: rig, sensors, disturbance, controller or manoeuvre, estimator, horizon,
seed and parameter mismatch. :mod:`testbed.runner` executes it once, batched or over a grid.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from testbed.rigs import resolve_rig


@dataclass
class Scenario:
    """Everything one closed-loop experiment needs, as plain data.

    Attributes
    ----------
    rig : str or Rig subclass
        Registered name (``"helicopter"``, ``"vehicle-roll"``), ``module:Class`` or a class.
    profile : str
        Simulation profile of the rig: ``"paper"`` (the papers' idealizations) or
        ``"hardware"`` (actuator and sensor effects of the real rig); the estimator's design
        model is the same in both.
    estimator : str or callable
        Registered filter name, ``package.module:factory`` or a factory.
    estimator_options : dict
        Keyword options of the factory (e.g. ``{"gamma": 2.0}``).
    controller : str, optional
        ``"lqr"`` or ``"open-loop"`` (default: the rig's).
    sensors : str or Sensor, optional
        A preset of the rig (default: its first) or a sensor object.
    sensor_options : dict
        Options of the preset (e.g. ``{"noise_std_rad": 0.002}``).
    disturbance : str, optional
        A named signal of the rig (``"basin-helicopter"``).
    process_noise : float
        Scale of the rig's white process noise (0: none).
    ambient_noise : float
        Scale of the rig's small documented ambient disturbance (air turbulence, gusts;
        default 1, 0: none). The design model's ``Q`` includes it.
    reset_noise_scale : float
        Scale of the rig's documented initial-state distribution (default 1; 0: the fixed
        default state, as in the papers).
    manoeuvre : str, optional
        Open-loop input profile of the rig (default: the rig's; ``"none"`` for none).
    manoeuvre_params : dict
    setpoints : sequence of rows, optional
        Reference ``(t_s, *tracked)``; default the rig's.
    params : dict
        Scale factors of the simulated rig's parameters (model mismatch: the estimator and
        controller keep the nominal ones).
    design_options : dict
        Rig-specific design options (``Rig.scenario_options``, e.g. ``process_noise_floor``).
    duration_s : float
    seed : int
    physics_dt_s : float
    frame_skip : int
    """

    rig: Any = "helicopter"
    profile: str = "paper"
    estimator: Any = "kalman"
    estimator_options: dict[str, Any] = field(default_factory=dict)
    controller: str | None = None
    sensors: Any = None
    sensor_options: dict[str, Any] = field(default_factory=dict)
    disturbance: str | None = None
    process_noise: float = 0.0
    ambient_noise: float = 1.0
    reset_noise_scale: float = 1.0
    manoeuvre: Any = None
    manoeuvre_params: dict[str, Any] = field(default_factory=dict)
    setpoints: Any = None
    params: dict[str, float] = field(default_factory=dict)
    design_options: dict[str, Any] = field(default_factory=dict)
    duration_s: float = 20.0
    seed: int = 0
    physics_dt_s: float = 0.001
    frame_skip: int = 10

    def replace(self, **changes: Any) -> Scenario:
        """A copy with some fields changed; unknown names raise ``ValueError``."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = set(changes) - names
        if unknown:
            raise ValueError(f"unknown scenario fields {sorted(unknown)}; expected among "
                             f"{sorted(names)}")
        return dataclasses.replace(self, **changes)

    def check(self) -> None:
        """Validate what can be checked without building anything (fields and rig options).

        Raises
        ------
        ValueError
            A bad value or an option the rig does not have, naming it.
        """
        rig = resolve_rig(self.rig)
        if not (isinstance(self.duration_s, int | float) and np.isfinite(self.duration_s)
                and self.duration_s > 0):
            raise ValueError(f"duration_s must be a positive finite time in s, got "
                             f"{self.duration_s!r}")
        if self.profile not in rig.profiles:
            raise ValueError(f"profile must be one of {rig.profiles} for rig {rig.name!r}, got "
                             f"{self.profile!r}")
        if not isinstance(self.seed, int | np.integer) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {self.seed!r}")
        unknown = set(self.design_options) - set(rig.scenario_options)
        if unknown:
            raise ValueError(f"design option(s) {sorted(unknown)} do not apply to rig "
                             f"{rig.name!r}; its options: {sorted(rig.scenario_options) or 'none'}")
        if self.setpoints is not None and not rig.tracked_states:
            raise ValueError(f"setpoints do not apply to rig {rig.name!r} (no tracked states)")

    def describe(self) -> dict[str, Any]:
        """JSON-ready description (callables and objects by name)."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, type):
                value = getattr(value, "name", value.__name__)
            elif callable(value) and not isinstance(value, str):
                value = getattr(value, "__name__", repr(value))
            elif hasattr(value, "describe") and not isinstance(value, dict | str):
                value = value.describe()
            out[f.name] = value
        return out
