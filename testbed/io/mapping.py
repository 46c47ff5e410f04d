"""Mapping files: how a log's columns become a rig's inputs and sensor channels (in SI units).

A log from a real unit rarely uses the rig's names and units: a QUARC model writes encoder
counts under a block's name, a spreadsheet has degrees. A mapping file (TOML) says, for
each of the rig's names, where its values are and how to convert them::

    time = "t"                   # the time column (default "time_s")
    time_unit = "s"              # "s", "ms" or "us"
    start_s = 2.0                # segment kept: start_s <= t <= stop_s (file time, s)
    stop_s = 30.0
    ignore = ["temperature"]     # columns of the file to drop

    [columns.pitch]              # the rig's name (an input or a sensor channel)
    from = "pitch_enc"           # the file's column (default: the rig's name)
    unit = "counts"              # the file's unit (see UNITS); converted to SI
    counts_per_rev = 4096        # with "counts" or "counts/s"
    sign = -1                    # +1 or -1
    scale = 1.0                  # a factor after the unit conversion
    offset = -40.5               # added last ...
    offset_unit = "deg"          # ... in this unit (default: the SI unit)
    kind = "channel"             # "input" or "channel" (needed only without a rig)

    [columns.V_pitch]            # QUARC "To File" layout: one 2-D array per file
    file = "voltage.mat"         # the file (a name inside the directory read)
    variable = "voltage"         # its variable (default: the file's only array)
    row = 1                      # the array's row (row 0 is time)

The value in SI units is ``sign * scale * factor(unit) * raw + offset * factor(offset_unit)``
(for ``counts``, ``factor = 2 pi / counts_per_rev``). Columns of the file the mapping does
not name pass through unchanged (they must already be the rig's names in SI units) unless
listed in ``ignore``. The full schema is in ``docs/twin.md`` ("Recordings").
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import tomllib
from typing import Any

import numpy as np

from testbed.io.recording import RecordingError

#: Standard gravity for the unit ``g``, m/s^2 (the rigs' value).
_G_M_S2 = 9.81
#: Largest mapping file read, bytes.
MAX_MAPPING_BYTES = 1 << 20

#: Units a mapping may name: ``unit -> (SI unit, factor to it)``; ``None`` for the encoder
#: units, whose factor is ``2 pi / counts_per_rev``.
UNITS: dict[str, tuple[str, float | None]] = {
    "rad": ("rad", 1.0), "deg": ("rad", math.pi / 180.0), "rev": ("rad", 2.0 * math.pi),
    "counts": ("rad", None),
    "rad/s": ("rad/s", 1.0), "deg/s": ("rad/s", math.pi / 180.0),
    "rpm": ("rad/s", 2.0 * math.pi / 60.0), "counts/s": ("rad/s", None),
    "rad/s^2": ("rad/s^2", 1.0), "deg/s^2": ("rad/s^2", math.pi / 180.0),
    "V": ("V", 1.0), "mV": ("V", 1e-3), "A": ("A", 1.0), "mA": ("A", 1e-3),
    "m": ("m", 1.0), "cm": ("m", 1e-2), "mm": ("m", 1e-3),
    "m/s": ("m/s", 1.0), "km/h": ("m/s", 1.0 / 3.6),
    "m/s^2": ("m/s^2", 1.0), "g": ("m/s^2", _G_M_S2),
    "N": ("N", 1.0), "N m": ("N m", 1.0), "1": ("1", 1.0),
}
#: Units of the time column: ``unit -> factor to s``.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}

_TOP_KEYS = {"time", "time_unit", "start_s", "stop_s", "ignore", "columns"}
_COLUMN_KEYS = {"from", "file", "variable", "row", "unit", "counts_per_rev", "sign", "scale",
                "offset", "offset_unit", "kind"}


@dataclasses.dataclass(frozen=True)
class ColumnMap:
    """Where one of the rig's names is in a log and how it becomes SI units.

    Attributes
    ----------
    name : str
        The rig's name (an input such as ``V_pitch`` or a channel such as ``pitch``).
    source : str
        The file's column (CSV header, NPZ key, MAT variable); default ``name``.
    file : str
        QUARC layout: the file holding the row ("" otherwise).
    variable : str
        QUARC layout: the variable in that file ("": its only 2-D array).
    row : int or None
        QUARC layout: the row of the array (>= 1; row 0 is time). None: a named column.
    unit : str
        The file's unit (a key of :data:`UNITS`); "" for SI (no conversion).
    counts_per_rev : float or None
        Encoder counts per revolution (units ``counts`` and ``counts/s``).
    sign : int
        +1 or -1.
    scale : float
        Factor applied after the unit conversion.
    offset : float
        Added last, in ``offset_unit``.
    offset_unit : str
        Unit of ``offset`` ("": the SI unit).
    kind : str
        ``"input"``, ``"channel"`` or "" (decided by the rig).
    """

    name: str
    source: str = ""
    file: str = ""
    variable: str = ""
    row: int | None = None
    unit: str = ""
    counts_per_rev: float | None = None
    sign: int = 1
    scale: float = 1.0
    offset: float = 0.0
    offset_unit: str = ""
    kind: str = ""

    def si_unit(self) -> str:
        """The SI unit the values come out in ("" when the mapping names no unit)."""
        return UNITS[self.unit][0] if self.unit else ""

    def _factor(self, unit: str) -> float:
        if not unit:
            return 1.0
        factor = UNITS[unit][1]
        return 2.0 * math.pi / self.counts_per_rev if factor is None else factor

    def apply(self, raw: np.ndarray) -> np.ndarray:
        """The raw column in SI units, shape of ``raw`` (float64).

        ``sign * scale * factor(unit) * raw + offset * factor(offset_unit)``; the identity
        mapping returns the values unchanged (bitwise).
        """
        gain = self.sign * self.scale * self._factor(self.unit)
        shift = self.offset * self._factor(self.offset_unit)
        values = np.asarray(raw, dtype=np.float64)
        if gain != 1.0:
            values = values * gain
        return values + shift if shift != 0.0 else values


@dataclasses.dataclass(frozen=True)
class Mapping:
    """A parsed mapping file (see the module docstring for the schema).

    Attributes
    ----------
    columns : dict of str to ColumnMap
        By the rig's name, in the file's order.
    time : str
        The file's time column (CSV/NPZ/MAT by name; the QUARC layout uses row 0).
    time_unit : str
        A key of :data:`TIME_UNITS`.
    start_s, stop_s : float or None
        The segment kept (inclusive, in the file's time converted to s); None: unbounded.
    ignore : tuple of str
        The file's columns dropped.
    source : str
        Where it came from, for messages.
    sha256 : str
        sha256 (hex) of the file's bytes ("" when built from a dict).
    """

    columns: dict[str, ColumnMap] = dataclasses.field(default_factory=dict)
    time: str = "time_s"
    time_unit: str = "s"
    start_s: float | None = None
    stop_s: float | None = None
    ignore: tuple[str, ...] = ()
    source: str = "<mapping>"
    sha256: str = ""

    @property
    def quarc(self) -> bool:
        """Whether the mapping reads the QUARC layout (its columns name rows of files)."""
        return any(c.row is not None for c in self.columns.values())

    @property
    def time_factor_s(self) -> float:
        """Factor from the file's time unit to s."""
        return TIME_UNITS[self.time_unit]

    def by_source(self) -> dict[str, ColumnMap]:
        """The named-column entries by the file's column name."""
        return {c.source: c for c in self.columns.values() if c.row is None}

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "<mapping>",
                  sha256: str = "") -> Mapping:
        """A mapping from the TOML document's dict (checked).

        Raises
        ------
        RecordingError
            One line naming ``source``, the key and what was expected.
        """
        return _parse(data, source, sha256)


