"""Rerun entity-path parts from free-form names (states, channels, bodies, geoms)."""

from __future__ import annotations

import re
from collections.abc import Sequence


def entity_part(name: str) -> str:
    """Make ``name`` a plain entity-path part.

    A trailing unit in brackets is dropped (``"pitch_voltage [V]"`` -> ``"pitch_voltage"``)
    and every character other than letters, digits, ``_``, ``-`` and ``.`` becomes ``_``
    (Rerun would otherwise escape them, e.g. ``[`` -> ``\\[``).
    """
    stripped = re.sub(r"\s*[\[(][^\])]*[\])]\s*$", "", str(name).strip())
    part = re.sub(r"[^\w.\-]+", "_", stripped).strip("_")
    return part or "unnamed"


def entity_parts(names: Sequence[str]) -> list[str]:
    """:func:`entity_part` of each name, made unique with ``_2``, ``_3``... suffixes."""
    out: list[str] = []
    for name in names:
        part, base, n = entity_part(name), entity_part(name), 1
        while part in out:
            n += 1
            part = f"{base}_{n}"
        out.append(part)
    return out
