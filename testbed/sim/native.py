"""A MuJoCo control callback in C: ``ctrl`` within a window around the actuator state.

Some rigs limit the input a motor receives by its own state at every physics step, e.g. the
helicopter's amplifier current limit: the voltage reaching a motor stays within
``c act +- r`` (back-EMF ``c act``, ``r = R I_max``). Evaluated in Python, that is one call
per physics step per member, holding the GIL. Here it is MuJoCo's ``mjcb_control``, a C
function compiled once per machine (``cc``) and called by ``mj_forward`` right before the
actuation stage, on the batch's threads, with the same floating-point operations as
:func:`testbed.rigs.helicopter.hardware.current_limited` (``fmin(fmax(u, c a - r), c a + r)``,
no contraction into fused multiply-adds): bitwise the same results.

A model opts in through ``userdata`` (``nuserdata == 1 + 3 nu``): ``[MAGIC, command (nu),
c (nu), r (nu)]``; the simulator writes the command each control step and the constants at
reset. Every other model, and this model's data with ``userdata[0] != MAGIC`` (the rig's own
data, a linearization), is left alone: the callback is process-wide.

:func:`install` returns False when no C compiler is found or another ``mjcb_control`` is
installed; the simulator then evaluates the rig's ``substep_ctrl`` in Python, vectorized
over the members, once per physics step.

Nothing is loaded from a place others can write: the library is built into
``$XDG_CACHE_HOME/testbed`` (default ``~/.cache/testbed``), a directory of this user with
mode 0700 (created so whatever the umask; a group- or world-accessible one is set to 0700 and
emptied of this module's files; one owned by someone else is not used). Beside the library
lies the sha256 of the bytes built; a library whose owner, mode or bytes do not match is
built again, and the bytes checked are the bytes loaded (the open descriptor is what
``dlopen`` gets). When it cannot be built or verified, one warning says so and the Python
hook runs (the same numbers).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import stat
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import mujoco

#: ``userdata[0]`` of a member whose ``ctrl`` the callback sets.
MAGIC = 7357.25

_SOURCE = r"""
#include <math.h>
#include <mujoco/mujoco.h>

#define TESTBED_MAGIC MAGIC_VALUE

void testbed_act_window(const mjModel* m, mjData* d) {
  int nu = m->nu;
  if (m->nuserdata != 1 + 3 * nu || d->userdata[0] != TESTBED_MAGIC) {
    return;
  }
  const mjtNum* command = d->userdata + 1;
  const mjtNum* c = command + nu;
  const mjtNum* r = c + nu;
  for (int i = 0; i < nu; i++) {
    int a = m->actuator_actadr[i];
    if (a < 0) {
      d->ctrl[i] = command[i];
      continue;
    }
    mjtNum back = c[i] * d->act[a];
    mjtNum lo = back - r[i];
    mjtNum hi = back + r[i];
    d->ctrl[i] = fmin(fmax(command[i], lo), hi);
  }
}
""".replace("MAGIC_VALUE", repr(MAGIC))

_lock = threading.Lock()
_callback: object = None  # the installed ctypes function (kept alive), or False: unavailable
_warned = False

#: Name of the compiled library in the cache: ``act_window_<key>.so``, its sha256 beside it.
_PREFIX = "act_window_"


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "testbed"


def _warn(reason: str) -> None:
    """One line on stderr, once per process: why the compiled callback is not used."""
    global _warned
    if not _warned:
        _warned = True
        print(f"testbed: warning: {reason}; the input limit runs in Python (same numbers, "
              "slower)", file=sys.stderr)


def _private(st: os.stat_result) -> bool:
    """Whether ``st`` (an ``lstat``) is this user's and nobody else may write to it."""
    return st.st_uid == os.getuid() and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


def private_directory(path: Path) -> int | None:
    """An open descriptor of ``path`` as a directory only this user can use (mode 0700),
    created or repaired; None when it cannot be one (someone else owns it, it is a symlink or
    not a directory).

    Created with mode 0700 whatever the umask. An existing directory of this user with any
    other mode is set to 0700 and emptied of this module's files, which someone else could
    have written. Later files are opened through the descriptor, so the directory checked is
    the directory used even if its path is replaced meanwhile.

    Parameters
    ----------
    path : Path
        The directory.

    Returns
    -------
    int or None
        The caller closes it.
    """
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.mkdir(path, 0o700)
        except FileExistsError:
            pass
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if st.st_uid != os.getuid():
            os.close(fd)
            return None
        if stat.S_IMODE(st.st_mode) != 0o700:
            os.chmod(fd, 0o700)  # mkdir's mode was masked by the umask, or someone widened it
            for name in os.listdir(fd):
                if name.startswith(_PREFIX):
                    os.unlink(name, dir_fd=fd)
        return fd
    except OSError:
        os.close(fd)
        return None


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _open_private(name: str, dir_fd: int) -> int | None:
    """A descriptor of the regular file ``name`` of ``dir_fd`` when it is this user's and
    nobody else may write to it (not following a symlink); else None."""
    try:
        fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW, dir_fd=dir_fd)
    except OSError:
        return None
    st = os.fstat(fd)
    if stat.S_ISREG(st.st_mode) and _private(st):
        return fd
    os.close(fd)
    return None


