"""Experiments as files: a :class:`~testbed.experiment.scenario.Scenario` in TOML or JSON.

A scenario file holds :class:`Scenario` fields as top-level keys (``rig``, ``estimator``,
``duration_s``, ``estimator_options = {gamma = 2.0}``...; a key left out keeps the field's
default) and, optionally, a ``[study]`` table for ``mc`` and ``sweep`` (``runs``, and
``grid = {process_noise = [0, 0.2]}`` for ``sweep``; ``run`` ignores it)::

    rig = "helicopter"
    estimator = "kalman"
    duration_s = 20.0
    seed = 0

    [study]
    runs = 100

``testbed run|mc|sweep --scenario FILE`` reads it; options given beside it override its
fields (a ``--filter-option``, ``--param``, ``--design-option``... adds to or replaces one
key of the file's table); ``--save-scenario FILE`` writes the effective scenario
(:func:`write`) without running. Every JSON output of ``run``, ``mc`` and ``sweep`` carries
the scenario it ran under the key ``scenario`` (:func:`block`); a file holding that block,
as TOML or as JSON, reproduces the numbers bitwise.

Errors (:class:`ScenarioFileError`, a ``ValueError``) are one line naming the file and the
key: unknown keys, wrong types, and (through :meth:`Scenario.check`) values or options that
do not apply to the rig.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from testbed.experiment.scenario import Scenario
from testbed.io.bounded import read_bounded

#: File suffixes read and written.
SUFFIXES = (".toml", ".json")
#: Largest scenario file read, in bytes (1 MiB; a scenario is a few hundred bytes).
MAX_FILE_BYTES = 1 << 20
#: Deepest nesting of arrays and tables in a scenario file (a grid is 3 levels deep).
MAX_NESTING = 32
#: Keys of the optional ``[study]`` table and their types.
STUDY_KEYS = {"runs": "a positive integer", "grid": "a table NAME = [V1, V2, ...]"}
#: Scenario fields whose value in a file is a name (the Python API also takes objects).
_NAME_FIELDS = ("rig", "estimator", "profile", "controller", "sensors", "disturbance",
                "manoeuvre")


class ScenarioFileError(ValueError):
    """A scenario file is unreadable, has an unknown key or a value of the wrong type.

    The message is one line: ``FILE: KEY: what is wrong``.
    """


@dataclass
class ScenarioFile:
    """A read scenario file.

    Attributes
    ----------
    path : str
    fields : dict
        The :class:`Scenario` fields it sets (the others keep their defaults).
    study : dict
        Its ``[study]`` table (``runs``, ``grid``), possibly empty.
    """

    path: str
    fields: dict[str, Any] = field(default_factory=dict)
    study: dict[str, Any] = field(default_factory=dict)

    def error(self, key: str, message: str) -> ScenarioFileError:
        """A one-line error naming this file and ``key``."""
        return ScenarioFileError(f"{self.path}: {key}: {message}".replace("\n", " "))


def _fields() -> dict[str, dataclasses.Field]:
    return {f.name: f for f in dataclasses.fields(Scenario)}


def _kind(f: dataclasses.Field) -> str:
    """What a file may hold for field ``f``: table, number, integer, name, rows or any."""
    if f.name == "setpoints":
        return "rows"
    if f.name in _NAME_FIELDS:
        return "name"
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        default = f.default_factory()  # type: ignore[misc]
    else:
        default = f.default
    if isinstance(default, dict):
        return "table"
    if isinstance(default, bool):
        return "boolean"
    if isinstance(default, int):
        return "integer"
    if isinstance(default, float):
        return "number"
    if isinstance(default, str) or "str" in str(f.type):
        return "name"
    return "any"


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and \
        math.isfinite(value)


def _is_scalar(value: Any) -> bool:
    return isinstance(value, str | bool) or _is_number(value)


_EXPECTED = {"table": "a table of NAME = value", "number": "a finite number",
             "integer": "an integer", "boolean": "true or false", "name": "a string",
             "rows": "a list of rows of numbers [t_s, ...]"}


def _checked(source: ScenarioFile, key: str, kind: str, value: Any) -> Any:
    """``value`` of field ``key`` converted to the field's type, else the one-line error."""
    if value is None and kind in ("name", "rows", "any"):
        return None  # JSON null: the field's default (None)
    ok = {"table": lambda v: isinstance(v, dict) and all(
              isinstance(k, str) and (_is_scalar(x) or isinstance(x, list)) for k, x in v.items()),
          "number": _is_number,
          "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
          "boolean": lambda v: isinstance(v, bool),
          "name": lambda v: isinstance(v, str),
          "rows": lambda v: isinstance(v, list) and all(
              isinstance(r, list) and r and all(_is_number(x) for x in r) for r in v),
          "any": lambda v: True}[kind]
    if not ok(value):
        raise source.error(key, f"expected {_EXPECTED[kind]}, got {_describe(value)}")
    if kind == "number":
        return float(value)
    if kind == "table":
        return dict(value)
    return value


