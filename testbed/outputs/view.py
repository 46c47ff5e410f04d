"""``testbed view FILE.rrd [--web]``: open a recording in Rerun's viewer, leave nothing behind.

:func:`view` starts the viewer binary itself (:func:`rerun_binary`, not the ``rerun`` console
script, a launcher that would start it as a grandchild) in a process group of its own (a
new session) and, when it returns for any reason (the viewer closed, Ctrl-C, SIGTERM, an
error), terminates the whole group: first SIGTERM, then SIGKILL for what is left after
:data:`GRACE_S` seconds. On Linux the viewer also gets SIGTERM when this process dies, even
by SIGKILL (:func:`parent_death_preexec`). No viewer, web server or gRPC server outlives the
command.

- native (default): the desktop viewer opens the file (needs a display);
- ``web=True``: for a headless machine. Rerun hosts its web viewer and a gRPC server that
  serves the file, both bound to ``127.0.0.1`` only (reach them from another machine
  through an SSH tunnel, e.g. ``ssh -L 9090:127.0.0.1:9090 -L 9876:127.0.0.1:9876 HOST``);
  the URL to open in a browser is printed once the web server answers.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from urllib.parse import quote

#: Default ports of the gRPC server and the web viewer (as for live viewing).
GRPC_PORT, WEB_PORT = 9876, 9090
#: Loopback only: the web viewer and its gRPC server are never bound to other interfaces.
BIND = "127.0.0.1"
#: Seconds between SIGTERM and SIGKILL of the viewer's process group.
GRACE_S = 3.0
#: Seconds to wait for the web server to answer before giving up.
START_TIMEOUT_S = 30.0


#: ``prctl`` option: the signal a process gets when its parent dies (Linux).
_PR_SET_PDEATHSIG = 1


def rerun_binary() -> str:
    """The Rerun viewer binary of this Python environment (the binary itself, not the
    ``rerun`` launcher script, so that stopping it stops the servers); else the launcher of
    this environment, else ``rerun`` on ``PATH``.

    Raises
    ------
    ValueError
        No Rerun viewer is installed.
    """
    try:
        import rerun_cli

        binary = os.path.join(os.path.dirname(rerun_cli.__file__), "rerun")
        if os.path.isfile(binary) and os.access(binary, os.X_OK):
            return binary
    except ImportError:
        pass
    script = Path(sys.executable).with_name("rerun")
    if script.exists():
        return str(script)
    found = shutil.which("rerun")
    if found is None:
        raise ValueError("the Rerun viewer ('rerun', from rerun-sdk) is not installed")
    return found


def parent_death_preexec(sig: int = signal.SIGTERM) -> Callable[[], None] | None:
    """On Linux, a ``preexec_fn`` for :class:`subprocess.Popen` giving the child ``sig`` when
    this process dies (even by SIGKILL; ``prctl(PR_SET_PDEATHSIG)``, kept across ``exec``);
    a child whose parent died before the call ends at once. None elsewhere.

    The signal comes when the thread that started the child ends: start children from a
    thread that lives as long as they should (the main thread).
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up before the fork
    except (OSError, AttributeError):
        return None
    parent = os.getpid()

    def preexec() -> None:
        prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        if os.getppid() != parent:  # the parent died before the signal was armed
            os._exit(1)

    return preexec


def web_url(web_port: int = WEB_PORT, grpc_port: int = GRPC_PORT) -> str:
    """The address of the web viewer showing the served file."""
    proxy = f"rerun+http://{BIND}:{grpc_port}/proxy"
    return f"http://{BIND}:{web_port}/?url={quote(proxy, safe='')}"


def viewer_command(path: str | os.PathLike, *, web: bool = False, grpc_port: int = GRPC_PORT,
                   web_port: int = WEB_PORT) -> list[str]:
    """The command line that shows ``path`` (the native viewer, or the web viewer)."""
    cmd = [rerun_binary()]
    if web:
        cmd += ["--web-viewer", "--bind", BIND, "--port", str(grpc_port),
                "--web-viewer-port", str(web_port)]
    return [*cmd, str(Path(path).resolve())]


def _check(path: str | os.PathLike, ports: tuple[int, ...]) -> Path:
    p = Path(path)
    if p.suffix != ".rrd":
        raise ValueError(f"testbed view expects a .rrd file, got {str(path)!r}")
    if not p.exists():
        raise ValueError(f"no such recording: {str(path)!r}")
    if not p.is_file():  # a directory, a FIFO, a device (through a symbolic link or not)
        raise ValueError(f"{str(path)!r} is not a regular file; testbed view expects a .rrd "
                         "recording file")
    for port in ports:
        if not (isinstance(port, int) and 0 < port < 65536):
            raise ValueError(f"ports must be numbers 1-65535, got {port!r}")
    return p


def loading_note(path: str | os.PathLike) -> str:
    """What the page shows while it loads: the browser downloads and compiles Rerun's web
    viewer, then streams the recording from the gRPC server; until then the page shows
    Rerun's welcome screen (measured: 45 s, the recording after 90 s on a busy two-core
    machine in headless Chromium)."""
    size_mb = Path(path).stat().st_size / 1e6
    return (f"loading: the page shows Rerun's welcome screen until the web viewer has "
            f"started and received the recording ({size_mb:.1f} MB); this can take a minute "
            "or two on a busy machine. Keep this command running while you look.")


