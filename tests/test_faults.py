"""No fault that leaks: listening sockets, full disks, plug-ins, huge studies, interrupts,
outputs checked first, OpenGL, copies of environments, and the small inconsistencies of the
command line (the issue's items 2-10, one or more tests each)."""

from __future__ import annotations

import contextvars
import copy
import errno
import os
import pickle
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import testbed  # noqa: F401 - registers the environments
from testbed import io as tio
from testbed.cli import build_parser, main
from testbed.experiment.scenario import Scenario, ScenarioError

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "RERUN_ANALYTICS": "off"}


def _cli(*argv: str, env: dict | None = None, timeout: float = 300,
         cwd: str | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "testbed.cli", *argv], capture_output=True,
                          text=True, env=env or ENV, timeout=timeout, cwd=cwd)


def _one_line(err: str) -> str:
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    return lines[0]


def _code(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:  # argparse
        return exc.code


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _listening(ports: set[int]) -> set[tuple[str, int]]:
    """(address, port) of the TCP sockets listening on ``ports`` (from /proc/net/tcp{,6})."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        if not os.path.exists(table):
            continue
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            local, state = fields[1], fields[3]
            address, port = local.split(":")
            if state == "0A" and int(port, 16) in ports:  # 0A: LISTEN
                found.add((address, int(port, 16)))
    return found


# ====================================================== 2. what listens binds 127.0.0.1
LOOPBACK_V4 = "0100007F"  # 127.0.0.1 as /proc/net/tcp writes it


def _serve(tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, list[str], set[int]]:
    grpc, web = _free_port(), _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "testbed.cli", "run", "helicopter", "--duration", "0.3",
         "--no-progress", "--serve", "--grpc-port", str(grpc), "--web-port", str(web),
         "--json", str(tmp_path / "served.json"), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if "press Ctrl-C" in line:
            break
    assert proc.poll() is None, (lines, proc.stderr.read())
    return proc, lines, {grpc, web}


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net/tcp")
def test_serve_listens_on_loopback_only_and_sigint_stops_it(tmp_path):
    proc, lines, ports = _serve(tmp_path)
    try:
        listening = _listening(ports)
        assert {p for _, p in listening} == ports, listening
        assert {a for a, _ in listening} == {LOOPBACK_V4}, listening  # not 0.0.0.0
        assert (tmp_path / "served.json").exists()  # written before serving goes on
        start = time.monotonic()
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
        assert time.monotonic() - start < 20
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, proc.stderr.read()  # stopped by Ctrl-C (its JSON kept)
    assert "Traceback" not in proc.stderr.read()
    assert (tmp_path / "served.json").exists()
    assert _listening(ports) == set()  # the server's whole process group is gone


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net/tcp")
def test_the_server_does_not_outlive_a_killed_run(tmp_path):
    proc, _, ports = _serve(tmp_path)
    assert len(_listening(ports)) == 2
    proc.kill()  # SIGKILL: no clean-up code runs
    proc.wait(10)
    deadline = time.monotonic() + 15
    while _listening(ports) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _listening(ports) == set()


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc/net/tcp")
def test_bind_elsewhere_is_honoured_with_a_warning(tmp_path):
    proc, _, ports = _serve(tmp_path, "--bind", "0.0.0.0")
    try:
        assert {a for a, _ in _listening(ports)} == {"00000000"}
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
    err = proc.stderr.read()
    assert "warning: --bind 0.0.0.0" in err and "other machines" in err
    assert _listening(ports) == set()


def test_a_viewer_that_went_away_does_not_hang_the_end_of_a_run(capsys):
    """A native viewer without a display may listen, then exit: the final flush waits a
    bounded time and warns instead of blocking forever."""
    import rerun as rr

    from testbed.outputs.live import flush, stop
    from testbed.outputs.viz import new_recording

    rec = new_recording("testbed/gone")
    rec.connect_grpc(f"rerun+http://127.0.0.1:{_free_port()}/proxy")  # nothing listens
    rec.log("a", rr.Scalars([1.0]))
    start = time.monotonic()
    assert flush(rec, 1.0) is False
    assert time.monotonic() - start < 10
    assert "warning: the live viewer did not take the data" in capsys.readouterr().err
    stop(rec)


def test_a_busy_port_is_one_line_before_anything_runs(tmp_path):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        out = _cli("run", "helicopter", "--duration", "0.3", "--no-progress", "--serve",
                   "--grpc-port", str(port), "--web-port", str(_free_port()), "--json",
                   str(tmp_path / "x.json"))
    assert out.returncode == 2, out.stderr
    assert "--grpc-port" in _one_line(out.stderr) and out.stdout == ""
    assert list(tmp_path.iterdir()) == []


# ====================================================== 3. a full disk: exit 5, nothing left
def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


def test_mc_on_a_full_disk_exits_5_before_simulating_and_leaves_nothing(tmp_path, capsys,
                                                                          monkeypatch):
    from testbed.experiment import loop

    monkeypatch.setattr(os, "posix_fallocate", _enospc)
    ran = []
    monkeypatch.setattr(loop.ClosedLoop, "run", lambda *a, **k: ran.append(1))
    out = tmp_path / "out"
    code = main(["mc", "helicopter", "--runs", "3", "--duration", "0.5", "--no-progress",
                 "--save-npz", str(out / "t.npz"), "--json", str(out / "t.json"),
                 "--plot", str(out / "t.png")])
    err = capsys.readouterr().err
    assert code == 5 and ran == []
    assert _one_line(err).startswith("testbed: --save-npz: cannot write ")
    assert "No space left on device" in err
    assert list(tmp_path.iterdir()) == []  # no temporary, no directory


def test_mc_disk_full_while_writing_removes_every_output(tmp_path, capsys, monkeypatch):
    """A file system that cannot reserve space: the disk fills in mid-write (pwrite), never a
    SIGBUS; exit 5 and none of --json/--plot/--save-npz is left."""
    def cannot_reserve(*args):
        raise OSError(errno.EOPNOTSUPP, "Operation not supported")

    real_pwrite, calls = os.pwrite, []

    def pwrite(fd, data, offset):
        calls.append(offset)
        if len(calls) > 10:
            _enospc()
        return real_pwrite(fd, data, offset)

    monkeypatch.setattr(os, "posix_fallocate", cannot_reserve)
    monkeypatch.setattr(os, "pwrite", pwrite)
    code = main(["mc", "helicopter", "--runs", "4", "--batch-size", "2", "--duration", "1",
                 "--no-progress", "--save-npz", str(tmp_path / "t.npz"), "--json",
                 str(tmp_path / "t.json"), "--plot", str(tmp_path / "t.png")])
    assert code == 5
    assert "--save-npz" in _one_line(capsys.readouterr().err)
    assert list(tmp_path.iterdir()) == []


def test_npz_stream_uses_no_memory_map_and_keeps_its_contents(tmp_path, monkeypatch):
    from testbed.experiment.runner import monte_carlo

    def no_memmap(*args, **kwargs):
        raise AssertionError("no memory-mapped output")

    monkeypatch.setattr(np.lib.format, "open_memmap", no_memmap)
    monkeypatch.setattr(np, "memmap", no_memmap)
    scenario = Scenario(rig="helicopter", duration_s=0.5, seed=2)
    monte_carlo(scenario, 3, batch_size=2, progress=False, save_npz=tmp_path / "a.npz")
    monkeypatch.setattr("testbed.io.trajectory_stream.FileRows.BUFFER_BYTES", 64)  # tiny chunks
    monte_carlo(scenario, 3, batch_size=3, progress=False, save_npz=tmp_path / "b.npz")
    a, b = np.load(tmp_path / "a.npz"), np.load(tmp_path / "b.npz")
    assert sorted(a.files) == sorted(b.files) and a["state"].shape == (3, 51, 4)
    for key in a.files:
        np.testing.assert_array_equal(a[key], b[key])
    from testbed.experiment.runner import run

    traj, _ = run(scenario.replace(seed=int(a["seeds"][1])), progress=False)
    np.testing.assert_array_equal(a["state"][1], traj.state)
    np.testing.assert_array_equal(a["estimate"][1], traj.estimate)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz", "b.npz"]


def _tiny_tmpfs(path: Path) -> bool:
    path.mkdir()
    if os.geteuid() != 0:
        return False
    return subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(path)],
                          capture_output=True).returncode == 0


def test_a_real_full_disk_on_a_tiny_tmpfs(tmp_path):
    disk = tmp_path / "tiny"
    if not _tiny_tmpfs(disk):
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        out = _cli("mc", "helicopter", "--runs", "20", "--duration", "5", "--no-progress",
                   "--save-npz", str(disk / "m.npz"), "--json", str(disk / "m.json"))
        assert out.returncode == 5, out.stderr
        assert "--save-npz" in _one_line(out.stderr)
        assert list(disk.iterdir()) == []
        (disk / "fill").write_bytes(b"\0" * 200_000)
        out = _cli("run", "helicopter", "--duration", "2", "--no-progress", "--json",
                   str(disk / "r.json"), "--plot", str(disk / "r.png"))
        assert out.returncode == 5, out.stderr
        assert "--plot" in _one_line(out.stderr)
        assert [p.name for p in disk.iterdir()] == ["fill"]  # no JSON without its PNG
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


# ====================================================== 4. plug-ins
PLUGIN = '''
import sys
import numpy as np

class Breaks:
    """Runs 50 steps, then its step raises LinAlgError (a ValueError subclass)."""
    def __init__(self, design, exit_in_step=False):
        self.x, self.P, self.n, self.exit_in_step = np.zeros(4), np.eye(4), 0, exit_in_step
    def reset(self, x0, P0):
        self.x = np.array(x0, float)
    def step(self, y, u=None):
        self.n += 1
        if self.n > 50:
            if self.exit_in_step:
                sys.exit(0)
            np.linalg.inv(np.zeros((2, 2)))
        return self.x

def make(design):
    return Breaks(design)

def exits_in_step(design):
    return Breaks(design, exit_in_step=True)

def raises(design):
    raise RuntimeError("no design for you")

def exits(design):
    sys.exit(0)

from testbed.rigs.helicopter.rig import HelicopterRig

class BadRig(HelicopterRig):
    def __init__(self, *args, **kwargs):
        raise KeyError("missing part")
'''


@pytest.fixture
def plugin_dir(tmp_path, monkeypatch):
    (tmp_path / "plug.py").write_text(PLUGIN)
    (tmp_path / "broken_import.py").write_text("raise RuntimeError('cannot even import')\n")
    (tmp_path / "exits_import.py").write_text("import sys\nsys.exit(0)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    return tmp_path


PLUGIN_CASES = [  # (argv, exit code, text of the one line)
    ("run helicopter --filter broken_import:make", 2,
     "--filter: filter 'broken_import:make' failed while loading: RuntimeError: cannot even"),
    ("run helicopter --filter exits_import:make", 2, "failed while loading: SystemExit(0)"),
    ("run helicopter --filter plug:nosuch", 2, "has no 'nosuch'"),
    ("run helicopter --filter plug:raises", 2,
     "--filter: filter 'plug:raises' failed while building: RuntimeError: no design for you"),
    ("run helicopter --filter plug:exits", 2, "failed while building: SystemExit(0)"),
    ("run helicopter --filter plug:make", 3,
     "--filter 'plug:make' failed while running: the estimator's step raised LinAlgError"),
    ("run helicopter --filter plug:exits_in_step", 3, "SystemExit(0) at t = 0.51 s"),
    ("run plug:BadRig", 2, "rig: rig 'plug:BadRig' failed while building: KeyError"),
    ("run nosuchmod:Rig", 2, "rig: rig 'nosuchmod:Rig' failed while loading"),
    ("run ./plug.py:nosuch", 2, "module './plug.py' has no 'nosuch'"),
    ("mc helicopter --runs 2 --filter ./plug.py:make", 3, "LinAlgError"),
    ("score --estimator broken_import:make", 2,  # --estimator: the alias of score's --filter
     "--filter: filter 'broken_import:make' failed while loading: RuntimeError"),
    ("score --filter broken_import:make", 2,
     "--filter: filter 'broken_import:make' failed while loading: RuntimeError"),
]


@pytest.mark.parametrize("line, code, text", PLUGIN_CASES, ids=[c[0] for c in PLUGIN_CASES])
def test_a_failing_plugin_is_one_line_with_its_exit_code(line, code, text, plugin_dir, capsys):
    argv = [*line.split(), "--no-progress"]
    if argv[0] != "score":
        argv += ["--duration", "1"]
    assert _code(argv) == code
    out = capsys.readouterr()
    assert text in _one_line(out.err), out.err
    if code == 2:
        assert out.out == ""  # nothing ran


def test_a_plugin_from_a_file_path_runs(plugin_dir, capsys):
    (plugin_dir / "sub").mkdir()
    (plugin_dir / "sub" / "good.py").write_text(
        "from testbed.estimators import ESTIMATORS\n"
        "def make(design):\n    return ESTIMATORS['kalman'](design)\n")
    assert main(["run", "helicopter", "--filter", "./sub/good.py:make", "--duration", "0.3",
                 "--no-progress"]) == 0
    assert main(["run", "helicopter", "--filter", str(plugin_dir / "sub" / "good.py") +
                 ":make", "--duration", "0.3", "--no-progress"]) == 0


def test_debug_shows_the_traceback(plugin_dir):
    env = {**ENV, "PYTHONPATH": f"{ROOT}{os.pathsep}{plugin_dir}"}
    quiet = _cli("run", "helicopter", "--filter", "plug:raises", "--no-progress", env=env,
                 cwd=str(plugin_dir))
    assert quiet.returncode == 2 and "Traceback" not in quiet.stderr
    for extra, environ in (((), {"TESTBED_DEBUG": "1"}), (("--debug",), {})):
        loud = _cli("run", "helicopter", "--filter", "plug:raises", "--no-progress", *extra,
                    env={**env, **environ}, cwd=str(plugin_dir))
        assert loud.returncode == 2
        assert "Traceback" in loud.stderr and "no design for you" in loud.stderr
        assert loud.stderr.rstrip().splitlines()[-1].startswith("testbed: error: --filter")


# ====================================================== 5. a huge study is refused first
def test_huge_runs_are_refused_with_the_estimate_before_any_allocation(capsys, monkeypatch):
    from testbed.experiment import study

    monkeypatch.setattr(study, "run_seeds", lambda *a: pytest.fail("allocated seeds"))
    start = time.perf_counter()
    assert main(["mc", "helicopter", "--runs", "100000000000", "--no-progress"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("testbed: error: --runs 100,000,000,000 would need about ")
    assert "TB of memory" in line and "available" in line
    assert time.perf_counter() - start < 20
    monkeypatch.setattr(study, "available_memory", lambda: 1_000_000)
    assert main(["sweep", "helicopter", "--grid", "process_noise=0,1", "--runs", "5000",
                 "--no-progress"]) == 2
    assert "--runs 5,000 would need" in capsys.readouterr().err


# ====================================================== 6. interrupts
@pytest.mark.parametrize("delay_s", [0.15, 0.3, 0.5, 0.8, 1.2])
def test_sigint_during_start_up_exits_130_without_a_traceback(delay_s, tmp_path):
    # a run long enough (seconds) that no delay here lets it finish before the signal
    proc = subprocess.Popen([sys.executable, "-m", "testbed.cli", "run", "helicopter",
                             "--duration", "600", "--no-progress", "--json",
                             str(tmp_path / "x.json")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(delay_s)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    # the traceback of an import that main() did not start: runpy or importlib frames of
    # module bodies ("in <module>") without testbed's main() on the stack
    importing = ("<frozen importlib" in err or "in <module>" in err) and ", in main" not in err
    if proc.returncode not in (0, 130) and (f"{os.sep}testbed{os.sep}" not in err
                                            or importing):
        # the signal came while the interpreter itself started, before ``import testbed``
        # installed the command's start-up handler (nothing of ours to handle it)
        pytest.skip(f"SIGINT before the command's handler ({proc.returncode})")
    assert proc.returncode == 130, err
    assert _one_line(err).startswith("testbed: interrupted (SIGINT)")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("signalled, debug, code", [
    (True, "", 130), (True, "1", 1), (False, "", 1)])
def test_an_interrupt_that_an_import_turns_into_another_error_still_exits_130(
        tmp_path, signalled, debug, code):
    """A real SIGINT while the command starts, after which an import fails with another
    exception and no chain to the interrupt (``ctypes.ArgumentError: argument 1:
    KeyboardInterrupt`` in PyOpenGL's EGL probe while ``import mujoco`` ran;
    ``ImportError: initialization failed`` from an extension module): the command ends with
    130 and one line (the traceback with ``TESTBED_DEBUG``); the same error without a
    Ctrl-C stays a traceback."""
    script = tmp_path / "testbed"  # the command's name: testbed.CLI_PROCESS
    script.write_text("import os, signal, time\n"
                      "import testbed\n"
                      + ("try:\n"  # where a library catches the interrupt ...
                         "    os.kill(os.getpid(), signal.SIGINT)\n"
                         "    time.sleep(0.2)\n"
                         "except KeyboardInterrupt:\n"
                         "    pass\n" if signalled else "")
                      + "raise ImportError('initialization failed')\n")  # ... and fails
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         env={**ENV, "TESTBED_DEBUG": debug}, timeout=120,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert out.returncode == code, out.stderr
    if code == 130:
        assert out.stderr == "testbed: interrupted (SIGINT)\n"
    else:
        assert "Traceback" in out.stderr and "initialization failed" in out.stderr


def test_a_ctrl_c_at_start_up_that_a_library_drops_still_exits_130(tmp_path):
    """A real SIGINT while the command starts is deferred to the end of its start-up: raised
    inside an import, the interpreter could print and drop it (an import's module-lock
    callback) and the command would run on. It ends with 130 and one line."""
    script = tmp_path / "testbed"
    script.write_text(
        "import os, signal, sys, time\n"
        "import testbed\n"
        "try:\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(0.2)\n"
        "except KeyboardInterrupt:\n"
        "    pass\n"
        "from testbed.cli import main\n"
        "sys.exit(main(['run', 'helicopter', '--duration', '0.1', '--no-progress']))\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         env=ENV, timeout=120, cwd=tmp_path,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert out.returncode == 130, out.stderr
    assert out.stderr == "testbed: interrupted (SIGINT)\n"


def test_a_second_ctrl_c_at_start_up_interrupts_at_once(tmp_path):
    script = tmp_path / "testbed"
    script.write_text("import os, signal, time\n"
                      "import testbed\n"
                      "os.kill(os.getpid(), signal.SIGINT)\n"
                      "os.kill(os.getpid(), signal.SIGINT)\n"
                      "time.sleep(600)\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         env=ENV, timeout=120,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert out.returncode == 130 and out.stderr == "testbed: interrupted (SIGINT)\n"


def test_sigint_at_many_points_of_a_study_leaves_all_outputs_or_none(tmp_path):
    """A real Ctrl-C at many moments of ``mc`` (start-up, building, the runs with the .npz
    temporaries, writing): exit 130 and nothing left, or exit 0 and every output."""
    outcomes = set()
    for i, delay_s in enumerate([0.8, 1.3, 1.8, 2.3, 2.8, 3.5, 4.5, 6.0]):
        out = tmp_path / str(i)
        out.mkdir()
        proc = subprocess.Popen(
            [sys.executable, "-m", "testbed.cli", "mc", "helicopter", "--runs", "6",
             "--batch-size", "2", "--duration", "2", "--no-progress", "--save-npz",
             str(out / "m.npz"), "--json", str(out / "m.json"), "--plot", str(out / "m.png")],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=ENV,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        time.sleep(delay_s)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        names = sorted(p.name for p in out.iterdir())
        # a Ctrl-C inside an import's module-lock callback is reported by the interpreter
        # ("Exception ignored in ... importlib"), not by us; the outcome is still checked
        interpreter = "Exception ignored in" in err and "importlib" in err
        assert "Traceback" not in err or interpreter, err
        if proc.returncode == 130:
            assert names == [], (delay_s, names)
        else:
            assert proc.returncode == 0 and names == ["m.json", "m.npz", "m.png"], (delay_s, err)
        outcomes.add(proc.returncode)
    assert 130 in outcomes


class _InterruptAt:
    """A trace function raising KeyboardInterrupt (once) at the n-th line executed: a Ctrl-C
    arriving at that point (Python runs signal handlers between bytecodes)."""

    def __init__(self, n: int):
        self.n, self.count, self.fired = n, 0, False

    def __call__(self, frame, event, arg):
        if event == "line" and not self.fired:
            self.count += 1
            if self.count == self.n:
                self.fired = True
                raise KeyboardInterrupt
        return self


def _interrupted_writes(tmp_path: Path, n: int, together: bool) -> bool:
    tracer = _InterruptAt(n)
    sys.settrace(tracer)
    try:
        tio.check_output_path(tmp_path / "d" / "a.json", "--json", ".json")
        if together:
            with tio.outputs_together():
                tio.write_json(tmp_path / "d" / "a.json", {"a": 1})
                tio.write_json(tmp_path / "d" / "b.json", {"b": 2})
        else:
            tio.write_json(tmp_path / "d" / "a.json", {"a": 1})
    except KeyboardInterrupt:
        pass
    finally:
        sys.settrace(None)
    return tracer.fired


@pytest.mark.parametrize("together", [False, True])
def test_an_interrupt_at_any_point_leaves_no_temporary(tmp_path, together):
    points = 0
    for n in range(1, 5000):
        target = tmp_path / str(n)
        target.mkdir()
        # in a context of its own: an interrupt inside outputs_together's own cleanup may
        # leave its transaction current, which in a real process ends with the process
        fired = contextvars.copy_context().run(_interrupted_writes, target, n, together)
        names = sorted(p.relative_to(target).as_posix() for p in target.rglob("*"))
        leftovers = [name for name in names if name.endswith((".tmp", ".tmpdir"))
                     or ".testbed-write-test" in name]
        assert leftovers == [], (n, names)
        if together:  # all or nothing
            assert names in ([], ["d"], ["d", "d/a.json", "d/b.json"]), (n, names)
        else:
            assert names in ([], ["d"], ["d", "d/a.json"]), (n, names)
        if not fired:  # the write finished before the n-th line: every point was tried
            break
        points += 1
    assert points > 100  # the interrupt came at many points (inside tempfile too)


def test_outputs_together_is_all_or_nothing_and_removes_created_directories(tmp_path):
    with pytest.raises(tio.OutputError, match="b.png"):
        with tio.outputs_together():
            tio.write_json(tmp_path / "new" / "deep" / "a.json", {"a": 1})
            with tio.atomic_path(tmp_path / "new" / "b.png"):
                _enospc()
    assert list(tmp_path.iterdir()) == []
    with tio.outputs_together():
        tio.write_json(tmp_path / "a.json", {"a": 1})
        assert not (tmp_path / "a.json").exists()  # held back until the block ends
    assert (tmp_path / "a.json").exists()


# ====================================================== 7. every output checked first
@pytest.fixture
def places(tmp_path) -> dict[str, str]:
    (tmp_path / "a_dir.mp4").mkdir()
    (tmp_path / "wc.worst_case.npz").mkdir()
    return {"mp4dir": str(tmp_path / "a_dir.mp4"), "txt": str(tmp_path / "x.txt"),
            "wc": str(tmp_path / "wc.json"), "tmp": str(tmp_path)}


OUTPUT_LINES = [
    ("run helicopter --video {mp4dir}", "--video"),
    ("run helicopter --video /proc/x.mp4", "--video"),
    ("run helicopter --video {tmp}/x.avi", "--video"),
    ("score --estimator kalman --markdown {txt}", "--markdown must be a .md file"),
    ("score --estimator kalman --json {wc}", "--json (its .worst_case.npz)"),
    ("score --estimator kalman --json /proc/x.json", "--json"),
]


@pytest.mark.parametrize("line, needle", OUTPUT_LINES, ids=[o[0] for o in OUTPUT_LINES])
def test_every_output_including_derived_ones_is_checked_first(line, needle, places, capsys,
                                                               monkeypatch):
    from testbed.experiment import episode, study, sweep
    from testbed.score import harness

    for module in (episode, study, sweep):
        monkeypatch.setattr(module, "build", lambda *a, **k: pytest.fail("built"))
    monkeypatch.setattr(harness, "score", lambda *a, **k: pytest.fail("scored"))
    assert _code(line.format(**places).split()) == 2
    err = capsys.readouterr().err
    assert needle in _one_line(err)


def test_missing_directories_are_created_at_the_end_and_removed_on_failure(tmp_path, capsys,
                                                                           monkeypatch):
    """Documented: a missing parent directory is created when the outputs are written (the
    check before the run finds the nearest existing one writable); a failure removes it."""
    from testbed.outputs import plots

    def full(*args, **kwargs):
        with tio.atomic_path(tmp_path / "a" / "b" / "r.png"):
            _enospc()

    monkeypatch.setattr(plots, "plot_trajectory", full)
    assert main(["run", "helicopter", "--duration", "0.3", "--no-progress", "--json",
                 str(tmp_path / "a" / "b" / "r.json"), "--plot",
                 str(tmp_path / "a" / "b" / "r.png")]) == 5
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("testbed: --plot: cannot write") and "No space left" in line
    assert list(tmp_path.iterdir()) == []  # neither the JSON nor the directories
    assert main(["run", "helicopter", "--duration", "0.3", "--no-progress", "--json",
                 str(tmp_path / "c" / "r.json")]) == 0
    assert (tmp_path / "c" / "r.json").exists()


# ====================================================== 8. MUJOCO_GL
def _gl_cases() -> list[str]:
    import ctypes.util

    cases = ["garbage", "glfw"]
    if ctypes.util.find_library("OSMesa") is None:
        cases.append("osmesa")
    return cases


@pytest.mark.parametrize("backend", _gl_cases())
def test_a_bad_mujoco_gl_is_one_line_before_the_run(backend, tmp_path):
    env = {k: v for k, v in ENV.items() if k != "DISPLAY"}
    env["MUJOCO_GL"] = backend
    out = _cli("run", "helicopter", "--duration", "0.5", "--no-progress", "--video",
               str(tmp_path / "v.mp4"), env=env)
    assert out.returncode == 2, out.stderr
    line = _one_line(out.stderr)
    assert line.startswith("testbed: error: --video: ") and "MUJOCO_GL" in line
    assert out.stdout == "" and list(tmp_path.iterdir()) == []
    script = ("import gymnasium as gym, testbed\n"
              "try:\n    gym.make('testbed/Helicopter2DOF-v0', render_mode='rgb_array')\n"
              "except ValueError as e:\n    print(e)\n")
    made = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env=env, timeout=120)
    assert made.stdout.startswith("render_mode='rgb_array': ") and "MUJOCO_GL" in made.stdout
    assert "Traceback" not in made.stderr
    if backend == "garbage":  # simulating does not need OpenGL
        assert _cli("run", "helicopter", "--duration", "0.2", "--no-progress",
                    env=env).returncode == 0


# ====================================================== 9. copies of environments
@pytest.mark.parametrize("env_id", ["testbed/Helicopter2DOF-v0", "testbed/VehicleRoll-v0"])
@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_copies_of_rig_envs_are_independent_and_step_identically(env_id, how):
    env = gym.make(env_id)
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.5, 0.5, (40, *env.action_space.shape))
    for a in actions[:10]:
        env.step(a)
    twin = copy.deepcopy(env) if how == "deepcopy" else pickle.loads(pickle.dumps(env))
    ours = [env.step(a) for a in actions[10:]]
    theirs = [twin.step(a) for a in actions[10:]]  # after the original moved on: independent
    for (o1, r1, t1, u1, i1), (o2, r2, t2, u2, i2) in zip(ours, theirs, strict=True):
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(i1["state"], i2["state"])
        assert (r1, t1, u1) == (r2, t2, u2)
    twin.close()
    env.close()


def test_copies_of_a_threaded_vector_env_step_identically():
    from testbed.envs.rig_env import RigVectorEnv

    env = RigVectorEnv(4, rig="helicopter", num_threads=2)
    env.reset(seed=1)
    action = np.full((4, 2), 0.2)
    for _ in range(5):
        env.step(action)
    copies = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    assert all(c.sim.physics.batch is not env.sim.physics.batch for c in copies)
    for _ in range(10):
        obs = env.step(action)[0]
        for c in copies:
            np.testing.assert_array_equal(c.step(action)[0], obs)
    for e in (env, *copies):
        e.close()


def test_filter_in_loop_is_recreatable_picklable_and_passes_check_env():
    from gymnasium.utils.env_checker import check_env

    from testbed.envs.wrappers import FilterInLoop

    env = FilterInLoop.from_design(gym.make("testbed/Helicopter2DOF-v0"), "kalman")
    again = gym.make(env.spec)
    assert isinstance(again, FilterInLoop)
    env.reset(seed=1)
    again.reset(seed=1)
    action = np.full(env.action_space.shape, 0.3)
    for _ in range(20):
        np.testing.assert_array_equal(env.step(action)[0], again.step(action)[0])
    copies = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    for _ in range(20):
        x = env.step(action)[0]
        for c in copies:
            np.testing.assert_array_equal(c.step(action)[0], x)
    check_env(FilterInLoop.from_design(gym.make("testbed/VehicleRoll-v0").unwrapped),
              skip_render_check=True)


def test_from_design_on_a_plain_plant_says_what_it_needs():
    from testbed.envs.wrappers import FilterInLoop

    with pytest.raises(ValueError, match=r"needs a testbed rig environment.*NonlinearDiscrete"
                                         r"Env has no rig.*design="):
        FilterInLoop.from_design(gym.make("testbed/NonlinearDiscrete-v0"))


# ====================================================== 10. small inconsistencies
def test_unknown_sensor_options_are_a_scenario_error():
    with pytest.raises(ScenarioError) as info:
        Scenario(rig="helicopter", sensor_options={"nosuch": 1}).check()
    assert info.value.field == "sensor_options" and "nosuch" in str(info.value)
    with pytest.raises(ScenarioError) as info:
        Scenario(rig="vehicle-roll", sensor_options={"nosuch": 1}).check()
    assert info.value.field == "sensor_options"


CLI_LINES = [  # plain ASCII decimal numbers only, every option named as typed
    ("run helicopter --duration \u0661", "--duration"),  # Arabic-Indic one
    ("run helicopter --seed \u0661", "--seed"),
    ("run helicopter --duration 1_0", "--duration"),
    ("run helicopter --seed 1_0", "--seed"),
    ("run helicopter --duration 0x10", "--duration"),
    ("run helicopter --seed 0x10", "--seed"),
    ("mc helicopter --runs 1_000", "--runs"),
    ("run helicopter --param mass_kg=1_0", "--param"),
    ("sweep helicopter --grid process_noise=0x1", "--grid"),
    ("run helicopter --ambient-noise inf", "--ambient-noise"),
    ("sweep helicopter --grid process_noise=1 --backend ray --address 127.0.0.1:\u0666\u0663"
     "\u0667\u0669", "--address"),
    ("run helicopter --serve --grpc-port 0", "--grpc-port"),
    ("run helicopter --serve --web-port 70000", "--web-port"),
    ("run helicopter --serve --bind nonsense", "--bind expects an IP address"),
    ("run helicopter --bind 127.0.0.1", "--bind applies to --spawn and --serve"),
    ("run helicopter --param mass_kg=1e300", "--param: mass_kg=1e+300: "),
    ("reproduce zhang-nonlinear-discrete --out-dir x", "--out-dir applies to 'reproduce all'"),
    ("reproduce zhang-nonlinear-discrete --doc x.md", "--doc applies to 'reproduce all'"),
    ("mc helicopter --runs 100000000000", "--runs 100,000,000,000 would need"),
    ("score --estimator kalman --runs 10000000", "--runs 10,000,000 of scenario"),
]


@pytest.mark.parametrize("line, needle", CLI_LINES, ids=[c[0] for c in CLI_LINES])
def test_command_line_inconsistencies_are_one_line(line, needle, capsys):
    argv = line.split()
    if argv[0] != "reproduce":
        argv.append("--no-progress")
    start = time.perf_counter()
    assert _code(argv) == 2
    assert needle in _one_line(capsys.readouterr().err)
    assert time.perf_counter() - start < 20


def test_plain_numbers_still_parse():
    args = build_parser().parse_args(["run", "helicopter", "--duration", "2.", "--seed",
                                      "+7", "--param", "mass_kg=1e-1"])
    assert (args.duration, args.seed, args.param) == (2.0, 7, [("mass_kg", 0.1)])
    assert build_parser().parse_args(["run", "helicopter", "--duration", ".5"]).duration == 0.5


def test_score_has_no_progress(monkeypatch, capsys):
    from testbed.score import harness

    seen = {}

    class Stop(Exception):
        pass

    def score(*args, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(harness, "score", score)
    with pytest.raises(Stop):
        from testbed.cli.score import command as cmd_score

        cmd_score(build_parser().parse_args(["score", "--estimator", "kalman",
                                             "--no-progress"]))
    assert seen["progress"] is None


@pytest.mark.parametrize("at", [1, 2])
def test_an_interrupt_right_after_a_rename_takes_it_back(tmp_path, monkeypatch, at):
    """The commit's window between a rename and its record: an interrupt there leaves
    neither output (the renamed one is taken back), never one of the two."""
    real, calls = os.replace, []

    def replace_then_interrupt(src, dst):
        real(src, dst)
        calls.append(dst)
        if len(calls) == at:
            raise KeyboardInterrupt

    monkeypatch.setattr(tio.os, "replace", replace_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        with tio.outputs_together():
            tio.write_json(tmp_path / "d" / "a.json", {"a": 1})
            tio.write_json(tmp_path / "d" / "b.json", {"b": 2})
    assert sorted(p.name for p in tmp_path.rglob("*")) == []
