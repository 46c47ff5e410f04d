"""``monte_carlo`` sharded over local processes or Ray equals the in-process study."""

from __future__ import annotations

import importlib.util
import json

import pytest

from testbed.cli import main
from testbed.experiment.runner import monte_carlo
from testbed.experiment.scenario import Scenario

#: Everything but timings and where it ran.
_TIMING = ("wall_s", "traj_steps_per_s", "backend", "workers", "batch_size", "threads")


def _results(result: dict) -> dict:
    return {k: v for k, v in result.items() if k not in _TIMING}


def test_local_shards_equal_the_in_process_study():
    scenario = Scenario(rig="vehicle-roll", estimator="kalman", seed=3, duration_s=0.3)
    one = monte_carlo(scenario, 5, progress=False)
    sharded = monte_carlo(scenario, 5, progress=False, backend="local", workers=2)
    assert sharded["backend"] == "local" and sharded["workers"] == 2
    assert _results(sharded) == _results(one)


def test_sharded_study_writes_no_npz_or_envelope(tmp_path):
    scenario = Scenario(rig="helicopter", estimator="kalman", duration_s=0.1)
    with pytest.raises(ValueError, match="npz"):
        monte_carlo(scenario, 2, progress=False, backend="local", save_npz=tmp_path / "a.npz")
    assert main(["mc", "helicopter", "--runs", "2", "--workers", "2",
                 "--plot", str(tmp_path / "a.png")]) == 2  # --workers alone means local


def test_workers_alone_shard_locally(tmp_path, capsys):
    """``mc --workers N`` without ``--backend`` is the local backend (the same results)."""
    args = ["mc", "helicopter", "--runs", "3", "--duration", "0.2", "--no-progress", "--json"]
    assert main([*args, str(tmp_path / "one.json")]) == 0
    assert main([*args, str(tmp_path / "two.json"), "--workers", "2"]) == 0
    one, two = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("one", "two"))
    assert two["backend"] == "local" and two["workers"] == 2
    assert two["rmse"] == one["rmse"]


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="needs Ray")
def test_cli_mc_on_ray_equals_the_local_run(tmp_path):
    args = ["mc", "helicopter", "--runs", "16", "--duration", "2", "--seed", "0",
            "--no-progress", "--json"]
    assert main([*args, str(tmp_path / "local.json")]) == 0
    assert main(["mc", "helicopter", "--backend", "ray", "--workers", "2", *args[2:],
                 str(tmp_path / "ray.json")]) == 0
    local, ray = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("local", "ray"))
    assert ray["rmse"] == local["rmse"]  # every RMSE, bitwise
    assert _results(ray) == _results(local)
