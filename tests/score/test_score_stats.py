"""Statistics of the scoring harness against closed forms and Monte Carlo."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from testbed.score import stats


def test_chi2_bounds_closed_forms():
    # one run: the chi-square quantiles themselves
    assert stats.chi2_bounds(1, 3) == pytest.approx(tuple(chi2.ppf([0.025, 0.975], 3)))
    lo, hi = stats.chi2_bounds(50, 4)
    assert lo < 4 < hi
    # the N-run average of chi2(n) has mean n and variance 2n/N: the band narrows like 1/sqrt(N)
    lo2, hi2 = stats.chi2_bounds(200, 4)
    assert (hi2 - lo2) == pytest.approx((hi - lo) / 2, rel=0.05)


def test_chi2_bounds_cover_95_percent_of_simulated_averages(rng):
    runs, dim = 20, 3
    lo, hi = stats.chi2_bounds(runs, dim)
    averages = rng.chisquare(dim, size=(20000, runs)).mean(axis=1)
    inside = np.mean((averages >= lo) & (averages <= hi))
    assert inside == pytest.approx(0.95, abs=0.006)


def test_rmse_ci_covers_the_true_rmse(rng):
    true_mse, runs, covered = 4.0, 30, 0
    for _ in range(1000):
        per_run = np.sqrt(rng.chisquare(5, size=runs) * true_mse / 5)  # E[r^2] = true_mse
        rmse, (lo, hi) = stats.rmse_ci(per_run)
        assert lo <= rmse <= hi
        covered += lo <= np.sqrt(true_mse) <= hi
    assert covered / 1000 == pytest.approx(0.95, abs=0.025)


def test_nees_matches_the_explicit_inverse(rng):
    e = rng.standard_normal((3, 5, 4))
    L = rng.standard_normal((3, 5, 4, 4))
    P = L @ np.swapaxes(L, -1, -2) + 0.1 * np.eye(4)
    expected = np.einsum("nki,nkij,nkj->nk", e, np.linalg.inv(P), e)
    assert np.allclose(stats.nees(e, P), expected, rtol=1e-10)
    P[1, 2] = -np.eye(4)
    with pytest.raises(ValueError, match="run 1, step 2"):
        stats.nees(e, P)


def test_rmse_ci_bad_input():
    with pytest.raises(ValueError):
        stats.rmse_ci(np.array([1.0]))
