"""Pieces every testbed environment shares: checks of ``reset``/``step`` arguments.

Every check raises ``ValueError`` naming the argument before the environment changes (its
state, time and random generator stay as they were).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

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
    name = getattr(rig, "name", None) if not isinstance(rig, str) else resolve_rig(rig).name
    if name != twin.rig:
        raise ValueError(f"twin: {path} is a twin of rig {twin.rig!r}, not {name!r}")
    kwargs.setdefault("profile", twin.profile)
    kwargs["rig_options"] = {**twin.options, **(kwargs.get("rig_options") or {})}
    kwargs["nominal_params"] = twin.params()
    return twin.rig, kwargs