def _answers(port: int) -> bool:
    try:
        with socket.create_connection((BIND, port), timeout=0.2):
            return True
    except OSError:
        return False


def _group_gone(proc: subprocess.Popen, wait_s: float) -> bool:
    deadline = time.monotonic() + wait_s
    while True:
        proc.poll()  # reap the leader: a zombie still counts as a member of its group
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)


def stop_group(proc: subprocess.Popen, grace_s: float = GRACE_S) -> None:
    """Terminate the process group led by ``proc`` (SIGTERM, then SIGKILL) and reap it."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:  # the group is gone
            break
        if _group_gone(proc, grace_s):
            break
    try:
        proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:  # pragma: no cover - SIGKILL not delivered
        pass


def _wait_until_served(proc: subprocess.Popen, port: int, what: str,
                       deadline: float) -> None:
    """Wait until the viewer ``proc`` answers on ``port``; ``OSError`` if it exits first or
    the monotonic ``deadline`` passes."""
    while not _answers(port):
        if proc.poll() is not None:
            raise OSError(f"the Rerun viewer exited with code {proc.returncode} before "
                          "serving")
        if time.monotonic() > deadline:
            raise OSError(f"the Rerun {what} did not answer on port {port} within "
                          f"{START_TIMEOUT_S:g} s")
        time.sleep(0.1)


def view(path: str | os.PathLike, *, web: bool = False, grpc_port: int = GRPC_PORT,
         web_port: int = WEB_PORT, timeout_s: float | None = None,
         echo: Callable[[str], None] = print) -> int:
    """Show a recording until the viewer closes (or ``timeout_s``, or an interrupt).

    Parameters
    ----------
    path : str or PathLike
        A ``.rrd`` file.
    web : bool
        Host the web viewer on ``127.0.0.1:web_port`` (and the file on
        ``127.0.0.1:grpc_port``) and print its URL instead of opening a window.
    grpc_port, web_port : int
    timeout_s : float, optional
        Stop after this many seconds (tests, demos); default: until the viewer ends.
    echo : callable
        Where the URL and the messages go.

    Returns
    -------
    int
        The viewer's exit code (0 when stopped by ``timeout_s``).

    Raises
    ------
    ValueError
        Not an existing ``.rrd`` file, or a bad port.
    OSError
        The viewer could not start, or a port is taken.
    """
    p = _check(path, (grpc_port, web_port))
    if web:
        for port in (grpc_port, web_port):
            if _answers(port):
                raise OSError(f"port {port} on {BIND} is in use (choose another with "
                              "--grpc-port / --web-port)")
    env = {**os.environ, "RERUN_ANALYTICS": os.environ.get("RERUN_ANALYTICS", "off")}
    proc = subprocess.Popen(viewer_command(p, web=web, grpc_port=grpc_port, web_port=web_port),
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True, env=env,
                            preexec_fn=parent_death_preexec())
    try:
        if web:
            deadline = time.monotonic() + START_TIMEOUT_S
            _wait_until_served(proc, web_port, "web viewer", deadline)
            # the file's server: the recording is being read
            _wait_until_served(proc, grpc_port, "gRPC server", deadline)
            echo(f"open {web_url(web_port, grpc_port)} in a browser (Ctrl-C stops the viewer)")
            echo(loading_note(p))
        if not web:
            try:
                return proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                return 0
        return _serve(proc, web_port, grpc_port, timeout_s, echo)
    finally:
        stop_group(proc)


def _serve(proc: subprocess.Popen, web_port: int, grpc_port: int, timeout_s: float | None,
           echo: Callable[[str], None]) -> int:
    """Wait for the web viewer to end, saying when a browser opened the page and when its
    viewer connected to the file's server (:func:`connections`, where it can be known)."""
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    said = set()
    while True:
        try:
            return proc.wait(timeout=POLL_S)
        except subprocess.TimeoutExpired:
            pass
        if deadline is not None and time.monotonic() > deadline:
            return 0
        if "viewer" in said:
            continue
        if "page" not in said and connections(web_port) > 0:
            said.add("page")
            echo("the page is open: the browser is loading Rerun's web viewer")
        if connections(grpc_port) > 0:
            said.add("viewer")
            echo("the web viewer has connected: the recording streams in and shows when "
                 "loaded")


#: Seconds between the checks of :func:`_serve`.
POLL_S = 0.5
#: ``/proc/net`` state code of an established TCP connection.
_ESTABLISHED = "01"


def connections(port: int) -> int:
    """Established TCP connections whose local port is ``port`` (Linux: ``/proc/net/tcp``
    and ``tcp6``); 0 where it cannot be known."""
    count = 0
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(table) as f:
                next(f, None)
                for line in f:
                    fields = line.split()
                    if len(fields) > 3 and fields[3] == _ESTABLISHED \
                            and int(fields[1].rsplit(":", 1)[1], 16) == port:
                        count += 1
        except (OSError, ValueError, IndexError):
            continue
    return count
