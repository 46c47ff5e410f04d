"""Estimators over a recording (testbed.experiment.replay): the run's estimates bitwise, the
innovation consistency, the held-out reference, bad input, plug-ins, outputs, speed."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from filters import KalmanFilter
from testbed.experiment import runner
from testbed.experiment.replay import (
    INPUT_CONVENTION,
    recording_from_result,
    replay,
    simulate_recording,
)
from testbed.experiment.scenario import Scenario
from testbed.io.recording import Recording

EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples"
#: The paper preset with a small intensity: white Gaussian channels the design models.
PAPER_SENSORS = {"intensity": 1e-4 * np.eye(2)}


def _run(**fields):
    traj, summary = runner.run(Scenario(rig="helicopter", estimator="kalman", **fields))
    return traj, summary


@pytest.fixture(scope="module")
def paper_run():
    return _run(duration_s=3.0, seed=5)


@pytest.fixture(scope="module")
def consistent_run():
    return _run(duration_s=10.0, seed=2, sensors="paper", sensor_options=PAPER_SENSORS)


def scaled_r_kalman(design, scale=0.1):
    """A user's Kalman filter that believes the noise is ``scale`` times what it is."""
    system = dataclasses.replace(design.discrete, R=design.discrete.R * scale)
    kf = KalmanFilter(system, design.x0, design.P0)
    kf.batched = True
    return kf


class Counting:
    """A user's estimator that counts its steps (nothing else)."""

    steps = 0

    def __init__(self, design):
        self.x, self.P = np.array(design.x0, float), None

    def reset(self, x0, P0):
        self.x = np.array(x0, float)

    def step(self, y, u):
        Counting.steps += 1
        return self.x


def counting(design):
    return Counting(design)


# ------------------------------------------------------------------ the recording
def test_recording_has_the_loop_samples_in_the_log_convention_and_no_truth(paper_run):
    traj, _ = paper_run
    rec = recording_from_result(paper_run)
    assert isinstance(rec, Recording) and rec.n_samples == len(traj.t_s)
    assert set(rec.inputs) == {"V_pitch", "V_yaw"} and list(rec.channels) == ["pitch", "yaw"]
    np.testing.assert_array_equal(rec.time_s, np.arange(rec.n_samples) * 0.01)
    # row k: the input held over [t_k, t_k+1) = the loop's action row k + 1
    np.testing.assert_array_equal(rec.inputs["V_pitch"][:-1], traj.action[1:, 0])
    np.testing.assert_array_equal(rec.inputs["V_yaw"][-1], traj.action[-1, 1])
    np.testing.assert_array_equal(rec.channels["yaw"], traj.measurement[:, 1])
    assert rec.meta["input_convention"] == INPUT_CONVENTION
    assert (rec.meta["rig"], rec.meta["profile"], rec.meta["seed"]) == ("helicopter", "paper", 5)
    text = json.dumps(rec.meta, default=str)
    assert "params" not in rec.meta["scenario"] and "state" not in rec.meta
    assert "pitch_rate" not in rec.channels and "x0" not in text


def test_loop_result_and_tape_give_the_trajectorys_recording(paper_run):
    scenario = Scenario(rig="helicopter", estimator="kalman", duration_s=3.0, seed=5)
    experiment = runner.build(scenario, 1, num_threads=1)
    try:
        result = experiment.loop.run(np.array([5]), 3.0, record=True, tape=True)
    finally:
        experiment.close()
    want = recording_from_result(paper_run)
    simulated = simulate_recording(scenario)
    for given in (result, dataclasses.replace(result, tape=None), result.tape, simulated):
        got = given if isinstance(given, Recording) else \
            recording_from_result(given, experiment=experiment)
        assert got.meta["seed"] == 5 and got.meta["rig"] == "helicopter"
        for key in ("inputs", "channels"):
            for name, values in getattr(want, key).items():
                np.testing.assert_array_equal(getattr(got, key)[name], values)
    with pytest.raises(ValueError, match="experiment="):
        recording_from_result(result)
    with pytest.raises(ValueError, match="member"):
        recording_from_result(result, experiment=experiment, member=1)


