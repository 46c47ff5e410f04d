"""Output files: validated before any work, written atomically, temporaries never left behind.

:func:`check_output_path` checks a destination before a run starts (suffix, not a directory,
parent creatable and writable). :func:`atomic_path` writes to a temporary name in the target
directory, then renames: an interrupted run never leaves a truncated ``.json``, ``.npz``,
``.png`` or ``.rrd`` behind, only the old file (or none) or the complete new one.

Temporary names are ``.<name>.<pid>.<random><suffix>.tmp`` (directories: ``...tmpdir``):
hidden, ending in ``.tmp``/``.tmpdir`` (never matched by ``*.json`` or ``*.rrd``), and
carrying the writer's process id. They are removed on success, on an exception and on
SIGINT/SIGTERM (the CLI turns both into exceptions); those of a process that no longer
exists (killed with SIGKILL) are removed by the next write to the same destination.
"""

from __future__ import annotations

import contextlib
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


def check_output_path(path: str | os.PathLike, name: str, suffix: str | None) -> Path:
    """Check an output destination before any work is done.

    Parameters
    ----------
    path : str or PathLike
        Destination file (or directory when ``suffix`` is None).
    name : str
        What to call it in messages (e.g. ``"--json"``).
    suffix : str or None
        Required file suffix (``".json"``, ``".png"``, ``".rrd"``, ``".npz"``...); None: a
        directory.

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
        if final.suffix.lower() != suffix:
            raise ValueError(f"{name} must be a {suffix} file, got {text!r}")
        if final.is_dir():
            raise ValueError(f"{name} {text!r} is a directory, expected a {suffix} file")
        start = final.parent
    ancestor = Path(os.path.abspath(start))
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ValueError(f"{name} {text!r}: {ancestor} is a file, not a directory")
    try:  # the only reliable test (permissions, read-only or pseudo file systems, quotas)
        fd, probe = tempfile.mkstemp(prefix=".testbed-write-test.", dir=ancestor)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ValueError(f"{name} {text!r}: cannot write in {ancestor} "
                         f"({exc.strerror or exc})") from None
    return final


def _alive(pid: int) -> bool:
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
        if not (entry.name.endswith((".tmp", ".tmpdir")) and pid.isdigit()) or _alive(int(pid)):
            continue
        with contextlib.suppress(OSError):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
            removed.append(entry)
    return removed


def temporary_directory(path: str | os.PathLike) -> Path:
    """A new private directory beside ``path`` (``.<name>.<pid>.<random>.tmpdir``).

    The caller removes it; stale ones of dead processes go with the next write to ``path``.
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(final)
    return Path(tempfile.mkdtemp(prefix=f".{final.name}.{os.getpid()}.", suffix=".tmpdir",
                                 dir=final.parent))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    The parent directory is created. On an exception (including ``KeyboardInterrupt`` and the
    CLI's SIGTERM) the temporary file is removed and ``path`` is left untouched.

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
    final.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(final)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.name}.{os.getpid()}.",
                                    suffix=final.suffix + ".tmp", dir=final.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the usual file mode
        os.replace(tmp, final)
    finally:
        if tmp.exists():
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
