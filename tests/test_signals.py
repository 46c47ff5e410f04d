"""Signals end the work, every process of it (issue 37, item 3): SIGINT/SIGTERM to a study
with workers cancels it within seconds and leaves no process; SIGKILL of the parent takes its
workers and viewers with it; the temporary design directory of ``score`` is removed, or
cleaned by the next call."""

from __future__ import annotations

import importlib
import importlib.util
import json
import math
import operator
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

from testbed.cli.parser import COMMON_DEFAULTS
from testbed.experiment import backend
from testbed.score import harness

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "RERUN_ANALYTICS": "off"}
#: A study that runs for a minute or more on two workers (it is always stopped early).
LONG_MC = ["mc", "helicopter", "--runs", "400", "--duration", "10", "--workers", "2",
           "--backend", "local", "--no-progress"]


# ----------------------------------------------------------------------- helpers
def _session(sid: int) -> list[tuple[int, int, str]]:
    """``(pid, ppid, command line)`` of the live (not zombie) processes of session ``sid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            fields = stat[stat.rindex(")") + 2:].split()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, ValueError):
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            found.append((int(entry.name), int(fields[1]), cmdline))
    return found


def _workers(sid: int) -> list[int]:
    return [pid for pid, _, cmd in _session(sid) if "spawn_main" in cmd]


def _start(args: list[str], cwd: Path) -> subprocess.Popen:
    """``testbed ARGS`` in a session of its own, SIGINT at its default (a Ctrl-C as from a
    terminal even when the test runner was started in the background)."""
    return subprocess.Popen([sys.executable, "-m", "testbed.cli", *args], cwd=cwd, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for(condition, timeout_s: float, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def _gone_within(sid: int, timeout_s: float) -> float:
    """Seconds until session ``sid`` has no live process (fails after ``timeout_s``)."""
    start = time.monotonic()
    while _session(sid):
        assert time.monotonic() - start < timeout_s, _session(sid)
        time.sleep(0.05)
    return time.monotonic() - start


def _kill_session(proc: subprocess.Popen) -> None:
    for pid, _, _ in _session(proc.pid):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    if proc.poll() is None:
        proc.kill()
    proc.wait(5)


# ---------------------------------------------------------------- map_jobs itself
def _interrupt_when_workers_run(n: int) -> threading.Thread:
    """SIGINT to this process once ``n`` of its children exist (and have started)."""
    import multiprocessing

    def later() -> None:
        deadline = time.monotonic() + 60
        while len(multiprocessing.active_children()) < n and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)
        os.kill(os.getpid(), signal.SIGINT)

    thread = threading.Thread(target=later, daemon=True)
    thread.start()
    return thread


@pytest.mark.skipif(threading.current_thread() is not threading.main_thread(),
                    reason="signals need the main thread")
def test_an_interrupt_stops_the_running_and_queued_jobs_at_once():
    import multiprocessing

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        pytest.skip("SIGINT is not raised as KeyboardInterrupt here")
    _interrupt_when_workers_run(2)
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        # 3 jobs of 60 s on 2 workers: one running on each, one queued
        backend.map_jobs(time.sleep, [(60,), (60,), (60,)], workers=2)
    assert time.monotonic() - start < 20  # the workers' start (imports) and 1 s, not 60 s
    assert multiprocessing.active_children() == []


def test_a_failed_job_stops_the_others_without_waiting_for_them():
    import multiprocessing

    start = time.monotonic()
    with pytest.raises(ValueError, match="math domain error"):
        # job 0 would sleep for a minute; job 1 fails at once
        backend.map_jobs(operator.call, [(time.sleep, 60), (math.sqrt, -1.0)], workers=2)
    assert time.monotonic() - start < 20
    assert multiprocessing.active_children() == []


def test_results_and_progress_stay_in_job_order_whatever_ends_first():
    seen: list[int] = []
    out = backend.map_jobs(operator.call, [(time.sleep, 1.0), (abs, -2), (abs, -3)],
                           workers=2, on_done=seen.append, costs=[0.0, 1.0, 1.0])
    assert out == [None, 2, 3] and seen == [0, 1, 2]


def test_held_signals_are_raised_after_the_block():
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals need the main thread")
    arrived: list[int] = []
    previous = signal.signal(signal.SIGTERM, lambda s, f: arrived.append(s))
    try:
        with backend._stop_signals_held():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
            assert arrived == []  # held: not delivered inside the block
        assert arrived == [signal.SIGTERM]  # delivered once, after it
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_a_worker_whose_parent_died_before_it_was_armed_ends():
    code = ("import os; from testbed.experiment.backend import die_with_parent; "
            "die_with_parent(os.getppid() + 1); print('alive')")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, env=ENV)
    assert done.returncode == 1 and "alive" not in done.stdout


# ---------------------------------------------------------------- the command line
@pytest.mark.parametrize("sig, code, name", [(signal.SIGINT, 130, "SIGINT"),
                                             (signal.SIGTERM, 143, "SIGTERM")])
def test_a_command_that_returns_after_catching_a_signal_is_still_interrupted(
        tmp_path, capsys, sig, code, name):
    """``run --serve`` stops serving on Ctrl-C and returns; a library may swallow the
    exception of a signal: the command's exit code is still the signal's, and outputs not
    yet in place are dropped."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals need the main thread")
    import argparse

    from testbed.io import atomic_path

    cli_main = importlib.import_module("testbed.cli.entry")  # the entry module

    def command(args: argparse.Namespace) -> int:
        with atomic_path(tmp_path / "late.json") as tmp:
            tmp.write_text("{}")
        try:
            os.kill(os.getpid(), sig)
            time.sleep(1.0)
        except BaseException:  # noqa: BLE001 - as a library (or --serve) would
            pass
        return 0

    args = argparse.Namespace(command="run", debug=False, **COMMON_DEFAULTS)
    # Python's own Ctrl-C handler, whatever this process inherited (a job started in the
    # background of a shell ignores SIGINT, and the signal would never arrive)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with cli_main._sigterm_raises():
            assert cli_main._run_command(command, args) == code
    finally:
        signal.signal(signal.SIGINT, previous)
    assert capsys.readouterr().err.strip() == f"testbed: stopped ({name})"
    assert list(tmp_path.iterdir()) == []


