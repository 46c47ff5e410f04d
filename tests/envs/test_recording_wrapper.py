"""RecordLog: what the sensors gave and the inputs as applied, one row per sample, no truth;
the rows of ``testbed run --save-log`` (recording_from_result)."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.envs import RigEnv
from testbed.envs.recording import RecordLog
from testbed.envs.wrappers import FilterInLoop
from testbed.io.formats import read_recording
from testbed.io.recording import RecordingError


def _episode(env, steps: int, seed: int = 2):
    """Drive ``env`` with inputs past the limits; what it gave, collected by hand."""
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    t, y, u = [info["t"]], [info.get("measurement", obs).copy()], []
    for _ in range(steps):
        obs, _, _, _, info = env.step(rng.uniform(-40.0, 40.0, env.action_space.shape))
        u.append(info["action_applied"].copy())
        t.append(info["t"])
        y.append(info.get("measurement", obs).copy())
    return np.array(t), np.array(y), np.array(u)


def test_rows_hold_the_measurement_and_the_input_applied_after_it(tmp_path):
    path = tmp_path / "episode.csv"
    env = RecordLog(RigEnv("helicopter"), path, meta={"operator": "test"})
    t, y, u = _episode(env, 120)
    rec = env.recording()
    assert rec.n_samples == 121 == env.steps + 1
    np.testing.assert_array_equal(rec.time_s, t)
    np.testing.assert_array_equal(rec.channel_matrix(("pitch", "yaw")), y)
    held = np.vstack([u, u[-1:]])  # the last row's input repeats the one before it
    np.testing.assert_array_equal(rec.input_matrix(("V_pitch", "V_yaw")), held)
    assert np.abs(u).max() == 24.0  # clipped by the amplifier, as applied
    assert set(rec.meta) == {"rig", "profile", "sensors", "control_dt_s", "seed", "operator",
                             "input_convention"}
    assert not path.exists()
    env.close()
    back = read_recording(path, rig="helicopter")
    np.testing.assert_array_equal(back.input_matrix(("V_pitch", "V_yaw")), held)
    assert back.meta == rec.meta
    env.close()  # a second close writes nothing new and does not fail


def test_a_slower_sensor_is_recorded_as_held_no_nan(tmp_path):
    from testbed.sensors import SampleAndHold, StateChannel, Suite, WhiteNoise

    names = ("pitch", "yaw", "pitch_rate", "yaw_rate")
    gyro = SampleAndHold(WhiteNoise(Suite(*(StateChannel(i, 4, 2, names[i], "rad/s")
                                             for i in (2, 3))), std=0.01), every=4)
    suite = Suite(StateChannel(0, 4, 2, "pitch", "rad"), gyro)
    env = RecordLog(RigEnv("helicopter", sensors=suite))
    _episode(env, 40)
    rec = env.recording()
    rate = rec.channels["pitch_rate"]
    assert np.isfinite(rate).all()
    changes = np.flatnonzero(np.diff(rate) != 0) + 1
    assert len(changes) == 10 and np.all(changes % 4 == 0)  # new samples every 4th step only
    assert len(np.unique(rec.channels["pitch"])) > 30  # the fast channel every step


def test_under_the_filter_wrapper_it_records_the_measurement(tmp_path):
    bare = RecordLog(RigEnv("vehicle-roll"))
    _episode(bare, 60, seed=7)
    filtered = RecordLog(FilterInLoop.from_design(RigEnv("vehicle-roll"), "kalman"))
    _episode(filtered, 60, seed=7)
    a, b = bare.recording(), filtered.recording()
    assert list(a.channels) == list(b.channels) == ["roll_rate", "lateral_accel", "speed",
                                                    "yaw_rate"]
    for name in a.channels:  # the sensors' values, not the estimate
        np.testing.assert_array_equal(a.channels[name], b.channels[name])
    np.testing.assert_array_equal(a.inputs["a_y"], b.inputs["a_y"])
    bare.close()
    filtered.close()


def test_checked_before_running_and_short_episodes(tmp_path):
    with pytest.raises(ValueError, match="must end in .csv, .npz, .mat"):
        RecordLog(RigEnv("helicopter"), tmp_path / "log.txt")
    path = tmp_path / "short.npz"
    env = RecordLog(RigEnv("helicopter"), path)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))
    env.reset(seed=0)
    with pytest.raises(RecordingError, match="no step recorded; a recording needs at least 1"):
        env.recording()
    env.close()
    assert not path.exists()
    env = RecordLog(RigEnv("helicopter"), path)
    _episode(env, 5)
    _episode(env, 1)  # a reset starts a new recording
    assert env.recording().n_samples == 2
    env.close()
    assert read_recording(path).n_samples == 2


@pytest.mark.parametrize(("rig", "profile"), [("helicopter", "paper"), ("aero", "hardware")])
def test_the_log_of_an_episode_is_the_recording_of_the_same_run(tmp_path, rig, profile):
    """RecordLog over the run's episode (its seed, its applied inputs) and
    recording_from_result of the run (``testbed run --save-log``): the same samples, bitwise,
    in memory and read back from the files both write."""
    from testbed.experiment import runner
    from testbed.experiment.replay import recording_from_result
    from testbed.experiment.scenario import Scenario
    from testbed.io.formats import write_recording

    result = runner.run(Scenario(rig=rig, profile=profile, duration_s=0.5, seed=3))
    traj = result[0]
    run = recording_from_result(result)
    env = RecordLog(RigEnv(rig, profile=profile), tmp_path / "env.csv")
    env.reset(seed=int(traj.meta["seed"]))
    for action in traj.action[1:]:  # row k + 1: the input applied over step k
        env.step(action)
    logged = env.recording()
    env.close()
    write_recording(tmp_path / "run.csv", run)
    for a, b in ((logged, run), (read_recording(tmp_path / "env.csv"),
                                 read_recording(tmp_path / "run.csv"))):
        assert a.n_samples == b.n_samples == len(traj.t_s)
        np.testing.assert_array_equal(a.time_s, b.time_s)
        assert list(a.inputs) == list(b.inputs) and list(a.channels) == list(b.channels)
        for name in a.inputs:
            np.testing.assert_array_equal(a.inputs[name], b.inputs[name])
        for name in a.channels:
            np.testing.assert_array_equal(a.channels[name], b.channels[name])
        assert a.meta["input_convention"] == b.meta["input_convention"]
