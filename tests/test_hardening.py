"""Hardening: bad input ends in one line before anything runs, numerical failures are typed,
outputs never leave temporaries, and the probes of the reliability review stay fixed."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import testbed
from filters import (
    DiscreteLinearSystem,
    FiniteEscapeError,
    KalmanBucyFilter,
    KalmanFilter,
    LinearSystem,
    SubstepLimitError,
)
from filters.kalman import MAX_AUTO_SUBSTEPS
from testbed.cli import main
from testbed.experiment.backend import RAY_CONNECT_TIMEOUT_S
from testbed.experiment.scenario import Scenario, ScenarioError
from testbed.io import atomic_path, check_output_path, remove_stale_temporaries
from testbed.sim.simulator import SimulationDiverged

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def places(tmp_path_factory) -> dict[str, str]:
    base = tmp_path_factory.mktemp("paths")
    (base / "a_dir.json").mkdir()
    (base / "a_file").write_text("x")
    return {"dir": str(base / "a_dir.json"), "file": str(base / "a_file" / "x.json"),
            "txt": str(base / "x.txt"), "json": str(base / "x.json")}


# (command line, text the one-line message must contain). Nothing here may simulate.
BAD_LINES = [
    ("run helicopter --seed -1", "--seed"),
    ("run helicopter --seed 1.5", "--seed"),
    ("run helicopter --seed 9223372036854775808", "--seed"),
    ("mc helicopter --seed -1", "--seed"),
    ("reproduce zhang-nonlinear-discrete --seed -2", "--seed"),
    ("run helicopter --duration 0", "--duration"),
    ("run helicopter --duration -1", "--duration"),
    ("run helicopter --duration nan", "--duration"),
    ("run helicopter --duration 0.004", "--duration"),
    ("run helicopter --duration 1e9", "--allow-long"),
    ("mc helicopter --duration 4000", "--allow-long"),
    ("reproduce zhang-nonlinear-discrete --horizon 1e9", "--horizon"),
    ("run helicopter --process-noise -1", "--process-noise"),
    ("run helicopter --process-noise nan", "--process-noise"),
    ("run helicopter --process-noise inf", "--process-noise"),
    ("run vehicle-roll --process-noise 1", "--process-noise"),
    ("run helicopter --sensor-option noise_std_rad=-0.1", "--sensor-option"),
    ("run vehicle-roll --sensor-option noise_std_rad=0.1", "--sensor-option"),
    ("run helicopter --rig-option yaw_locked=true", "--rig-option"),
    ("run helicopter --rig-option nonsense", "--rig-option"),
    ("mc helicopter --runs 0", "--runs"),
    ("mc helicopter --batch-size -3", "--batch-size"),
    ("sweep helicopter --grid process_noise=0,1 --workers 0", "--workers"),
    ("sweep helicopter --grid nosuch=1,2", "--grid"),
    ("sweep helicopter --grid mass_kg=1,2", "params.mass_kg"),
    ("sweep helicopter --grid process_noise=a,b", "--grid"),
    ("sweep helicopter --grid process_noise=1 --grid process_noise=2", "--grid"),
    ("sweep helicopter --grid params.mass_kg=-1", "--grid"),
    ("sweep helicopter --grid process_noise=-1", "--grid"),
    ("sweep helicopter --grid process_noise=1 --address 127.0.0.1:6379", "--address"),
    ("sweep helicopter --grid process_noise=1 --backend ray --address nonsense", "--address"),
    ("run helicopter --json {txt}", "--json"),
    ("run helicopter --plot {txt}", "--plot"),
    ("run helicopter --rrd {json}", "--rrd"),
    ("mc helicopter --save-npz {json}", "--save-npz"),
    ("run helicopter --json {dir}", "--json"),
    ("run helicopter --json {file}", "--json"),
    ("run helicopter --json /proc/x.json", "--json"),
    ("reproduce all --doc {txt}", "--doc"),
    ("run helicopter --filter nope", "--filter"),
    ("run vehicle-roll --filter ms-hinf", "--filter"),
    ("run helicopter --filter-option foo=1", "--filter-option"),
    ("run helicopter --filter-option gamma=nan", "--filter-option"),
    ("run helicopter --filter-option gamma", "--filter-option"),
    ("run helicopter --param mass_kg=-1", "--param"),
    ("run helicopter --param nosuch=1", "--param"),
    ("run helicopter --sensors nope", "--sensors"),
    ("run helicopter --manoeuvre double-lane-change", "--manoeuvre"),
    ("run vehicle-roll --manoeuvre nope", "--manoeuvre"),
    ("run vehicle-roll --manoeuvre-param nosuch=1", "--manoeuvre-param"),
    ("run helicopter --disturbance nope", "--disturbance"),
    ("run helicopter --design-option nosuch=1", "--design-option"),
    ("run helicopter --design-option process_noise_floor=-1", "--design-option"),
    ("run helicopter --controller nope", "--controller"),
    ("run nosuchrig", "rig"),
    ("reproduce nosuch", "name"),
]


@pytest.mark.parametrize("line, needle", BAD_LINES, ids=[b[0] for b in BAD_LINES])
def test_bad_command_lines_end_in_one_line_before_any_simulation(line, needle, places, capsys):
    argv = [*line.format(**places).split(), "--no-progress"]
    if argv[0] == "reproduce":
        argv.remove("--no-progress")
    start = time.perf_counter()
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's parser.error
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("testbed: error: ") and err.count("\n") == 1, err
    assert needle in err and "Traceback" not in err
    assert time.perf_counter() - start < 20  # validation only: nothing simulated


def test_the_table_has_at_least_30_lines():
    assert len(BAD_LINES) >= 30


def test_a_bad_line_in_a_real_process_has_no_traceback(tmp_path):
    out = subprocess.run([sys.executable, "-m", "testbed.cli", "run", "helicopter", "--json",
                          str(tmp_path / "a.txt")], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120)
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr == f"testbed: error: --json must be a .json file, got " \
                         f"'{tmp_path / 'a.txt'}'\n"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_directory_is_refused(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    assert main(["run", "helicopter", "--json", str(ro / "x.json")]) == 2
    assert "--json" in capsys.readouterr().err


def test_check_output_path_accepts_new_nested_directories(tmp_path):
    assert check_output_path(tmp_path / "a" / "b" / "r.rrd", "--rrd", ".rrd").name == "r.rrd"
    assert list(tmp_path.iterdir()) == []  # nothing created by the check
    check_output_path(tmp_path / "out", "--out-dir", None)
    with pytest.raises(ValueError, match="--plot must be a .png file"):
        check_output_path(tmp_path / "r.PNG.txt", "--plot", ".png")


# ------------------------------------------------------------------ divergence
def test_diverging_simulation_exits_4_and_writes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo's default handler would write MUJOCO_LOG.TXT here
    out = tmp_path / "out" / "x.json"
    assert main(["run", "helicopter", "--duration", "2", "--process-noise", "1e6", "--json",
                 str(out), "--no-progress"]) == 4
    err = capsys.readouterr().err
    assert err.startswith("testbed: simulation diverged at t = ") and "pitch" in err
    assert len(err.strip().splitlines()) == 1  # MuJoCo's own warning went to the logger
    assert not out.parent.exists()
    assert list(tmp_path.iterdir()) == []  # no MUJOCO_LOG.TXT either


def test_stiff_actuator_diverges_with_time_and_state(tmp_path, monkeypatch):
    from testbed.experiment.runner import run

    monkeypatch.chdir(tmp_path)

    with pytest.raises(SimulationDiverged) as info:
        run(Scenario(rig="helicopter", params={"K_pp": 1e5}, duration_s=2), record=False,
            progress=False)
    exc = info.value
    assert exc.time_s == pytest.approx(0.01) and exc.members == [0]
    assert exc.reason == "outside envelope" and abs(exc.state[0, 0]) > np.pi / 2


def test_mujoco_warning_is_detected_even_though_mujoco_resets_the_state(tmp_path,
                                                                        monkeypatch):
    from testbed.sim import build_simulator

    monkeypatch.chdir(tmp_path)

    sim = build_simulator("helicopter", 1, num_threads=1)
    sim.reset(None, [0])
    sim.physics.state[0, sim.physics._gather[2]] = 1e30  # a huge pitch rate: bad qacc
    with pytest.raises(SimulationDiverged) as info:
        sim.step(np.zeros((1, 2)))
    assert info.value.reason == "mujoco warning"
    with pytest.raises(RuntimeError, match="reset"):
        sim.step(np.zeros((1, 2)))  # the diverged member must be reset first
    sim.reset(None, [0])
    sim.step(np.zeros((1, 2)))
    sim.close()


def test_simulation_diverged_pickles():
    import pickle

    exc = SimulationDiverged("m", time_s=1.5, state=np.ones((1, 4)), members=[3],
                             reason="outside envelope")
    back = pickle.loads(pickle.dumps(exc))
    assert (back.time_s, back.members, back.reason, str(back)) == (1.5, [3],
                                                                   "outside envelope", "m")


def test_filter_failure_exits_3(tmp_path, capsys, monkeypatch):
    (tmp_path / "stiffkb.py").write_text(
        "import numpy as np\n"
        "from filters import KalmanBucyFilter\n"
        "class Stiff(KalmanBucyFilter):  # a huge prior whatever the loop asks for\n"
        "    batched = True\n"
        "    def reset(self, x0, P0):\n"
        "        super().reset(x0, 1e4 * np.eye(4))\n"
        "def make(design):\n"
        "    return Stiff(design.continuous, design.x0, design.P0, dt_s=design.dt_s,\n"
        "                 substeps='auto')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert main(["run", "helicopter", "--filter", "stiffkb:make", "--duration", "1",
                 "--no-progress"]) == 3
    err = capsys.readouterr().err
    assert "substeps" in err and "MAX_AUTO_SUBSTEPS" in err and "t = 0 s" in err


# ------------------------------------------------------------------ filters
def test_kalman_filter_raises_instead_of_returning_nan():
    eye = np.eye(2)
    kf = KalmanFilter(DiscreteLinearSystem(F=eye, B=None, H=eye, Q=eye, R=eye), np.zeros(2),
                      1e6 * eye)
    kf.step(np.full(2, 1.5e308))
    x_before = kf.x.copy()
    with np.errstate(all="ignore"), pytest.raises(FiniteEscapeError) as info:
        kf.step(np.full(2, -1.5e308))
    assert info.value.quantity == "x" and info.value.time == 2.0
    np.testing.assert_array_equal(kf.x, x_before)  # unchanged
    assert kf.t_s == 1.0


def test_batched_kalman_filter_raises_on_a_non_finite_member():
    eye = np.eye(2)
    kf = KalmanFilter(DiscreteLinearSystem(F=eye, B=None, H=eye, Q=eye, R=eye),
                      np.zeros((3, 2)), 1e6 * eye)
    kf.step(np.array([[0.0, 0.0], [1.5e308, 1.5e308], [0.0, 0.0]]))
    with np.errstate(all="ignore"), pytest.raises(FiniteEscapeError, match="'x'"):
        kf.step(np.array([[0.0, 0.0], [-1.5e308, -1.5e308], [0.0, 0.0]]))


@pytest.mark.parametrize("value, match", [
    ([10**400, 0], "beyond the float64 range"), ([1 + 1j, 0], "must be real"),
    ({"a": 1}, "real numeric array"), ("12", "real numeric array"), ({1, 2}, "real numeric"),
])
def test_filters_refuse_complex_huge_and_non_numeric(value, match):
    eye = np.eye(2)
    kf = KalmanFilter(DiscreteLinearSystem(F=eye, B=None, H=eye, Q=eye, R=eye), np.zeros(2),
                      eye)
    with pytest.raises(ValueError, match=f"^y .*{match}"):
        kf.step(value)
    with pytest.raises(ValueError, match="x0"):
        kf.reset(value, eye)
    with pytest.raises(ValueError, match="F"):
        DiscreteLinearSystem(F=np.array([[1 + 1j, 0], [0, 1]]), B=None, H=eye, Q=eye, R=eye)
    assert kf.t_s == 0.0


def test_auto_substeps_cap_is_a_typed_error_before_any_change():
    A = np.array([[0.0, 1.0], [0.0, -1.0]])
    system = LinearSystem(A=A, B=None, C=np.array([[1.0, 0.0]]), Q=np.eye(2) * 0.1,
                          R=np.array([[1e-7]]))
    kb = KalmanBucyFilter(system, np.zeros(2), np.eye(2), dt_s=0.01, substeps="auto")
    assert kb.suggested_substeps() > MAX_AUTO_SUBSTEPS
    start = time.perf_counter()
    with pytest.raises(SubstepLimitError) as info:
        kb.step(np.zeros(1))
    assert time.perf_counter() - start < 1.0
    assert info.value.quantity == "substeps" and info.value.value > MAX_AUTO_SUBSTEPS
    assert kb.t_s == 0.0 and np.array_equal(kb.P, np.eye(2))
    # the same filter from a small prior stays under the cap and runs
    kb.reset(np.zeros(2), 1e-4 * np.eye(2))
    kb.step(np.zeros(1))
    assert kb.substeps <= MAX_AUTO_SUBSTEPS


# ------------------------------------------------------------------ environments
def test_plain_plants_stop_at_escape_with_finite_observations_and_rewards():
    env = gym.make("testbed/NonlinearDiscrete-v0").unwrapped
    with pytest.raises(ValueError, match="escape bound"):
        env.reset(seed=0, options={"x0": [1e300, 1e300]})
    env.reset(seed=0, options={"x0": [9.9e5, 9.9e5]})
    outs = [env.step([0.0]) for _ in range(3)]
    for y, reward, terminated, _, info in outs:
        assert np.all(np.isfinite(y)) and np.isfinite(reward) and terminated
        assert info["escape"] == {"quantity": "state", "time": 1.0}
        np.testing.assert_array_equal(info["state"], [9.9e5, 9.9e5])  # stopped
    poly = gym.make("testbed/PolynomialCubic-v0").unwrapped
    with pytest.raises(ValueError, match="escape bound"):
        poly.reset(seed=0, options={"x0": [1e200, 1e200]})
    lin = gym.make("testbed/UncertainLinear-v0").unwrapped
    with pytest.raises(ValueError, match="escape bound"):
        lin.reset(seed=0, options={"x0": [1e300, 0.0]})


def test_plant_rollout_stops_at_escape_instead_of_returning_nan():
    from testbed.experiment.numpy_plant import rollout
    from testbed.reproductions.zhang_lmi_hinf import plant
    out = rollout(plant.NonlinearDiscretePlant(), np.array([[1.0, 1.0], [9e5, 9e5]]), 5,
                  noise=lambda k: np.zeros(2), u=lambda k: np.full((2, 1), 8.0))
    assert isinstance(out.escape, FiniteEscapeError)
    assert out.escape.quantity == "state" and out.escape.time == 1.0
    assert out.x.shape == (2, 1, 2) and np.isfinite(out.x).all()


@pytest.mark.parametrize("env_id", testbed.ENV_IDS)
def test_every_env_names_the_argument_of_a_bad_input(env_id):
    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    k, n = env.action_space.shape[0], len(env.state_names)
    for action, match in (([10**400] + [0] * (k - 1), "action.*float64 range"),
                          (np.full(k, 1 + 1j), "action.*real"), ("ab", "action")):
        with pytest.raises(ValueError, match=match):
            env.step(action)
    for options, match in (([1, 2], "options must be a dict"),
                           ({"x0": np.full(n, 1j)}, r"options\['x0'\].*real"),
                           ({"x0": [10**400] * n}, r"options\['x0'\].*float64")):
        with pytest.raises(ValueError, match=match):
            env.reset(options=options)
    for seed in (-1, 1.5, True):
        with pytest.raises(ValueError, match="seed"):
            env.reset(seed=seed)
    env.close()


@pytest.mark.parametrize("env_id", ["testbed/Helicopter2DOF-v0", "testbed/VehicleRoll-v0"])
def test_rig_params_option_must_be_a_dict(env_id):
    env = gym.make(env_id).unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"options\['params'\]"):
        env.reset(options={"params": [1.0]})
    name = dataclasses.fields(env.rig.params_type)[0].name
    with pytest.raises(ValueError, match="beyond the float64"):
        env.reset(options={"params": {name: 10**400}})
    env.close()


def test_rig_x0_outside_the_envelope_is_refused():
    env = gym.make("testbed/Helicopter2DOF-v0").unwrapped
    with pytest.raises(ValueError, match="envelope"):
        env.reset(options={"x0": [0.0, 0.0, 1e3, 0.0]})
    env.close()


# ------------------------------------------------------------------ scenario
@pytest.mark.parametrize("changes, field", [
    ({"seed": -1}, "seed"), ({"seed": 2**63}, "seed"), ({"seed": True}, "seed"),
    ({"duration_s": 0.001}, "duration_s"), ({"duration_s": float("nan")}, "duration_s"),
    ({"process_noise": -1.0}, "process_noise"), ({"estimator": "nope"}, "estimator"),
    ({"estimator_options": {"foo": 1}}, "estimator_options"), ({"params": [1.0]}, "params"),
    ({"params": {"mass_kg": 1j}}, "params"), ({"sensors": "nope"}, "sensors"),
    ({"disturbance": "nope"}, "disturbance"), ({"controller": "nope"}, "controller"),
    ({"frame_skip": 0}, "frame_skip"), ({"setpoints": [[0.0, 2.0, 0.0]]}, "setpoints"),
])
def test_scenario_check_names_the_field(changes, field):
    with pytest.raises(ScenarioError) as info:
        Scenario(rig="helicopter").replace(**changes).check()
    assert info.value.field == field


# ------------------------------------------------------------------ outputs
def test_stale_temporaries_of_dead_processes_are_removed_by_the_next_write(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    stale = tmp_path / f".r.json.{dead}.abc123.json.tmp"
    stale.write_text("half")
    stale_dir = tmp_path / f".r.json.{dead}.xyz.tmpdir"
    stale_dir.mkdir()
    live = tmp_path / f".r.json.{os.getpid()}.def456.json.tmp"  # a writer still running
    live.write_text("busy")
    other = tmp_path / ".r.json.notapid.json.tmp"
    other.write_text("?")
    with atomic_path(tmp_path / "r.json") as tmp:
        assert tmp.name.startswith(f".r.json.{os.getpid()}.") and tmp.name.endswith(".json.tmp")
        tmp.write_text("{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, other.name,
                                                                  "r.json"])
    assert remove_stale_temporaries(tmp_path / "r.json") == []


def _interrupt_mc(tmp_path: Path, sig: int) -> subprocess.CompletedProcess:
    out = tmp_path / "mc.npz"
    proc = subprocess.Popen([sys.executable, "-m", "testbed.cli", "mc", "helicopter", "--runs",
                             "4", "--duration", "600", "--save-npz", str(out), "--no-progress"],
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            # a suite started in the background (nohup ... &) inherits an
                            # ignored SIGINT, which Python keeps: restore the default
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.time() + 60
    while not any(p.name.endswith(".tmpdir") for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.time() < deadline, proc.communicate()
        time.sleep(0.1)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signals_remove_temporary_outputs(tmp_path, sig, code):
    done = _interrupt_mc(tmp_path, sig)
    assert done.returncode == code, done.stderr
    assert "Traceback" not in done.stderr and "partial outputs removed" in done.stderr
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ Ray, memory
def test_unreachable_ray_cluster_fails_fast_with_exit_5(capsys):
    start = time.perf_counter()
    assert main(["sweep", "helicopter", "--grid", "process_noise=0,1", "--runs", "2",
                 "--duration", "0.1", "--backend", "ray", "--address", "127.0.0.1:1",
                 "--no-progress"]) == 5
    assert time.perf_counter() - start < RAY_CONNECT_TIMEOUT_S + 5
    assert "no Ray cluster reachable at '127.0.0.1:1'" in capsys.readouterr().err


def test_long_runs_record_decimated_rows_equal_to_the_full_recording(monkeypatch):
    from testbed.experiment import episode, runner

    scenario = Scenario(rig="helicopter", duration_s=1.23)
    full, summary_full = runner.run(scenario, progress=False)
    monkeypatch.setattr(episode, "RECORD_MAX_ROWS", 20)
    part, summary_part = runner.run(scenario, progress=False)
    assert summary_part["rmse"] == summary_full["rmse"]  # metrics use every step
    every = part.meta["recorded_every_steps"]
    assert every == 7  # ceil(124 / 20)
    rows = np.r_[np.arange(0, 124, every), 123]
    np.testing.assert_array_equal(part.t_s, full.t_s[rows])
    for name in ("state", "estimate", "covariance", "measurement", "action", "setpoint",
                 "body_pos", "body_quat_wxyz"):
        np.testing.assert_array_equal(getattr(part, name), getattr(full, name)[rows])


def _peak_rss_mb(tmp_path: Path, duration: float) -> float:
    # VmHWM belongs to the process's own memory map; ru_maxrss would inherit the peak of
    # the forking parent (pytest) across exec
    script = ("import sys\nfrom testbed.cli import main\n"
              f"code = main(['run', 'helicopter', '--duration', '{duration}', '--json', "
              f"r'{tmp_path / 'x.json'}', '--no-progress'])\n"
              "hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0]\n"
              "print(int(hwm.split()[1]) / 1024)\n"
              "sys.exit(code)\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=1800)
    assert out.returncode == 0, out.stderr
    return float(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_json_only_run_memory_is_flat_in_duration(tmp_path):
    # keeping the trajectory would add about 1.9 KB per step: 110 MB over these 57,000 steps
    short, long = _peak_rss_mb(tmp_path, 30), _peak_rss_mb(tmp_path, 600)
    assert long < 250 and abs(long - short) <= 0.1 * short, (short, long)


def test_json_only_run_keeps_no_trajectory(monkeypatch):
    from testbed.experiment.loop import ClosedLoop

    seen = {}
    original = ClosedLoop.run

    def spy(self, *args, **kwargs):
        seen["record"] = kwargs.get("record")
        return original(self, *args, **kwargs)

    monkeypatch.setattr(ClosedLoop, "run", spy)
    assert main(["run", "helicopter", "--duration", "0.2", "--no-progress"]) == 0
    assert seen["record"] is False


def test_cli_json_of_a_run_is_finite(tmp_path):
    out = tmp_path / "r.json"
    assert main(["run", "helicopter", "--duration", "0.5", "--json", str(out),
                 "--no-progress"]) == 0
    assert json.loads(out.read_text())["steps"] == 50


@pytest.mark.parametrize("num", [1, 3])
def test_a_non_finite_manoeuvre_input_is_refused_before_the_step(num):
    """A manoeuvre returning NaN stops the step with a ValueError, the state unchanged (one
    member or a batch on one time, where only one row of the profile is checked)."""
    from testbed.sim import build_simulator

    sim = build_simulator("vehicle-roll", num, num_threads=1,
                          manoeuvre=lambda t: float("nan") if t >= 0.05 else 0.0)
    sim.reset(None, list(range(num)), None)
    for _ in range(5):
        sim.step(np.zeros((num, 1)))
    before = sim.physics.state.copy(), sim.steps.copy()
    with pytest.raises(ValueError, match="non-finite input"):
        sim.step(np.zeros((num, 1)))
    assert np.array_equal(sim.physics.state, before[0]) and np.array_equal(sim.steps, before[1])
    sim.close()
