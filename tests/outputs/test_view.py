"""``testbed view``: Rerun's viewer on a recording, and nothing left running afterwards."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main
from testbed.experiment.trajectory import Trajectory
from testbed.outputs import view
from testbed.outputs.viz import write_rrd

RERUN = Path(sys.executable).with_name("rerun")
ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "RERUN_ANALYTICS": "off", "PYTHONPATH": str(ROOT)}

needs_rerun = pytest.mark.skipif(not RERUN.exists(),
                                 reason="the rerun binary is not installed next to this Python")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _processes_showing(path: Path) -> list[int]:
    """Pids of live processes with ``path`` on their command line (launcher and viewer)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if str(path).encode() in cmdline and state != "Z":
            pids.append(int(entry.name))
    return pids


@pytest.fixture
def rrd(tmp_path) -> Path:
    t = np.linspace(0.0, 1.0, 11)
    traj = Trajectory(t_s=t, state=np.c_[np.sin(t)], state_names=["x"],
                      measurement=np.c_[np.sin(t)], measurement_names=["x_meas"],
                      measured_state_index=[0], action=np.zeros((11, 1)), action_names=["u"],
                      estimate=np.c_[np.sin(t) + 0.01], covariance=np.full((11, 1, 1), 1e-4),
                      meta={"units": {"x": "m", "u": "N"}})
    return write_rrd(traj, tmp_path / "run.rrd").resolve()


def test_commands_bind_loopback_only(rrd):
    web = view.viewer_command(rrd, web=True, grpc_port=1234, web_port=5678)
    assert web[0].endswith("rerun") and web[-1] == str(rrd)
    assert web[web.index("--bind") + 1] == "127.0.0.1"
    assert web[web.index("--port") + 1] == "1234"
    assert web[web.index("--web-viewer-port") + 1] == "5678"
    native = view.viewer_command(rrd)
    assert "--web-viewer" not in native and native[-1] == str(rrd)
    assert view.web_url(5678, 1234) == ("http://127.0.0.1:5678/?url="
                                        "rerun%2Bhttp%3A%2F%2F127.0.0.1%3A1234%2Fproxy")


def test_bad_arguments_are_usage_errors(tmp_path, capsys):
    (tmp_path / "x.txt").write_text("x")
    assert main(["view", str(tmp_path / "x.txt")]) == 2
    assert "expects a .rrd file" in capsys.readouterr().err
    assert main(["view", str(tmp_path / "missing.rrd")]) == 2
    assert "no such recording" in capsys.readouterr().err


@needs_rerun
def test_web_view_stops_every_process_it_started_in_process(rrd):
    grpc, web = _free_port(), _free_port()
    printed: list[str] = []
    assert view.view(rrd, web=True, grpc_port=grpc, web_port=web, timeout_s=1.0,
                     echo=printed.append) == 0
    assert printed and view.web_url(web, grpc) in printed[0]
    assert _processes_showing(rrd) == []
    for port in (grpc, web):  # both servers are gone
        with socket.socket() as s:
            assert s.connect_ex(("127.0.0.1", port)) != 0


@needs_rerun
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_cli_web_view_serves_the_file_and_leaves_nothing_behind(rrd, tmp_path, sig):
    """The printed URL answers, a viewer connecting to the gRPC server receives the file,
    and a signal to ``testbed view`` (not to its group) ends every viewer process."""
    grpc, web = _free_port(), _free_port()
    cli = subprocess.Popen([sys.executable, "-m", "testbed.cli", "view", str(rrd), "--web",
                            "--grpc-port", str(grpc), "--web-port", str(web)],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                           env=ENV, start_new_session=True,
                           # a Ctrl-C as from a terminal even when the test runner itself was
                           # started in the background (SIGINT ignored, inherited)
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    client = None
    try:
        line = cli.stdout.readline()
        assert line.startswith(f"open {view.web_url(web, grpc)} in a browser"), line
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=10) as r:
            assert r.status == 200
        assert _processes_showing(rrd)  # the launcher and the viewer are running
        out = tmp_path / "received.rrd"
        client = subprocess.Popen([str(RERUN), f"rerun+http://127.0.0.1:{grpc}/proxy",
                                   "--save", str(out), "--port", str(_free_port())],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                  env=ENV, start_new_session=True)
        from testbed.outputs.rrd_inspect import inspect_rrd

        deadline, rows = time.monotonic() + 20, 0
        while time.monotonic() < deadline and rows < 11:
            time.sleep(0.3)
            try:
                rows = inspect_rrd(out).rows.get("state/x/actual", 0)
            except Exception:  # noqa: BLE001 - not written yet
                rows = 0
        assert rows == 11
        cli.send_signal(sig)
        cli.wait(timeout=20)
        assert cli.returncode in (130, 143)
        assert _processes_showing(rrd) == []
    finally:
        for proc in (client, cli):
            if proc is not None and proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)
        if client is not None:
            try:
                os.killpg(client.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


@needs_rerun
def test_web_view_says_it_is_loading_and_stops_without_claiming_outputs(rrd):
    """After the URL, a line says the page loads (with the recording's size); SIGTERM ends
    the viewer and says so, not 'partial outputs removed' (the command writes nothing)."""
    grpc, web = _free_port(), _free_port()
    cli = subprocess.Popen([sys.executable, "-m", "testbed.cli", "view", str(rrd), "--web",
                            "--grpc-port", str(grpc), "--web-port", str(web)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV,
                           start_new_session=True)
    try:
        first, second = cli.stdout.readline(), cli.stdout.readline()
        assert first.startswith("open http://127.0.0.1:")
        assert second.startswith("loading: ") and " MB)" in second
        with socket.create_connection(("127.0.0.1", grpc), timeout=5):
            # the file's server answers before the URL is printed; a client connected to it
            # is reported (a browser's viewer would be)
            if sys.platform.startswith("linux"):
                third = cli.stdout.readline()
                assert third.startswith("the web viewer has connected"), third
        cli.send_signal(signal.SIGTERM)
        _, err = cli.communicate(timeout=30)
    finally:
        if cli.poll() is None:
            os.killpg(cli.pid, signal.SIGKILL)
            cli.wait()
    assert cli.returncode == 143
    assert err.strip() == "testbed: stopped (SIGTERM)"
    assert _processes_showing(rrd) == []