def test_a_decimated_trajectory_is_refused(paper_run):
    traj, _ = paper_run
    decimated = dataclasses.replace(traj, meta=dict(traj.meta, recorded_every_steps=2))
    with pytest.raises(ValueError, match="every 2th step"):
        recording_from_result(decimated)
    with pytest.raises(ValueError, match="must be a Trajectory"):
        recording_from_result({"t_s": traj.t_s})


# ------------------------------------------------------------------ bitwise
@pytest.mark.parametrize(("rig", "profile"), [("helicopter", "paper"),
                                              ("helicopter", "hardware"),
                                              ("vehicle-roll", "paper")])  # a tapped input
def test_replay_gives_the_runs_estimates_bitwise(rig, profile):
    traj, summary = runner.run(Scenario(rig=rig, estimator="kalman", duration_s=3.0, seed=7,
                                        profile=profile))
    rec = recording_from_result((traj, summary))
    result = replay(rec, rig=rig, profile=profile, estimator="kalman")
    np.testing.assert_array_equal(result.x_hat, traj.estimate)
    np.testing.assert_array_equal(result.P_diag,
                                  np.diagonal(traj.covariance, axis1=1, axis2=2))
    assert result.steps == summary["steps"] == 300
    np.testing.assert_array_equal(result.time_s, rec.time_s)


@pytest.mark.parametrize(("rig", "profile"), [("helicopter", "paper"), ("aero", "hardware")])
def test_the_kalman_record_by_blocks_equals_the_per_step_record(rig, profile, monkeypatch):
    """The Kalman filter's block path (its covariance steps first, then the mean's
    arithmetic, the record copied per block) equals the stage stepped and read after every
    step: estimates, variances, innovations and their covariances, across block
    boundaries."""
    from testbed.experiment import replay_collect

    rec = recording_from_result(runner.run(Scenario(rig=rig, profile=profile, duration_s=2.0,
                                                    seed=4, frame_skip=2)))
    monkeypatch.setattr(replay_collect.Collector, "BLOCK", 97)
    blocks = replay(rec, rig=rig, profile=profile)
    monkeypatch.setattr(replay_collect.Collector, "block",
                        lambda self, j0, j1: self._generic(j0, j1))
    steps = replay(rec, rig=rig, profile=profile)
    assert blocks.steps == 1000
    for name in ("x_hat", "P_diag", "innovations", "innovation_cov", "nis"):
        np.testing.assert_array_equal(getattr(blocks, name), getattr(steps, name), name)
    assert blocks.consistency == steps.consistency


@pytest.mark.parametrize("kwargs", [{"reference": "yaw"},  # behind a channel selection
                                    {"sensors": "hardware"},  # an IMU: 5 channels, D != 0
                                    {"sensors": "hardware", "reference": "pitch",
                                     "exclude": ("yaw",)}])
def test_the_block_path_behind_a_channel_selection_equals_the_stage(kwargs, monkeypatch):
    from testbed.experiment import replay_collect

    rec = recording_from_result(runner.run(Scenario(rig="helicopter", duration_s=2.0, seed=6,
                                                    sensors="hardware")))
    blocks = replay(rec, rig="helicopter", **kwargs)
    monkeypatch.setattr(replay_collect.Collector, "block",
                        lambda self, j0, j1: self._generic(j0, j1))
    steps = replay(rec, rig="helicopter", **kwargs)
    for name in ("x_hat", "P_diag", "innovations", "innovation_cov"):
        np.testing.assert_array_equal(getattr(blocks, name), getattr(steps, name), name)
    if "reference" in kwargs:
        assert blocks.reference == steps.reference


