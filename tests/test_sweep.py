"""Sweeps: grid expansion, local processes, Ray (local 2-worker instance), the CLI."""

from __future__ import annotations

import json

import pytest

from testbed.cli import main
from testbed.sweep import grid_points, point_kwargs, sweep, without_timings

GRID = {"process_noise_scale": [0.0, 0.3], "params.mass_kg": [1.0, 1.1]}
STUDY = {"runs": 3, "duration_s": 0.5, "seed": 4, "progress": False}


def test_grid_points_and_kwargs():
    points = grid_points(GRID)
    assert len(points) == 4 and points[1] == {"process_noise_scale": 0.0, "params.mass_kg": 1.1}
    assert point_kwargs(points[1], {"params": {"com_m": 1.2}, "sensors": "paper"}) == {
        "process_noise_scale": 0.0, "params": {"com_m": 1.2, "mass_kg": 1.1},
        "sensors": "paper"}
    with pytest.raises(ValueError, match="no values"):
        grid_points({"gamma": []})


def test_bad_names_fail_before_any_work():
    with pytest.raises(TypeError):
        sweep({"not_an_argument": [1.0]}, **STUDY)
    with pytest.raises(ValueError, match="unknown params key"):
        sweep({"params.nope": [1.0]}, **STUDY)
    with pytest.raises(ValueError, match="backend"):
        sweep(GRID, backend="dask", **STUDY)


def test_local_processes_equal_serial_and_mismatch_shows():
    serial = sweep(GRID, workers=1, **STUDY)
    pooled = sweep(GRID, workers=2, **STUDY)
    assert without_timings(serial) == without_timings(pooled)
    rmse = {(p["point"]["process_noise_scale"], p["point"]["params.mass_kg"]):
            p["result"]["rmse"]["pitch"]["mean"] for p in serial["points"]}
    assert rmse[(0.0, 1.1)] != rmse[(0.0, 1.0)]  # the parameter reached the rig


def test_ray_backend_equals_local():
    pytest.importorskip("ray", reason="Ray is an optional extra: pip install -e .[ray]")
    local = sweep(GRID, workers=2, **STUDY)
    on_ray = sweep(GRID, backend="ray", workers=2, **STUDY)
    assert on_ray["backend"] == "ray"
    assert without_timings(local)["points"] == without_timings(on_ray)["points"]


def test_cli_mc_and_sweep(tmp_path):
    assert main(["mc", "helicopter", "--runs", "3", "--duration", "0.5", "--seed", "1",
                 "--process-noise", "0.2", "--json", str(tmp_path / "mc.json"),
                 "--no-progress"]) == 0
    mc = json.loads((tmp_path / "mc.json").read_text())
    assert {"runs", "steps_per_run", "wall_s", "traj_steps_per_s", "rmse", "nees_mean",
            "T_final"} <= set(mc)
    assert mc["runs"] == 3 and mc["steps_per_run"] == 50 and mc["T_final"] is None
    assert main(["sweep", "helicopter", "--runs", "2", "--duration", "0.3", "--grid",
                 "process_noise_scale=0,0.2", "--workers", "1", "--json",
                 str(tmp_path / "sw.json"), "--no-progress"]) == 0
    sw = json.loads((tmp_path / "sw.json").read_text())
    assert [p["point"] for p in sw["points"]] == [{"process_noise_scale": 0.0},
                                                  {"process_noise_scale": 0.2}]
    assert main(["sweep", "helicopter", "--grid", "gamma=oops", "--runs", "1"]) == 2