def _describe(value: Any) -> str:
    text = json.dumps(value) if isinstance(value, list | dict | str | bool) else repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{type(value).__name__} {text}"


def _study(source: ScenarioFile, table: Any) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise source.error("study", f"expected a table with keys {sorted(STUDY_KEYS)}, got "
                           f"{_describe(table)}")
    unknown = sorted(set(table) - set(STUDY_KEYS))
    if unknown:
        raise source.error(f"study.{unknown[0]}", f"unknown key; expected one of "
                           f"{sorted(STUDY_KEYS)}")
    out: dict[str, Any] = {}
    if "runs" in table:
        runs = table["runs"]
        if not (isinstance(runs, int) and not isinstance(runs, bool) and runs >= 1):
            raise source.error("study.runs", f"expected {STUDY_KEYS['runs']}, got "
                               f"{_describe(runs)}")
        out["runs"] = runs
    if "grid" in table:
        grid = table["grid"]
        if not (isinstance(grid, dict) and grid and all(
                isinstance(v, list) and v and all(_is_number(x) for x in v)
                for v in grid.values())):
            raise source.error("study.grid", f"expected {STUDY_KEYS['grid']} (finite "
                               f"numbers), got {_describe(grid)}")
        out["grid"] = [(str(name), [float(x) for x in values]) for name, values in grid.items()]
    return out


def read(path: str | os.PathLike) -> ScenarioFile:
    """Read and type-check a scenario file (TOML, or JSON by its ``.json`` suffix).

    Raises
    ------
    ScenarioFileError
        The file is missing or not valid TOML/JSON, a key is unknown or a value has the wrong
        type; one line naming the file and the key. Values are checked against the rig
        later, by :meth:`Scenario.check` (:func:`scenario_error` names the file then).
    """
    text_path = os.fspath(path)
    source = ScenarioFile(text_path)
    suffix = Path(text_path).suffix.lower()
    raw = read_bounded(text_path, MAX_FILE_BYTES, what="scenario file",
                       error=ScenarioFileError)
    kind = "JSON" if suffix == ".json" else "TOML"
    try:
        if suffix == ".json":
            data = json.loads(raw.decode("utf-8"))
        else:
            data = tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ScenarioFileError(f"{text_path}: not valid {kind}: {exc}".replace("\n", " ")
                                ) from None
    except RecursionError:  # deeper than the parser can go
        data = None
    if data is None or _depth(data, MAX_NESTING) > MAX_NESTING:
        raise ScenarioFileError(f"{text_path}: not a scenario file: {kind} arrays or tables "
                                f"nested more than {MAX_NESTING} deep")
    if not isinstance(data, dict):
        raise ScenarioFileError(f"{text_path}: expected a table of scenario fields, got "
                                f"{_describe(data)}")
    fields = _fields()
    for key, value in data.items():
        if key == "study":
            source.study = _study(source, value)
        elif key not in fields:
            raise source.error(key, f"unknown key; expected scenario fields "
                               f"({', '.join(fields)}) or a [study] table")
        else:
            source.fields[key] = _checked(source, key, _kind(fields[key]), value)
    return source