#: A sweep of four long points on two workers (each point's study makes a progress bar,
#: whose lock is a semaphore of the worker: released when the worker is stopped).
LONG_SWEEP = ["sweep", "helicopter", "--grid", "process_noise=0,1,2,3", "--runs", "100",
              "--duration", "10", "--workers", "2", "--no-progress"]


@pytest.mark.parametrize("command, sig, code", [(LONG_MC, signal.SIGTERM, 143),
                                                (LONG_MC, signal.SIGINT, 130),
                                                (LONG_SWEEP, signal.SIGTERM, 143)])
def test_studies_with_workers_stop_within_3_s_and_leave_no_process(tmp_path, command, sig,
                                                                   code):
    proc = _start([*command, "--json", "out.json"], tmp_path)
    try:
        _wait_for(lambda: len(_workers(proc.pid)) == 2, 90, proc)
        time.sleep(1.0)  # the workers are simulating
        start = time.monotonic()
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=30)
        elapsed = time.monotonic() - start
        assert proc.returncode == code, stderr
        assert elapsed < 3.0, elapsed
        assert stderr.strip().splitlines()[-1].startswith("testbed: ")
        assert "Traceback" not in stderr and "leaked" not in stderr
        _gone_within(proc.pid, 2.0)  # no worker, no resource tracker
        assert list(tmp_path.iterdir()) == []
    finally:
        _kill_session(proc)


def test_mc_killed_by_sigkill_takes_its_workers_along(tmp_path):
    proc = _start(LONG_MC, tmp_path)
    try:
        _wait_for(lambda: len(_workers(proc.pid)) == 2, 90, proc)
        proc.kill()
        proc.wait(10)
        assert _gone_within(proc.pid, 5.0) < 5.0
    finally:
        _kill_session(proc)


def test_a_signal_while_the_command_starts_ends_it(tmp_path):
    """SIGTERM before any worker exists (start-up, the scenario's check and build)."""
    proc = _start([*LONG_MC, "--json", "out.json"], tmp_path)
    try:
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)
        assert proc.returncode in (143, -signal.SIGTERM)  # 143 once its handler is in place
        _gone_within(proc.pid, 3.0)
        assert list(tmp_path.iterdir()) == []
    finally:
        _kill_session(proc)


def test_a_signal_as_the_results_are_written_leaves_all_or_nothing(tmp_path):
    """SIGTERM once the workers are done: the command completes (exit 0, the JSON in place)
    or ends with 143 and no file; never a partial file, never a process left."""
    proc = _start(["mc", "helicopter", "--runs", "4", "--duration", "1", "--workers", "2",
                   "--backend", "local", "--no-progress", "--json", "out.json"], tmp_path)
    try:
        _wait_for(lambda: len(_workers(proc.pid)) == 2, 90, proc)
        while _workers(proc.pid) and proc.poll() is None:
            time.sleep(0.01)
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=30)
        _gone_within(proc.pid, 3.0)
        files = sorted(p.name for p in tmp_path.iterdir())
        if proc.returncode == 0:
            assert files == ["out.json"] and json.loads((tmp_path / "out.json").read_text())
        else:
            assert proc.returncode == 143 and files == [], stderr
    finally:
        _kill_session(proc)


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="needs Ray")
def test_a_ray_study_stops_on_sigterm_within_seconds(tmp_path):
    """Ray's get does not act on a handler that raises until the task ends: the waits are
    short, the handlers run between them; the local instance is shut down."""
    proc = _start(["mc", "helicopter", "--runs", "4000", "--duration", "10", "--workers", "2",
                   "--backend", "ray", "--no-progress"], tmp_path)
    try:
        _wait_for(lambda: sum("ray::_mc_shard" in cmd for _, _, cmd in _session(proc.pid))
                  == 2, 120, proc)
        time.sleep(1.0)
        start = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=60)
        assert proc.returncode == 143, stderr
        assert time.monotonic() - start < 6.0  # ray.shutdown takes 1.5 s of it
        assert stderr.strip().splitlines()[-1].startswith("testbed: terminated (SIGTERM)")
    finally:
        _kill_session(proc)


