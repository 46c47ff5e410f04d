"""Live viewing: a run streamed to a Rerun viewer while the rig runs.

Three ways to reach a viewer (:func:`open_recording`):

- ``spawn``: start the native viewer on this machine (needs a display);
- ``connect``: a viewer (or ``rerun --serve-grpc``) already listening, e.g.
  ``rerun+http://127.0.0.1:9876/proxy``;
- ``serve``: start Rerun's gRPC server and web viewer (``rerun --serve-web``, a child
  process in its own process group, stopped with the run's end of serving); open the
  printed URL in a browser (the way to watch from a headless machine). Data logged before
  the browser connects is buffered by the server.

What is started listens on ``127.0.0.1`` only (``bind``; the CLI's ``--bind ADDRESS``): to
be reached from other machines, bind another address (``0.0.0.0``: every interface; the CLI
warns), or forward the ports (``ssh -L 9090:localhost:9090 -L 9876:localhost:9876``).

:class:`LiveView` is the runner's per-step observer (``runner.run(observe=live.attach)``):
it buffers the rows of member 0 as :meth:`testbed.experiment.loop.ClosedLoop.run` produces them and
sends them every ``flush_s`` seconds of wall time (and at the end) with the entity
layout, styles and blueprint of the ``.rrd`` files (:mod:`testbed.outputs.viz`). When the run
ends, the blueprint is sent again with the error views fitted to the steady state and the
legends placed where they hide no data. The last row's setpoint (the reference after the
run's end) is replaced by the one in force, as in the files.
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import signal
import socket
import subprocess
import sys
import time
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import numpy as np

from testbed.experiment.trajectory import Trajectory
from testbed.outputs.view import parent_death_preexec
from testbed.outputs.viz import (
    Layout,
    log_static,
    new_recording,
    release_recordings,
    send_rig_poses,
    send_series,
)

if TYPE_CHECKING:  # pragma: no cover - typing only
    import rerun as rr

    from testbed.experiment.runner import Experiment

#: Default ports of Rerun's gRPC server and web viewer.
GRPC_PORT, WEB_PORT = 9876, 9090
#: Address the servers listen on unless told otherwise (``--bind``): this machine only.
DEFAULT_BIND = "127.0.0.1"
#: Seconds to wait for a started viewer or server to listen.
START_TIMEOUT_S = 30.0
#: Seconds to wait for a viewer to take the buffered data (at the end of a run).
FLUSH_TIMEOUT_S = 15.0
#: The viewer or server processes this process started, by recording.
_CHILDREN: dict[int, subprocess.Popen] = {}


def check_bind(address: str) -> tuple[str, bool]:
    """``(address, loopback)`` of a ``--bind`` address (an IPv4 or IPv6 address).

    Raises
    ------
    ValueError
        Not an IP address (names are refused: a name may resolve to another interface).
    """
    try:
        ip = ipaddress.ip_address(str(address).strip().strip("[]"))
    except ValueError:
        raise ValueError(f"--bind expects an IP address such as 127.0.0.1, ::1 or 0.0.0.0, "
                         f"got {address!r}") from None
    return str(ip), ip.is_loopback


def _host(address: str) -> str:
    """The host to reach a server bound to ``address`` from this machine (for URLs)."""
    ip = ipaddress.ip_address(address)
    if ip.is_unspecified:
        return "127.0.0.1" if ip.version == 4 else "[::1]"
    return str(ip) if ip.version == 4 else f"[{ip}]"


def _launch(argv: list[str], *, outlive: bool = False) -> subprocess.Popen:
    """Start a Rerun process in its own process group (stopped as a whole by :func:`stop`;
    a Ctrl-C in the terminal reaches this process, which stops it). Unless ``outlive`` (a
    native viewer), it also ends when this process dies."""
    from testbed.outputs.view import rerun_binary  # (the binary, not the launcher script:
    # stopping it stops the server)

    env = {**os.environ, "RERUN_ANALYTICS": os.environ.get("RERUN_ANALYTICS", "off")}
    return subprocess.Popen([rerun_binary(), *argv], stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                            start_new_session=True,
                            preexec_fn=None if outlive else parent_death_preexec())


def _wait_listening(proc: subprocess.Popen, host: str, ports: list[int], what: str) -> None:
    """Wait until something accepts connections on every port (or the process ends)."""
    deadline = time.monotonic() + START_TIMEOUT_S
    pending = list(ports)
    while pending:
        if proc.poll() is not None:
            err = (proc.stderr.read() if proc.stderr else b"").decode(errors="replace")
            last = [line for line in err.splitlines() if line.strip()][-1:] or ["no output"]
            raise ValueError(f"{what} did not start (exit code {proc.returncode}): "
                             f"{last[0].strip()[:300]}")
        with socket.socket(socket.AF_INET6 if host.startswith("[") else socket.AF_INET) as s:
            s.settimeout(0.5)
            if s.connect_ex((host.strip("[]"), pending[0])) == 0:
                pending.pop(0)
                continue
        if time.monotonic() > deadline:
            _terminate(proc)
            raise ValueError(f"{what} does not listen on port {pending[0]} after "
                             f"{START_TIMEOUT_S:g} s")
        time.sleep(0.05)


def _terminate(proc: subprocess.Popen) -> None:
    """Stop the process group of ``proc`` (SIGTERM, then SIGKILL after 5 s)."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)
    if proc.stderr is not None:
        proc.stderr.close()