def _depth(value: Any, limit: int) -> int:
    """Nesting depth of lists and dicts in ``value`` (a scalar: 0), counted up to
    ``limit + 1`` (deeper is not explored)."""
    if not isinstance(value, list | dict) or limit < 0:
        return 0
    children = value.values() if isinstance(value, dict) else value
    return 1 + max((_depth(child, limit - 1) for child in children), default=0)


def merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """The file's fields ``base`` with the command line's ``overrides``: a table field
    (``estimator_options``, ``params``...) is merged key by key, any other field replaced."""
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
        else:
            out[key] = value
    return out


def scenario_error(source: ScenarioFile | None, overridden: set[str], field_name: str,
                   message: str, flag: str) -> str:
    """The message of a :class:`ScenarioError` of ``field_name``: naming the file and the key
    when the value came from the file, else the command-line ``flag``."""
    if source is not None and field_name in source.fields and field_name not in overridden:
        return f"{source.path}: {field_name}: {message}"
    return f"{flag}: {message}"


# ------------------------------------------------------------------------------- writing
def _plain(value: Any) -> Any:
    """JSON/TOML-ready: numpy scalars and arrays to Python, tuples to lists, None dropped
    from tables."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items() if v is not None}
    if isinstance(value, list | tuple | np.ndarray):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def block(scenario: Scenario) -> dict[str, Any]:
    """The scenario block of the JSON outputs: every field, the rig's and the estimator's
    defaults filled in (what ran), JSON-ready; :func:`read` accepts it unchanged."""
    from testbed.experiment.build import described
    from testbed.experiment.scenario import with_defaults

    return {k: (_plain(v) if isinstance(v, dict | list | tuple | np.ndarray | np.generic) else v)
            for k, v in described(with_defaults(scenario)).items()}


def check_destination(path: str | os.PathLike, name: str = "--save-scenario") -> Path:
    """Check a scenario file destination (``.toml`` or ``.json``) before anything runs."""
    from testbed.io import check_output_path

    suffix = Path(os.fspath(path)).suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"{name} must end in .toml or .json, got {os.fspath(path)!r}")
    return check_output_path(path, name, suffix)


def write(path: str | os.PathLike, scenario_block: dict[str, Any],
          study: dict[str, Any] | None = None) -> Path:
    """Write a scenario file (TOML or JSON by the suffix), atomically.

    Parameters
    ----------
    path : str or PathLike
        ``.toml`` or ``.json``.
    scenario_block : dict
        Scenario fields (:func:`block`); None values and empty tables are left out (TOML
        has no null: a missing key is the field's default).
    study : dict, optional
        ``runs`` and ``grid`` (``{name: [values]}`` or a list of ``(name, values)``).
    """
    from testbed.io import atomic_path

    data = {k: _plain(v) for k, v in scenario_block.items()
            if v is not None and not (isinstance(v, dict) and not v)}  # {}: the default
    if study:
        table = {}
        if study.get("runs") is not None:
            table["runs"] = int(study["runs"])
        if study.get("grid"):
            grid = study["grid"]
            items = grid.items() if isinstance(grid, dict) else grid
            table["grid"] = {str(k): [float(x) for x in v] for k, v in items}
        if table:
            data["study"] = table
    if Path(os.fspath(path)).suffix.lower() == ".json":
        payload = json.dumps(data, indent=2, allow_nan=False) + "\n"
    else:
        import tomli_w

        payload = tomli_w.dumps(data)
    with atomic_path(path) as tmp:
        tmp.write_text(payload)
    return Path(path)
