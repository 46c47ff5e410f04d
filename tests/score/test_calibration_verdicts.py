"""Calibration of the harness's verdicts on the linear-Gaussian calibration plant.

The Kalman filter is exactly optimal there, so it must be consistent at every step (the
prior included); filters whose covariance is known to be wrong must be flagged, in the right
direction; two identical estimators must show no difference.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from testbed.score import report
from testbed.score.consistency import consistency_test
from testbed.score.harness import score, score_pair
from testbed.score.stats import chi2_bounds
from testbed.score.suite import calibration_entry

HERE = Path(__file__).resolve().parent
ESTIMATORS = ["kalman", "kalman-bucy", "fixed_gain:half_covariance",
              "fixed_gain:double_covariance", "fixed_gain:same_as_kalman"]


@pytest.fixture(scope="module")
def summary():
    """64 runs x 5 s (the quick suite's horizon; Kalman-Bucy's overconfidence grows over the
    first seconds with the plant's 6 s modal decay), seed 0, no worst-case search."""
    mp = pytest.MonkeyPatch()
    mp.syspath_prepend(str(HERE))
    try:
        run = score(ESTIMATORS, "quick", seed=0, runs=64, scenarios=["calibration"],
                    worst_case=False)
    finally:
        mp.undo()
    return {r["estimator"]: r for r in report.results(run)["results"]}


def test_kalman_at_64_runs_and_ten_times_more(summary):
    """The exact Kalman filter at seed 0, 64 runs x 5 s: its NEES mean test rejects at
    p = 0.002 (time average 2.10 [2.04, 2.17]; the band diagnostic accepts), a correct 5 %
    test's false alarm. The ten times larger Monte Carlo of the same entry and seed decides
    between chance and a modelling cause: consistent (p 0.41). Its first steps (the prior)
    are inside their band, its NIS is consistent and its innovations white."""
    kalman = summary["kalman"]
    nees, nis = kalman["nees_test"], kalman["nis_test"]
    assert nees["mean_p"] < 0.05 and nees["verdict"] == "overconfident"
    assert nees["steps_verdict"] == "consistent" and kalman["consistent"] is False
    assert nis["verdict"] == "consistent" and nis["mean_verdict"] == "consistent"
    lo, hi = nees["band"]
    assert all(lo <= v <= hi for v in nees["per_step"][:2])  # steps 1 and 2: the prior
    # about 5 % of the steps outside their band, as for a consistent filter
    assert nees["steps_outside_ci"][0] <= 0.05 <= nees["steps_outside_ci"][1]
    assert nis["steps_outside_ci"][0] <= 0.05 <= nis["steps_outside_ci"][1]
    assert kalman["whiteness"]["verdict"] == "white"
    assert kalman["versus_reference"] is None  # it is the reference
    larger = score_pair(calibration_entry(640, 5.0, None), "kalman", 0, worst_case=False)
    for values, dim in ((larger.nees, 2), (larger.nis, 1)):
        test = consistency_test(values, dim)
        assert test["verdict"] == "consistent" and test["mean_p"] > 0.05


def test_the_prior_agrees_with_the_first_draw_and_update():
    """1000 runs of three steps: the N-run average NEES at steps 1-3 within the 1000-run
    band [1.88, 2.13] (before the fix, the initial state was drawn from the run's own noise
    stream: about 3.1 and 2.7 at steps 1 and 2)."""
    pair = score_pair(calibration_entry(1000, 0.03, None), "kalman", 0, worst_case=False)
    lo, hi = chi2_bounds(1000, 2)
    per_step = pair.nees.mean(axis=0)
    print(f"Kalman NEES at steps 1-3, 1000 runs: {np.round(per_step, 3)} band "
          f"[{lo:.3f}, {hi:.3f}]")
    assert np.all((lo <= per_step) & (per_step <= hi))
    assert consistency_test(pair.nis, 1)["mean_verdict"] == "consistent"


def test_kalman_bucy_is_overconfident(summary):
    kb = summary["kalman-bucy"]["nees_test"]
    assert kb["verdict"] == "overconfident" == kb["mean_verdict"] == kb["steps_verdict"]
    assert kb["mean_ci"][0] > 2 and kb["steps_outside_ci"][0] > 0.05
    assert summary["kalman-bucy"]["consistent"] is False


@pytest.mark.parametrize("name, verdict", [("fixed_gain:half_covariance", "overconfident"),
                                           ("fixed_gain:double_covariance", "underconfident")])
def test_scaled_covariance_is_flagged_in_its_direction(summary, name, verdict):
    test = summary[name]["nees_test"]
    assert test["verdict"] == verdict
    factor = 2.0 if verdict == "overconfident" else 0.5
    assert test["mean"] == pytest.approx(factor * summary["kalman"]["nees_test"]["mean"],
                                         rel=1e-9)


def test_paired_comparisons_with_the_reference(summary):
    same = summary["fixed_gain:same_as_kalman"]["versus_reference"]
    assert same["reference"] == "kalman"
    for comparison in same["states"].values():  # identical numbers: exactly equivalent
        assert comparison["verdict"] == "equivalent"
        assert comparison["difference_ci"] == [0.0, 0.0] and comparison["ratio"] == 1.0
    kb = summary["kalman-bucy"]["versus_reference"]["states"]
    position = kb["position"]
    assert position["verdict"] == "worse" and position["ratio_ci"][0] > 1.02
    assert position["p_holm"] >= position["p_difference"]
    # velocity: ratio 1.006 [1.002, 1.010], a detectable difference inside the +-2 % margin
    assert kb["velocity"]["verdict"] == "equivalent"
    assert 1 < kb["velocity"]["ratio_ci"][0] and kb["velocity"]["ratio_ci"][1] < 1.02
    # common random numbers: the runs' MSEs are correlated, so the paired interval is narrow
    assert position["correlation"] > 0.5 and kb["velocity"]["correlation"] > 0.9
    # scaling P does not change the estimates: no difference from the reference
    for name in ("fixed_gain:half_covariance", "fixed_gain:double_covariance"):
        states = summary[name]["versus_reference"]["states"]
        assert all(c["mean_difference"] == 0.0 for c in states.values())
