"""Output files: validated before any work, written atomically, temporaries never left behind.

:func:`check_output_path` checks a destination before a run starts (suffix, not a directory,
the nearest existing parent a writable directory; it creates nothing: missing parents are
created when the output is written, after the work, and removed again if writing fails).
:func:`atomic_path` writes to a temporary name in the target directory, then renames: an
interrupted run never leaves a truncated ``.json``, ``.npz``, ``.png`` or ``.rrd`` behind,
only the old file (or none) or the complete new one. :func:`outputs_together` holds a
command's outputs back until all are written: all of them appear, or none.

Temporary names are ``.<name>.<pid>.<random><suffix>.tmp`` (directories: ``...tmpdir``):
hidden, ending in ``.tmp``/``.tmpdir`` (never matched by ``*.json`` or ``*.rrd``), and
carrying the writer's process id. They are removed on success, on an exception and on
SIGINT/SIGTERM (the CLI turns both into exceptions); those of a process that no longer
exists (killed with SIGKILL) are removed by the next write to the same destination.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import glob
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


def check_output_path(path: str | os.PathLike, name: str,
                      suffix: str | tuple[str, ...] | None) -> Path:
    """Check an output destination before any work is done.

    Parameters
    ----------
    path : str or PathLike
        Destination file (or directory when ``suffix`` is None).
    name : str
        What to call it in messages (e.g. ``"--json"``).
    suffix : str, tuple of str or None
        Required file suffix (``".json"``, ``".png"``, ``".rrd"``, ``".npz"``...), or the
        suffixes allowed; None: a directory.

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        Wrong suffix, an existing directory where a file is expected (or a file where a
        directory is), or a parent that cannot be created or written (a file on the way, a
        read-only directory, a pseudo file system); the message names ``name``.
    """
    text = os.fspath(path)
    final = Path(text)
    if not text or final.name in ("", ".", ".."):
        raise ValueError(f"{name} must name a {'directory' if suffix is None else 'file'}, "
                         f"got {text!r}")
    if suffix is None:
        if final.exists() and not final.is_dir():
            raise ValueError(f"{name} {text!r} exists and is not a directory")
        start = final
    else:
        allowed = (suffix,) if isinstance(suffix, str) else tuple(suffix)
        if final.suffix.lower() not in allowed:
            raise ValueError(f"{name} must be a {' or '.join(allowed)} file, got {text!r}")
        if final.is_dir():
            raise ValueError(f"{name} {text!r} is a directory, expected a "
                             f"{' or '.join(allowed)} file")
        start = final.parent
    ancestor = Path(os.path.abspath(start))
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ValueError(f"{name} {text!r}: {ancestor} is a file, not a directory")
    prefix = f".testbed-write-test.{os.getpid()}."
    try:  # the only reliable test (permissions, read-only or pseudo file systems, quotas)
        fd, probe = tempfile.mkstemp(prefix=prefix, dir=ancestor)
        os.close(fd)
        os.unlink(probe)
    except BaseException as exc:  # an interrupt included: no probe file left behind
        for entry in ancestor.glob(f"{glob.escape(prefix)}*"):
            with contextlib.suppress(OSError):
                entry.unlink()
        if isinstance(exc, OSError):
            raise ValueError(f"{name} {text!r}: cannot write in {ancestor} "
                             f"({exc.strerror or exc})") from None
        raise
    return final


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (on this machine)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def remove_stale_temporaries(path: str | os.PathLike) -> list[Path]:
    """Remove the temporaries of ``path`` left by processes that no longer exist.

    Parameters
    ----------
    path : str or PathLike
        A destination written through :func:`atomic_path` or :func:`temporary_directory`.

    Returns
    -------
    list of Path
        The removed files and directories.
    """
    final = Path(path)
    prefix = f".{final.name}."
    removed = []
    if not final.parent.is_dir():
        return removed
    for entry in final.parent.glob(f"{glob.escape(prefix)}*"):
        pid = entry.name[len(prefix):].split(".", 1)[0]
        if not (entry.name.endswith((".tmp", ".tmpdir")) and pid.isdigit()) \
                or process_alive(int(pid)):
            continue
        if _remove_entry(entry):
            removed.append(entry)
    return removed


class OutputError(OSError):
    """An output could not be written (a full disk, a vanished directory...): ``path`` names
    the destination; the partial output has been removed."""

    def __init__(self, path: str | os.PathLike, cause: BaseException | str):
        self.path = Path(path)
        system = cause if isinstance(cause, OSError) else None
        detail = cause if isinstance(cause, str) else \
            ((system and system.strerror) or str(cause) or type(cause).__name__)
        super().__init__(f"cannot write {os.fspath(path)!r} ({detail}); nothing was written")
        self.errno = None if system is None else system.errno

    def __reduce__(self) -> tuple[Any, ...]:
        return (_rebuild_output_error, (os.fspath(self.path), str(self), self.errno))


def _rebuild_output_error(path: str, message: str, errno: int | None) -> OutputError:
    err = OutputError.__new__(OutputError)
    OSError.__init__(err, message)
    err.path, err.errno = Path(path), errno
    return err


def _own_prefix(final: Path) -> str:
    return f".{final.name}.{os.getpid()}."


def remove_own_temporaries(path: str | os.PathLike, keep: tuple[Path, ...] = ()) -> None:
    """Remove this process's temporaries of ``path`` (all but ``keep``): the clean-up after an
    interrupt that came while a temporary was being created (before its name was known)."""
    final = Path(path)
    if not final.parent.is_dir():
        return
    transaction = _TRANSACTION.get()
    if transaction is not None:  # written, waiting for the end of outputs_together
        keep = (*keep, *(tmp for tmp, _ in transaction.pending))
    kept = {os.path.abspath(k) for k in keep}  # a relative and an absolute name of one file
    for entry in final.parent.glob(f"{glob.escape(_own_prefix(final))}*"):
        if os.path.abspath(entry) in kept or not entry.name.endswith((".tmp", ".tmpdir")):
            continue
        _remove_entry(entry)


def _remove_entry(entry: Path) -> bool:
    """Remove a temporary file or directory (not following a symlink); whether it went."""
    try:
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()
    except OSError:
        return False
    return True


def _make_parents(final: Path) -> list[Path]:
    """Create the missing parent directories of ``final``; the created ones, outermost
    first (a rolled-back output removes them again)."""
    missing = []
    parent = final.parent
    while not parent.exists() and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
    final.parent.mkdir(parents=True, exist_ok=True)
    return missing[::-1]


def _remove_empty(created: list[Path]) -> None:
    """Remove the directories of ``created`` (outermost first) that are empty."""
    for directory in reversed(created):
        with contextlib.suppress(OSError):
            directory.rmdir()  # only when empty


class _Transaction:
    """Outputs held back until :func:`outputs_together` ends: temporaries and their
    destinations, and the directories created for them."""

    def __init__(self) -> None:
        self.pending: list[tuple[Path, Path]] = []
        self.created: list[Path] = []

    def commit(self) -> list[Path]:
        done: list[Path] = []
        try:
            while self.pending:
                tmp, final = self.pending[0]
                os.replace(tmp, final)
                done.append(final)
                self.pending.pop(0)
        except BaseException as exc:  # all or nothing: take back what was renamed
            if self.pending:  # renamed but not yet recorded (an interrupt between the two)?
                tmp, final = self.pending[0]
                if not os.path.lexists(tmp) and final not in done:
                    done.append(final)
                    self.pending.pop(0)
            failed = self.pending[0][1] if self.pending else Path("output")
            for final in done:
                with contextlib.suppress(OSError):
                    final.unlink()
            self.rollback()
            if isinstance(exc, OSError) and not isinstance(exc, OutputError):
                raise OutputError(failed, exc) from exc
            raise
        # a directory made on the way to a file that is not inside it (``nosuchdir/../o.json``
        # creates ``nosuchdir``): removed again, when empty
        kept = {Path(os.path.realpath(final)).parent for final in done}
        kept |= {parent for path in kept for parent in path.parents}
        _remove_empty([d for d in self.created if Path(os.path.realpath(d)) not in kept])
        self.created.clear()
        return done

    def rollback(self) -> None:
        pending, self.pending = self.pending, []
        for tmp, final in pending:
            with contextlib.suppress(OSError):
                tmp.unlink()
            remove_own_temporaries(final)
        _remove_empty(self.created)
        self.created.clear()


_TRANSACTION: contextvars.ContextVar[_Transaction | None] = contextvars.ContextVar(
    "testbed_outputs", default=None)


@contextlib.contextmanager
def outputs_together() -> Iterator[None]:
    """All or nothing: the outputs written (through :func:`atomic_path`) within the block
    appear together when it ends without an exception; on an exception (a full disk, an
    interrupt) none of them appears and the directories created for them are removed.

    The CLI writes every command's outputs this way: a run never leaves its JSON without
    its PNG or RRD. :func:`commit_outputs` makes the outputs so far appear early (``--serve``
    keeps serving after its files are written).
    """
    transaction = _Transaction()
    token = _TRANSACTION.set(transaction)
    try:
        yield
        transaction.commit()
    except BaseException:
        transaction.rollback()
        raise
    finally:
        _TRANSACTION.reset(token)


def commit_outputs() -> list[Path]:
    """Within :func:`outputs_together`: rename the outputs written so far into place now."""
    transaction = _TRANSACTION.get()
    return [] if transaction is None else transaction.commit()


def reserve(f: Any, size: int, path: str | os.PathLike) -> None:
    """Allocate ``size`` bytes of the open file ``f`` up front (``posix_fallocate``): a full
    disk is an :class:`OutputError` now, never a failure (or a SIGBUS) in mid-write."""
    if size <= 0 or not hasattr(os, "posix_fallocate"):
        return
    try:
        os.posix_fallocate(f if isinstance(f, int) else f.fileno(), 0, int(size))
    except OSError as exc:
        if exc.errno in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
            return  # the file system cannot reserve: the writes will say
        raise OutputError(path, exc) from None


def temporary_directory(path: str | os.PathLike) -> Path:
    """A new private directory beside ``path`` (``.<name>.<pid>.<random>.tmpdir``).

    The caller removes it; stale ones of dead processes go with the next write to ``path``.
    An interrupt while it is being created leaves nothing.
    """
    final = Path(path)
    transaction = _TRANSACTION.get()
    created: list[Path] = []
    try:
        created = _make_parents(final)
        if transaction is not None:
            transaction.created.extend(created)
        remove_stale_temporaries(final)
        return Path(tempfile.mkdtemp(prefix=_own_prefix(final), suffix=".tmpdir",
                                     dir=final.parent))
    except BaseException as exc:
        remove_own_temporaries(final)
        if transaction is None:
            _remove_empty(created)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise OutputError(final, exc) from None
        raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    The parent directory is created. On an exception (including ``KeyboardInterrupt`` and the
    CLI's SIGTERM, at any point) the temporary file is removed and ``path`` is left untouched;
    an ``OSError`` becomes :class:`OutputError` naming ``path``. Within
    :func:`outputs_together` the rename waits for the end of the block.

    Parameters
    ----------
    path : str or PathLike
        Final destination.

    Yields
    ------
    Path
        Temporary file to write (same directory, name ``.<name>.<pid>.<random><suffix>.tmp``).
    """
    final = Path(path)
    transaction = _TRANSACTION.get()
    tmp: Path | None = None
    handed_over = False
    created: list[Path] = []
    try:
        created = _make_parents(final)
        if transaction is not None:
            transaction.created.extend(created)
        remove_stale_temporaries(final)
        fd, tmp_name = tempfile.mkstemp(prefix=_own_prefix(final),
                                        suffix=final.suffix + ".tmp", dir=final.parent)
        tmp = Path(tmp_name)
        os.close(fd)
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the usual file mode
        if transaction is not None:
            transaction.pending.append((tmp, final))
            handed_over = True
        else:
            os.replace(tmp, final)
    except BaseException as exc:
        if not handed_over:
            remove_own_temporaries(final)
            if transaction is None:
                if tmp is not None:
                    with contextlib.suppress(OSError):
                        tmp.unlink()
                _remove_empty(created)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise OutputError(final, exc) from exc
        raise
    finally:
        if tmp is not None and not handed_over and tmp.exists():
            tmp.unlink()


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"refusing to write a non-finite number ({value}) to JSON")
    return value


def write_json(path: str | os.PathLike, data: dict) -> Path:
    """Write ``data`` as indented JSON atomically; NaN or inf raise ``ValueError``.

    Parameters
    ----------
    path : str or PathLike
        Destination file.
    data : dict
        JSON-serialisable mapping; numpy arrays and scalars are converted.

    Returns
    -------
    Path
        The written path.
    """
    payload = json.dumps(_jsonable(data), indent=2, allow_nan=False) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(payload)
    return Path(path)
