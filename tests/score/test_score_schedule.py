"""The suite's speed work changes no result: replayed episodes, parallel entries."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.experiment.backend import map_jobs
from testbed.score.harness import PairResult, entry_cost, run_entries, score_entry, score_pair
from testbed.score.suite import get_suite


def _entry(name: str, runs: int = 3, duration_s: float = 0.5):
    entry = next(e for e in get_suite("quick") if e.name == name)
    return entry.replace(runs=runs, scenario=entry.scenario.replace(duration_s=duration_s))


def _assert_same(a: PairResult, b: PairResult) -> None:
    assert (a.skipped, a.worst_skipped, a.notes) == (b.skipped, b.worst_skipped, b.notes)
    assert a.rmse_per_run.keys() == b.rmse_per_run.keys()
    for key, value in a.rmse_per_run.items():
        assert np.array_equal(value, b.rmse_per_run[key])
    for field in ("nees", "nis", "innovations"):
        x, y = getattr(a, field), getattr(b, field)
        assert (x is None) == (y is None), field
        if x is not None:
            assert np.array_equal(x, y), field
    for key, value in (a.trajectory or {}).items():
        assert np.array_equal(value, b.trajectory[key]), key
    if a.worst is not None:
        assert a.worst.worst_case_gain == b.worst.worst_case_gain
        assert np.array_equal(a.worst.worst_case_w, b.worst.worst_case_w)


@pytest.mark.parametrize("name", ["vehicle-dlc", "calibration"])
def test_replayed_estimators_equal_simulated_ones(name):
    """Every estimator after the first is replayed on the first one's episodes; each equals
    its own simulated run, bitwise (the vehicle's measured a_y reads the sensors' tap, the
    calibration entry draws the initial states from the prior)."""
    entry = _entry(name)
    shared = score_entry(entry, ["kalman", "kalman-bucy"], 0, worst_case=False)
    assert list(shared) == ["kalman", "kalman-bucy"]
    for estimator, pair in shared.items():
        assert pair.skipped is None
        _assert_same(pair, score_pair(entry, estimator, 0, worst_case=False))


def test_parallel_entries_equal_single_worker():
    entries = [_entry("calibration"), _entry("vehicle-dlc", duration_s=0.3)]
    single = run_entries(entries, ["kalman"], 0, workers=1, worst_case=False)
    parallel = run_entries(entries, ["kalman"], 0, workers=2, worst_case=False)
    assert [list(p) for p in single] == [list(p) for p in parallel]
    for a, b in zip(single, parallel, strict=True):
        for name in a:
            _assert_same(a[name], b[name])


def test_costs_change_the_order_of_execution_not_of_results():
    assert map_jobs(abs, [(-1,), (-2,), (-3,)], workers=2, costs=[1.0, 3.0, 2.0]) == [1, 2, 3]
    with pytest.raises(ValueError, match="costs"):
        map_jobs(abs, [(-1,)], costs=[1.0, 2.0])


def test_the_hardware_helicopter_entries_start_first():
    costs = {e.name: entry_cost(e) for e in get_suite("standard")}
    assert max(costs, key=costs.get) == "helicopter-hardware"
    assert all(c > 0 for c in costs.values())


def test_replayed_impulse_responses_equal_simulated_ones(monkeypatch):
    """The worst-case search's impulse run is simulated for the entry's first estimator and
    replayed for the others; every search equals its own simulated one, bitwise."""
    import dataclasses

    from testbed.experiment.loop import ClosedLoop

    entry = _entry("vehicle-dlc")
    entry = entry.replace(worst_case=dataclasses.replace(entry.worst_case, horizon_s=0.4))
    replays = []
    replay = ClosedLoop.replay

    def counted(self, tape, *args, **kwargs):
        replays.append(tape.state.shape[1])  # members: the MC's runs or the impulse's s + 1
        return replay(self, tape, *args, **kwargs)

    monkeypatch.setattr(ClosedLoop, "replay", counted)
    shared = score_entry(entry, ["kalman", "kalman-bucy"], 0)
    assert sorted(replays) == [2, entry.runs]  # kalman-bucy's Monte Carlo and impulse run
    for estimator, pair in shared.items():
        single = score_pair(entry, estimator, 0)
        _assert_same(pair, single)
        assert (pair.worst.random_gain, pair.worst.linear_gain) == \
            (single.worst.random_gain, single.worst.linear_gain)
