"""The twin of a unit from the command line, as a new user would run it (the issue's
acceptance, shortened): record a simulated unit with a hidden stiffness, identify it,
compare, replay with and without a held-out channel, and run a study on the twin."""

from __future__ import annotations

import json
import os

import pytest

from testbed.cli import main


@pytest.fixture(scope="module")
def unit(tmp_path_factory):
    """A yaw-locked Aero on the hardware profile whose pitch stiffness is 2.2 x nominal,
    recorded for 30 s (the issue's command); then stiffness, viscous and Coulomb friction
    identified with the last 30 % held out."""
    folder = tmp_path_factory.mktemp("twin")
    cwd = os.getcwd()
    os.chdir(folder)  # relative paths, as typed
    try:
        assert main(["run", "aero", "--profile", "hardware", "--rig-option", "yaw_locked=true",
                     "--param", "pitch_stiffness=2.2", "--duration", "30", "--seed", "0",
                     "--save-log", "unit.csv", "--no-progress"]) == 0
        assert main(["identify", "unit.csv", "--rig", "aero", "--rig-option",
                     "yaw_locked=true", "--free",
                     "pitch_stiffness,pitch_damping,pitch_coulomb_Nm",
                     "--holdout", "0.3", "--json", "id.json", "--twin", "twin.toml",
                     "--plot", "id.png"]) == 0
    finally:
        os.chdir(cwd)
    return folder


def test_identify_reports_each_parameter_and_the_fit_per_channel(unit):
    result = json.loads((unit / "id.json").read_text())
    stiffness = result["parameters"]["pitch_stiffness"]
    assert set(stiffness) >= {"value", "ci95", "nominal", "identifiable"}
    assert stiffness["identifiable"]
    assert stiffness["value"] / stiffness["nominal"] == pytest.approx(2.2, rel=0.05)
    lo, hi = stiffness["ci95"]
    assert lo < stiffness["value"] < hi
    assert set(result["fit_percent"]) == set(result["holdout_fit_percent"]) >= {"pitch"}
    assert result["fit_percent"]["pitch"] > 95.0
    assert (unit / "twin.toml").is_file() and (unit / "id.png").stat().st_size > 0


def test_compare_of_the_twin_on_its_recording_gives_the_identify_fit(unit, capsys):
    cwd = os.getcwd()
    os.chdir(unit)
    try:
        assert main(["compare", "unit.csv", "--twin", "twin.toml", "--json", "cmp.json",
                     "--plot", "cmp.png", "--rrd", "cmp.rrd"]) == 0
        assert main(["compare", "unit.csv", "--rig", "aero", "--rig-option",
                     "yaw_locked=true", "--json", "nominal.json"]) == 0
    finally:
        os.chdir(cwd)
    twin = json.loads((unit / "cmp.json").read_text())["fit_percent"]
    identified = json.loads((unit / "id.json").read_text())["fit_percent"]
    assert twin == pytest.approx(identified, abs=1e-9)
    nominal = json.loads((unit / "nominal.json").read_text())["fit_percent"]
    assert nominal["pitch"] < twin["pitch"] - 5.0  # the nominal rig is not this unit
    assert (unit / "cmp.rrd").stat().st_size > 0


def test_replay_with_the_twin_and_a_held_out_reference(unit):
    cwd = os.getcwd()
    os.chdir(unit)
    try:
        assert main(["replay", "unit.csv", "--rig", "aero", "--twin", "twin.toml", "--filter",
                     "kalman", "--json", "rp.json", "--rrd", "rp.rrd", "--no-progress"]) == 0
        for twin in (True, False):
            extra = ["--twin", "twin.toml"] if twin else []
            assert main(["replay", "unit.csv", "--rig", "aero", *extra, "--filter", "kalman",
                         "--reference", "pitch", "--json", f"imu_{twin}.json",
                         "--no-progress"]) == 0
    finally:
        os.chdir(cwd)
    replayed = json.loads((unit / "rp.json").read_text())
    assert replayed["consistency"]["verdict"] in ("consistent", "overconfident",
                                                  "underconfident")
    assert replayed["recording"]["sha256"] and replayed["twin"]["sha256"]
    with_twin = json.loads((unit / "imu_True.json").read_text())["reference"]["rmse"]
    nominal = json.loads((unit / "imu_False.json").read_text())["reference"]["rmse"]
    assert with_twin < nominal  # the twin's design knows this unit's stiffness


def test_a_study_on_the_twin_and_gym_make_with_it(unit, capsys):
    import gymnasium as gym

    assert main(["mc", "aero", "--twin", str(unit / "twin.toml"), "--runs", "4", "--duration",
                 "1", "--json", str(unit / "mc.json"), "--no-progress"]) == 0
    scenario = json.loads((unit / "mc.json").read_text())["scenario"]
    assert scenario["profile"] == "hardware" and scenario["rig_options"] == {"yaw_locked": True}
    identified = json.loads((unit / "id.json").read_text())["parameters"]
    assert scenario["nominal_params"]["pitch_stiffness"] == \
        identified["pitch_stiffness"]["value"]
    env = gym.make("testbed/Aero2DOF-v0", twin=str(unit / "twin.toml"))
    assert env.unwrapped.nominal_params.pitch_stiffness == \
        identified["pitch_stiffness"]["value"]
    assert env.unwrapped.state_names == ["pitch", "pitch_rate"]
    with pytest.raises(ValueError, match="twin of rig 'aero'"):
        gym.make("testbed/Helicopter2DOF-v0", twin=str(unit / "twin.toml"))
    assert main(["mc", "helicopter", "--twin", str(unit / "twin.toml"), "--runs", "2"]) == 2
    assert "a twin of rig 'aero'" in capsys.readouterr().err


def test_describe_lists_what_a_recording_may_hold(capsys):
    assert main(["describe", "aero", "--rig-option", "yaw_locked=true"]) == 0
    out = capsys.readouterr().out
    assert "pitch_stiffness" in out and "gyro_pitch" in out and "yaw_locked" in out
    assert main(["describe", "aero", "--rig-option", "nope=1"]) == 2