def open_recording(application_id: str, *, spawn: bool = False, connect: str | None = None,
                   serve: bool = False, grpc_port: int = GRPC_PORT,
                   web_port: int = WEB_PORT,
                   bind: str = DEFAULT_BIND) -> tuple[rr.RecordingStream, str | None]:
    """A recording stream sending to a live viewer.

    Parameters
    ----------
    application_id : str
    spawn : bool
        Start the native viewer (``rerun`` of this Python environment) listening on
        ``bind:grpc_port``.
    connect : str, optional
        URL of a running viewer or gRPC server (``rerun+http://HOST:PORT/proxy``).
    serve : bool
        Start Rerun's gRPC server on ``bind:grpc_port`` and its web viewer on
        ``bind:web_port`` (a child process, stopped by :func:`stop`).
    grpc_port, web_port : int
    bind : str
        The IP address the started viewer or server listens on: ``127.0.0.1`` (this machine
        only) unless another is given (``0.0.0.0``: every interface).

    Returns
    -------
    recording : rerun.RecordingStream
    url : str or None
        With ``serve``: the web viewer's URL to open in a browser.

    Raises
    ------
    ValueError
        Not exactly one of ``spawn``, ``connect``, ``serve``, a ``connect`` URL that is
        not ``rerun://``, ``rerun+http://`` or ``rerun+https://`` ending in ``/proxy``, a bad
        port or address, or a viewer that did not start (a port in use).
    """
    if sum([bool(spawn), connect is not None, bool(serve)]) != 1:
        raise ValueError("choose exactly one of --spawn, --connect URL, --serve")
    if connect is not None and (not connect.startswith(("rerun://", "rerun+http://",
                                                        "rerun+https://"))
                                or not connect.rstrip("/").endswith("/proxy")):
        raise ValueError(f"--connect expects rerun+http://HOST:PORT/proxy, got {connect!r}")
    for name, port in (("--grpc-port", grpc_port), ("--web-port", web_port)):
        if not (isinstance(port, int) and 0 < port < 65536):
            raise ValueError(f"{name} must be a port number (1-65535), got {port!r}")
    address, _ = check_bind(bind)
    url = None
    if connect is not None:
        rec = new_recording(application_id)
        rec.connect_grpc(connect)
        return rec, url
    host = _host(address)
    if spawn:
        proc = _launch(["--bind", address, "--port", str(grpc_port)], outlive=True)
        what = f"the Rerun viewer (--grpc-port {grpc_port})"
        ports = [grpc_port]
    else:
        proc = _launch(["--serve-web", "--bind", address, "--port", str(grpc_port),
                        "--web-viewer-port", str(web_port)])
        what = f"the Rerun server (--grpc-port {grpc_port}, --web-port {web_port})"
        ports = [grpc_port, web_port]
    try:
        _wait_listening(proc, host, ports, what)
        rec = new_recording(application_id)
        server = f"rerun+http://{host}:{grpc_port}/proxy"
        rec.connect_grpc(server)
    except BaseException:
        _terminate(proc)
        raise
    if serve:
        _CHILDREN[id(rec)] = proc
        url = f"http://{host}:{web_port}/?url={quote(server, safe='')}"
    elif proc.stderr is not None:  # the native viewer outlives the run: let it be
        proc.stderr.close()
    return rec, url


