"""The four layouts of a recording file parsed into columns (:mod:`testbed.io.formats` checks
and assembles them into a :class:`~testbed.io.recording.Recording`): CSV with a header, NPZ,
MATLAB v5 (or v7.3 through ``h5py``) and the QUARC "To File" layout of several ``.mat`` files,
each read from a regular file of bounded size; every problem one
:class:`~testbed.io.recording.RecordingError` line naming the file, the column and the row.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import math
import os
import stat
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from testbed.io import bounded
from testbed.io.mapping import ColumnMap, Mapping
from testbed.io.recording import RecordingError

#: Largest recording file read, bytes (2 GiB), checked before reading.
MAX_RECORDING_BYTES = 2 << 30
#: Largest step deviation accepted, as a fraction of the median step (1 %): a rate within it
#: is uniform (timer jitter); the QUARC files' times must agree within it too.
RATE_TOLERANCE = 0.01
#: The name of the time column.
TIME = "time_s"
#: NPZ key / MAT variable holding the writer's declaration (JSON).
META_KEY = "testbed_meta"
#: The CSV comment line holding the writer's declaration (JSON follows).
CSV_META_PREFIX = "# testbed-recording "
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


# ---------------------------------------------------------------------------- bounded input
def read_bounded(path: str | os.PathLike, limit: int | None = None, *,
                 what: str = "recording") -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (default
    :data:`MAX_RECORDING_BYTES`; :func:`testbed.io.bounded.read_bounded`), or a one-line
    :class:`RecordingError` naming the file."""
    return bounded.read_bounded(path, MAX_RECORDING_BYTES if limit is None else int(limit),
                                what=what, error=RecordingError)


def check_kind(name: str) -> None:
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
class Column:
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
class Table:
    time: Column
    columns: list[Column]
    meta: dict[str, Any]
    declared_inputs: tuple[str, ...] = ()


def sample_label(i: int) -> str:
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
def parse_csv(data: bytes, name: str, time_name: str) -> Table:
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

    columns = [Column(h, matrix[:, j], name, where, f"line {header_line} (the header)")
               for j, h in enumerate(header)]
    time = columns.pop(header.index(time_name))
    return Table(time, columns, meta, inputs)


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
def as_vector(value: Any, file: str, key: str, kind: str = "column") -> np.ndarray:
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
                meta_text: str | None) -> Table:
    meta, inputs = _declaration(meta_text, name) if meta_text is not None else ({}, ())
    if not arrays:
        raise RecordingError(f"{name}: empty file (no arrays)")
    if time_name not in arrays:
        raise RecordingError(f"{name}: column {time_name!r} missing (arrays: "
                             f"{', '.join(sorted(arrays))})")
    vectors = {k: as_vector(v, name, k) for k, v in arrays.items()}
    n = len(vectors[time_name])
    for key, values in vectors.items():
        if len(values) != n:
            raise RecordingError(f"{name}: column {key!r}, sample {min(len(values), n)}: "
                                 f"{len(values)} samples, {time_name!r} has {n}")
    time = Column(time_name, vectors.pop(time_name), name, sample_label)
    return Table(time, [Column(k, v, name, sample_label) for k, v in vectors.items()], meta,
                  inputs)


def parse_npz(data: bytes, name: str, time_name: str) -> Table:
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


def parse_mat(data: bytes, name: str, time_name: str) -> Table:
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


def parse_quarc(path: Any, mapping: Mapping) -> tuple[Table, str, str, dict[str, str]]:
    files = _quarc_files(path, mapping)
    digests, arrays = {}, {}
    raw: dict[str, bytes] = {}
    for key, file in files.items():
        raw[key] = read_bounded(file)
        digests[key] = hashlib.sha256(raw[key]).hexdigest()
        arrays[key] = _mat_arrays(raw[key], str(file))
    columns: list[Column] = []
    time: Column | None = None
    for col in mapping.columns.values():
        file = str(files[col.file])
        var, arr = _quarc_array(arrays[col.file], file, col)
        if col.row >= arr.shape[0]:
            raise RecordingError(f"{file}: variable {var!r} has rows 0..{arr.shape[0] - 1}, "
                                 f"[columns.{col.name}] reads row {col.row}")
        values = arr.astype(np.float64, copy=False)
        t = Column("row 0 (time)", values[0], file, sample_label)
        check_time(t, 1.0)
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
        columns.append(Column(f"row {col.row}", values[col.row], file, sample_label))
    if len(files) == 1:
        sha = digests[next(iter(files))]
    else:  # several files: the sha256 of their digests (raw, 32 bytes each) in name order
        sha = hashlib.sha256(b"".join(bytes.fromhex(digests[k]) for k in sorted(files))
                             ).hexdigest()
    single = isinstance(path, str | os.PathLike)
    source = os.fspath(path) if single else " + ".join(os.fspath(p) for p in path)
    file_digests = {os.fspath(files[k]): digests[k] for k in sorted(files)}
    return Table(time, columns, {}), source, sha, file_digests


def check_time(time: Column, factor_s: float) -> np.ndarray:
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
