"""The private temporary directory through which the workers of one ``score`` call share
their designs, and the removal of those a killed process left behind."""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator

from testbed.io import process_alive

#: Name prefix of the temporary directory through which one ``score`` call's workers share
#: their designs: ``testbed-designs-<pid>-<random>`` (``pid``: the process that made it).
DESIGNS_PREFIX = "testbed-designs-"


@contextlib.contextmanager
def designs_directory(parent: str | os.PathLike[str] | None = None) -> Iterator[str]:
    """A new private directory (mode 0700) for the designs the workers of one call share,
    removed when the block ends (an exception or an interrupt included).

    Its name carries this process's id. A process killed by SIGKILL cannot remove its own;
    the next call removes it: every ``testbed-designs-<pid>-*`` directory of this user in
    ``parent`` whose process no longer exists (:func:`remove_stale_designs`).

    Parameters
    ----------
    parent : path-like, optional
        Where to make it (default ``tempfile.gettempdir()``).
    """
    parent = tempfile.gettempdir() if parent is None else os.fspath(parent)
    remove_stale_designs(parent)
    with tempfile.TemporaryDirectory(prefix=f"{DESIGNS_PREFIX}{os.getpid()}-",
                                     dir=parent) as designs:
        yield designs


def remove_stale_designs(parent: str | os.PathLike[str] | None = None) -> list[str]:
    """Remove the design directories (:func:`designs_directory`) of this user in ``parent``
    (default the temporary directory) left by processes that no longer exist; the removed
    paths. Directories of other users, of live processes, symbolic links and names
    without a process id are left alone."""
    parent = tempfile.gettempdir() if parent is None else os.fspath(parent)
    removed: list[str] = []
    try:
        names = os.listdir(parent)
    except OSError:
        return removed
    for name in names:
        pid = name[len(DESIGNS_PREFIX):].split("-", 1)[0]
        if not (name.startswith(DESIGNS_PREFIX) and pid.isdigit()) or process_alive(int(pid)):
            continue
        path = os.path.join(parent, name)
        try:
            st = os.lstat(path)
        except OSError:
            continue
        if stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid():
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed
