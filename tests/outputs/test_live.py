"""Live viewing: the runner's per-step observer and streaming to a Rerun gRPC server."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.outputs.view import rerun_binary

RERUN = Path(sys.executable).with_name("rerun")
ENV = {**os.environ, "RERUN_ANALYTICS": "off"}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    """SIGINT to the process group we started (the ``rerun`` wrapper and its binary)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


def _wait_for_port(port: int, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise TimeoutError(f"nothing listens on port {port}")


@pytest.fixture
def grpc_sink(tmp_path):
    """A local Rerun gRPC server saving what it receives to a file: (url, path)."""
    if not RERUN.exists():
        pytest.skip("the rerun binary is not installed next to this Python")
    port, out = _free_port(), tmp_path / "received.rrd"
    proc = subprocess.Popen([str(RERUN), "--port", str(port), "--save", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV,
                            start_new_session=True)
    try:
        _wait_for_port(port)
        yield f"rerun+http://127.0.0.1:{port}/proxy", out, proc
    finally:
        _stop(proc)


SCENARIO = Scenario(rig="helicopter", duration_s=1.0, seed=3)


def test_on_step_observer_is_bitwise_neutral_and_sees_every_row():
    seen: list[tuple[int, float, np.ndarray, np.ndarray]] = []

    def observe(experiment):
        def on_step(k, row):
            seen.append((k, row["t_s"], row["state"][0].copy(), row["estimate"][0].copy()))
        return on_step

    traj, summary = runner.run(SCENARIO, progress=False)
    traj2, summary2 = runner.run(SCENARIO, progress=False, observe=observe)
    assert summary2 == summary
    for field in ("state", "estimate", "covariance", "measurement", "action", "body_pos"):
        assert np.array_equal(getattr(traj, field), getattr(traj2, field)), field
    assert [k for k, *_ in seen] == list(range(len(traj.t_s)))
    np.testing.assert_array_equal([t for _, t, *_ in seen], traj.t_s)
    np.testing.assert_array_equal(np.array([s for *_, s, _ in seen]), traj.state)
    np.testing.assert_array_equal(np.array([e for *_, e in seen]), traj.estimate)


def test_live_view_streams_the_run_to_a_grpc_server(grpc_sink):
    from testbed.outputs.live import LiveView, open_recording, stop
    from testbed.outputs.rrd_inspect import inspect_rrd, series

    url, out, proc = grpc_sink
    rec, web = open_recording("testbed/helicopter", connect=url)
    assert web is None
    live = LiveView(rec, description="# live test", flush_s=0.0)  # one send per step
    sends_during_run = []

    def observe(experiment):
        on_step = live.attach(experiment)

        def wrapped(k, row):
            on_step(k, row)
            sends_during_run.append(live.sends)
        return wrapped

    traj, _ = runner.run(SCENARIO, progress=False, observe=observe)
    live.close()
    stop(rec)
    time.sleep(1.0)
    _stop(proc)
    n = len(traj.t_s)
    assert sends_during_run == list(range(1, n + 1))  # sent while the rig ran, step by step
    c = inspect_rrd(out)
    assert c.rows["state/pitch/actual"] == n == c.rows["error/yaw/plus_3sigma"]
    assert c.rows["rig/helicopter"] == n and c.rows["rig/helicopter/boom"] == 0
    assert c.chunks["state/pitch/actual"] > 1
    assert c.time_range_s == pytest.approx((0.0, traj.t_s[-1]))
    assert c.texts["about"] == "# live test"
    assert c.styles["state/pitch/actual"]["names"] == ["truth [deg]"]
    t, values = series(out, "state/pitch/estimate")
    np.testing.assert_allclose(t, traj.t_s, atol=1e-9)
    np.testing.assert_allclose(values, np.degrees(traj.estimate[:, 0]), rtol=1e-12)


def test_cli_run_connect(grpc_sink, capsys):
    from testbed.outputs.rrd_inspect import inspect_rrd

    url, out, proc = grpc_sink
    assert main(["run", "vehicle-roll", "--duration", "0.5", "--no-progress",
                 "--connect", url]) == 0
    time.sleep(1.0)
    _stop(proc)
    c = inspect_rrd(out)
    assert c.rows["state/roll/actual"] == 51
    assert c.styles["measurement/lateral_accel"]["names"] == ["measured lateral_accel [m/s^2]"]
    assert "RMSE" in c.texts["about"]  # the description with the run's metrics
    # the final blueprint: error views fitted to the steady state, the description shown
    assert c.view("roll error [deg]").y_range is not None
    from testbed.outputs.viz import time_axis_range

    assert c.view("roll [deg]").time_range_s == pytest.approx(time_axis_range((0.0, 0.5)))
    assert c.view("about") and c.view("rig").eye_position is not None


def test_cli_live_options_are_checked_before_running(capsys):
    assert main(["run", "helicopter", "--connect", "http://localhost:9876"]) == 2
    assert "--connect expects rerun+http://HOST:PORT/proxy" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["run", "helicopter", "--serve", "--spawn"])


def test_cli_run_serve_prints_a_url_and_serves_the_run(tmp_path):
    """``--serve`` on a headless machine: the web viewer answers at the printed URL and a
    viewer connecting to its gRPC server after the run receives the whole run."""
    if not RERUN.exists():
        pytest.skip("the rerun binary is not installed next to this Python")
    from testbed.outputs.rrd_inspect import inspect_rrd

    grpc, web = _free_port(), _free_port()
    env = {**ENV, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    cli = subprocess.Popen([sys.executable, "-m", "testbed.cli", "run", "helicopter",
                            "--duration", "0.5", "--no-progress", "--serve", "--grpc-port",
                            str(grpc), "--web-port", str(web)], stdout=subprocess.PIPE,
                           stderr=subprocess.DEVNULL, text=True, env=env,
                           start_new_session=True)
    client = None
    try:
        lines = []
        for line in cli.stdout:
            lines.append(line)
            if "press Ctrl-C" in line:
                break
        url = next(li for li in lines if li.startswith("Rerun web viewer: open "))
        assert f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}" in url
        import urllib.request

        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10) as r:
            assert r.status == 200
        out = tmp_path / "viewer.rrd"
        client = subprocess.Popen([str(RERUN), f"rerun+http://127.0.0.1:{grpc}/proxy",
                                   "--save", str(out), "--port", str(_free_port())],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                  env=ENV, start_new_session=True)
        deadline = time.monotonic() + 20
        rows = 0
        while time.monotonic() < deadline and rows < 51:
            time.sleep(0.5)
            if out.exists() and out.stat().st_size:
                try:
                    rows = inspect_rrd(out).rows.get("state/pitch/actual", 0)
                except Exception:  # noqa: BLE001 - the file is being written
                    rows = 0
        assert rows == 51
    finally:
        if client is not None:
            _stop(client)
        _stop(cli)


def test_spawn_starts_this_environments_viewer(monkeypatch):
    """``--spawn`` needs a display, so only the call is checked: this environment's
    ``rerun`` binary in its own process group, listening on 127.0.0.1 and the requested
    port, our recording connected to it."""
    from testbed.outputs import live
    from testbed.outputs.live import open_recording, stop

    calls, connected = [], []

    class FakeProc:
        pid, stderr, returncode = -1, None, None

        def poll(self):
            return None

    monkeypatch.setattr(live, "_launch", lambda argv, **kw: calls.append(argv) or FakeProc())
    monkeypatch.setattr(live, "_wait_listening", lambda *a: None)
    import rerun as rr

    monkeypatch.setattr(rr.RecordingStream, "connect_grpc",
                        lambda self, url=None, **kw: connected.append(url))
    port = _free_port()
    rec, url = open_recording("testbed/x", spawn=True, grpc_port=port)
    try:
        assert url is None and calls == [["--bind", "127.0.0.1", "--port", str(port)]]
        assert connected == [f"rerun+http://127.0.0.1:{port}/proxy"]
        assert Path(rerun_binary()).name == "rerun"
    finally:
        stop(rec)
    with pytest.raises(ValueError, match="exactly one"):
        open_recording("testbed/x", spawn=True, serve=True)
    with pytest.raises(ValueError, match="port"):
        open_recording("testbed/x", serve=True, web_port=70000)


def test_live_run_ending_on_a_switching_time_logs_no_setpoint_past_its_end(grpc_sink):
    """The last row's reference (yaw 30 deg from 5 s on) is used by no control step: the
    stream logs the one in force, as the files do; the final blueprint places the legends."""
    from testbed.outputs.axes import held_setpoint
    from testbed.outputs.live import LiveView, open_recording, stop
    from testbed.outputs.rrd_inspect import inspect_rrd, series

    url, out, proc = grpc_sink
    rec, _ = open_recording("testbed/helicopter", connect=url)
    live = LiveView(rec, flush_s=0.5)
    scenario = SCENARIO.replace(duration_s=5.0)
    traj, _ = runner.run(scenario, progress=False, observe=live.attach)
    live.close()
    stop(rec)
    time.sleep(1.0)
    _stop(proc)
    yaw = traj.setpoint_names().index("yaw")
    assert np.degrees(traj.setpoint[-1, yaw]) > 20 > np.degrees(traj.setpoint[-2, yaw])
    t, values = series(out, "setpoint/yaw")
    np.testing.assert_allclose(t, traj.t_s, atol=1e-9)
    np.testing.assert_allclose(values, np.degrees(held_setpoint(traj.setpoint)[:, yaw]))
    assert np.abs(values).max() < 1.0
    views = [v for v in inspect_rrd(out).views if v.name not in ("rig", "about")]
    assert views and all(v.name.endswith("]") and v.legend_visible is not None for v in views)
