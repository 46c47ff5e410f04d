"""Pieces every testbed environment shares."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


def reset_options(options: dict[str, Any] | None, allowed: Iterable[str]) -> dict[str, Any]:
    """A copy of ``options`` after checking its keys.

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
        An unknown key, naming it and listing the allowed ones.
    """
    options = dict(options or {})
    allowed = tuple(allowed)
    unknown = set(options) - set(allowed)
    if unknown:
        raise ValueError(f"unknown reset options {sorted(unknown)}; expected keys among "
                         f"{allowed}")
    return options
