"""A scenario is data: rig, sensors, disturbance, controller or manoeuvre, estimator, horizon,
seed and parameter mismatch. :mod:`testbed.experiment.runner` executes it once, batched or over a
grid.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from filters.base import Named
from testbed.plugins import factory_name
from testbed.records import field_items
from testbed.rigs import resolve_rig
from testbed.rigs.base import Rig, build_rig

#: Largest seed (numpy's and the runner's int64 seed arrays).
MAX_SEED = 2**63 - 1


class ScenarioError(ValueError):
    """A scenario field has a bad or inapplicable value.

    Parameters
    ----------
    field : str
        The :class:`Scenario` field (``"duration_s"``, ``"estimator_options"``...).
    message : str
    """

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (self.field, str(self)))


def _nominal_params(rig_cls: type, values: dict[str, float]) -> Any:
    """The rig's nominal parameters with ``values`` in place of some fields (a twin's),
    validated; a :class:`ScenarioError` of ``nominal_params`` names a bad one."""
    params = rig_cls.params_type()
    if not values:
        return params
    fields = {f.name for f in dataclasses.fields(params)}
    unknown = sorted(set(values) - fields)
    if unknown:
        raise ScenarioError("nominal_params", f"rig {rig_cls.name!r} has no parameter "
                            f"{unknown[0]!r}; expected one of {sorted(fields)}")
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not np.isfinite(value):
            raise ScenarioError("nominal_params", f"{name} must be a finite number, got "
                                f"{value!r}")
    try:
        params = dataclasses.replace(params, **{k: float(v) for k, v in values.items()})
        params.validate()
    except ValueError as exc:
        raise ScenarioError("nominal_params", str(exc)) from None
    return params


def _build_rig(rig_cls: type, spec: Any, dt_s: float, profile: str,
               options: dict[str, Any] | None = None, params: Any = None) -> Rig:
    """``rig_cls(params, physics_dt_s, profile, options)``; whatever a rig's code raises is
    a :class:`ScenarioError` of ``rig`` (one line, the exception named)."""
    from testbed.plugins import PLUGIN_FAILURES, PluginError

    try:
        return build_rig(rig_cls, params, physics_dt_s=dt_s, profile=profile, options=options)
    except PLUGIN_FAILURES as exc:
        label = spec if isinstance(spec, str) else rig_cls.name
        raise ScenarioError("rig", str(PluginError(f"rig {label!r}", "build", exc))) from None


def _build_sensors(rig: Rig, preset: str | None, dt_s: float, options: dict[str, Any]) -> Any:
    """The rig's sensor preset; options it does not take are a :class:`ScenarioError` of
    ``sensor_options``."""
    import inspect

    method = rig.sensors
    try:
        params = inspect.signature(method).parameters.values()
    except (TypeError, ValueError):
        params = None
    if params is not None and not any(p.kind is p.VAR_KEYWORD for p in params):
        known = {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        known -= {"preset", "dt_s"}
        unknown = set(options) - known
        if unknown:
            raise ScenarioError("sensor_options", f"sensor_options {sorted(unknown)} do not "
                                f"apply to the sensors of rig {rig.name!r}; they take "
                                f"{sorted(known) or 'none'}")
    try:
        return method(preset, dt_s=dt_s, **options)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ValueError) and not _builds_without(method, preset, dt_s, options):
            raise  # about the preset, not the options
        raise ScenarioError("sensor_options", f"bad sensor_options {sorted(options)} for rig "
                            f"{rig.name!r} ({exc})") from None


def _builds_without(method: Any, preset: str | None, dt_s: float,
                    options: dict[str, Any]) -> bool:
    """Whether the preset builds without ``options`` (then a failure was theirs)."""
    if not options:
        return False
    try:
        method(preset, dt_s=dt_s)
    except (TypeError, ValueError):
        return False
    return True


@contextlib.contextmanager
def blame(field: str) -> Iterator[None]:
    """Re-raise a ``ValueError`` of the block as :class:`ScenarioError` of ``field``."""
    try:
        yield
    except ScenarioError:
        raise
    except ValueError as exc:
        raise ScenarioError(field, str(exc)) from None


def _is_int(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def _number(field: str, value: Any, *, positive: bool = False) -> float:
    """A finite non-negative (or positive) real number, else :class:`ScenarioError`."""
    ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
    if ok:
        value = float(value)
    if not (ok and np.isfinite(value) and (value > 0 if positive else value >= 0)):
        raise ScenarioError(field, f"{field} must be a finite number "
                            f"{'> 0' if positive else '>= 0'}, got {value!r}")
    return value


@dataclass(frozen=True)
class Resolved:
    """A scenario resolved by :func:`resolve`: its defaults filled, every field checked, the
    rig and sensors built (the build takes them: resolve once, build once).

    Attributes
    ----------
    scenario : Scenario
        The scenario with the rig's and the estimator's defaults filled
        (:func:`with_defaults`): the one that was checked and that the build runs.
    rig_cls : type
        The rig class.
    rig : Rig
        The rig built for the scenario's ``profile`` and ``physics_dt_s`` at nominal
        parameters: it becomes the simulated rig (its MJCF is read once for it).
    sensors : Sensor
        The sensor suite built from the (defaulted) preset and its options, or the
        scenario's object.
    factory : callable
        The estimator factory.
    """

    scenario: Scenario
    rig_cls: type
    rig: Rig
    sensors: Any
    factory: Any


#: The MuJoCo step a scenario may ask for, s: below a microsecond a run of seconds is
#: billions of steps; above 0.1 s no rig's dynamics are resolved (the rigs' fastest time
#: constants are tens of milliseconds).
MIN_PHYSICS_DT_S, MAX_PHYSICS_DT_S = 1e-6, 0.1
#: Largest process-noise scale (the rigs' intensities are already physical at 1).
MAX_PROCESS_NOISE = 1e6
#: Scenario fields left out of :meth:`Scenario.describe` while empty (added after suite v2).
OMITTED_AT_DEFAULT = ("rig_options", "nominal_params")


@dataclass
class Scenario:
    """Everything one closed-loop experiment needs, as plain data.

    Attributes
    ----------
    rig : str or Rig subclass
        Registered name (``"helicopter"``, ``"vehicle-roll"``), ``module:Class`` or a class.
    profile : str
        Simulation profile of the rig: ``"paper"`` (the papers' idealizations) or
        ``"hardware"`` (actuator and sensor effects of the real rig).
    design_profile : str
        ``"matched"`` (default): the estimator designs from the model of the rig as the
        profile declares it (``hardware``: actuator, sensor-bias and delay states, see the
        rig's docs); ``"paper"``: from the papers' model whatever the profile (a deliberate
        model-mismatch study; the behaviour before matched designs). Equal for ``paper``.
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
    rig_options : dict
        The rig's construction options (``Rig.rig_options``, e.g. the Aero's
        ``yaw_locked``), for the simulated rig and the designer's alike.
    nominal_params : dict
        Values (not scales) of the rig's parameters that replace its nominal ones for the
        simulated rig and the designer alike: a twin of a real unit
        (:func:`testbed.identify.twin.read_twin`). ``params`` scales the simulated rig on top.
    duration_s : float
    seed : int
    physics_dt_s : float
    frame_skip : int
    """

    rig: Any = "helicopter"
    profile: str = "paper"
    design_profile: str = "matched"
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
    rig_options: dict[str, Any] = field(default_factory=dict)
    nominal_params: dict[str, float] = field(default_factory=dict)
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

    def check(self) -> Resolved:
        """Validate every field before anything is built or simulated: :func:`resolve`.

        Checks types and ranges, the options against the rig (parameters, sensor presets,
        disturbances, manoeuvres, design options, setpoints) and the estimator (its name
        and, when its factory declares them, its option names), after the rig's and the
        estimator's defaults are filled. The values of estimator and design options are
        checked when :func:`testbed.experiment.runner.build` builds them.

        Returns
        -------
        Resolved
            The defaulted scenario, the rig class, the rig and the sensor suite built for the
            check, and the estimator factory. Each call resolves anew (the scenario is not
            changed and keeps nothing).

        Raises
        ------
        ScenarioError
            A bad value or an option the rig does not have; ``field`` names the field.
        """
        return resolve(self)

    def _check_fields(self, rig_cls: type) -> Resolved:
        """:func:`resolve`'s checks of a scenario whose defaults are filled."""
        from testbed import estimators
        from testbed.experiment.control import CONTROLLERS
        from testbed.rigs.disturbances import Disturbance

        if self.profile not in rig_cls.profiles:
            raise ScenarioError("profile", f"profile must be one of {rig_cls.profiles} for rig "
                                f"{rig_cls.name!r}, got {self.profile!r}")
        from testbed.design import DESIGN_PROFILES

        if self.design_profile not in DESIGN_PROFILES:
            raise ScenarioError("design_profile", f"design_profile must be one of "
                                f"{DESIGN_PROFILES}, got {self.design_profile!r}")
        _number("ambient_noise", self.ambient_noise)
        _number("reset_noise_scale", self.reset_noise_scale)
        dt_s = _number("physics_dt_s", self.physics_dt_s, positive=True)
        if not MIN_PHYSICS_DT_S <= dt_s <= MAX_PHYSICS_DT_S:
            raise ScenarioError("physics_dt_s", f"physics_dt_s must be between "
                                f"{MIN_PHYSICS_DT_S:g} and {MAX_PHYSICS_DT_S:g} s, got {dt_s:g}")
        if not _is_int(self.frame_skip) or self.frame_skip < 1:
            raise ScenarioError("frame_skip", f"frame_skip must be a positive integer, got "
                                f"{self.frame_skip!r}")
        control_dt_s = dt_s * int(self.frame_skip)
        duration = _number("duration_s", self.duration_s, positive=True)
        if round(duration / control_dt_s) < 1:
            raise ScenarioError("duration_s", f"duration_s must cover at least one control "
                                f"period ({control_dt_s:g} s), got {duration:g} s")
        if not _is_int(self.seed) or not 0 <= self.seed <= MAX_SEED:
            raise ScenarioError("seed", f"seed must be an integer in [0, 2**63), got "
                                f"{self.seed!r}")
        if self.controller is not None and self.controller not in CONTROLLERS:
            raise ScenarioError("controller", f"unknown controller {self.controller!r}; "
                                f"expected one of {CONTROLLERS}")
        with blame("estimator"):
            factory = estimators.resolve(self.estimator)
        with blame("estimator_options"):
            estimators.check_options(factory, self.estimator, self.estimator_options)
        try:
            rig_options = rig_cls.resolve_options(self.rig_options)
        except ValueError as exc:
            raise ScenarioError("rig_options", str(exc)) from None
        nominal = _nominal_params(rig_cls, self.nominal_params)
        try:
            nominal.scaled(self.params)
        except ValueError as exc:
            message = str(exc)
            if isinstance(self.params, dict) and self.params:  # what the user typed first
                given = ", ".join(f"{k}={v!r}" for k, v in self.params.items())
                message = f"{given}: {message}"
            raise ScenarioError("params", message) from None
        unknown = set(self.design_options) - set(rig_cls.scenario_options)
        if unknown:
            raise ScenarioError("design_options", f"design option(s) {sorted(unknown)} do not "
                                f"apply to rig {rig_cls.name!r}; its options: "
                                f"{sorted(rig_cls.scenario_options) or 'none'}")
        for key, value in self.design_options.items():  # of the declared default's type
            default = rig_cls.scenario_options[key]
            number = isinstance(default, int | float) and not isinstance(default, bool)
            if number and (isinstance(value, bool) or not isinstance(value, int | float)):
                raise ScenarioError("design_options", f"design option {key} must be a number, "
                                    f"got {value!r}")
            if isinstance(default, str) and not isinstance(value, str):
                raise ScenarioError("design_options", f"design option {key} must be a word "
                                    f"(default {default!r}), got {value!r}")
        noise = _number("process_noise", self.process_noise)
        if noise > MAX_PROCESS_NOISE:
            raise ScenarioError("process_noise", f"process_noise must be at most "
                                f"{MAX_PROCESS_NOISE:g} (a scale of the rig's process noise), "
                                f"got {noise:g}")
        if noise > 0 and rig_cls.process_noise_matrix is Rig.process_noise_matrix:
            raise ScenarioError("process_noise", f"rig {rig_cls.name!r} has no process-noise "
                                "model; process_noise must be 0")
        if not (self.disturbance in (None, "none") or isinstance(self.disturbance, Disturbance)
                or self.disturbance in rig_cls.disturbance_signals):
            raise ScenarioError("disturbance", f"unknown disturbance {self.disturbance!r} for "
                                f"rig {rig_cls.name!r}; expected one of "
                                f"{sorted(rig_cls.disturbance_signals) or ['none']}")
        rig = _build_rig(rig_cls, self.rig, dt_s, self.profile, rig_options, nominal)
        sensors = self.sensors
        if self.sensors is None or isinstance(self.sensors, str):
            with blame("sensors"):
                sensors = _build_sensors(rig, self.sensors, control_dt_s, self.sensor_options)
        elif self.sensor_options:
            raise ScenarioError("sensor_options", "sensor_options apply to a sensor preset "
                                "name, not to a sensor object")
        self._check_manoeuvre(rig)
        if self.setpoints is not None:
            if not rig.tracked_states:
                raise ScenarioError("setpoints", f"setpoints do not apply to rig {rig.name!r} "
                                    "(no tracked states)")
            with blame("setpoints"):
                rig.validate_setpoints(self.setpoints)
        return Resolved(scenario=self, rig_cls=rig_cls, rig=rig, sensors=sensors,
                        factory=factory)

    def _check_manoeuvre(self, rig: Rig) -> None:
        """The manoeuvre (or the rig's default) and its parameters."""
        name = self.manoeuvre if self.manoeuvre is not None else \
            rig.scenario_defaults.get("manoeuvre")
        if name is None or name == "none":
            if self.manoeuvre_params:
                raise ScenarioError("manoeuvre_params", "manoeuvre_params given without a "
                                    "manoeuvre")
            return
        if not isinstance(name, str):
            if not callable(name):
                raise ScenarioError("manoeuvre", f"manoeuvre must be a name, 'none' or a "
                                    f"callable t_s -> input, got {name!r}")
            return
        if name not in rig.manoeuvres:
            raise ScenarioError("manoeuvre", f"unknown manoeuvre {name!r} for rig "
                                f"{rig.name!r}; expected one of {sorted(rig.manoeuvres) or 'none'}")
        try:
            rig.manoeuvres[name](**self.manoeuvre_params)
        except (TypeError, ValueError) as err:
            raise ScenarioError("manoeuvre_params", f"bad manoeuvre_params for {name!r}: "
                                f"{err}") from None

    def describe(self) -> dict[str, Any]:
        """JSON-ready description (callables and objects by name); the fields of
        :data:`OMITTED_AT_DEFAULT` only when set (so that earlier descriptions, e.g. a score
        suite's hash, stay as they were)."""
        out = {}
        for f, value in field_items(self):
            if f.name in OMITTED_AT_DEFAULT and not value:
                continue
            if isinstance(value, type):
                value = value.name if isinstance(value, Named) else value.__name__
            elif callable(value) and not isinstance(value, str):
                value = factory_name(value)
            elif hasattr(value, "describe") and not isinstance(value, dict | str):
                value = value.describe()
            out[f.name] = value
        return out


#: The scenario fields that hold option tables (checked to be dicts before defaults fill them).
OPTION_FIELDS = ("estimator_options", "sensor_options", "manoeuvre_params", "params",
                 "design_options", "rig_options", "nominal_params")


def resolve(scenario: Scenario) -> Resolved:
    """The scenario's defaults filled, then every field checked, the rig and sensors built.

    A pure function of ``scenario`` (which it does not change): the rig class is resolved and
    the option fields checked to be tables first (filling the defaults needs both), then
    :func:`with_defaults` fills what the user left unset and the result is checked as a whole
    (:meth:`Scenario.check` documents the checks).

    Parameters
    ----------
    scenario : Scenario

    Returns
    -------
    Resolved

    Raises
    ------
    ScenarioError
        A bad value or an option the rig does not have; ``field`` names the field.
    """
    with blame("rig"):
        rig_cls = resolve_rig(scenario.rig)
    for name in OPTION_FIELDS:
        value = getattr(scenario, name)
        if not isinstance(value, dict):
            raise ScenarioError(name, f"{name} must be a dict, got {type(value).__name__}")
    return with_defaults(scenario, rig_cls)._check_fields(rig_cls)


def with_defaults(scenario: Scenario, rig_cls: type | None = None) -> Scenario:
    """Fill the fields the user left unset from the rig's and the estimator's defaults.

    Parameters
    ----------
    scenario : Scenario
    rig_cls : type, optional
        The scenario's rig class (resolved from ``scenario.rig`` when not given).

    Returns
    -------
    Scenario
        A copy with the defaults filled (``scenario`` itself when there is nothing to fill).
    """
    from testbed import estimators

    rig = rig_cls if rig_cls is not None else resolve_rig(scenario.rig)
    changes: dict[str, Any] = {}
    for key, value in rig.scenario_defaults.items():
        if getattr(scenario, key) is None:
            changes[key] = value
    spec = estimators.family(scenario.estimator)
    needs = dict(spec.scenario_defaults) if spec is not None else {}
    if needs.get("disturbance") not in rig.disturbance_signals:
        needs = {}  # the rig lacks what the estimator needs: its factory says so
    for key, value in needs.items():
        if key == "disturbance_channel":
            if scenario.sensors is None or isinstance(scenario.sensors, str):
                changes["sensor_options"] = {**scenario.sensor_options, key: value}
        elif getattr(scenario, key) is None:
            changes[key] = value
    return scenario.replace(**changes) if changes else scenario
