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

import csv
import dataclasses
import hashlib
import io
import json
import math
import os
import re
import stat
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from testbed.io import atomic_path, bounded, check_output_path
from testbed.io.mapping import ColumnMap, Mapping, load_mapping
from testbed.io.recording import Recording, RecordingError

#: Largest recording file read, bytes (2 GiB), checked before reading.
MAX_RECORDING_BYTES = 2 << 30
#: Largest step deviation accepted, as a fraction of the median step (1 %): a rate within it
#: is uniform (timer jitter); the QUARC files' times must agree within it too.
RATE_TOLERANCE = 0.01
#: File suffixes of :func:`read_recording` and :func:`write_recording`.
SUFFIXES = (".csv", ".npz", ".mat")
#: The name of the time column.
TIME = "time_s"
#: NPZ key / MAT variable holding the writer's declaration (JSON).
META_KEY = "testbed_meta"
#: The CSV comment line holding the writer's declaration (JSON follows).
CSV_META_PREFIX = "# testbed-recording "

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_CSV_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")
_MAT_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,62}$")


# ---------------------------------------------------------------------------- bounded input
def read_bounded(path: str | os.PathLike, limit: int | None = None, *,
                 what: str = "recording") -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (default
    :data:`MAX_RECORDING_BYTES`; :func:`testbed.io.bounded.read_bounded`), or a one-line
    :class:`RecordingError` naming the file."""
    return bounded.read_bounded(path, MAX_RECORDING_BYTES if limit is None else int(limit),
                                what=what, error=RecordingError)


def _check_kind(name: str) -> None:
    """Refuse a path that is not a regular file by its ``stat`` (nothing is opened)."""
    try:
        mode = os.stat(name).st_mode
    except FileNotFoundError:
        raise RecordingError(f"{name}: no such recording file") from None
    except OSError as exc:
        raise RecordingError(f"{name}: cannot read the recording ({exc.strerror or exc})"
                             ) from None
    if not stat.S_ISREG(mode):
        raise RecordingError(f"{name}: {bounded.file_kind(mode)}; a recording must be a regular "
                             "file")


# ---------------------------------------------------------------------------- parsed tables
@dataclasses.dataclass
class _Column:
    """One parsed column: its values and how to name a row of it in a message."""

    name: str  # the file's name for it (a header cell, an NPZ key, "row 2")
    values: np.ndarray  # (N,) float64
    file: str
    where: Callable[[int], str]  # sample index -> "line 7" / "sample 5"
    header: str = ""  # where the name is: "line 1 (the header)" ("": not in a header)

    def at(self, i: int, problem: str, label: str | None = None) -> RecordingError:
        return RecordingError(f"{self.file}: column {label or self.name!r}, {self.where(i)}: "
                              f"{problem}")


@dataclasses.dataclass
class _Table:
    time: _Column
    columns: list[_Column]
    meta: dict[str, Any]
    declared_inputs: tuple[str, ...] = ()


def _samples(i: int) -> str:
    return f"sample {i}"


def _declaration(text: str, name: str) -> tuple[dict[str, Any], tuple[str, ...]]:
    """The writer's JSON declaration: (meta, input names)."""
    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise RecordingError(f"{name}: the {META_KEY} declaration is not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != "testbed-recording":
        raise RecordingError(f"{name}: the {META_KEY} declaration is not a testbed recording's")
    meta = doc.get("meta", {})
    inputs = doc.get("inputs", [])
    if not isinstance(meta, dict) or not isinstance(inputs, list):
        raise RecordingError(f"{name}: the {META_KEY} declaration has a bad meta or inputs")
    return meta, tuple(str(v) for v in inputs)


# ---------------------------------------------------------------------------- CSV
def _parse_csv(data: bytes, name: str, time_name: str) -> _Table:
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise RecordingError(f"{name}: not UTF-8 text (byte {exc.start})") from None
    lines = text.splitlines()
    meta: dict[str, Any] = {}
    inputs: tuple[str, ...] = ()
    head = 0
    while head < len(lines) and (lines[head].startswith("#") or not lines[head].strip()):
        if lines[head].startswith(CSV_META_PREFIX):
            meta, inputs = _declaration(lines[head][len(CSV_META_PREFIX):], name)
        head += 1
    if head == len(lines):
        raise RecordingError(f"{name}: empty file (no header line, no samples)")
    header_line = head + 1
    header = [cell.strip() for cell in next(csv.reader([lines[head]]))]
    for j, cell in enumerate(header):
        if not cell:
            raise RecordingError(f"{name}: column {j + 1} of the header (line {header_line}) "
                                 "has no name")
        if header.index(cell) != j:
            raise RecordingError(f"{name}: column {cell!r} appears twice in the header (line "
                                 f"{header_line})")
    if time_name not in header:
        raise RecordingError(f"{name}: column {time_name!r} missing from the header (line "
                             f"{header_line}: {', '.join(header)})")
    body = lines[head + 1:]
    while body and not body[-1].strip():
        body.pop()
    first = header_line + 1
    matrix = None
    if body and all(line.strip() for line in body):
        try:  # the fast path; any trouble: the cell-by-cell pass below names it
            matrix = np.loadtxt(io.StringIO("\n".join(body)), delimiter=",", dtype=np.float64,
                                ndmin=2, comments=None, quotechar='"')
        except ValueError:
            matrix = None
        if matrix is not None and matrix.shape != (len(body), len(header)):
            matrix = None
    if matrix is None:
        matrix = _parse_cells(body, header, name, first)

    def where(i: int) -> str:
        return f"line {first + i}"

    columns = [_Column(h, matrix[:, j], name, where, f"line {header_line} (the header)")
               for j, h in enumerate(header)]
    time = columns.pop(header.index(time_name))
    return _Table(time, columns, meta, inputs)


def _parse_cells(body: list[str], header: list[str], name: str, first: int) -> np.ndarray:
    """The CSV body cell by cell: the first bad cell named by line and column."""
    matrix = np.empty((len(body), len(header)))
    for i, row in enumerate(csv.reader(body)):
        line = first + i
        if not row or not any(cell.strip() for cell in row):
            raise RecordingError(f"{name}: column {header[0]!r}, line {line}: empty row")
        if len(row) != len(header):
            column = repr(header[len(row)]) if len(row) < len(header) else \
                f"{len(header) + 1} (past the header)"
            raise RecordingError(f"{name}: column {column}, line {line}: {len(row)} cells, the "
                                 f"header has {len(header)}")
        for j, cell in enumerate(row):
            cell = cell.strip()
            if not cell:
                raise RecordingError(f"{name}: column {header[j]!r}, line {line}: empty cell")
            try:
                if "_" in cell:
                    raise ValueError
                matrix[i, j] = float(cell)
            except ValueError:
                raise RecordingError(f"{name}: column {header[j]!r}, line {line}: not a "
                                     f"number: {cell[:40]!r}") from None
    return matrix


# ---------------------------------------------------------------------------- NPZ and MAT
def _vector(value: Any, file: str, key: str, kind: str = "column") -> np.ndarray:
    """A numeric 1-D (or MATLAB row/column vector) array as float64, else one line."""
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf":
        what = {"b": "booleans", "c": "complex numbers", "U": "text", "S": "bytes",
                "O": "objects"}.get(arr.dtype.kind, f"dtype {arr.dtype}")
        raise RecordingError(f"{file}: {kind} {key!r}: not a number ({what})")
    if arr.ndim == 2 and 1 in arr.shape:
        arr = arr.reshape(-1)
    if arr.ndim != 1:
        raise RecordingError(f"{file}: {kind} {key!r}: a {' x '.join(map(str, arr.shape))} "
                             "array, expected a vector")
    return arr.astype(np.float64, copy=False)


def _columns_of(arrays: dict[str, Any], name: str, time_name: str,
                meta_text: str | None) -> _Table:
    meta, inputs = _declaration(meta_text, name) if meta_text is not None else ({}, ())
    if not arrays:
        raise RecordingError(f"{name}: empty file (no arrays)")
    if time_name not in arrays:
        raise RecordingError(f"{name}: column {time_name!r} missing (arrays: "
                             f"{', '.join(sorted(arrays))})")
    vectors = {k: _vector(v, name, k) for k, v in arrays.items()}
    n = len(vectors[time_name])
    for key, values in vectors.items():
        if len(values) != n:
            raise RecordingError(f"{name}: column {key!r}, sample {min(len(values), n)}: "
                                 f"{len(values)} samples, {time_name!r} has {n}")
    time = _Column(time_name, vectors.pop(time_name), name, _samples)
    return _Table(time, [_Column(k, v, name, _samples) for k, v in vectors.items()], meta,
                  inputs)


def _parse_npz(data: bytes, name: str, time_name: str) -> _Table:
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            unpacked = sum(entry.file_size for entry in archive.infolist())
    except zipfile.BadZipFile:
        raise RecordingError(f"{name}: not an NPZ file (not a zip archive)") from None
    if unpacked > MAX_RECORDING_BYTES:
        raise RecordingError(f"{name}: unpacks to {unpacked} bytes, more than the recording "
                             f"size limit of {MAX_RECORDING_BYTES} bytes")
    arrays: dict[str, Any] = {}
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            for key in npz.files:
                try:
                    arrays[key] = npz[key]
                except ValueError:  # object arrays need pickle: refused
                    raise RecordingError(f"{name}: column {key!r}: not a number (objects)"
                                         ) from None
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        if isinstance(exc, RecordingError):
            raise
        raise RecordingError(f"{name}: not a readable NPZ file ({exc})") from None
    meta = arrays.pop(META_KEY, None)
    return _columns_of(arrays, name, time_name, None if meta is None else str(meta))


def _is_hdf5(data: bytes) -> bool:
    return data[:8] == _HDF5_SIGNATURE or data[512:520] == _HDF5_SIGNATURE or \
        b"MATLAB 7.3" in data[:116]


def _mat_arrays(data: bytes, name: str) -> dict[str, Any]:
    """The variables of a MATLAB file (v5 via scipy; v7.3 via h5py when installed)."""
    if _is_hdf5(data):
        try:
            import h5py
        except ImportError:
            raise RecordingError(f"{name}: a MATLAB v7.3 (HDF5) file; save it as v5 (MATLAB: "
                                 "save(file, '-v7')) or install h5py to read it") from None
        return _hdf5_arrays(h5py, data, name)
    import scipy.io

    try:
        sizes = scipy.io.whosmat(io.BytesIO(data))
        unpacked = sum(8 * math.prod(shape) for _, shape, _ in sizes)
        if unpacked > MAX_RECORDING_BYTES:
            raise RecordingError(f"{name}: holds {unpacked} bytes of arrays, more than the "
                                 f"recording size limit of {MAX_RECORDING_BYTES} bytes")
        loaded = scipy.io.loadmat(io.BytesIO(data), squeeze_me=False, chars_as_strings=True)
    except RecordingError:
        raise
    except Exception as exc:  # scipy raises ValueError, TypeError, MatReadError...
        raise RecordingError(f"{name}: not a readable MATLAB v5 file ({type(exc).__name__}: "
                             f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    return {k: v for k, v in loaded.items() if not k.startswith("__")}


def _hdf5_arrays(h5py: Any, data: bytes, name: str) -> dict[str, Any]:
    """Top-level numeric datasets of a MATLAB v7.3 file, in MATLAB's orientation."""
    out: dict[str, Any] = {}
    try:
        with h5py.File(io.BytesIO(data), "r") as f:
            for key, item in f.items():
                if key.startswith("#") or not isinstance(item, h5py.Dataset):
                    continue
                value = item[()]
                if item.attrs.get("MATLAB_class", b"") in (b"char", "char"):
                    out[key] = "".join(map(chr, np.asarray(value).reshape(-1)))
                else:
                    out[key] = np.asarray(value).T  # MATLAB stores column-major
    except OSError as exc:
        raise RecordingError(f"{name}: not a readable MATLAB v7.3 file ({exc})") from None
    return out


def _meta_text(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, str):
        return value
    arr = np.asarray(value)
    return "".join(str(v) for v in arr.reshape(-1)) if arr.dtype.kind in "US" else None


def _parse_mat(data: bytes, name: str, time_name: str) -> _Table:
    arrays = _mat_arrays(data, name)
    meta = _meta_text(arrays.pop(META_KEY, None))
    for key, value in arrays.items():
        shape = np.shape(value)
        if len(shape) == 2 and min(shape) > 1 and time_name not in arrays:
            raise RecordingError(f"{name}: variable {key!r} is a {shape[0]} x {shape[1]} "
                                 "array (the QUARC 'To File' layout, row 0 time): give a "
                                 "mapping naming its rows (docs/twin.md)")
    return _columns_of(arrays, name, time_name, meta)


# ---------------------------------------------------------------------------- QUARC
def _quarc_files(path: Any, mapping: Mapping) -> dict[str, Path]:
    """The files of a QUARC experiment by the names the mapping uses."""
    single = isinstance(path, str | os.PathLike)
    if single and Path(path).is_dir():
        names = sorted({c.file for c in mapping.columns.values()})
        if "" in names:
            col = next(c for c in mapping.columns.values() if not c.file)
            raise RecordingError(f"{mapping.source}: [columns.{col.name}] needs a file (the "
                                 f"directory {os.fspath(path)} is read)")
        return {n: Path(path) / n for n in names}
    paths = [Path(path)] if single else [Path(p) for p in path]
    if not paths:
        raise RecordingError("read_recording: no files given")
    files: dict[str, Path] = {}
    for col in mapping.columns.values():
        if not col.file:
            if len(paths) != 1:
                raise RecordingError(f"{mapping.source}: [columns.{col.name}] needs a file "
                                     f"({len(paths)} files are read)")
            files[""] = paths[0]
            continue
        match = [p for p in paths if p.name == col.file or p.as_posix().endswith("/" + col.file)
                 or p.as_posix() == col.file]
        if not match:
            raise RecordingError(f"{mapping.source}: [columns.{col.name}] file {col.file!r} is "
                                 f"not among the files read ({', '.join(map(str, paths))})")
        files[col.file] = match[0]
    unused = [p for p in paths if p not in files.values()]
    if unused:
        raise RecordingError(f"{unused[0]}: no column of mapping {mapping.source} reads it")
    return files


def _quarc_array(arrays: dict[str, Any], file: str, col: ColumnMap) -> tuple[str, np.ndarray]:
    arrays = {k: v for k, v in arrays.items() if k != META_KEY}
    if col.variable:
        if col.variable not in arrays:
            raise RecordingError(f"{file}: no variable {col.variable!r} ([columns.{col.name}]; "
                                 f"variables: {', '.join(sorted(arrays)) or 'none'})")
        key = col.variable
    else:
        candidates = [k for k, v in arrays.items() if np.ndim(v) == 2]
        if len(candidates) != 1:
            raise RecordingError(f"{file}: {len(candidates)} 2-D arrays "
                                 f"({', '.join(sorted(candidates)) or 'none'}): name one with "
                                 f"variable = in [columns.{col.name}]")
        key = candidates[0]
    arr = np.asarray(arrays[key])
    if arr.dtype.kind not in "iuf" or arr.ndim != 2 or arr.shape[0] < 2:
        raise RecordingError(f"{file}: variable {key!r} must be a numeric array with row 0 time "
                             f"and a row per signal, got {arr.dtype} {arr.shape}")
    return key, arr


def _parse_quarc(path: Any, mapping: Mapping) -> tuple[_Table, str, str, dict[str, str]]:
    files = _quarc_files(path, mapping)
    digests, arrays = {}, {}
    raw: dict[str, bytes] = {}
    for key, file in files.items():
        raw[key] = read_bounded(file)
        digests[key] = hashlib.sha256(raw[key]).hexdigest()
        arrays[key] = _mat_arrays(raw[key], str(file))
    columns: list[_Column] = []
    time: _Column | None = None
    for col in mapping.columns.values():
        file = str(files[col.file])
        var, arr = _quarc_array(arrays[col.file], file, col)
        if col.row >= arr.shape[0]:
            raise RecordingError(f"{file}: variable {var!r} has rows 0..{arr.shape[0] - 1}, "
                                 f"[columns.{col.name}] reads row {col.row}")
        values = arr.astype(np.float64, copy=False)
        t = _Column("row 0 (time)", values[0], file, _samples)
        _check_time(t, 1.0)
        if time is None:
            time = t
        elif len(t.values) != len(time.values):
            raise RecordingError(f"{file}: column {t.name!r}, sample "
                                 f"{min(len(t.values), len(time.values))}: {len(t.values)} "
                                 f"samples, {time.file} has {len(time.values)}")
        else:
            step = float(np.median(np.diff(time.values)))
            off = np.abs(t.values - time.values) > RATE_TOLERANCE * step
            if off.any():
                i = int(np.flatnonzero(off)[0])
                raise t.at(i, f"time {t.values[i]:.9g} s, {time.file} has {time.values[i]:.9g} s "
                              f"(the files' times must agree within {RATE_TOLERANCE:.0%} of the "
                              f"step, {RATE_TOLERANCE * step:.3g} s)")
        columns.append(_Column(f"row {col.row}", values[col.row], file, _samples))
    if len(files) == 1:
        sha = digests[next(iter(files))]
    else:  # several files: the sha256 of their digests (raw, 32 bytes each) in name order
        sha = hashlib.sha256(b"".join(bytes.fromhex(digests[k]) for k in sorted(files))
                             ).hexdigest()
    single = isinstance(path, str | os.PathLike)
    source = os.fspath(path) if single else " + ".join(os.fspath(p) for p in path)
    file_digests = {os.fspath(files[k]): digests[k] for k in sorted(files)}
    return _Table(time, columns, {}), source, sha, file_digests


# ---------------------------------------------------------------------------- checks
def _check_time(time: _Column, factor_s: float) -> np.ndarray:
    """Time in s, finite and strictly increasing, at least two samples."""
    t = time.values if factor_s == 1.0 else time.values * factor_s
    if len(t) < 2:
        raise RecordingError(f"{time.file}: column {time.name!r}: {len(t)} sample"
                             f"{'' if len(t) == 1 else 's'}; a recording needs at least 2")
    bad = ~np.isfinite(t)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise time.at(i, f"time {t[i]} is not finite")
    step = np.diff(t)
    if not (step > 0).all():
        i = int(np.flatnonzero(step <= 0)[0]) + 1
        problem = (f"time {float(t[i])!r} s repeats" if step[i - 1] == 0 else
                   f"time {float(t[i])!r} s goes back (after {float(t[i - 1])!r} s)")
        raise time.at(i, problem + "; time must be strictly increasing")
    return t


def _check_rate(time: _Column, t: np.ndarray, offset: int) -> None:
    step = np.diff(t)
    median = float(np.median(step))
    off = np.abs(step - median) > RATE_TOLERANCE * median
    if off.any():
        j = int(np.flatnonzero(off)[0])
        raise time.at(offset + j + 1, f"step {step[j]:.6g} s after {t[j]:.9g} s, the median "
                                      f"step is {median:.6g} s: the rate must be uniform "
                                      f"within {RATE_TOLERANCE:.0%} of the median step "
                                      "(resample, or cut a segment with start_s/stop_s)")


def _check_finite(col: _Column, values: np.ndarray, offset: int, label: str) -> None:
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
        names = getattr(sensors, "names", None)
        if names is None:
            raise RecordingError(f"read_recording: sensors must be a sensor suite (with names) "
                                 f"or a preset name, got {sensors!r}")
        units = tuple(getattr(sensors, "units", ())) or ("",) * len(names)
        channels = dict(zip(names, units, strict=True))
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
        table, source, sha, files = _parse_quarc(path, mapping)
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
        _check_kind(source)
        suffix = Path(source).suffix.lower()
        if suffix not in SUFFIXES:
            raise RecordingError(f"{source}: unknown recording format {suffix or '(none)'!r}; "
                                 f"expected one of {', '.join(SUFFIXES)}")
        data = read_bounded(source)
        if not data:
            raise RecordingError(f"{source}: empty file (0 bytes)")
        sha = hashlib.sha256(data).hexdigest()
        parse = {".csv": _parse_csv, ".npz": _parse_npz, ".mat": _parse_mat}[suffix]
        table = parse(data, source, time_name)
        meta = dict(table.meta)
    if mapping is not None:
        meta["mapping"] = {"source": mapping.source, "sha256": mapping.sha256}
    return _assemble(table, mapping, declared, source, sha, meta)


def _assemble(table: _Table, mapping: Mapping | None, declared: _Declared | None,
              source: str, sha: str, meta: dict[str, Any]) -> Recording:
    """Map, classify and check the parsed columns; the Recording."""
    time = table.time
    t = _check_time(time, mapping.time_factor_s if mapping is not None else 1.0)
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
    named: list[tuple[str, _Column, ColumnMap | None]] = []
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


def _kind(name: str, col: _Column, entry: ColumnMap | None, declared: _Declared | None,
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
    time = _Column(TIME, _vector(recording.time_s, name, TIME), name, _samples)
    t = _check_time(time, 1.0)
    _check_rate(time, t, 0)
    seen = {TIME, META_KEY}
    for kind, group in (("input", recording.inputs), ("channel", recording.channels)):
        for key, values in group.items():
            if not isinstance(key, str) or not key or key in seen:
                raise RecordingError(f"{name}: {kind} name {key!r} is empty, reserved or used "
                                     "twice")
            seen.add(key)
            col = _Column(key, _vector(values, name, key), name, _samples)
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
