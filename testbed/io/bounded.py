"""Files read with a bound: only regular files (never a FIFO, which would wait for a writer,
or a device such as ``/dev/zero``, which never ends), and at most a stated size. Recordings
(:mod:`testbed.io.formats`), mapping files and scenario files are read through here."""

from __future__ import annotations

import os
import stat


def file_kind(mode: int) -> str:
    """What a non-regular file is (``"a FIFO"``, ``"a directory"``...), from ``st_mode``."""
    for test, kind in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a regular file"


def read_bounded(path: str | os.PathLike, limit: int, *, what: str,
                 error: type[ValueError] = ValueError) -> bytes:
    """The bytes of ``path``, a regular file (followed through symbolic links) of at most
    ``limit`` bytes.

    The file is opened without blocking (a FIFO with no writer does not hang), then checked
    on its descriptor: FIFOs, devices, sockets and directories are refused before a byte is
    read; the size is counted as it is read, not trusted (a file that grows past ``limit``
    while being read is refused too).

    Parameters
    ----------
    path : str or PathLike
    limit : int
        Largest size accepted, bytes.
    what : str
        What the file is, for messages (``"recording"``, ``"scenario file"``).
    error : type
        The ``ValueError`` subclass raised.

    Raises
    ------
    ValueError
        (``error``) One line naming the file: it cannot be opened or read, is not a regular
        file, or is larger than ``limit``.
    """
    name = os.fspath(path)
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC  # POSIX
    try:
        fd = os.open(name, flags)
    except FileNotFoundError:
        raise error(f"{name}: no such {what}") from None
    except OSError as exc:
        raise error(f"{name}: cannot read the {what} ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise error(f"{name}: {file_kind(info.st_mode)}; the {what} must be a regular file")
        if info.st_size > limit:  # refused before reading (a sparse file is not read)
            raise error(f"{name}: {info.st_size} bytes, larger than {limit:,} bytes, the limit "
                        f"of a {what}")
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(1 << 24, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > limit:
            raise error(f"{name}: larger than {limit:,} bytes, the limit of a {what}")
        return b"".join(chunks)
    except OSError as exc:
        raise error(f"{name}: cannot read the {what} ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
