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
