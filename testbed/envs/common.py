"""Pieces every testbed environment shares: checks of ``reset``/``step`` arguments.

Every check raises ``ValueError`` naming the argument before the environment changes (its
state, time and random generator stay as they were).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from filters import real_array


def check_seed(seed: Any) -> None:
    """``seed`` must be None or a non-negative integer (not a bool or a float)."""
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer)
                             or seed < 0):
        raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")


def reset_options(options: dict[str, Any] | None, allowed: Iterable[str]) -> dict[str, Any]:
    """A copy of ``options`` after checking its type and keys.

    Parameters
    ----------
    options : dict or None
        ``reset(options=...)`` as given by the caller.
    allowed : iterable of str
        The keys the environment understands.

    Returns
    -------
    dict
        A new dict (empty for None).

    Raises
    ------
    ValueError
        ``options`` is not a dict, or has an unknown key (named, the allowed ones listed).
    """
    if options is not None and not isinstance(options, dict):
        raise ValueError(f"options must be a dict or None, got {type(options).__name__}")
    options = dict(options or {})
    allowed = tuple(allowed)
    unknown = set(options) - set(allowed)
    if unknown:
        raise ValueError(f"unknown reset options {sorted(unknown, key=str)}; expected keys "
                         f"among {allowed}")
    return options


def initial_state(value: Any, n: int, bound: float = np.inf,
                  names: Iterable[str] | None = None) -> np.ndarray:
    """``options['x0']`` as a finite array of shape (n,) with ``|x0_i| <= bound``.

    Parameters
    ----------
    value : array_like
    n : int
    bound : float
        Largest admissible magnitude (the environment's escape bound).
    names : iterable of str, optional
        State names for the message.
    """
    label = "options['x0']" + (f" {list(names)}" if names is not None else "")
    x0 = real_array(value, label, shape=(n,))
    if np.any(np.abs(x0) > bound):
        raise ValueError(f"{label} must lie within the escape bound |x0_i| <= {bound:g}, got "
                         f"{x0}")
    return x0


def action_array(action: Any, k: int) -> np.ndarray:
    """``action`` as a finite real array of shape (k,)."""
    return real_array(action, "action", shape=(k,))


def with_twin(rig: Any, kwargs: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
    """The rig and :func:`~testbed.sim.build_simulator` keywords of an environment made with
    ``twin=FILE`` (``gym.make("testbed/Aero2DOF-v0", twin="twin.toml")``): the twin's rig
    (it must be the environment's), profile (unless ``profile`` is given), options (under
    those given) and identified parameters as the nominal ones.

    Parameters
    ----------
    rig : str, Rig subclass or Rig
        The environment's rig.
    kwargs : dict
        The environment's other keywords; ``twin`` is taken out.

    Returns
    -------
    rig, kwargs
    """
    kwargs = dict(kwargs)
    path = kwargs.pop("twin", None)
    if path is None:
        return rig, kwargs
    from testbed.identify.twin import read_twin
    from testbed.rigs import resolve_rig

    twin = read_twin(path)
    name = rig.name if not isinstance(rig, str) else resolve_rig(rig).name
    if name != twin.rig:
        raise ValueError(f"twin: {path} is a twin of rig {twin.rig!r}, not {name!r}")
    kwargs.setdefault("profile", twin.profile)
    kwargs["rig_options"] = {**twin.options, **(kwargs.get("rig_options") or {})}
    kwargs["nominal_params"] = twin.params()
    return twin.rig, kwargs


class EnvSensors(Protocol):
    """The sensor contract the wrappers read (:class:`testbed.sensors.Sensor` and
    :class:`~testbed.envs.plant_env.PlantSensors` have it): channel names, the state each
    channel measures (None: none directly), and a short description."""

    names: Sequence[str]
    measured_state: Sequence[int | None]

    def describe(self) -> str: ...


class EnvRig(Protocol):
    """The rig contract the wrappers read (:class:`testbed.rigs.base.Rig` has it)."""

    name: str
    profile: str


@dataclass(frozen=True)
class EnvDeclarations:
    """What the testbed's wrappers read from the environment they wrap (its ``unwrapped``).

    A testbed environment (:class:`~testbed.envs.rig_env.RigEnv`,
    :class:`~testbed.envs.plant_env.PlantEnv`) declares them; any other Gymnasium
    environment may declare some or none: each is then None (or empty).

    Attributes
    ----------
    state_names, action_names : list of str or None
    sensors : EnvSensors or None
        The sensor suite (``names``, ``measured_state``, ``describe()``).
    dt_s : float or None
        Control period, s.
    rig : EnvRig or None
        The rig (``name``, ``profile``).
    sim : object or None
        The simulator (a :class:`~testbed.envs.rig_env.RigEnv`'s).
    measured : list of int or None
        The state each channel measures (empty without sensors).
    channel_names : tuple of str
    sensors_text : str
        ``sensors.describe()`` ("" without).
    rig_name, profile : str
        The rig's (or "").
    """

    state_names: Any
    action_names: Any
    sensors: Any
    dt_s: Any
    rig: Any
    sim: Any
    measured: list[int | None]
    channel_names: tuple[str, ...]
    sensors_text: str
    rig_name: str
    profile: str


def env_declarations(inner: Any) -> EnvDeclarations:
    """The declarations of an environment (:class:`EnvDeclarations`): the one place the
    wrappers probe the environment they wrap, which may be any Gymnasium environment. What
    it declares follows the contracts: its ``sensors`` an :class:`EnvSensors`, its ``rig``
    an :class:`EnvRig`."""
    found = {name: getattr(inner, name, None)
             for name in ("state_names", "action_names", "sensors", "dt_s", "rig", "sim")}
    sensors: EnvSensors | None = found["sensors"]
    rig: EnvRig | None = found["rig"]
    return EnvDeclarations(
        **found,
        measured=[] if sensors is None else list(sensors.measured_state),
        channel_names=() if sensors is None else tuple(sensors.names),
        sensors_text="" if sensors is None else sensors.describe(),
        rig_name="" if rig is None else rig.name, profile="" if rig is None else rig.profile)
