"""Live viewing: a run streamed to a Rerun viewer while the rig runs.

Three ways to reach a viewer (:func:`open_recording`):

- ``spawn``: start the native viewer on this machine (needs a display);
- ``connect``: a viewer (or ``rerun --serve-grpc``) already listening, e.g.
  ``rerun+http://127.0.0.1:9876/proxy``;
- ``serve``: this process hosts a gRPC server and Rerun's web viewer; open the printed
  URL in a browser (the way to watch from a headless machine). Data logged before the
  browser connects is buffered by the server.

:class:`LiveView` is the runner's per-step observer (``runner.run(observe=live.attach)``):
it buffers the rows of member 0 as :meth:`testbed.experiment.loop.ClosedLoop.run` produces them and
sends them every ``flush_s`` seconds of wall time (and at the end) with the entity
layout, styles and blueprint of the ``.rrd`` files (:mod:`testbed.outputs.viz`). When the run
ends, the blueprint is sent again with the error views fitted to the steady state and the
legends placed where they hide no data. The last row's setpoint (the reference after the
run's end) is replaced by the one in force, as in the files.
"""

from __future__ import annotations

import os
import sys
import time
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import numpy as np

from testbed.experiment.trajectory import Trajectory
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


def open_recording(application_id: str, *, spawn: bool = False, connect: str | None = None,
                   serve: bool = False, grpc_port: int = GRPC_PORT,
                   web_port: int = WEB_PORT) -> tuple[rr.RecordingStream, str | None]:
    """A recording stream sending to a live viewer.

    Parameters
    ----------
    application_id : str
    spawn : bool
        Start the native viewer (``rerun`` of this Python environment) on ``grpc_port``.
    connect : str, optional
        URL of a running viewer or gRPC server (``rerun+http://HOST:PORT/proxy``).
    serve : bool
        Host a gRPC server on ``grpc_port`` and the web viewer on ``web_port``.
    grpc_port, web_port : int

    Returns
    -------
    recording : rerun.RecordingStream
    url : str or None
        With ``serve``: the web viewer's URL to open in a browser.

    Raises
    ------
    ValueError
        Not exactly one of ``spawn``, ``connect``, ``serve``, or a ``connect`` URL that is
        not ``rerun://``, ``rerun+http://`` or ``rerun+https://`` ending in ``/proxy``.
    """
    if sum([bool(spawn), connect is not None, bool(serve)]) != 1:
        raise ValueError("choose exactly one of --spawn, --connect URL, --serve")
    if connect is not None and (not connect.startswith(("rerun://", "rerun+http://",
                                                        "rerun+https://"))
                                or not connect.rstrip("/").endswith("/proxy")):
        raise ValueError(f"--connect expects rerun+http://HOST:PORT/proxy, got {connect!r}")
    for name, port in (("grpc_port", grpc_port), ("web_port", web_port)):
        if not (isinstance(port, int) and 0 < port < 65536):
            raise ValueError(f"{name} must be a port number (1-65535), got {port!r}")
    import rerun as rr

    rec = new_recording(application_id)
    url = None
    if spawn:
        exe = os.path.join(os.path.dirname(sys.executable), "rerun")
        rr.spawn(port=grpc_port, connect=True, recording=rec,
                 executable_path=exe if os.path.exists(exe) else None)
    elif connect is not None:
        rec.connect_grpc(connect)
    else:
        server = rec.serve_grpc(grpc_port=grpc_port)
        rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=server)
        url = f"http://127.0.0.1:{web_port}/?url={quote(server, safe='')}"
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
        self.rec.flush()

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


def stop(rec: rr.RecordingStream) -> None:
    """Flush and disconnect a live recording (ends a ``serve`` server too)."""
    try:
        rec.flush()
        rec.disconnect()
    finally:
        release_recordings()
