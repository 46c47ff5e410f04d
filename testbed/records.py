"""Reading a dataclass record by field: the one place the testbed reads a record's fields by
name (validation loops over the fields, subsets named in a tuple, fields named by a user).

A field always exists on its record: these reads are not probes of optional attributes.
"""

from __future__ import annotations

import dataclasses
from typing import Any

__all__ = ["field_items", "field_values"]


def field_items(record: Any) -> list[tuple[dataclasses.Field, Any]]:
    """``(field, value)`` of every field of the dataclass instance ``record``, in
    declaration order."""
    return [(f, getattr(record, f.name)) for f in dataclasses.fields(record)]


def field_values(record: Any) -> dict[str, Any]:
    """``{name: value}`` of every field of the dataclass instance ``record``, in declaration
    order (the values themselves, not copies)."""
    return {f.name: value for f, value in field_items(record)}