def test_shared_covariance_step_is_the_steps_own():
    """filters.KalmanFilter.shared_covariance_step returns the arrays the next step uses."""
    from testbed.rigs.helicopter import HelicopterRig

    design = HelicopterRig().design_model(HelicopterRig().sensors(None, dt_s=0.01), 0.01)
    kf = KalmanFilter(design.discrete, design.x0[None], design.P0)
    S, K, P = kf.shared_covariance_step(kf.shared_P, 1)
    kf.step(np.zeros((1, design.discrete.m)), np.zeros((1, design.discrete.k)))
    for used, given in ((kf.shared_innovation_cov, S), (kf.shared_P, P)):
        assert np.shares_memory(used, given)
        np.testing.assert_array_equal(used, given)
    np.testing.assert_array_equal(kf.gain[0], K)
    assert not (S.flags.writeable or K.flags.writeable or P.flags.writeable)


def test_the_covariance_is_not_stepped_past_its_fixed_point(monkeypatch):
    """The helicopter's paper design settles into a short cycle of its covariance recursion
    (bitwise; at 1 kHz a fixed point): the block path stops stepping it once a covariance
    comes back (and its record still equals the stage's, test above); the yaw-locked Aero's
    hardware design does not settle, every step is taken."""
    from filters import KalmanFilter as KF

    calls = []
    own = KF.shared_covariance_step

    def counted(self, P, steps):
        calls.append(steps)
        return own(self, P, steps)

    monkeypatch.setattr(KF, "shared_covariance_step", counted)
    rec = recording_from_result(runner.run(Scenario(rig="helicopter", duration_s=3.0,
                                                    seed=4)))
    settled = replay(rec, rig="helicopter")
    assert 2 <= len(calls) < 100 and calls == list(range(2, 2 + len(calls)))
    # past it the innovation covariances and variances repeat with a short period
    last = calls[-1]
    period = next(c for c in range(1, 17)
                  if np.array_equal(settled.P_diag[last - c:-c], settled.P_diag[last:]))
    np.testing.assert_array_equal(settled.innovation_cov[last - 1 - period:-period],
                                  settled.innovation_cov[last - 1:])
    calls.clear()
    aero = {"rig": "aero", "profile": "hardware", "options": {"yaw_locked": True}}
    rec = recording_from_result(runner.run(Scenario(rig="aero", profile="hardware",
                                                    rig_options={"yaw_locked": True},
                                                    duration_s=1.0, seed=4)))
    result = replay(rec, **aero)
    assert calls == list(range(2, result.steps + 1))


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning",
                            "ignore:invalid value encountered:RuntimeWarning")
def test_a_failing_block_is_stepped_again_by_the_stage_and_fails_as_the_run(monkeypatch):
    """An estimate that escapes (a channel of 1e308 in row 150): the block path hands the
    replay back to the stage from the reset, which raises what it raises step by step (the
    same error, at the same step)."""
    from filters.errors import FiniteEscapeError
    from testbed.experiment import replay_collect

    rec = recording_from_result(runner.run(Scenario(rig="helicopter", duration_s=3.0,
                                                    seed=4)))
    pitch = rec.channels["pitch"].copy()
    pitch[150:] = 1e308
    rec = dataclasses.replace(rec, channels=dict(rec.channels, pitch=pitch))
    with pytest.raises(FiniteEscapeError) as blocks:
        replay(rec, rig="helicopter")
    monkeypatch.setattr(replay_collect.Collector, "block",
                        lambda self, j0, j1: self._generic(j0, j1))
    with pytest.raises(FiniteEscapeError) as steps:
        replay(rec, rig="helicopter")
    assert str(blocks.value) == str(steps.value) and blocks.value.time == steps.value.time
    assert 1.5 <= blocks.value.time < 3.0


