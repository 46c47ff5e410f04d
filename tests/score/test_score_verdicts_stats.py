"""The consistency tests and paired comparisons against scipy and Monte Carlo of their nulls."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps
from scipy.signal import lfilter

from testbed.score import consistency as cons
from testbed.score import paired
from testbed.score.stats import chi2_bounds


def ar_nees(rng: np.random.Generator, runs: int, steps: int, dim: int, phi: float,
            scale: float = 1.0) -> np.ndarray:
    """NEES of a consistent filter whose errors are AR(1) in time (coefficient ``phi``):
    every value is exactly chi2(dim) (times ``scale``), correlated over ~1/(1-phi^2) steps."""
    w = rng.standard_normal((runs, steps, dim))
    w[:, 0] /= np.sqrt(1 - phi**2)
    e = lfilter([np.sqrt(1 - phi**2)], [1, -phi], w, axis=1)
    return scale * np.sum(e**2, axis=-1)


# ---------------------------------------------------------------- against scipy
def test_t_interval_matches_scipy(rng):
    x = rng.normal(1.3, 2.0, size=17)
    mean, (lo, hi), p = cons.t_interval(x, 1.0)
    ref = sps.ttest_1samp(x, 1.0)
    ci = ref.confidence_interval(0.95)
    assert mean == pytest.approx(np.mean(x))
    assert (lo, hi) == pytest.approx((ci.low, ci.high), rel=1e-12)
    assert p == pytest.approx(ref.pvalue, rel=1e-10)
    assert cons.t_interval(np.full(5, 2.0), 2.0) == (2.0, (2.0, 2.0), 1.0)
    assert cons.t_interval(np.full(5, 2.0), 1.0)[2] == 0.0
    with pytest.raises(ValueError):
        cons.t_interval(np.array([1.0]))


@pytest.mark.parametrize("k, n", [(0, 10), (1, 10), (5, 10), (10, 10), (23, 500), (114, 500)])
def test_clopper_pearson_matches_scipy_binomtest(k, n):
    ci = sps.binomtest(k, n).proportion_ci(0.95, method="exact")
    assert cons.clopper_pearson(k, n) == pytest.approx((ci.low, ci.high), rel=1e-9, abs=1e-12)


def test_consistency_test_fields_against_scipy(rng):
    values = rng.chisquare(3, size=(20, 40))
    test = cons.consistency_test(values, 3)
    ref = sps.ttest_1samp(values.mean(axis=1), 3.0)
    assert test["mean"] == pytest.approx(values.mean())
    assert test["mean_ci"] == pytest.approx(list(ref.confidence_interval(0.95)), rel=1e-12)
    assert test["mean_p"] == pytest.approx(ref.pvalue, rel=1e-10)
    lo, hi = sps.chi2.ppf([0.025, 0.975], 60) / 20
    assert test["band"] == pytest.approx([lo, hi]) and tuple(test["band"]) == chi2_bounds(20, 3)
    per_step = values.mean(axis=0)
    assert test["steps_above"] == np.sum(per_step > hi)
    assert test["steps_below"] == np.sum(per_step < lo)
    assert test["per_step"] == pytest.approx(per_step, rel=1e-3)
    with pytest.raises(ValueError):
        cons.consistency_test(values[:1], 3)


def test_paired_comparison_matches_scipy(rng):
    common = rng.gamma(2.0, 1.0, size=30)
    a = common * 1.05 + 0.02 * rng.standard_normal(30)
    b = common
    c = paired.paired_comparison(a, b)
    ref = sps.ttest_rel(a, b)
    assert c["mean_difference"] == pytest.approx(np.mean(a - b))
    assert c["difference_ci"] == pytest.approx(list(ref.confidence_interval(0.95)), rel=1e-10)
    assert c["p_t"] == pytest.approx(ref.pvalue, rel=1e-10)
    assert c["p_wilcoxon"] == pytest.approx(sps.wilcoxon(a - b).pvalue, rel=1e-12)
    assert c["effect_size"] == pytest.approx(np.mean(a - b) / np.std(a - b, ddof=1))
    assert c["correlation"] == pytest.approx(sps.pearsonr(a, b).statistic)
    assert c["ratio"] == pytest.approx(np.mean(a) / np.mean(b))
    assert c["ratio_ci"][0] < c["ratio"] < c["ratio_ci"][1]


def test_margin_tests_are_the_interval_inclusions(rng):
    """Duality: the minimum-effect test rejects at 5 % exactly when the 95 % ratio interval
    lies outside [0.98, 1.02]; the two one-sided tests (Schuirmann 1987) exactly when the 90 %
    interval lies inside."""
    outcomes = set()
    for scale in np.linspace(0.95, 1.05, 41):
        common = rng.gamma(3.0, 1.0, size=24)
        a = common * scale * rng.gamma(400.0, 1 / 400.0, size=24)
        c95 = paired.paired_comparison(a, common)
        c90 = paired.paired_comparison(a, common, level=0.90)
        lo95, hi95 = c95["ratio_ci"]
        lo90, hi90 = c90["ratio_ci"]
        outside = hi95 < 0.98 or lo95 > 1.02
        inside = 0.98 < lo90 and hi90 < 1.02
        assert (c95["p_difference"] < 0.05) == outside
        assert (c95["p_equivalence"] < 0.05) == inside
        outcomes.add((outside, inside))
    assert outcomes >= {(True, False), (False, True), (False, False)}
    assert paired.margin_tests(1.0, 1.0, 0.0, 10) == (1.0, 0.0)  # identical: equivalent
    assert paired.margin_tests(1.0, 0.0, 0.0, 10) == (0.0, 1.0)
    with pytest.raises(ValueError):
        paired.margin_tests(1.0, 1.0, 0.1, 10, margin=0.0)


def test_holm_by_hand():
    # sorted p 0.01, 0.02, 0.04 times 3, 2, 1: 0.03, 0.04, 0.04 (made monotone)
    assert paired.holm([0.04, 0.01, 0.02]) == pytest.approx([0.04, 0.03, 0.04])
    assert paired.holm([0.5, 0.9]) == pytest.approx([1.0, 1.0])  # 2 x 0.5, then monotone
    assert paired.holm([0.2, 0.9]) == pytest.approx([0.4, 0.9])
    assert paired.holm([]) == []
    with pytest.raises(ValueError):
        paired.holm([1.5])
    # a declared family of 4 with two members untested: they enter with p = 1
    assert paired.holm([0.01, 0.02], family_size=4) == pytest.approx([0.04, 0.06])
    with pytest.raises(ValueError):
        paired.holm([0.1, 0.2], family_size=1)


def test_identical_estimators_are_equivalent(rng):
    a = rng.gamma(2.0, 1.0, size=12)
    out = paired.compare_family({"same": a, "other": 1.5 * a}, a)
    assert out["same"]["verdict"] == paired.EQUIVALENT
    assert out["same"]["difference_ci"] == [0.0, 0.0] and out["same"]["p_wilcoxon"] == 1.0
    assert out["same"]["ratio_ci"] == pytest.approx([1.0, 1.0])
    assert out["other"]["verdict"] == paired.WORSE
    assert paired.compare_family({"x": 0.5 * a}, a)["x"]["verdict"] == paired.BETTER
    noisy = a * rng.gamma(30.0, 1 / 30.0, size=12)  # a 2 % margin cannot be resolved
    assert paired.compare_family({"x": noisy}, a)["x"]["verdict"] == paired.INCONCLUSIVE
    text = paired.comparison_text(out["other"], "m^2")
    assert text.startswith("worse: ratio 1.5 [1.5, 1.5] (margin +-2 %), p_holm ")


def test_a_verdict_does_not_depend_on_the_other_estimators_scored(rng):
    """The family is declared (the lineup): scoring ukf beside ekf, or a user's estimator
    beside both, does not change ekf's adjusted p-values; scoring part of the lineup can
    only raise them (untested members at p = 1)."""
    from testbed.score.harness import PairResult
    from testbed.score.report import comparisons

    ref = rng.gamma(4.0, 1.0, size=(2, 20))
    per_run = {"kalman": ref,
               "ekf": ref * 1.001 + 1e-4 * rng.standard_normal((2, 20)),
               "ukf": ref * 1.001 + 1e-4 * rng.standard_normal((2, 20)),
               "mine": ref * 0.5}

    def pairs(names):
        return {n: PairResult(estimator=n, scenario="s", runs=20, rmse_per_run={
            "x": np.sqrt(per_run[n][0]), "y": np.sqrt(per_run[n][1])}) for n in names}

    lineup = ("kalman", "ekf", "ukf")
    both = comparisons(pairs(["kalman", "ekf", "ukf"]), ["ekf", "ukf"], "kalman",
                       lineup=lineup)
    with_mine = comparisons(pairs(["kalman", "ekf", "ukf", "mine"]), ["ekf", "ukf", "mine"],
                            "kalman", lineup=lineup)
    alone = comparisons(pairs(["kalman", "ekf"]), ["ekf"], "kalman", lineup=lineup)
    for state in ("x", "y"):
        full = both["ekf"]["states"][state]
        assert with_mine["ekf"]["states"][state] == full
        assert full["family_size"] == 4 and with_mine["mine"]["states"][state][
            "family_size"] == 6
        part = alone["ekf"]["states"][state]
        assert part["p_holm_difference"] >= full["p_holm_difference"]
        assert part["p_holm_equivalence"] >= full["p_holm_equivalence"]
        assert full["verdict"] == "equivalent"  # ratio 1.001: inside the margin
    assert both["ekf"]["family"] == "2 estimators x 2 states"


def test_ties_share_their_rank():
    from testbed.score.report import _ranks

    group = [{"estimator": n, "skipped": None, "rmse": {"x": v}}
             for n, v in (("a", 2.0), ("b", 1.0), ("c", 1.0 + 1e-23), ("d", 1.5))]
    assert _ranks(group) == {"b": 1, "c": 1, "d": 3, "a": 4}


# ---------------------------------------------------------------- Monte Carlo of the nulls
def test_mean_test_false_alarm_rate_with_correlated_steps():
    """Runs independent, steps correlated (AR(1), ~8x variance inflation as the calibration
    plant's Kalman filter): the verdict is the mean test, whose level is the stated 5 %; the
    band diagnostic at the effective number of steps does not false-alarm more than its
    level (before, at K steps, it did: 10 %), so "inconclusive" is rare."""
    rng = np.random.default_rng(7)
    reps = 600
    tests = [cons.consistency_test(ar_nees(rng, 32, 200, 2, 0.886), 2) for _ in range(reps)]
    mean_rate = np.mean([t["mean_verdict"] != cons.CONSISTENT for t in tests])
    step_rate = np.mean([t["steps_verdict"] != cons.CONSISTENT for t in tests])
    rejected = np.mean([t["verdict"] in (cons.OVERCONFIDENT, cons.UNDERCONFIDENT)
                        for t in tests])
    inconclusive = np.mean([t["verdict"] == cons.INCONCLUSIVE for t in tests])
    print(f"false alarms: mean test {mean_rate:.3f}, step test {step_rate:.3f}, "
          f"verdict {rejected:.3f}, inconclusive {inconclusive:.3f}")
    assert mean_rate == pytest.approx(0.05, abs=0.025)
    assert rejected == mean_rate  # the verdict's level is the mean test's
    assert step_rate <= 0.05 and inconclusive <= 0.05


def test_effective_steps_of_an_ar1_nees():
    """NEES = |e|^2 of AR(1) errors: the autocorrelation of e^2 is phi^(2l), so the time
    average's variance inflation is (1 + phi^2) / (1 - phi^2) (8.3 at phi = 0.886)."""
    rng = np.random.default_rng(12)
    phi, K = 0.886, 2000
    k_eff = cons.effective_steps(ar_nees(rng, 2000, K, 2, phi))
    assert k_eff == pytest.approx(K * (1 - phi**2) / (1 + phi**2), rel=0.05)
    white = cons.effective_steps(rng.chisquare(2, size=(500, 400)))
    assert white == pytest.approx(400, rel=0.1)
    assert cons.effective_steps(np.full((3, 10), 2.0)) == 10.0


def test_verdict_rule_cases(rng):
    """The rule: no verdict below MIN_RUNS runs; the mean test decides when it rejects
    (whatever the band); a band rejection alone is inconclusive, never consistent."""
    assert cons.MIN_RUNS == 6  # the sign test's smallest two-sided p 2^(1 - N) below 0.05
    assert 2.0 ** (1 - cons.MIN_RUNS) < 0.05 < 2.0 ** (2 - cons.MIN_RUNS)
    few = cons.consistency_test(ar_nees(rng, 5, 200, 2, 0.5, 20.0), 2)
    assert few["verdict"] == cons.NO_VERDICT and few["mean_verdict"] == cons.OVERCONFIDENT
    assert "no verdict (5 runs < 6)" in cons.verdict_text(few)
    # half the steps far above the band, half far below, time averages exactly dim
    steps = np.where(np.arange(200) % 2 == 0, 3.9, 0.1)
    values = steps[None, :] * rng.uniform(0.95, 1.05, size=(20, 1))
    values *= 2.0 / values.mean(axis=1, keepdims=True)
    values += 1e-3 * rng.standard_normal(values.shape)
    test = cons.consistency_test(values, 2)
    assert test["mean_verdict"] == cons.CONSISTENT and test["steps_verdict"] != cons.CONSISTENT
    assert test["verdict"] == cons.INCONCLUSIVE
    assert cons.verdict_text(test).startswith("inconclusive: mean test")
    # a small shift the mean test sees and the band does not: the mean test's verdict
    shifted = rng.chisquare(2, size=(400, 50)) * 1.03
    test = cons.consistency_test(shifted, 2)
    assert test["mean_p"] < 0.05 and test["steps_verdict"] == cons.CONSISTENT
    assert test["verdict"] == cons.OVERCONFIDENT
    assert test["test_level"] == 0.05 and test["min_runs"] == 6


def test_verdict_directions_and_power():
    rng = np.random.default_rng(8)
    over = [cons.consistency_test(ar_nees(rng, 64, 400, 2, 0.886, 1.13), 2)["verdict"]
            for _ in range(100)]
    under = [cons.consistency_test(ar_nees(rng, 64, 400, 2, 0.886, 0.87), 2)["verdict"]
             for _ in range(100)]
    assert np.mean([v == cons.OVERCONFIDENT for v in over]) >= 0.95
    assert np.mean([v == cons.UNDERCONFIDENT for v in under]) >= 0.95
    assert cons.consistency_test(ar_nees(rng, 16, 100, 3, 0.5, 2.0), 3)["verdict"] == \
        cons.OVERCONFIDENT
    assert cons.consistency_test(ar_nees(rng, 16, 100, 3, 0.5, 0.5), 3)["verdict"] == \
        cons.UNDERCONFIDENT


def test_whiteness_null_and_alternative():
    rng = np.random.default_rng(9)
    N, K, m = 16, 120, 2
    white = [cons.whiteness_test(rng.standard_normal((N, K, m))) for _ in range(800)]
    rate = np.mean([w["verdict"] != "white" for w in white])
    scores = np.array([w["z"] for w in white])
    print(f"whiteness false alarms {rate:.3f}, sd of the standardized lags "
          f"{scores.std(axis=0)}")
    assert rate == pytest.approx(0.05, abs=0.025)
    assert np.allclose(scores.std(axis=0), 1.0, atol=0.08)  # the N(0, (K-l)/(N K^2 m)) null
    w = rng.standard_normal((N, K, m))
    colored = lfilter([1.0], [1.0, -0.3], w, axis=1)
    assert cons.whiteness_test(colored)["verdict"] == "correlated"
    assert cons.whiteness_test(w[:, :1]) is None  # no lag fits one step
    z = cons.whiten(np.array([[3.0, 4.0]]), np.array([[[4.0, 0.0], [0.0, 16.0]]]))
    assert z == pytest.approx(np.array([[1.5, 1.0]]))


def test_paired_t_and_wilcoxon_false_alarm_and_ratio_coverage():
    """Correlated per-run MSEs with equal means: the paired tests' false-alarm rate is near
    the level; the delta-method interval of the mean ratio covers the true ratio ~95 %."""
    rng = np.random.default_rng(10)
    reps, n = 1000, 32
    alarms_t = alarms_w = covered = 0
    for _ in range(reps):
        common = rng.gamma(4.0, 1.0, size=n)
        a = common * rng.gamma(50.0, 1 / 50.0, size=n)
        b = common * rng.gamma(50.0, 1 / 50.0, size=n) * 1.1
        c = paired.paired_comparison(a, b / 1.1)
        alarms_t += c["p_t"] < 0.05
        alarms_w += c["p_wilcoxon"] < 0.05
        r = paired.paired_comparison(a, b)["ratio_ci"]
        covered += r[0] <= 1 / 1.1 <= r[1]
    print(f"paired t {alarms_t / reps:.3f}, Wilcoxon {alarms_w / reps:.3f}, ratio coverage "
          f"{covered / reps:.3f}")
    assert alarms_t / reps == pytest.approx(0.05, abs=0.02)
    assert alarms_w / reps == pytest.approx(0.05, abs=0.02)
    assert covered / reps == pytest.approx(0.95, abs=0.02)


def test_holm_controls_the_family_wise_error_rate():
    """Four estimators whose true MSE ratio sits on the margin, 1.02 (the hardest case for
    both claims): "worse" (beyond the margin) and "equivalent" (inside it) are both false
    there, and the family claims either in at most 5 % of the families; at a ratio of 1 no
    "better"/"worse" claim either."""
    rng = np.random.default_rng(11)
    reps, false_difference, false_equivalence, false_at_one = 250, 0, 0, 0
    for _ in range(reps):
        ref = rng.gamma(4.0, 1.0, size=20)
        noise = rng.gamma(1000.0, 1 / 1000.0, size=(4, 20))  # mean 1, 3 % per run
        out = paired.compare_family({f"e{j}": 1.02 * ref * noise[j] for j in range(4)}, ref)
        false_difference += any(c["verdict"] == paired.WORSE for c in out.values())
        false_equivalence += any(c["verdict"] == paired.EQUIVALENT for c in out.values())
        out = paired.compare_family({f"e{j}": ref * noise[j] for j in range(4)}, ref)
        false_at_one += any(c["verdict"] in (paired.BETTER, paired.WORSE)
                            for c in out.values())
    print(f"family-wise false claims at the margin: worse {false_difference / reps:.3f}, "
          f"equivalent {false_equivalence / reps:.3f}; at 1: {false_at_one / reps:.3f}")
    assert false_difference / reps <= 0.05 + 0.025
    assert false_equivalence / reps <= 0.05 + 0.025
    assert false_at_one / reps <= 0.05 + 0.025
