"""The ``testbed`` command line."""

from __future__ import annotations

import json

import pytest

from testbed.cli import main


def test_run_writes_json_png_rrd(tmp_path, capsys):
    out = tmp_path / "runs"
    code = main(["run", "helicopter", "--filter", "kalman", "--controller", "lqr",
                 "--duration", "1.5", "--seed", "0", "--json", str(out / "r.json"),
                 "--plot", str(out / "r.png"), "--rrd", str(out / "r.rrd"), "--no-progress"])
    assert code == 0
    data = json.loads((out / "r.json").read_text())
    assert data["rig"] == "helicopter" and data["filter"] == "kalman" and data["seed"] == 0
    assert data["duration_s"] == 1.5 and data["steps"] == 150
    assert set(data["rmse"]) == {"pitch", "yaw", "pitch_rate", "yaw_rate"}
    assert set(data["measurement_rmse"]) == {"pitch", "yaw"}
    assert data["nees_mean"] > 0
    assert (out / "r.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "r.rrd").stat().st_size > 1000
    assert sorted(p.name for p in out.iterdir()) == ["r.json", "r.png", "r.rrd"]
    printed = capsys.readouterr().out
    assert "estimate RMSE" in printed and "pitch" in printed


def test_bad_arguments_exit_with_a_message(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "helicopter", "--duration", "-1"])
    assert exc.value.code == 2
    assert main(["run", "helicopter", "--filter", "nope", "--duration", "0.1"]) == 2
    assert "nope" in capsys.readouterr().err
    assert main(["run", "helicopter", "--duration", "0.1", "--param", "mass_kg=-1"]) == 2
    assert "mass_kg" in capsys.readouterr().err


def test_run_vehicle_roll_writes_the_three_files(tmp_path):
    out = tmp_path / "v"
    code = main(["run", "vehicle-roll", "--filter", "kalman", "--manoeuvre",
                 "double-lane-change", "--sensors", "imu", "--duration", "2", "--seed", "0",
                 "--json", str(out / "r.json"), "--rrd", str(out / "r.rrd"),
                 "--plot", str(out / "r.png"), "--no-progress"])
    assert code == 0
    data = json.loads((out / "r.json").read_text())
    assert data["rig"] == "vehicle-roll" and data["steps"] == 200
    assert set(data["rmse"]) == {"roll", "roll_rate"}
    assert set(data["measurement_rmse"]) == {"roll_rate"}
    assert sorted(p.name for p in out.iterdir()) == ["r.json", "r.png", "r.rrd"]


def test_sensor_suite_must_match_the_rig(capsys):
    assert main(["run", "vehicle-roll", "--sensors", "encoders", "--duration", "0.1"]) == 2
    assert "vehicle-roll sensor preset" in capsys.readouterr().err