def _read(fd: int) -> bytes:
    with os.fdopen(os.dup(fd), "rb") as file:
        file.seek(0)
        return file.read()


def _verified(name: str, dir_fd: int) -> int | None:
    """An open descriptor of the library ``name`` (in ``dir_fd``) when it and its digest
    file are private (:func:`_open_private`) and its bytes have the stored sha256; None
    otherwise. The descriptor is what gets loaded, so the bytes checked are the bytes run."""
    stored_fd = _open_private(f"{name}.sha256", dir_fd)
    if stored_fd is None:
        return None
    try:
        stored = _read(stored_fd).decode("ascii", "replace").strip()
    finally:
        os.close(stored_fd)
    fd = _open_private(f"{name}.so", dir_fd)
    if fd is not None and _digest(_read(fd)) != stored:
        os.close(fd)
        fd = None
    return fd


def _write_private(name: str, data: bytes, mode: int, dir_fd: int) -> None:
    """``data`` as the file ``name`` of ``dir_fd`` with ``mode``: a new temporary file
    renamed (concurrent processes build the same file)."""
    tmp = f".{name}.{os.getpid()}.{threading.get_ident()}.tmp"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW,
                 mode, dir_fd=dir_fd)
    try:
        with os.fdopen(fd, "wb") as file:
            file.write(data)
        os.replace(tmp, name, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
    except BaseException:
        os.unlink(tmp, dir_fd=dir_fd)
        raise


def _build(compiler: str, name: str, dir_fd: int) -> None:
    """Compile the callback (in a private temporary directory) and store it as ``name.so``
    with its sha256 as ``name.sha256`` in ``dir_fd``."""
    include = Path(mujoco.__file__).parent / "include"
    with tempfile.TemporaryDirectory(prefix="testbed-cc-") as tmp:
        src, out = Path(tmp) / "act_window.c", Path(tmp) / "act_window.so"
        src.write_text(_SOURCE)
        subprocess.run([compiler, "-O2", "-ffp-contract=off", "-fno-fast-math", "-shared",
                        "-fPIC", f"-I{include}", str(src), "-o", str(out)],
                       check=True, capture_output=True, timeout=120)
        data = out.read_bytes()
    _write_private(f"{name}.so", data, 0o700, dir_fd)
    _write_private(f"{name}.sha256", (_digest(data) + "\n").encode(), 0o600, dir_fd)


def _load() -> ctypes.CDLL | None:
    """The compiled library, loaded: from the cache when it verifies, else built again
    (None, with one warning, when it cannot be built, verified or loaded)."""
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        return None
    key = hashlib.sha256(f"{_SOURCE}{mujoco.__version__}{sys.platform}".encode()).hexdigest()
    name = f"{_PREFIX}{key[:16]}"
    dir_fd = private_directory(_cache_dir())
    if dir_fd is None:
        _warn(f"the cache directory {_cache_dir()} is not a private directory of this user")
        return None
    try:
        fd = _verified(name, dir_fd)
        if fd is None:
            try:
                for stale in (f"{name}.so", f"{name}.sha256"):
                    try:
                        os.unlink(stale, dir_fd=dir_fd)
                    except FileNotFoundError:
                        pass
                _build(compiler, name, dir_fd)
            except (OSError, subprocess.SubprocessError) as exc:
                _warn(f"the compiled input limit could not be built in {_cache_dir()} "
                      f"({exc})")
                return None
            fd = _verified(name, dir_fd)
            if fd is None:
                _warn(f"the compiled input limit in {_cache_dir()} does not verify after "
                      "building")
                return None
    finally:
        os.close(dir_fd)
    try:
        proc = f"/proc/self/fd/{fd}"
        return ctypes.CDLL(proc if os.path.exists(proc) else str(_cache_dir() / f"{name}.so"))
    except OSError as exc:
        _warn(f"the compiled input limit does not load ({exc})")
        return None
    finally:
        os.close(fd)


def install() -> bool:
    """Install the callback as MuJoCo's ``mjcb_control`` (once per process); whether it is
    installed."""
    global _callback
    with _lock:
        if _callback is None:
            _callback = False
            if os.environ.get("TESTBED_NO_NATIVE") or mujoco.get_mjcb_control() is not None:
                return False
            lib = _load()
            if lib is None:
                return False
            try:
                fn = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)(
                    ("testbed_act_window", lib))
            except AttributeError:  # the digest matched a library without the symbol
                _warn("the compiled input limit has no testbed_act_window")
                return False
            mujoco.set_mjcb_control(fn)
            _callback = (lib, fn)
            return True
        if _callback is False:
            return False
        return mujoco.get_mjcb_control() is _callback[1]


def installed() -> bool:
    """Whether the callback is MuJoCo's ``mjcb_control`` now (another one may have replaced
    it since :func:`install`)."""
    return bool(_callback) and mujoco.get_mjcb_control() is _callback[1]
