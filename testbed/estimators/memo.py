"""Expensive designs memoized by their inputs: in this process, and across the worker
processes of one run.

A design search (an LMI bisection, a variance-constrained design) is deterministic, so a
design computed once for some matrices and options equals one computed again: the same
object is returned for the same key. :func:`memoized` keeps the last :data:`SIZE` designs of
this process. Inside :func:`shared_directory` it also keeps them as pickles in a directory
that the worker processes of one run share (``testbed score`` makes one per call): an entry
scored on one worker then reuses the designs another worker computed for an entry with the
same design model (the +-20 % mismatch entries share their nominal entry's). The directory is
only read and written inside the context, and only when it is a directory of this user that
nobody else may write to; an entry that cannot be read, does not unpickle, or is not of the
type the caller expects is recomputed, never an error.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import stat
import tempfile
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")

#: Designs kept in this process (least recently used dropped first).
SIZE = 32
_memory: OrderedDict[str, Any] = OrderedDict()
_directory: Path | None = None


def key(*parts: Any) -> str:
    """sha256 (hex) of arrays (dtype, shape and bytes) and of other values' ``repr``.

    Parameters
    ----------
    *parts : ndarray or any value with a deterministic ``repr``
    """
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            arr = np.ascontiguousarray(part)
            h.update(f"{arr.dtype.str}{arr.shape}".encode())
            h.update(arr.tobytes())
        else:
            h.update(repr(part).encode())
        h.update(b"|")
    return h.hexdigest()


@contextmanager
def shared_directory(path: str | os.PathLike[str] | None) -> Iterator[None]:
    """Share designs through the directory ``path`` inside the context (None: this process
    only).

    Parameters
    ----------
    path : path-like or None
        An existing directory that the processes of one run share.
    """
    global _directory
    before = _directory
    _directory = None if path is None else Path(path)
    try:
        yield
    finally:
        _directory = before


def _private(directory: Path) -> bool:
    """Whether ``directory`` is a directory of this user that nobody else may write to."""
    try:
        st = os.lstat(directory)
    except OSError:
        return False
    return (stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid()
            and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH))


def memoized(kind: str, digest: str, compute: Callable[[], T],
             valid: Callable[[Any], bool]) -> T:
    """``compute()``, or the design an earlier call with the same ``kind`` and ``digest``
    returned (in this process, or in the shared directory).

    Parameters
    ----------
    kind : str
        The family of design (a file-name prefix).
    digest : str
        :func:`key` of everything the design depends on.
    compute : callable
        Computes the design (exceptions propagate and nothing is kept).
    valid : callable
        Whether a value read from the shared directory is a design of this kind (e.g. an
        ``isinstance`` test); one that is not is recomputed.
    """
    name = f"{kind}-{digest}"
    if name in _memory:
        _memory.move_to_end(name)
        return _memory[name]
    directory = _directory
    value: Any = None
    found = False
    if directory is not None and not _private(directory):
        directory = None
    if directory is not None:
        try:
            with open(directory / f"{name}.pkl", "rb") as file:
                value = pickle.load(file)
            found = bool(valid(value))
        except Exception:  # noqa: BLE001 - a damaged entry is recomputed, whatever it raises
            found = False
    if not found:
        value = compute()
        if directory is not None:
            _write(directory, name, value)
    _memory[name] = value
    while len(_memory) > SIZE:
        _memory.popitem(last=False)
    return value


def _write(directory: Path, name: str, value: Any) -> None:
    """Write ``value`` as ``directory/name.pkl`` atomically (a temporary file renamed); any
    failure leaves no file."""
    try:
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{name}.", suffix=".tmp")
    except OSError:
        return
    try:
        with os.fdopen(fd, "wb") as file:
            pickle.dump(value, file, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, directory / f"{name}.pkl")
    except Exception:  # noqa: BLE001 - an unpicklable design is simply not shared
        try:
            os.unlink(tmp)
        except OSError:
            pass


def clear() -> None:
    """Forget the designs of this process (the shared directory is left as it is)."""
    _memory.clear()