def load_mapping(path: str | os.PathLike) -> Mapping:
    """Read and check a mapping file (TOML).

    Parameters
    ----------
    path : str or PathLike
        A regular file of at most :data:`MAX_MAPPING_BYTES` bytes.

    Returns
    -------
    Mapping

    Raises
    ------
    RecordingError
        One line naming the file and the key (or the TOML syntax error's line).
    """
    from testbed.io.bounded import read_bounded

    name = os.fspath(path)
    data = read_bounded(path, MAX_MAPPING_BYTES, what="mapping", error=RecordingError)
    try:
        doc = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise RecordingError(f"{name}: not UTF-8 text (byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise RecordingError(f"{name}: not a TOML file ({exc})") from None
    return _parse(doc, name, hashlib.sha256(data).hexdigest())


def _number(value: Any, where: str, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or \
            not math.isfinite(value):
        raise RecordingError(f"{where}: {key} must be a finite number, got {value!r}")
    return float(value)


def _text(value: Any, where: str, key: str) -> str:
    if not isinstance(value, str) or not value.strip() or "\n" in value:
        raise RecordingError(f"{where}: {key} must be a non-empty one-line string, "
                             f"got {value!r}")
    return value.strip()


def _unit(value: Any, where: str, key: str) -> str:
    text = _text(value, where, key)
    if text not in UNITS:
        raise RecordingError(f"{where}: {key} {text!r} is not a known unit; expected one of "
                             f"{sorted(UNITS)}")
    return text


def _column(name: str, entry: Any, source: str) -> ColumnMap:
    where = f"{source}: [columns.{name}]"
    if not isinstance(entry, dict):
        raise RecordingError(f"{where} must be a table, got {entry!r}")
    unknown = sorted(set(entry) - _COLUMN_KEYS)
    if unknown:
        raise RecordingError(f"{where}: unknown key {unknown[0]!r}; expected one of "
                             f"{sorted(_COLUMN_KEYS)}")
    out: dict[str, Any] = {"name": name, "source": name}
    if "from" in entry:
        out["source"] = _text(entry["from"], where, "from")
    if "file" in entry:
        file = _text(entry["file"], where, "file")
        parts = file.replace("\\", "/").split("/")
        if os.path.isabs(file) or ".." in parts:
            raise RecordingError(f"{where}: file {file!r} must be a name inside the "
                                 "directory read (relative, without '..')")
        out["file"] = file
    if "variable" in entry:
        out["variable"] = _text(entry["variable"], where, "variable")
    if "row" in entry:
        row = entry["row"]
        if isinstance(row, bool) or not isinstance(row, int) or row < 1:
            raise RecordingError(f"{where}: row must be an integer >= 1 (row 0 is time), "
                                 f"got {row!r}")
        out["row"] = row
    elif "file" in entry or "variable" in entry:
        raise RecordingError(f"{where}: file and variable need a row (the QUARC layout)")
    if "from" in entry and "row" in entry:
        raise RecordingError(f"{where}: give either from (a named column) or row (QUARC)")
    if "unit" in entry:
        out["unit"] = _unit(entry["unit"], where, "unit")
    if "offset_unit" in entry:
        out["offset_unit"] = _unit(entry["offset_unit"], where, "offset_unit")
    encoder = UNITS.get(out.get("unit", ""), ("", 1.0))[1] is None or \
        UNITS.get(out.get("offset_unit", ""), ("", 1.0))[1] is None
    if "counts_per_rev" in entry:
        cpr = _number(entry["counts_per_rev"], where, "counts_per_rev")
        if cpr <= 0:
            raise RecordingError(f"{where}: counts_per_rev must be positive, got {cpr:g}")
        out["counts_per_rev"] = cpr
    elif encoder:
        raise RecordingError(f"{where}: unit 'counts' needs counts_per_rev")
    if "sign" in entry:
        if entry["sign"] not in (1, -1) or isinstance(entry["sign"], bool):
            raise RecordingError(f"{where}: sign must be 1 or -1, got {entry['sign']!r}")
        out["sign"] = int(entry["sign"])
    if "scale" in entry:
        out["scale"] = _number(entry["scale"], where, "scale")
        if out["scale"] == 0:
            raise RecordingError(f"{where}: scale must not be 0")
    if "offset" in entry:
        out["offset"] = _number(entry["offset"], where, "offset")
    if "kind" in entry:
        if entry["kind"] not in ("input", "channel"):
            raise RecordingError(f"{where}: kind must be 'input' or 'channel', got "
                                 f"{entry['kind']!r}")
        out["kind"] = entry["kind"]
    si = UNITS[out["unit"]][0] if out.get("unit") else ""
    if out.get("offset_unit") and si and UNITS[out["offset_unit"]][0] != si:
        raise RecordingError(f"{where}: offset_unit {out['offset_unit']!r} is not a unit of "
                             f"{si} like unit {out['unit']!r}")
    return ColumnMap(**out)


def _parse(doc: dict[str, Any], source: str, sha256: str) -> Mapping:
    if not isinstance(doc, dict):
        raise RecordingError(f"{source}: a mapping must be a table, got {type(doc).__name__}")
    unknown = sorted(set(doc) - _TOP_KEYS)
    if unknown:
        raise RecordingError(f"{source}: unknown key {unknown[0]!r}; expected one of "
                             f"{sorted(_TOP_KEYS)}")
    out: dict[str, Any] = {"source": source, "sha256": sha256}
    if "time" in doc:
        out["time"] = _text(doc["time"], source, "time")
    if "time_unit" in doc:
        if doc["time_unit"] not in TIME_UNITS:
            raise RecordingError(f"{source}: time_unit must be one of {sorted(TIME_UNITS)}, "
                                 f"got {doc['time_unit']!r}")
        out["time_unit"] = doc["time_unit"]
    for key in ("start_s", "stop_s"):
        if key in doc:
            out[key] = _number(doc[key], source, key)
    if out.get("start_s") is not None and out.get("stop_s") is not None and \
            not out["start_s"] < out["stop_s"]:
        raise RecordingError(f"{source}: start_s ({out['start_s']:g}) must be before stop_s "
                             f"({out['stop_s']:g})")
    if "ignore" in doc:
        ignore = doc["ignore"]
        if not isinstance(ignore, list):
            raise RecordingError(f"{source}: ignore must be a list of column names, got "
                                 f"{ignore!r}")
        out["ignore"] = tuple(_text(v, source, "ignore") for v in ignore)
    tables = doc.get("columns", {})
    if not isinstance(tables, dict):
        raise RecordingError(f"{source}: columns must be a table of tables ([columns.NAME])")
    columns = {str(name): _column(str(name), entry, source) for name, entry in tables.items()}
    seen: dict[tuple[str, str, int | None], str] = {}
    for col in columns.values():
        key = (col.file, col.variable, col.row) if col.row is not None else ("", col.source, None)
        if key in seen:
            raise RecordingError(f"{source}: [columns.{col.name}] reads the same data as "
                                 f"[columns.{seen[key]}]")
        seen[key] = col.name
        if col.row is None and col.source == out.get("time", "time_s"):
            raise RecordingError(f"{source}: [columns.{col.name}] reads the time column "
                                 f"{col.source!r}")
    rows = [c.row is not None for c in columns.values()]
    if any(rows) and not all(rows):
        named = next(c.name for c in columns.values() if c.row is None)
        raise RecordingError(f"{source}: [columns.{named}] names a column but others name "
                             "rows (QUARC layout): use one layout per mapping")
    out["columns"] = columns
    return Mapping(**out)
