"""The runner: run, mc and sweep follow one code path (bitwise equal), on every rig."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.cli import main
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario

RIGS = [Scenario(rig="helicopter", duration_s=2.0, process_noise=1.0),
        Scenario(rig="vehicle-roll", duration_s=2.0)]


@pytest.mark.parametrize("scenario", RIGS, ids=["helicopter", "vehicle-roll"])
def test_mc_run_i_equals_run_with_its_seed(scenario):
    one = runner.monte_carlo(scenario.replace(seed=3), runs=1, progress=False)
    _, single = runner.run(scenario.replace(seed=one["seeds"][0]), record=False, progress=False)
    for name in single["rmse"]:  # the acceptance criterion: float equality
        assert one["rmse_per_run"][name][0] == single["rmse"][name]
    mc = runner.monte_carlo(scenario.replace(seed=3), runs=4, progress=False)
    for i in (0, 3):
        _, single = runner.run(scenario.replace(seed=mc["seeds"][i]), record=False,
                               progress=False)
        for name in single["rmse"]:  # row-wise products (vecmat): bitwise for any N
            assert mc["rmse_per_run"][name][i] == single["rmse"][name]


@pytest.mark.parametrize("scenario", RIGS, ids=["helicopter", "vehicle-roll"])
def test_results_do_not_depend_on_batch_size(scenario):
    a = runner.monte_carlo(scenario, runs=5, batch_size=5, progress=False)
    b = runner.monte_carlo(scenario, runs=5, batch_size=2, progress=False)
    assert a["seeds"] == b["seeds"]
    for name, values in a["rmse_per_run"].items():
        assert values == b["rmse_per_run"][name]


@pytest.mark.parametrize("rig, estimator", [("helicopter", "kalman"),
                                            ("helicopter", "kalman-bucy"),
                                            ("helicopter", "ms-hinf"),
                                            ("vehicle-roll", "kalman"),
                                            ("vehicle-roll", "lmi-hinf")])
def test_member_of_a_batch_equals_the_single_run_bitwise(rig, estimator):
    """Every trajectory (state, estimate, covariance) of member 2 of a batch of 4 equals the
    batch of 1 with its seed, for each batch-capable built-in estimator."""
    sc = Scenario(rig=rig, estimator=estimator, duration_s=1.0,
                  **({"process_noise": 0.5} if rig == "helicopter" else {}))
    seeds = runner.run_seeds(0, 4)
    results = []
    for num, members in ((4, seeds), (1, seeds[2:3])):
        experiment = runner.build(sc, num)
        try:
            results.append(experiment.loop.run(members, sc.duration_s, record=True))
        finally:
            experiment.close()
    batch, single = (r.trajectory for r in results)
    for key in ("state", "estimate", "measurement", "covariance"):
        if key in single:
            np.testing.assert_array_equal(batch[key][2], single[key][0], err_msg=key)


def test_seed_changes_outcome_and_same_seed_repeats():
    sc = RIGS[0]
    _, a = runner.run(sc.replace(seed=1), record=False, progress=False)
    _, b = runner.run(sc.replace(seed=1), record=False, progress=False)
    _, c = runner.run(sc.replace(seed=2), record=False, progress=False)
    assert a["rmse"] == b["rmse"] and a["rmse"] != c["rmse"]


def test_npz_holds_every_trajectory(tmp_path):
    path = tmp_path / "t.npz"
    res = runner.monte_carlo(RIGS[1], runs=3, progress=False, save_npz=path)
    data = np.load(path)
    assert data["state"].shape == (3, res["steps_per_run"] + 1, 2)
    assert np.array_equal(data["seeds"], res["seeds"])


def test_sweep_local_equals_the_mc_of_each_point():
    sc = RIGS[1].replace(duration_s=1.0)
    out = runner.sweep(sc, {"design.a_y_std": [0.05, 0.2]}, runs=2, workers=1, progress=False)
    assert len(out["points"]) == 2
    ref = runner.monte_carlo(sc.replace(design_options={"a_y_std": 0.2}), 2, progress=False)
    assert out["points"][1]["result"]["rmse_per_run"] == ref["rmse_per_run"]


@pytest.mark.slow
def test_sweep_ray_equals_local():
    pytest.importorskip("ray")
    sc = RIGS[1].replace(duration_s=0.5)
    grid = {"params.roll_damping": [0.9, 1.1]}
    local = runner.sweep(sc, grid, runs=2, workers=2, progress=False)
    ray = runner.sweep(sc, grid, runs=2, backend="ray", workers=2, progress=False)
    assert runner.without_timings(local) == runner.without_timings(ray)


@pytest.mark.parametrize("argv, needle", [
    (["run", "vehicle-roll", "--process-noise", "5"], "--process-noise"),
    (["run", "vehicle-roll", "--sensor-option", "noise_std_rad=1"], "--sensor-option"),
    (["run", "vehicle-roll", "--rig-option", "yaw_locked=true"], "--rig-option"),
    (["run", "vehicle-roll", "--disturbance", "basin-helicopter"], "--disturbance"),
    (["run", "helicopter", "--manoeuvre", "step-steer"], "manoeuvre"),
    (["run", "helicopter", "--design-option", "a_y_std=1"], "a_y_std"),
    (["run", "helicopter", "--filter", "nosuch"], "nosuch"),
    (["run", "helicopter", "--filter", "nosuchmodule:make"], "nosuchmodule"),
    (["mc", "vehicle-roll", "--filter", "ms-hinf", "--runs", "2"], "ms-hinf"),
])
def test_inapplicable_options_are_errors_naming_them(argv, needle, capsys):
    assert main([*argv, "--duration", "0.1", "--no-progress"]) == 2
    assert needle in capsys.readouterr().err


def test_cli_mc_vehicle_roll_json(tmp_path):
    path = tmp_path / "mc.json"
    assert main(["mc", "vehicle-roll", "--runs", "4", "--duration", "1", "--json", str(path),
                 "--no-progress"]) == 0
    import json

    data = json.loads(path.read_text())
    assert data["units"]["roll"] == "rad" and len(data["seeds"]) == 4


@pytest.mark.parametrize("profile, reads", [("paper", 1), ("hardware", 2)])
def test_a_run_reads_its_mjcf_at_most_twice(monkeypatch, profile, reads):
    """Check once, build once: the simulated, the controller's and the designer's rig share
    one reading of the MJCF per profile (the file is parsed, each rig gets a copy)."""
    import mujoco

    from testbed.rigs import mjcf

    paths: list[str] = []
    for owner, name in ((mujoco.MjModel, "from_xml_path"), (mujoco.MjSpec, "from_file")):
        original = getattr(owner, name)
        monkeypatch.setattr(owner, name,
                            lambda path, *a, _f=original, **k: paths.append(path) or _f(path))
    mjcf.read_mjcf.cache_clear()
    scenario = Scenario(rig="helicopter", duration_s=0.1, profile=profile)
    _, summary = runner.run(scenario, record=False, progress=False)
    mjcf.read_mjcf.cache_clear()
    assert len(paths) == reads and all(p.endswith("helicopter_2dof.xml") for p in paths)
    assert np.isfinite(summary["rmse"]["pitch"])


def test_lanes_share_the_covariance_memo_of_their_study(monkeypatch):
    """The lanes and batches of one study share one :class:`filters.kalman.CovarianceMemo`
    (the vehicle's covariance sequence computed once for all): every per-run number is
    bitwise the one without it, and each study has a memo of its own."""
    from filters.kalman import _AHEAD_STEPS, CovarianceMemo, KalmanFilter

    scenario = Scenario(rig="vehicle-roll", estimator="kalman", duration_s=0.5, seed=3)
    memos: list[CovarianceMemo] = []
    share = KalmanFilter.share_covariance_memo

    def recorded(self, memo):
        memos.append(memo)
        share(self, memo)

    monkeypatch.setattr(KalmanFilter, "share_covariance_memo", recorded)
    shared = [runner.monte_carlo(scenario, runs=6, num_threads=2),
              runner.monte_carlo(scenario, runs=7, batch_size=2, num_threads=1)]
    assert len(memos) == 2 + 2  # two lanes, then batches of 2 and of 1 (a separate build)
    assert len({id(m) for m in memos}) == 2  # one per study
    # 0.5 s at 10 ms: the sequence, computed once (in bursts of _AHEAD_STEPS steps)
    assert all(len(m) == -(-50 // _AHEAD_STEPS) * _AHEAD_STEPS for m in memos)
    monkeypatch.setattr(KalmanFilter, "share_covariance_memo", lambda self, memo: None)
    alone = [runner.monte_carlo(scenario, runs=6, num_threads=2),
             runner.monte_carlo(scenario, runs=7, batch_size=2, num_threads=1)]
    for a, b in zip(shared, alone, strict=True):
        assert a["rmse_per_run"] == b["rmse_per_run"]
        assert a["nees"] == b["nees"]


def test_lanes_equal_one_thread_and_a_failing_lane_stops_the_study(monkeypatch):
    """``num_threads`` > 1 runs contiguous parts of the runs on as many Python threads: the
    same per-run results as one thread; a lane's failure is raised once the others stop."""
    scenario = Scenario(rig="helicopter", duration_s=0.5, seed=4)
    one = runner.monte_carlo(scenario, runs=5, num_threads=1)
    three = runner.monte_carlo(scenario, runs=5, num_threads=3)
    assert three["threads"] == 3
    assert three["rmse_per_run"] == one["rmse_per_run"]
    assert three["nees"] == one["nees"]

    from testbed.experiment.loop import ClosedLoop

    run = ClosedLoop.run
    last = runner.run_seeds(4, 5)[-1]

    def failing(self, seeds, *args, **kwargs):
        if seeds[-1] == last:
            raise RuntimeError("lane failed")
        return run(self, seeds, *args, **kwargs)

    monkeypatch.setattr(ClosedLoop, "run", failing)
    with pytest.raises(RuntimeError, match="lane failed"):
        runner.monte_carlo(scenario.replace(duration_s=5.0), runs=5, num_threads=3)