def test_an_unbatched_kalman_plugin_replays_member_by_member(paper_run):
    """A factory returning an unbatched Kalman filter (a wrapper declaring batched = False):
    stepped as one member (estimators.PerMember), its innovations read after each step."""
    from testbed.estimators import EstimatorWrapper

    rec = recording_from_result(paper_run)

    class Unbatched(EstimatorWrapper):
        batched = False

    def plain(design):
        return Unbatched(KalmanFilter(design.discrete, design.x0, design.P0))

    alone = replay(rec, rig="helicopter", estimator=plain)
    batched = replay(rec, rig="helicopter", estimator="kalman")
    assert alone.innovations.shape == batched.innovations.shape
    np.testing.assert_allclose(alone.x_hat, batched.x_hat, rtol=1e-9, atol=1e-12)
    assert alone.consistency["anis"] == pytest.approx(batched.consistency["anis"], rel=1e-6)


def test_a_held_multi_rate_channel_replays_bitwise():
    from testbed.rigs.helicopter import HelicopterRig
    from testbed.sensors import SampleAndHold, StateChannel, Suite, WhiteNoise

    def suite():
        encoders = HelicopterRig().sensors("encoders")
        gyro = WhiteNoise(StateChannel(2, 4, 2, "gyro_pitch", "rad/s"), std=0.01)
        return Suite(encoders, SampleAndHold(gyro, 4))  # a gyro at a quarter of the rate

    scenario = Scenario(rig="helicopter", estimator="kalman", duration_s=2.0, seed=3,
                        sensors=suite())
    experiment = runner.build(scenario, 1, num_threads=1)
    try:
        run = experiment.loop.run(np.array([3]), 2.0, record=True)
    finally:
        experiment.close()
    rec = recording_from_result(run, experiment=experiment)
    gyro = rec.channels["gyro_pitch"]
    assert np.all(gyro[1:4] == gyro[0]) and gyro[4] != gyro[3]  # held between samples
    assert rec.meta["hold_samples"] == {"gyro_pitch": 4}
    result = replay(rec, rig="helicopter", sensors=suite())
    np.testing.assert_array_equal(result.x_hat, run.trajectory["estimate"][0])


def test_period_takes_every_kth_sample_and_holds_its_input(paper_run):
    rec = recording_from_result(paper_run)
    coarse = replay(rec, rig="helicopter", period_s=0.02)
    # the same, written out: every second row, the input of each row held over two periods
    rows = slice(0, None, 2)
    by_hand = Recording(time_s=rec.time_s[rows],
                        inputs={k: v[rows] for k, v in rec.inputs.items()},
                        channels={k: v[rows] for k, v in rec.channels.items()})
    np.testing.assert_array_equal(coarse.x_hat, replay(by_hand, rig="helicopter").x_hat)
    assert coarse.every == 2 and coarse.period_s == 0.02 and coarse.steps == 150


# ------------------------------------------------------------------ consistency
def test_consistent_filter_inside_its_band_mistuned_one_overconfident(consistent_run):
    rec = recording_from_result(consistent_run)
    good = replay(rec, rig="helicopter", sensors="paper", sensor_options=PAPER_SENSORS)
    c = good.consistency
    K, m = good.steps, 2
    # independently: NIS from the innovations and S, the band of a K-step average
    nis = np.einsum("ki,ki->k", good.innovations,
                    np.linalg.solve(good.innovation_cov, good.innovations[..., None])[..., 0])
    np.testing.assert_allclose(good.nis, nis, rtol=1e-10)
    np.testing.assert_allclose(c["anis"], nis.mean(), rtol=1e-12)
    np.testing.assert_allclose(c["band"], chi2.ppf([0.025, 0.975], K * m) / K, rtol=1e-12)
    np.testing.assert_allclose(c["step_band"], chi2.ppf([0.025, 0.975], m), rtol=1e-12)
    outside = np.mean((nis < chi2.ppf(0.025, m)) | (nis > chi2.ppf(0.975, m)))
    assert c["band_fraction"] == pytest.approx(outside)
    assert c["band"][0] <= c["anis"] <= c["band"][1] and c["verdict"] == "consistent"
    assert c["band_fraction_ci"][0] <= 0.05 <= c["band_fraction_ci"][1]
    assert c["whiteness"]["verdict"] == "white"

    bad = replay(rec, rig="helicopter", sensors="paper", sensor_options=PAPER_SENSORS,
                 estimator=scaled_r_kalman, estimator_options={"scale": 0.1})
    assert bad.consistency["verdict"] == "overconfident"
    assert bad.consistency["anis"] > 5 * c["anis"]  # S about 10 times too small
    assert bad.consistency["band_fraction"] > 0.5


