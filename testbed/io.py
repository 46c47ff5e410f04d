"""Atomic output files: write to a temporary name in the target directory, then rename.

An interrupted run therefore never leaves a truncated ``.json``, ``.npz``, ``.png`` or
``.rrd`` behind: either the old file (or none) or the complete new one exists.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    The parent directory is created. On an exception the temporary file is removed and
    ``path`` is left untouched.

    Parameters
    ----------
    path : str or PathLike
        Final destination.

    Yields
    ------
    Path
        Temporary file to write (same directory and suffix as ``path``).
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=final.suffix + ".tmp",
                                    dir=final.parent)
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
