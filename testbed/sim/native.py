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
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
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


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "testbed"


def _compile() -> Path | None:
    """The shared library, compiled on first use (None without a C compiler)."""
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        return None
    include = Path(mujoco.__file__).parent / "include"
    key = hashlib.sha256(f"{_SOURCE}{mujoco.__version__}{sys.platform}".encode()).hexdigest()
    try:
        out = _cache_dir() / f"act_window_{key[:16]}.so"
        if out.exists():
            return out
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
            src, lib = Path(tmp) / "act_window.c", Path(tmp) / "act_window.so"
            src.write_text(_SOURCE)
            subprocess.run([compiler, "-O2", "-ffp-contract=off", "-fno-fast-math", "-shared",
                            "-fPIC", f"-I{include}", str(src), "-o", str(lib)],
                           check=True, capture_output=True, timeout=120)
            os.replace(lib, out)  # atomic: concurrent processes compile the same file
        return out
    except (OSError, subprocess.SubprocessError):
        return None


def install() -> bool:
    """Install the callback as MuJoCo's ``mjcb_control`` (once per process); whether it is
    installed."""
    global _callback
    with _lock:
        if _callback is None:
            _callback = False
            if os.environ.get("TESTBED_NO_NATIVE") or mujoco.get_mjcb_control() is not None:
                return False
            path = _compile()
            if path is None:
                return False
            try:
                lib = ctypes.CDLL(str(path))
            except OSError:
                return False
            fn = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)(
                ("testbed_act_window", lib))
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