def test_reference_channel_rmse_matches_the_true_error_of_an_imu_only_replay():
    traj, _ = _run(duration_s=10.0, seed=4, sensors="hardware")
    rec = recording_from_result(traj)
    result = replay(rec, rig="helicopter", sensors="hardware", reference="pitch",
                    exclude=("yaw",))
    assert result.innovation_names == ["gyro_pitch", "gyro_yaw", "accel_x"]  # IMU only
    ref = result.reference
    assert (ref["channel"], ref["state"], ref["samples"]) == ("pitch", "pitch", 1000)
    # the held-out encoder against the pitch estimate, written out
    rmse = np.sqrt(np.mean((rec.channels["pitch"][1:] - result.x_hat[1:, 0]) ** 2))
    assert ref["rmse"] == pytest.approx(rmse, rel=1e-12)
    true = np.sqrt(np.mean((result.x_hat[1:, 0] - traj.state[1:, 0]) ** 2))
    assert 0.8 < ref["rmse"] / true < 1.25  # the encoder's resolution is far below the error
    with_encoder = replay(rec, rig="helicopter", sensors="hardware")
    assert np.sqrt(np.mean((with_encoder.x_hat[1:, 0] - traj.state[1:, 0]) ** 2)) < true / 2


# ------------------------------------------------------------------ bad input
def _without(rec, *, inputs=(), channels=()):
    return dataclasses.replace(
        rec, inputs={k: v for k, v in rec.inputs.items() if k not in inputs},
        channels={k: v for k, v in rec.channels.items() if k not in channels})


@pytest.mark.parametrize(("change", "kwargs", "message"), [
    ({"inputs": ("V_yaw",)}, {}, "no input 'V_yaw'"),
    ({"channels": ("yaw",)}, {}, "no channel 'yaw', which filter"),
    ({}, {"period_s": 0.015}, "whole multiple"),
    ({}, {"period_s": -0.01}, "whole multiple"),
    ({"channels": ("pitch",)}, {"reference": "pitch"}, "no channel 'pitch' \\(reference\\)"),
    ({}, {"reference": "gyro_pitch"}, "not a channel of the sensors"),
    ({}, {"profile": "lab"}, "unknown profile"),
    ({}, {"options": {"yaw_locked": True}}, "has no option .yaw_locked."),
    ({}, {"params": "twin.toml"}, "params must be a HelicopterParams"),
    ({}, {"sensors": "lidar"}, "unknown helicopter sensor preset"),
])
def test_bad_input_is_one_line_before_any_step(paper_run, change, kwargs, message):
    rec = _without(recording_from_result(paper_run), **change)
    Counting.steps = 0
    with pytest.raises(ValueError, match=message) as err:
        replay(rec, rig="helicopter", estimator=counting, **kwargs)
    assert "\n" not in str(err.value) and Counting.steps == 0


def test_a_non_uniform_recording_is_refused(paper_run):
    rec = recording_from_result(paper_run)
    t = rec.time_s.copy()
    t[10:] += 0.004
    with pytest.raises(ValueError, match="uniform rate .* row 10"):
        replay(dataclasses.replace(rec, time_s=t), rig="helicopter")