def _designs_of(pid: int) -> list[Path]:
    return sorted(Path(tempfile.gettempdir()).glob(f"{harness.DESIGNS_PREFIX}{pid}-*"))


def test_score_with_workers_stops_on_sigint_and_removes_its_designs(tmp_path):
    proc = _start(["score", "--estimator", "kalman", "--workers", "2", "--no-progress"],
                  tmp_path)
    try:
        _wait_for(lambda: len(_workers(proc.pid)) == 2 and _designs_of(proc.pid), 90, proc)
        time.sleep(1.0)
        start = time.monotonic()
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=30)
        assert proc.returncode == 130, stderr
        assert time.monotonic() - start < 3.0
        _gone_within(proc.pid, 2.0)
        assert _designs_of(proc.pid) == []
    finally:
        _kill_session(proc)


def test_stale_design_directories_of_dead_processes_are_removed(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f"{harness.DESIGNS_PREFIX}{dead.pid}-abc"
    stale.mkdir()
    (stale / "design.pkl").write_bytes(b"x")
    live = tmp_path / f"{harness.DESIGNS_PREFIX}{os.getpid()}-abc"  # this process: kept
    live.mkdir()
    unnamed = tmp_path / f"{harness.DESIGNS_PREFIX}xyz"  # no process id: not ours to judge
    unnamed.mkdir()
    link = tmp_path / f"{harness.DESIGNS_PREFIX}{dead.pid}-link"  # a link: left alone
    link.symlink_to(live)
    with harness.designs_directory(tmp_path) as designs:
        assert Path(designs).name.startswith(f"{harness.DESIGNS_PREFIX}{os.getpid()}-")
        assert oct(os.stat(designs).st_mode & 0o777) == "0o700"
        assert not stale.exists() and live.is_dir() and unnamed.is_dir() and link.is_symlink()
    assert not Path(designs).exists()


# ---------------------------------------------------------------- viewers
def _viewers_of(marker: str) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if marker.encode() in cmdline and b"testbed.cli" not in cmdline and state != "Z":
            pids.append(int(entry.name))
    return pids


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rerun_installed() -> bool:
    from testbed.outputs.view import rerun_binary

    try:
        return Path(rerun_binary()).exists()
    except ValueError:
        return False


needs_rerun = pytest.mark.skipif(not sys.platform.startswith("linux") or not _rerun_installed(),
                                 reason="needs Linux and the rerun binary")


@needs_rerun
def test_view_web_killed_by_sigkill_leaves_no_viewer(tmp_path):
    from testbed.experiment.runner import run
    from testbed.experiment.scenario import Scenario
    from testbed.outputs.viz import write_rrd

    traj, _ = run(Scenario(rig="helicopter", duration_s=0.2), record=True, progress=False)
    rrd = write_rrd(traj, tmp_path / "killed.rrd").resolve()
    web = _free_port()
    proc = _start(["view", str(rrd), "--web", "--grpc-port", str(_free_port()),
                   "--web-port", str(web)], tmp_path)
    try:
        assert proc.stdout.readline().startswith("open ")  # the viewer serves
        assert _viewers_of(str(rrd))
        proc.kill()
        proc.wait(10)
        deadline = time.monotonic() + 5
        while _viewers_of(str(rrd)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _viewers_of(str(rrd)) == []
    finally:
        for pid in _viewers_of(str(rrd)):
            os.kill(pid, signal.SIGKILL)
        _kill_session(proc)


@needs_rerun
def test_run_serve_stopped_by_ctrl_c_exits_130_and_keeps_its_json(tmp_path):
    grpc, web = _free_port(), _free_port()
    proc = _start(["run", "helicopter", "--duration", "0.2", "--no-progress", "--serve",
                   "--grpc-port", str(grpc), "--web-port", str(web), "--json", "run.json"],
                  tmp_path)
    try:
        for line in proc.stdout:
            if "press Ctrl-C" in line:
                break
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=30)
        assert proc.returncode == 130, stderr
        assert stderr.strip().splitlines()[-1] == "testbed: stopped (SIGINT)"
        assert json.loads((tmp_path / "run.json").read_text())["duration_s"] == 0.2
        assert _viewers_of(f"--port\0{grpc}\0") == []  # the server's group is stopped
        _gone_within(proc.pid, 5.0)
    finally:
        _kill_session(proc)
