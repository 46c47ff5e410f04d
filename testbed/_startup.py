"""What the package does before anything else is imported: the ``testbed`` command's
deferred start-up Ctrl-C, and MuJoCo's OpenGL backend (``MUJOCO_GL``) for headless machines.

Imported first by :mod:`testbed` (so before MuJoCo, Gymnasium or any command module).
"""

from __future__ import annotations

import os
import signal
import sys
import threading

#: Whether this process is the ``testbed`` command (not a library user, not a test calling
#: :func:`testbed.cli.entry.main`).
CLI_PROCESS = os.path.basename(sys.argv[0]) == "testbed" or \
    sys.orig_argv[1:3] == ["-m", "testbed.cli"]


#: Whether a SIGINT arrived while the ``testbed`` command started (see
#: :func:`_quiet_interrupt_at_startup`).
_startup_interrupted = False


def _on_startup_sigint(signum: int, frame: object) -> None:
    """SIGINT while the command starts: remembered (the command ends with 130 when its
    start-up ends); a second one interrupts at once."""
    global _startup_interrupted
    if _startup_interrupted:
        raise KeyboardInterrupt
    _startup_interrupted = True


def _quiet_interrupt_at_startup() -> None:
    """The ``testbed`` command: a Ctrl-C while it starts (importing its modules, before its
    own handling is in place) ends it with exit code 130 and one line, not a traceback.

    The interrupt is deferred to the end of the start-up (:func:`end_of_startup`, well
    under a second later): raised inside an import, an extension module or a ctypes call
    may turn it into another exception (``ImportError: initialization failed``,
    ``ctypes.ArgumentError: argument 1: KeyboardInterrupt``), or the interpreter may print
    and drop it (an import's module-lock callback). A second Ctrl-C interrupts at once; any
    exception after the first still ends the command with 130 and one line."""
    if not CLI_PROCESS:
        return
    if threading.current_thread() is threading.main_thread() \
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _on_startup_sigint)
    previous = sys.excepthook

    def hook(kind: type, value: BaseException, tb: object) -> None:
        if (_startup_interrupted or issubclass(kind, KeyboardInterrupt)) \
                and os.environ.get("TESTBED_DEBUG", "") in ("", "0"):
            sys.stderr.write("testbed: interrupted (SIGINT)\n")
            sys.stderr.flush()
            os._exit(130)
        previous(kind, value, tb)

    sys.excepthook = hook


def end_of_startup() -> bool:
    """The ``testbed`` command's start-up is over: SIGINT raises ``KeyboardInterrupt`` again
    from here on. Returns whether a SIGINT arrived while it started."""
    if threading.current_thread() is threading.main_thread() \
            and signal.getsignal(signal.SIGINT) is _on_startup_sigint:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    return _startup_interrupted


_quiet_interrupt_at_startup()

if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") \
        and "mujoco" not in sys.modules:
    # headless rendering (testbed.outputs.render): MuJoCo picks its OpenGL backend at import
    os.environ.setdefault("MUJOCO_GL", "egl")
#: Why the ``MUJOCO_GL`` given cannot work, when ``import mujoco`` would fail on it (a typo;
#: ``osmesa`` without libOSMesa): it is then replaced by ``disable`` so that simulating still
#: works, and rendering (``--video``, ``render_mode="rgb_array"``) fails with one line saying
#: this.
BAD_MUJOCO_GL: str | None = None


def _check_mujoco_gl() -> None:
    global BAD_MUJOCO_GL
    value = os.environ.get("MUJOCO_GL", "")
    backend = value.lower().strip()
    if backend not in ("", "disable", "disabled", "off", "false", "0", "enable", "enabled",
                       "on", "true", "1", "glfw", "glx", "egl", "osmesa", "wgl", "cgl"):
        BAD_MUJOCO_GL = f"MUJOCO_GL={value!r} is not an OpenGL backend MuJoCo knows"
    elif backend == "osmesa" and sys.platform.startswith("linux"):
        import ctypes.util

        if ctypes.util.find_library("OSMesa") is None:
            BAD_MUJOCO_GL = "MUJOCO_GL='osmesa' but the OSMesa library (libOSMesa) is missing"
    if BAD_MUJOCO_GL is not None:
        os.environ["MUJOCO_GL"] = "disable"


if "mujoco" not in sys.modules:
    _check_mujoco_gl()
