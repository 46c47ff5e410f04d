"""Recordings in files: CSV, NPZ, MATLAB v5 ``.mat`` and the QUARC "To File" layout.

:func:`read_recording` reads a log of a real (or simulated) unit into a
:class:`~testbed.io.recording.Recording`, checked before anything runs; a bad file is one
:class:`~testbed.io.recording.RecordingError` line naming the file, the column and the row.
:func:`write_recording` writes one atomically (:func:`testbed.io.atomic_path`); reading it back
gives the same arrays, bitwise.
A simulated run becomes one with :func:`testbed.experiment.replay.recording_from_result`.

Layouts (the column names are the rig's ``action_names`` and its sensor suite's ``names``, in
SI units; a :class:`~testbed.io.mapping.Mapping` renames and converts others):

- CSV with a header line: ``time_s`` and one column per input or channel; ``#`` lines before
  the header are comments (the writer's first one holds the recording's declaration and
  ``meta`` as JSON). Values as ``%.17g`` (round-trips every float64).
- NPZ: one 1-D array per column name, plus ``time_s``.
- MAT (MATLAB v5, :func:`scipy.io.loadmat`): one vector variable per column name.
- QUARC "To File": one 2-D array per file, row 0 the time and one row per signal, an
  experiment spread over several files (``pitch.mat``, ``voltage.mat``...): read a list of
  files or a directory with a mapping saying which row of which file is which signal. The
  files' times must agree within :data:`RATE_TOLERANCE` of the median step.

MATLAB v7.3 files are HDF5: read with ``h5py`` when it is installed, otherwise refused with a
line saying to save them as v5 (``save(name, '-v7')``).

Sample convention (that of a real rig's log): row ``k`` holds the time ``t_k``, the channels
the sensors gave at ``t_k``, and the inputs applied from ``t_k`` to ``t_{k+1}`` (the command
computed after reading row ``k``'s channels, held over the next step).

Checks (all before anything runs): only regular files (not FIFOs, devices, directories) of at
most :data:`MAX_RECORDING_BYTES`, checked before reading; a ``time_s`` column; at least two
samples; cells that are numbers (no empty cells, no text); time strictly increasing (no
duplicates); finite values (no NaN gaps); a uniform rate: every step within
:data:`RATE_TOLERANCE` (1 %) of the median step (smaller jitter is accepted); with ``rig`` or
``sensors``: only their inputs and channels, in their units. The finite-value and rate checks
apply to the segment a mapping keeps (``start_s``/``stop_s``), the others to the whole file.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from testbed.io import atomic_path, check_output_path
from testbed.io.mapping import ColumnMap, Mapping, load_mapping
from testbed.io.readers import (  # (the constants re-exported)
    CSV_META_PREFIX,
    MAX_RECORDING_BYTES,
    META_KEY,
    RATE_TOLERANCE,
    TIME,
    Column,
    Table,
    as_vector,
    check_kind,
    check_time,
    parse_csv,
    parse_mat,
    parse_npz,
    parse_quarc,
    read_bounded,
    sample_label,
)
from testbed.io.recording import Recording, RecordingError
from testbed.sensors.base import Sensor

__all__ = ["CSV_META_PREFIX", "MAX_RECORDING_BYTES", "META_KEY", "RATE_TOLERANCE", "SUFFIXES",
           "TIME", "check_recording", "read_bounded", "read_recording", "write_recording"]

#: File suffixes of :func:`read_recording` and :func:`write_recording`.
SUFFIXES = (".csv", ".npz", ".mat")

_CSV_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")
_MAT_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,62}$")


# ---------------------------------------------------------------------------- checks
def _check_rate(time: Column, t: np.ndarray, offset: int) -> None:
    step = np.diff(t)
    median = float(np.median(step))
    off = np.abs(step - median) > RATE_TOLERANCE * median
    if off.any():
        j = int(np.flatnonzero(off)[0])
        raise time.at(offset + j + 1, f"step {step[j]:.6g} s after {t[j]:.9g} s, the median "
                                      f"step is {median:.6g} s: the rate must be uniform "
                                      f"within {RATE_TOLERANCE:.0%} of the median step "
                                      "(resample, or cut a segment with start_s/stop_s)")


def _check_finite(col: Column, values: np.ndarray, offset: int, label: str) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        what = "NaN (a gap)" if np.isnan(values[i]) else f"{values[i]} (not finite)"
        raise col.at(offset + i, what, label)


# ---------------------------------------------------------------------------- declarations
@dataclasses.dataclass
class _Declared:
    label: str
    inputs: dict[str, str]  # name -> unit
    channels: dict[str, str]

    def expected(self) -> str:
        return (f"inputs [{', '.join(self.inputs) or 'none'}], channels "
                f"[{', '.join(self.channels) or 'none'}]")


def _declared(rig: Any, sensors: Any) -> _Declared | None:
    """The names (and units) a recording of ``rig`` / ``sensors`` may hold."""
    if rig is None and sensors is None:
        return None
    inputs: dict[str, str] = {}
    channels: dict[str, str] = {}
    instance = None
    label = "the sensors"
    if rig is not None:
        from testbed.rigs import resolve_rig
        from testbed.rigs.base import Rig

        if isinstance(rig, Rig):
            instance, cls = rig, type(rig)
        else:
            try:
                cls = resolve_rig(rig)
            except ValueError as exc:
                raise RecordingError(f"read_recording: rig: {exc}") from None
        decl = instance or cls
        inputs = dict(zip(decl.action_names, decl.action_units, strict=True))
        label = f"rig {cls.name!r}"
        if sensors is None:
            from testbed.rigs.describe import sensor_channels

            channels = sensor_channels(instance or cls)
        elif isinstance(sensors, str):
            try:
                suite = (instance or cls()).sensors(sensors)
            except ValueError as exc:
                raise RecordingError(f"read_recording: sensors: {exc}") from None
            channels = dict(zip(suite.names, suite.units, strict=True))
    if sensors is not None and not isinstance(sensors, str):
        if not isinstance(sensors, Sensor):
            raise RecordingError(f"read_recording: sensors must be a sensor suite (with names) "
                                 f"or a preset name, got {sensors!r}")
        units = tuple(sensors.units) or ("",) * len(sensors.names)
        channels = dict(zip(sensors.names, units, strict=True))
    elif sensors is not None and rig is None:
        raise RecordingError(f"read_recording: sensors={sensors!r} names a preset: give the rig")
    return _Declared(label, inputs, channels)


# ---------------------------------------------------------------------------- reading
def _resolve_mapping(mapping: Mapping | str | os.PathLike | None) -> Mapping | None:
    if mapping is None or isinstance(mapping, Mapping):
        return mapping
    if isinstance(mapping, str | os.PathLike):
        return load_mapping(mapping)
    raise RecordingError(f"read_recording: mapping must be a Mapping or a mapping file, got "
                         f"{mapping!r}")


def read_recording(path: str | os.PathLike | Sequence[str | os.PathLike], *,
                   mapping: Mapping | str | os.PathLike | None = None, rig: Any = None,
                   sensors: Any = None) -> Recording:
    """Read and check a recorded run (CSV, NPZ, MAT or QUARC files).

    Parameters
    ----------
    path : str, PathLike or sequence of them
        A ``.csv``, ``.npz`` or ``.mat`` file; for the QUARC "To File" layout (a mapping with
        ``row`` entries) also a directory or a list of ``.mat`` files.
    mapping : Mapping, str or PathLike, optional
        A :class:`~testbed.io.mapping.Mapping` or a mapping file
        (:func:`~testbed.io.mapping.load_mapping`): names, units, signs, offsets, segment.
    rig : str, Rig subclass or Rig, optional
        Restricts the columns to the rig's inputs (``action_names``) and sensor channels (all
        its presets' ``names`` unless ``sensors`` says) and tells inputs from channels.
    sensors : Sensor or str, optional
        The sensor suite (or, with ``rig``, a preset name) whose ``names`` the channels are.

    Returns
    -------
    Recording
        ``time_s`` (N,) in s; ``inputs`` and ``channels`` (N,) each in SI units; ``source``
        the path(s); ``sha256`` of the file's bytes (several QUARC files: the sha256 of their
        32-byte digests concatenated in the order of the mapping's file names); ``meta`` the
        writer's (``meta["mapping"]``/``meta["files"]`` added when a mapping / several files
        were read). Without ``rig`` or ``sensors``, inputs are the columns the mapping
        (``kind = "input"``) or the file's declaration (written by :func:`write_recording`)
        call inputs; every other column is a channel.

    Raises
    ------
    RecordingError
        One line naming the file, the column and the row (CSV: the file's line, 1-based;
        arrays: the sample, 0-based) and what is wrong, before anything runs.
    """
    mapping = _resolve_mapping(mapping)
    declared = _declared(rig, sensors)
    time_name = mapping.time if mapping is not None else TIME
    single = isinstance(path, str | os.PathLike)
    if not single and not (isinstance(path, Sequence) and not isinstance(path, bytes)):
        raise RecordingError(f"read_recording: path must be a file, a directory or a list of "
                             f"files, got {path!r}")
    if mapping is not None and mapping.quarc:
        table, source, sha, files = parse_quarc(path, mapping)
        meta: dict[str, Any] = {"files": files}
    else:
        if not single:
            if len(path) != 1:
                raise RecordingError("read_recording: several files are read with a mapping of "
                                     "the QUARC layout (rows of files)")
            path = path[0]
        source = os.fspath(path)
        if Path(source).is_dir():
            raise RecordingError(f"{source}: a directory: a directory of QUARC files needs a "
                                 "mapping naming rows of files (docs/twin.md)")
        check_kind(source)
        suffix = Path(source).suffix.lower()
        if suffix not in SUFFIXES:
            raise RecordingError(f"{source}: unknown recording format {suffix or '(none)'!r}; "
                                 f"expected one of {', '.join(SUFFIXES)}")
        data = read_bounded(source)
        if not data:
            raise RecordingError(f"{source}: empty file (0 bytes)")
        sha = hashlib.sha256(data).hexdigest()
        parse = {".csv": parse_csv, ".npz": parse_npz, ".mat": parse_mat}[suffix]
        table = parse(data, source, time_name)
        meta = dict(table.meta)
    if mapping is not None:
        meta["mapping"] = {"source": mapping.source, "sha256": mapping.sha256}
    return _assemble(table, mapping, declared, source, sha, meta)


def _assemble(table: Table, mapping: Mapping | None, declared: _Declared | None,
              source: str, sha: str, meta: dict[str, Any]) -> Recording:
    """Map, classify and check the parsed columns; the Recording."""
    time = table.time
    t = check_time(time, mapping.time_factor_s if mapping is not None else 1.0)
    start, stop = 0, len(t)
    if mapping is not None and (mapping.start_s is not None or mapping.stop_s is not None):
        if mapping.start_s is not None:
            start = int(np.searchsorted(t, mapping.start_s, side="left"))
        if mapping.stop_s is not None:
            stop = int(np.searchsorted(t, mapping.stop_s, side="right"))
        if stop - start < 2:
            raise RecordingError(f"{mapping.source}: the segment start_s..stop_s keeps "
                                 f"{max(stop - start, 0)} samples of {time.file} (time "
                                 f"{t[0]:.6g}..{t[-1]:.6g} s); a recording needs at least 2")
    t = t[start:stop]
    # the file's columns under the rig's names, converted
    named: list[tuple[str, Column, ColumnMap | None]] = []
    if mapping is not None and mapping.quarc:
        named = [(c.name, col, c) for c, col in zip(mapping.columns.values(), table.columns,
                                                    strict=True)]
    else:
        by_source = mapping.by_source() if mapping is not None else {}
        present = {col.name for col in table.columns}
        for entry in by_source.values():
            if entry.source not in present:
                raise RecordingError(f"{mapping.source}: [columns.{entry.name}] reads column "
                                     f"{entry.source!r}, which {time.file} does not have "
                                     f"(columns: {', '.join(sorted(present))})")
        ignore = set(mapping.ignore) if mapping is not None else set()
        for col in table.columns:
            if col.name in ignore:
                continue
            entry = by_source.get(col.name)
            named.append((entry.name if entry else col.name, col, entry))
    if not named:
        raise RecordingError(f"{time.file}: no column besides {time.name!r}; a recording holds "
                             "inputs or sensor channels")
    inputs: dict[str, np.ndarray] = {}
    channels: dict[str, np.ndarray] = {}
    for name, col, entry in named:
        label = col.name if entry is None or entry.row is None else f"{col.name} ({name})"
        kind = _kind(name, col, entry, declared, table.declared_inputs, label)
        target = inputs if kind == "input" else channels
        if name in inputs or name in channels:
            raise col.at(0, f"a second column for {name!r}", label)
        raw = col.values[start:stop]
        _check_finite(col, raw, start, label)
        values = entry.apply(raw) if entry is not None else raw
        target[name] = np.array(values, dtype=np.float64, copy=True)
    _check_rate(time, t, start)
    return Recording(time_s=np.array(t, dtype=np.float64, copy=True), inputs=inputs,
                     channels=channels, source=source, sha256=sha, meta=meta)


def _kind(name: str, col: Column, entry: ColumnMap | None, declared: _Declared | None,
          declared_inputs: tuple[str, ...], label: str) -> str:
    """``"input"`` or ``"channel"`` for a column named ``name`` (checked with the rig)."""
    if declared is None:
        if entry is not None and entry.kind:
            return entry.kind
        return "input" if name in declared_inputs else "channel"
    if name in declared.inputs:
        kind, unit = "input", declared.inputs[name]
    elif name in declared.channels:
        kind, unit = "channel", declared.channels[name]
    else:
        what = f"mapped to {name!r}, " if entry is not None and entry.name != col.name else ""
        raise RecordingError(f"{col.file}: column {label!r}, {col.header or 'all samples'}: "
                             f"{what}not an input or sensor channel of {declared.label}; "
                             f"expected {declared.expected()}")
    if entry is not None and entry.kind and entry.kind != kind:
        raise RecordingError(f"{col.file}: column {label!r}: the mapping says kind "
                             f"{entry.kind!r} for {entry.name!r}, "
                             f"{declared.label} has it as an {kind}")
    if entry is not None and entry.unit and unit and entry.si_unit() != unit:
        raise RecordingError(f"{col.file}: column {label!r}: the mapping's unit "
                             f"{entry.unit!r} gives {entry.si_unit()}, {declared.label}'s "
                             f"{name!r} is in {unit}")
    return kind


# ---------------------------------------------------------------------------- checks in memory
def check_recording(recording: Recording) -> Recording:
    """Check a recording made in memory as :func:`read_recording` checks a file.

    Returns
    -------
    Recording
        ``recording`` itself.

    Raises
    ------
    RecordingError
        One line naming ``recording.source``, the column and the sample.
    """
    if not isinstance(recording, Recording):
        raise RecordingError(f"expected a Recording, got {type(recording).__name__}")
    name = recording.source
    time = Column(TIME, as_vector(recording.time_s, name, TIME), name, sample_label)
    t = check_time(time, 1.0)
    _check_rate(time, t, 0)
    seen = {TIME, META_KEY}
    for kind, group in (("input", recording.inputs), ("channel", recording.channels)):
        for key, values in group.items():
            if not isinstance(key, str) or not key or key in seen:
                raise RecordingError(f"{name}: {kind} name {key!r} is empty, reserved or used "
                                     "twice")
            seen.add(key)
            col = Column(key, as_vector(values, name, key), name, sample_label)
            if len(col.values) != len(t):
                raise RecordingError(f"{name}: column {key!r}, sample "
                                     f"{min(len(col.values), len(t))}: {len(col.values)} "
                                     f"samples, {TIME!r} has {len(t)}")
            _check_finite(col, col.values, 0, key)
    if len(seen) == 2:
        raise RecordingError(f"{name}: no inputs and no channels")
    return recording


# ---------------------------------------------------------------------------- writing
def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return os.fspath(value)
    raise TypeError(f"meta value {value!r} is not JSON-serialisable")


def write_recording(path: str | os.PathLike, recording: Recording) -> Path:
    """Write a recording as CSV, NPZ or MATLAB v5 (by the suffix), atomically.

    The file is checked first (:func:`testbed.io.check_output_path`), written to a temporary
    name and renamed (:func:`testbed.io.atomic_path`). :func:`read_recording` gives back the
    same arrays (bitwise; CSV values as ``%.17g``), names, input/channel split and ``meta``.

    Parameters
    ----------
    path : str or PathLike
        Ends in ``.csv``, ``.npz`` or ``.mat``.
    recording : Recording
        Checked (:func:`check_recording`); names must be identifiers (MAT: MATLAB's, at most
        63 characters); ``meta`` must be JSON-serialisable.

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        A bad destination or suffix; :class:`RecordingError` for a bad recording.
    """
    suffix = Path(os.fspath(path)).suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"recording file must end in {', '.join(SUFFIXES)}, got "
                         f"{os.fspath(path)!r}")
    final = check_output_path(path, "recording", suffix)
    check_recording(recording)
    pattern = _MAT_NAME if suffix == ".mat" else _CSV_NAME
    names = [*recording.inputs, *recording.channels]
    for key in names:
        if not pattern.match(key):
            raise RecordingError(f"{os.fspath(path)}: column name {key!r} cannot be written to "
                                 f"a {suffix} file (expected {pattern.pattern})")
    try:
        declaration = json.dumps({"format": "testbed-recording", "version": 1,
                                  "inputs": list(recording.inputs),
                                  "channels": list(recording.channels),
                                  "meta": recording.meta}, allow_nan=False, default=_plain)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"{recording.source}: meta cannot be written ({exc})") from None
    columns = {TIME: recording.time_s, **recording.inputs, **recording.channels}
    arrays = {k: np.ascontiguousarray(v, dtype=np.float64) for k, v in columns.items()}
    with atomic_path(final) as tmp:
        if suffix == ".csv":
            with open(tmp, "w", encoding="utf-8", newline="\n") as f:
                f.write(CSV_META_PREFIX + declaration + "\n")
                f.write(",".join(arrays) + "\n")
                np.savetxt(f, np.column_stack(list(arrays.values())), fmt="%.17g",
                           delimiter=",")
        elif suffix == ".npz":
            with open(tmp, "wb") as f:
                np.savez(f, **arrays, **{META_KEY: np.array(declaration)})
        else:
            import scipy.io

            with open(tmp, "wb") as f:
                scipy.io.savemat(f, {**arrays, META_KEY: declaration}, format="5",
                                 oned_as="column", do_compression=False)
    return final
