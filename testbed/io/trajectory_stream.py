"""Trajectories of a Monte-Carlo study streamed to one ``.npz`` (``testbed mc --save-npz``):
``.npy`` files written batch by batch, the space reserved up front, zipped atomically."""

from __future__ import annotations

import contextlib
import io
import os
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from testbed.io import (
    OutputError,
    atomic_path,
    remove_own_temporaries,
    reserve,
    temporary_directory,
)


class FileRows:
    """Runs ``start:start+size`` of one array of a ``.npy`` file being written, as the loop
    records them (``rows[:, k] = value``): a few steps are buffered, then written with
    ``os.pwrite`` at their place. No memory map (a full disk is an ``OSError``, never a
    SIGBUS); RAM bounded by ``size x chunk`` rows."""

    #: Bytes of a buffer (the chunk of steps is chosen from it).
    BUFFER_BYTES = 8 << 20

    def __init__(self, stream: NpzStream, key: str, start: int, size: int):
        self.stream, self.key, self.start = stream, key, start
        total = stream.shapes[key]
        self.shape = (size, *total[1:])
        self._row_items = int(np.prod(total[2:], dtype=np.int64))
        steps = total[1]
        per_step = max(1, size * self._row_items * 8)
        self.chunk = int(max(1, min(steps, self.BUFFER_BYTES // per_step)))
        self._buf = np.zeros((size, self.chunk, *total[2:]))
        self._c0, self._top = 0, -1

    def __setitem__(self, key: Any, value: Any) -> None:
        rows, k = key
        if rows != slice(None) or not isinstance(k, int | np.integer):
            raise IndexError(f"a streamed recording supports [:, k] only, got {key!r}")
        k = int(k)
        if not self._c0 <= k < self._c0 + self.chunk:
            self.flush()
            self._c0 = k - k % self.chunk
        self._buf[:, k - self._c0] = value
        self._top = max(self._top, k)

    def __getitem__(self, key: Any) -> Any:
        if isinstance(key, tuple) and isinstance(key[1], slice):
            return self  # truncation at an early end: the rows not written stay zero
        raise IndexError("a streamed recording is write-only")

    def flush(self) -> None:
        """Write the buffered steps to the file."""
        if self._top < self._c0:
            return
        n = self._top - self._c0 + 1
        steps = self.stream.shapes[self.key][1]
        item = self._row_items * 8
        fd, base = self.stream.files[self.key]
        try:
            for i in range(self.shape[0]):
                data = np.ascontiguousarray(self._buf[i, :n]).tobytes()
                offset = base + ((self.start + i) * steps + self._c0) * item
                while data:
                    written = os.pwrite(fd, data, offset)
                    data, offset = data[written:], offset + written
        except OSError as exc:
            raise OutputError(self.stream.path, exc) from None
        self._buf[:, :n] = 0.0
        self._top = self._c0 - 1


class NpzStream:
    """Trajectories written batch by batch into ``.npy`` files, zipped into one ``.npz``.

    The space is reserved up front (``posix_fallocate``): a full disk fails before the
    simulation starts, as :class:`testbed.io.OutputError` naming the ``.npz``, and every
    temporary is removed. RAM stays bounded by one batch times a few steps; the ``.npz``
    appears atomically.
    """

    def __init__(self, path: str | Path, shapes: dict[str, tuple[int, ...]]):
        self.path = Path(path)
        self.shapes = dict(shapes)
        self.files: dict[str, tuple[int, int]] = {}  # key -> (fd, header bytes)
        self._open: list[FileRows] = []
        self._dir: Path | None = None
        try:
            self._dir = temporary_directory(self.path)
            for key, shape in shapes.items():
                header = io.BytesIO()
                np.lib.format.write_array_header_1_0(header, {
                    "descr": "<f8", "fortran_order": False, "shape": tuple(shape)})
                fd = os.open(self._dir / f"{key}.npy", os.O_RDWR | os.O_CREAT | os.O_EXCL,
                             0o600)
                self.files[key] = (fd, header.tell())
                size = header.tell() + 8 * int(np.prod(shape, dtype=np.int64))
                reserve(fd, size, self.path)
                os.ftruncate(fd, size)
                os.pwrite(fd, header.getvalue(), 0)
        except BaseException as exc:
            self.abort()
            if isinstance(exc, OSError) and not isinstance(exc, OutputError):
                raise OutputError(self.path, exc) from None
            raise

    def rows(self, start: int, stop: int) -> dict[str, FileRows]:
        """Writable rows of runs ``start:stop`` of every array (write them with
        :meth:`flush` after the batch)."""
        self.flush()
        self._open = [FileRows(self, k, start, stop - start) for k in self.shapes]
        return {r.key: r for r in self._open}

    def flush(self) -> None:
        """Write what the rows of the last batch still buffer."""
        for rows in self._open:
            rows.flush()
        self._open = []

    def finish(self, extra: dict[str, np.ndarray]) -> Path:
        """Write the ``.npz`` with the trajectories and the ``extra`` arrays."""
        try:
            self.flush()
            arrays = {k: np.asanyarray(v) for k, v in extra.items()}
            size = sum(os.fstat(fd).st_size for fd, _ in self.files.values())
            size += sum(a.nbytes + 256 for a in arrays.values())
            size += 512 * (len(self.files) + len(arrays)) + 4096  # zip headers
            with atomic_path(self.path) as tmp, open(tmp, "r+b") as f:
                reserve(f, size, self.path)
                with zipfile.ZipFile(f, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
                    for key, (fd, _) in self.files.items():
                        with zf.open(f"{key}.npy", "w", force_zip64=True) as out:
                            os.lseek(fd, 0, os.SEEK_SET)
                            while block := os.read(fd, 1 << 22):
                                out.write(block)
                    for key, value in arrays.items():
                        with zf.open(f"{key}.npy", "w", force_zip64=True) as out:
                            np.lib.format.write_array(out, value, allow_pickle=False)
                f.truncate(f.tell())  # the reserved space beyond the zip's end
        except OutputError:
            raise
        except OSError as exc:
            raise OutputError(self.path, exc) from None
        finally:
            self.abort()
        return self.path

    def abort(self) -> None:
        """Close and remove the temporary files."""
        self._open = []
        for fd, _ in self.files.values():
            with contextlib.suppress(OSError):
                os.close(fd)
        self.files.clear()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
        remove_own_temporaries(self.path)