def test_the_designers_parameters_reach_the_design(paper_run):
    from testbed.rigs.helicopter.rig import HelicopterParams

    traj, _ = _run(duration_s=2.0, seed=1, profile="hardware")
    rec = recording_from_result(traj)
    twin = HelicopterParams().scaled({"mass_kg": 1.2, "pitch_damping": 1.2})
    nominal = replay(rec, rig="helicopter", profile="hardware")
    other = replay(rec, rig="helicopter", profile="hardware", params=twin)
    assert np.abs(other.x_hat - nominal.x_hat).max() > 1e-3
    same = replay(rec, rig="helicopter", profile="hardware", params=HelicopterParams())
    np.testing.assert_array_equal(same.x_hat, nominal.x_hat)


# ------------------------------------------------------------------ plug-ins, outputs
def test_a_plugin_estimator_by_import_path_runs_on_a_replay(paper_run, monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))
    traj, _ = paper_run
    rec = recording_from_result(paper_run)
    user = replay(rec, rig="helicopter", estimator="userkf:make")
    assert user.estimator == "userkf:make" and user.x_hat.shape == traj.estimate.shape
    assert user.consistency is None and "no consistency" in user.notes[0]
    err_user = np.sqrt(np.mean((user.x_hat[1:] - traj.state[1:]) ** 2, axis=0))
    err_kf = np.sqrt(np.mean((traj.estimate[1:] - traj.state[1:]) ** 2, axis=0))
    assert np.all(err_user < 3 * err_kf + 1e-9)


def test_json_plot_and_rerun(consistent_run, tmp_path):
    from testbed.outputs.replay import log_replay_rerun, plot_replay
    from testbed.outputs.viz import rrd_summary

    rec = dataclasses.replace(recording_from_result(consistent_run), source="log.csv",
                              sha256="ab" * 32)
    result = replay(rec, rig="helicopter", sensors="paper", sensor_options=PAPER_SENSORS,
                    reference="pitch")
    out = json.loads(json.dumps(result.to_json()))
    assert out["recording"] == {"source": "log.csv", "sha256": "ab" * 32}
    assert (out["rig"], out["estimator"], out["n_samples"], out["period_s"]) == \
        ("helicopter", "kalman", 1001, 0.01)
    assert set(out["consistency"]["whiteness"]) >= {"lags", "z", "p"}
    assert out["reference"]["channel"] == "pitch" and out["estimates"]["pitch"]["std_final"] > 0
    png = plot_replay(result, tmp_path / "replay.png")
    assert png.stat().st_size > 10_000
    rrd = log_replay_rerun(result, tmp_path / "replay.rrd")
    rows = rrd_summary(rrd)
    assert rows.get("state/pitch/estimate") == 1001
    assert rows.get("innovation/yaw/plus_3sigma") == 1000
    assert rows.get("measurement/pitch") == 1001


# ------------------------------------------------------------------ speed
@pytest.mark.slow
def test_speed_of_a_30_s_recording_at_1_khz():
    scenario = Scenario(rig="helicopter", estimator="kalman", duration_s=30.0, frame_skip=1,
                        seed=1)
    experiment = runner.build(scenario, 1, num_threads=1)
    try:
        result = experiment.loop.run(np.array([1]), 30.0, record=True)
    finally:
        experiment.close()
    rec = recording_from_result(result, experiment=experiment)
    start = time.perf_counter()
    out = replay(rec, rig="helicopter")
    wall = time.perf_counter() - start
    np.testing.assert_array_equal(out.x_hat, result.trajectory["estimate"][0])
    print(f"replay 30 s at 1 kHz: loop {out.wall_s:.3f} s ({out.real_time_factor:.0f}x real "
          f"time; CPU {out.cpu_s:.3f} s, {out.cpu_real_time_factor:.0f}x), with the build "
          f"{wall:.3f} s")
    assert out.real_time_factor > 5  # a guard only: the machine is shared (see the report)
