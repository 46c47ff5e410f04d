"""Shared helper of the rigs' parameter dataclasses: scaling for model-mismatch studies."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import numpy as np

from filters import real_array

P = TypeVar("P")


def scaled_copy(params: P, scales: dict[str, Any]) -> P:
    """Copy of a parameter dataclass with fields multiplied by factors, then validated.

    Parameters
    ----------
    params : dataclass instance with a ``validate()`` method
    scales : dict
        ``{field_name: factor}``; factors must be finite and non-negative (0 only where the
        parameter may vanish: ``validate()`` decides).

    Raises
    ------
    ValueError
        Unknown field name (the valid ones are listed), a factor that is not a finite
        non-negative number, or an unphysical result (named by ``validate()``).
    """
    if not isinstance(scales, dict):
        raise ValueError(f"params must be a dict {{field: scale factor}}, got "
                         f"{type(scales).__name__}")
    names = {f.name for f in dataclasses.fields(params)}
    changes = {}
    for key, factor in scales.items():
        if key not in names:
            raise ValueError(f"unknown params key {key!r}; expected one of {sorted(names)}")
        factor = float(real_array(factor, f"params[{key!r}] (scale factor)", shape=(),
                                  finite=False))
        if not np.isfinite(factor) or factor < 0.0:
            raise ValueError(f"params[{key!r}] must be a finite non-negative scale factor, "
                             f"got {factor}")
        value = getattr(params, key) * factor
        if not np.isfinite(value):
            raise ValueError(f"params[{key!r}] = {factor!r} scales {key} out of range "
                             f"({getattr(params, key)!r} x {factor!r} is not finite)")
        changes[key] = value
    out = dataclasses.replace(params, **changes)
    with np.errstate(over="raise", invalid="raise"):
        try:
            out.validate()
        except (OverflowError, FloatingPointError) as exc:
            given = ", ".join(f"{k}={v!r}" for k, v in scales.items())
            raise ValueError(f"params {given}: the scaled parameters are out of range "
                             f"({exc})") from None
    return out
