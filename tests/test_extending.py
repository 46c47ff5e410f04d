"""The three examples of docs/extending.md run: a user estimator, a user rig, a decorator."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from testbed.experiment import runner
from testbed.experiment.scenario import Scenario

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"


@pytest.fixture(autouse=True)
def examples_on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=str(EXAMPLES))
    return subprocess.run([sys.executable, "-m", "testbed.cli", *args], env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("rig", ["helicopter", "vehicle-roll"])
def test_user_estimator_by_import_path_in_run_and_mc(rig, tmp_path):
    done = _cli("run", rig, "--filter", "userkf:make", "--duration", "2",
                "--json", str(tmp_path / "r.json"), "--no-progress")
    assert done.returncode == 0, done.stderr
    done = _cli("mc", rig, "--filter", "userkf:make", "--runs", "3", "--duration", "1",
                "--no-progress")
    assert done.returncode == 0, done.stderr
    # the user's constant-gain filter is close to the built-in Kalman filter
    _, user = runner.run(Scenario(rig=rig, estimator="userkf:make", duration_s=3), record=False,
                         progress=False)
    _, kf = runner.run(Scenario(rig=rig, estimator="kalman", duration_s=3), record=False,
                       progress=False)
    first = next(iter(kf["rmse"]))
    assert user["rmse"][first] < 3 * kf["rmse"][first]


def test_user_rig_runs_with_the_builtin_kalman_filter():
    import pendulum  # noqa: F401  (registers the rig)

    sc = Scenario(rig="pendulum", estimator="kalman", duration_s=2.0,
                  setpoints=[(0.0, 0.2)])
    traj, summary = runner.run(sc, progress=False)
    assert 0.05 < traj.state[-1, 0] < 0.25  # the LQR moves the angle toward the setpoint
    assert summary["rmse"]["angle"] < 2e-3
    mc = runner.monte_carlo(sc, runs=3, progress=False)
    assert mc["units"]["angle"] == "rad" and mc["runs"] == 3
    done = _cli("run", "pendulum:PendulumRig", "--duration", "1", "--no-progress")
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("rig", ["helicopter", "vehicle-roll"])
def test_deadband_decorator_on_both_rigs(rig):
    from deadband import Deadband

    from testbed.rigs import resolve_rig

    base = resolve_rig(rig)().sensors(None)
    sensors = Deadband(base, width=1e-3)
    traj, _ = runner.run(Scenario(rig=rig, sensors=sensors, duration_s=2.0), progress=False)
    y = traj.measurement
    assert np.all((y == 0) | (np.abs(y) > 1e-3))
    assert np.any(y == 0) and np.any(y != 0)


def test_the_gymnasium_loop_snippet_runs(capsys):
    """The last snippet of docs/extending.md, executed as written."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "extending.md").read_text()
    section = text.split("## In your own Gymnasium loop", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    exec(compile(code, "extending.md", "exec"), {})
    assert "roll" in capsys.readouterr().out
