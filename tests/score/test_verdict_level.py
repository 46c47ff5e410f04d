"""The consistency verdict keeps its stated level (5 %) on the calibration plant, and its
replica of the plant's Kalman filter is the exact one (scipy's Riccati solution, chi-square
NEES from the prior on)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg
from scipy.stats import chi2

from testbed.score import level
from testbed.score.consistency import OVERCONFIDENT, UNDERCONFIDENT


@pytest.fixture(scope="module")
def model() -> level.LinearGaussianModel:
    return level.calibration_model()


def test_replica_is_the_exact_kalman_filter(model):
    gains, covs, innov = level.kalman_sequence(model, 3000)
    prior = linalg.solve_discrete_are(model.F.T, model.H.T, model.Q, model.R)
    S = model.H @ prior @ model.H.T + model.R
    posterior = prior - prior @ model.H.T @ np.linalg.solve(S, model.H @ prior)
    assert covs[-1] == pytest.approx(posterior, rel=1e-6)
    assert innov[-1] == pytest.approx(S, rel=1e-9)
    nees, nis = level.kalman_nees_nis(model, 40_000, 3, np.random.default_rng(1))
    lo, hi = chi2.ppf([0.001, 0.999], 40_000 * 2) / 40_000  # steps 1-3 test the prior
    assert np.all((lo < nees.mean(axis=0)) & (nees.mean(axis=0) < hi))
    lo, hi = chi2.ppf([0.001, 0.999], 40_000) / 40_000
    assert np.all((lo < nis.mean(axis=0)) & (nis.mean(axis=0) < hi))


def _check(result: dict, min_power: float) -> None:
    total = result["studies"]
    for kind in ("nees", "nis"):
        counts = result["counts"][kind]
        rejected = counts[1.0][OVERCONFIDENT] + counts[1.0][UNDERCONFIDENT]
        value, (lo, hi) = level.rate(rejected, total)
        power_over = counts[0.9][OVERCONFIDENT] / total
        power_under = counts[1.1][UNDERCONFIDENT] / total
        print(f"{kind} {result['runs']} x {result['steps']}: level {value:.3f} "
              f"[{lo:.3f}, {hi:.3f}], power {power_over:.3f} / {power_under:.3f}")
        assert 0.03 <= value <= 0.07 and lo <= 0.05 <= hi
        assert power_over >= min_power and power_under >= min_power
        assert counts[0.9][UNDERCONFIDENT] == counts[1.1][OVERCONFIDENT] == 0


def test_level_at_a_small_size(model):
    """1500 studies of 16 runs x 200 steps: the level's 95 % interval contains 5 % and its
    estimate lies in [3 %, 7 %]."""
    _check(level.verdict_rates(model, 16, 200, 1500, seed=3), min_power=0.5)


@pytest.mark.slow
def test_level_and_power_at_the_standard_size(model):
    """The standard suite's calibration entry (100 runs x 20 s): level in [3 %, 7 %], power
    at least 95 % against 0.9 P and 1.1 P (about 90 s)."""
    _check(level.verdict_rates(model, 100, 2000, 1000, seed=4), min_power=0.95)