class LiveView:
    """Per-step observer streaming member 0 of a run to a recording.

    Parameters
    ----------
    rec : rerun.RecordingStream
        From :func:`open_recording` (or any sink).
    description : str, optional
        Markdown logged as ``about`` (default: the scenario, from
        :func:`testbed.outputs.viz.run_description`).
    flush_s : float
        Wall time between two sends (0: every step).
    degrees : bool
        Angles in degrees, as in the ``.rrd`` files.
    """

    def __init__(self, rec: rr.RecordingStream, *, description: str | None = None,
                 flush_s: float = 0.05, degrees: bool = True):
        if not (np.isfinite(flush_s) and flush_s >= 0):
            raise ValueError(f"flush_s must be >= 0, got {flush_s}")
        self.rec, self.description, self.flush_s, self.degrees = rec, description, flush_s, \
            degrees
        self.layout: Layout | None = None
        self.sent_rows = 0
        self.sends = 0
        self._empty: Trajectory | None = None
        self._model: Any = None
        self._duration_s = 0.0
        self._rows: list[dict[str, Any]] = []
        self._history: dict[str, list[np.ndarray]] = {
            "t_s": [], "state": [], "estimate": [], "covariance": [], "measurement": [],
            "action": [], "setpoint": []}
        self._dt_s = 0.0
        self._last_send = 0.0

    # -- the runner's hook
    def attach(self, experiment: Experiment) -> LiveView:
        """``observe`` of :func:`testbed.experiment.runner.run`: set up from the built experiment,
        send the static part and the blueprint, return the per-step observer (self)."""
        sim = experiment.loop.sim
        rig, sensors = sim.rig, sim.sensors
        n = rig.n_states
        has_p = experiment.loop.stage.estimator.P is not None
        self._empty = Trajectory(
            t_s=np.zeros(0), state=np.zeros((0, n)), state_names=list(rig.state_names),
            measurement=np.zeros((0, sensors.dim)), measurement_names=list(sensors.names),
            measured_state_index=list(sensors.measured_state),
            action=np.zeros((0, rig.n_actions)),
            action_names=[f"{a} [{u}]" for a, u in zip(rig.action_names, rig.action_units,
                                                        strict=True)],
            estimate=np.zeros((0, n)), covariance=np.zeros((0, n, n)) if has_p else None,
            setpoint=np.zeros((0, len(rig.tracked_states))),
            meta=dict(experiment.meta, setpoint_names=list(rig.tracked_states)))
        self._model = rig.model
        self._duration_s = float(experiment.scenario.duration_s)
        self._dt_s = float(sim.dt_s)
        if self.description is None:
            from testbed.outputs.viz import run_description

            self.description = run_description(experiment.meta)
        self.layout = Layout.of(self._empty, degrees=self.degrees)
        log_static(self.rec, self.layout, model=self._model, description=self.description)
        self.rec.send_blueprint(self._blueprint(None), make_active=True, make_default=True)
        self._last_send = time.perf_counter()
        return self

    def __call__(self, k: int, row: dict[str, Any]) -> None:
        """Buffer member 0 of ``row`` (copied); send when ``flush_s`` has passed."""
        if self.layout is None:
            raise RuntimeError("LiveView.attach(experiment) must run before the first step")
        one = {key: np.array(value[0]) for key, value in row.items()
               if key != "t_s" and value is not None}
        one["t_s"] = float(row["t_s"])
        h = self._history
        if (h["setpoint"] and "setpoint" in one
                and one["t_s"] >= self._duration_s - 0.5 * self._dt_s):
            # the last row's reference is the NEXT setpoint, used by no control step
            one["setpoint"] = h["setpoint"][-1].copy()
        self._rows.append(one)
        for key in ("measurement", "action", "setpoint"):
            if key in one:
                h[key].append(one[key])
        self._history["t_s"].append(one["t_s"])
        self._history["state"].append(one["state"])
        self._history["estimate"].append(one["estimate"])
        if "covariance" in one:
            self._history["covariance"].append(np.diagonal(one["covariance"]).copy())
        if time.perf_counter() - self._last_send >= self.flush_s:
            self.send()

    def send(self) -> None:
        """Send the buffered rows now."""
        if not self._rows:
            return
        rows, self._rows = self._rows, []
        stack = {key: np.stack([r[key] for r in rows]) for key in rows[0]}
        empty = self._empty
        chunk = Trajectory(
            t_s=stack["t_s"], state=stack["state"], state_names=empty.state_names,
            measurement=stack["measurement"], measurement_names=empty.measurement_names,
            measured_state_index=empty.measured_state_index, action=stack["action"],
            action_names=empty.action_names, estimate=stack["estimate"],
            covariance=stack.get("covariance") if empty.covariance is not None else None,
            setpoint=stack["setpoint"], meta=empty.meta)
        send_series(self.rec, self.layout, chunk)
        if "body_pos" in stack:
            send_rig_poses(self.rec, self._model, self.layout.prefix, stack["t_s"],
                           stack["body_pos"], stack["body_quat_wxyz"])
        self.sent_rows += len(rows)
        self.sends += 1
        self._last_send = time.perf_counter()

    def close(self, description: str | None = None) -> None:
        """Send what is left, the final blueprint (error views fitted to the steady state)
        and, if given, a new description (e.g. with the run's metrics); flush."""
        import rerun as rr

        self.send()
        if description:
            self.description = description
            self.rec.log("about", rr.TextDocument(description, media_type=rr.MediaType.MARKDOWN),
                         static=True)
        if self.layout is not None and self._history["t_s"]:
            self.rec.send_blueprint(self._blueprint(self._final_trajectory()),
                                    make_active=True, make_default=True)
        flush(self.rec)

    # -- helpers
    def _final_trajectory(self) -> Trajectory:
        h, empty = self._history, self._empty
        t = np.asarray(h["t_s"])
        n = len(empty.state_names)
        cov = None
        if h["covariance"]:
            var = np.asarray(h["covariance"])
            cov = np.zeros((len(t), n, n))
            cov[:, np.arange(n), np.arange(n)] = var
        def rows(key: str, like: np.ndarray) -> np.ndarray:
            return np.asarray(h[key]) if h[key] else np.zeros((len(t), like.shape[1]))

        return Trajectory(t_s=t, state=np.asarray(h["state"]), state_names=empty.state_names,
                          measurement=rows("measurement", empty.measurement),
                          measurement_names=empty.measurement_names,
                          measured_state_index=empty.measured_state_index,
                          action=rows("action", empty.action), action_names=empty.action_names,
                          estimate=np.asarray(h["estimate"]), covariance=cov,
                          setpoint=rows("setpoint", empty.setpoint), meta=empty.meta)

    def _blueprint(self, traj: Trajectory | None) -> Any:
        """The live layout: time axes over the scenario's duration; error views fitted
        to the data of ``traj`` when given (auto range before)."""
        import rerun.blueprint as rrb

        from testbed.outputs.viz_rig import rig_camera

        limits = None if traj is None else self.layout.error_limits(traj)
        legends = None if traj is None else self.layout.legends(traj, limits)
        container = self.layout.container(
            camera=rig_camera(self._model), with_rig=True, with_about=bool(self.description),
            time_range_s=(0.0, self._duration_s), error_limits=limits, legends=legends)
        return rrb.Blueprint(container, rrb.TimePanel(timeline="time"), collapse_panels=False)


def flush(rec: rr.RecordingStream, timeout_s: float = FLUSH_TIMEOUT_S) -> bool:
    """Send what the recording buffers, waiting at most ``timeout_s`` (a viewer that went
    away, e.g. a native viewer without a display, would block forever); False, with a
    warning on stderr, when it did not go through."""
    try:
        rec.flush(timeout_sec=timeout_s)
    except Exception as exc:  # noqa: BLE001 - rerun raises its own on a timeout
        print(f"testbed: warning: the live viewer did not take the data within {timeout_s:g} "
              f"s ({type(exc).__name__}: {' '.join(str(exc).split())[:200]}); is it still "
              "running?", file=sys.stderr, flush=True)
        return False
    return True


def stop(rec: rr.RecordingStream) -> None:
    """Flush and disconnect a live recording; stop the server :func:`open_recording` started
    for it with ``serve`` (its whole process group)."""
    proc = _CHILDREN.pop(id(rec), None)
    try:
        flush(rec)
        rec.disconnect()
    finally:
        try:
            if proc is not None:
                _terminate(proc)
        finally:
            release_recordings()
