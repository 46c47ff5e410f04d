"""Statistics every study shares: the chi-square band of an N-run average, the NEES/NIS
consistency tests with directions, and innovation whiteness.

Pure numpy and scipy, below :mod:`testbed.experiment` (the replay of a recording tests its
innovations with them) and :mod:`testbed.score` (which re-exports them from
:mod:`testbed.score.consistency` and :mod:`testbed.score.stats`).

``N`` independent runs of ``K`` steps; ``values[i, k]`` is the NEES (or NIS) of run ``i`` at
step ``k`` with ``dim`` degrees of freedom (Bar-Shalom, Li & Kirubarajan 2001, ch. 5.4;
docs/scoring.md). Two tests, both reported:

- **mean test** (the verdict): the per-run time averages ``a_i = mean_k values[i, k]``
  are independent across runs (the steps of one run are not), so Student's t test of their
  mean against ``dim`` is valid whatever the correlation in time; it is applied at the level
  ``1 - level`` (5 %), two-sided, and its p-value is reported. Under consistency
  ``E a_i = dim``.
- **per-step band** (the step test, a diagnostic): at each step the N-run average times
  ``N`` is ``chi2(N dim)``, so it lies outside ``[chi2.ppf(a/2, N dim), chi2.ppf(1-a/2,
  N dim)] / N`` with probability ``a = 1 - level``. The steps are correlated in time, so
  the fraction outside gets a Clopper-Pearson interval at the effective number of
  independent steps ``K / tau`` (:func:`effective_steps`: ``tau`` is the variance inflation
  of the time average, measured from the runs), not at ``K``.

The verdict (measured level and power: docs/verdict_level.md, ``scripts/verdict_level.py``):

- fewer than :data:`MIN_RUNS` runs: ``"no verdict"`` (the tests are still reported);
- the mean test rejects: ``"overconfident"`` (NEES above ``dim``: the reported covariance is
  too small) or ``"underconfident"`` (below), whatever the band diagnostic says (the text
  shows it); the verdict's false-alarm rate is the mean test's level;
- the mean test accepts: ``"consistent"`` when the band diagnostic accepts too, else
  ``"inconclusive"`` (never "consistent" on a disagreement).

Whiteness: the normalized (whitened) innovations ``z_ik = S_ik^-1/2 nu_ik`` of a consistent
filter are white. Per run and lag ``l``, ``r_i(l) = sum_k z_ik . z_i,k+l / sum_k |z_ik|^2``;
the average over runs is about ``N(0, (K - l) / (N K^2 m))`` (``1 / (N K m)`` for ``l << K``),
and the sum of the squared standardized averages over a few lags is about ``chi2(lags)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.stats import beta, chi2, t

#: Two-sided confidence level of every interval and bound.
LEVEL = 0.95


def chi2_bounds(runs: int, dim: int, level: float = LEVEL) -> tuple[float, float]:
    """Two-sided bounds of an ``runs``-run average of chi-square(``dim``) variables.

    ``N * average ~ chi2(N dim)`` for a consistent estimator, so the bounds are
    ``chi2.ppf([(1 - level)/2, (1 + level)/2], N dim) / N``.
    """
    if runs < 1 or dim < 1:
        raise ValueError(f"runs and dim must be positive, got {runs}, {dim}")
    lo, hi = chi2.ppf([(1 - level) / 2, (1 + level) / 2], runs * dim) / runs
    return float(lo), float(hi)


#: Verdict words of the NEES/NIS tests.
CONSISTENT, OVERCONFIDENT, UNDERCONFIDENT = "consistent", "overconfident", "underconfident"
#: The mean test accepts and the per-step band test rejects: neither "consistent" nor a
#: direction.
INCONCLUSIVE = "inconclusive"
#: Fewer than :data:`MIN_RUNS` runs.
NO_VERDICT = "no verdict"
#: Fewest runs with a verdict: the smallest ``N`` at which an exact distribution-free test of
#: the ``N`` per-run averages (the sign test, smallest two-sided p ``2^(1 - N)``) can reject
#: at 5 %: ``2^-4 = 0.0625`` at 5 runs, ``2^-5 = 0.031`` at 6. Below it a rejection by the t
#: test rests on the normality of the per-run averages alone, which a diverging filter's do
#: not have.
MIN_RUNS = 6
#: Lags of the whiteness test (those below ``K / 2`` are used).
LAGS = (1, 2, 5, 10)


def _sig(value: float, digits: int = 4) -> float:
    """``value`` rounded to ``digits`` significant digits (compact JSON)."""
    return float(f"{value:.{digits}g}")


def t_interval(x: np.ndarray, mu0: float = 0.0, level: float = LEVEL
               ) -> tuple[float, tuple[float, float], float]:
    """Mean of independent samples, Student's t interval and the two-sided p-value of
    ``mean == mu0``.

    Parameters
    ----------
    x : ndarray, shape (N,), N >= 2, finite
    mu0 : float
    level : float

    Returns
    -------
    mean : float
    ci : (float, float)
    p : float
        1 when every sample equals ``mu0``; 0 when the samples are equal to another value.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 1 or len(x) < 2 or not np.all(np.isfinite(x)):
        raise ValueError(f"x must be finite with shape (N,), N >= 2, got {x.shape}")
    n = len(x)
    mean = float(np.mean(x))
    se = float(np.std(x, ddof=1) / np.sqrt(n))
    if se == 0.0:
        return mean, (mean, mean), 1.0 if mean == mu0 else 0.0
    half = float(t.ppf(0.5 + level / 2, n - 1) * se)
    p = float(2 * t.sf(abs(mean - mu0) / se, n - 1))
    return mean, (mean - half, mean + half), p


def clopper_pearson(k: int, n: int, level: float = LEVEL) -> tuple[float, float]:
    """Exact (Clopper-Pearson) interval of a binomial proportion, ``k`` of ``n``."""
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"need 0 <= k <= n, n >= 1, got k = {k}, n = {n}")
    a = 1 - level
    lo = 0.0 if k == 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def effective_steps(values: np.ndarray) -> float:
    """Effective number of independent steps of one run, ``K / tau``.

    ``tau = K s^2(a) / s^2(v)`` is the variance inflation of the per-run time average
    ``a_i = mean_k values[i, k]`` over that of ``K`` independent steps (the integrated
    autocorrelation time, Kish's design effect), with ``s^2(a)`` the sample variance of the
    time averages across runs and ``s^2(v)`` the pooled variance of the values about their
    step's run average; ``tau`` is clipped to ``[1, K]``.

    Parameters
    ----------
    values : ndarray, shape (N, K), N >= 2

    Returns
    -------
    float
        In ``[1, K]``.
    """
    N, K = values.shape
    s2_v = float(np.sum((values - values.mean(axis=0)) ** 2) / ((N - 1) * K))
    if s2_v == 0.0:
        return float(K)
    tau = K * float(np.var(values.mean(axis=1), ddof=1)) / s2_v
    return float(K / min(max(tau, 1.0), K))


def _beta_interval(k: float, n: float, level: float) -> tuple[float, float]:
    """Clopper-Pearson interval for a (possibly fractional) count ``k`` of ``n``."""
    a = 1 - level
    lo = 0.0 if k <= 0 else float(beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k >= n else float(beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def consistency_test(values: np.ndarray, dim: int, level: float = LEVEL) -> dict[str, Any]:
    """NEES (or NIS) of N runs and K steps against ``dim``: the mean test (the verdict), the
    per-step band test (a diagnostic) and the per-step curve (see the module docstring).

    Parameters
    ----------
    values : ndarray, shape (N, K), N >= 2, finite
    dim : int
        Degrees of freedom (state or innovation dimension).
    level : float
        Confidence level; the tests' level is ``1 - level``.

    Returns
    -------
    dict
        ``dim``, ``runs``, ``steps``, ``min_runs`` (:data:`MIN_RUNS`), ``test_level``
        (``1 - level``); ``mean`` (over runs and steps), ``mean_ci`` (t interval of the
        per-run time averages), ``mean_p`` (two-sided p-value of ``mean == dim``),
        ``mean_verdict``; ``band`` (per-step N-run band), ``steps_above``,
        ``steps_below``, ``steps_outside_fraction``, ``steps_effective`` (the effective
        number of independent steps, :func:`effective_steps`), ``steps_outside_ci``
        (Clopper-Pearson at the effective number of steps), ``steps_verdict``; ``verdict``
        (:data:`CONSISTENT`, :data:`OVERCONFIDENT`, :data:`UNDERCONFIDENT`,
        :data:`INCONCLUSIVE` or :data:`NO_VERDICT`); ``per_step`` (the N-run average at each
        step, 4 significant digits).
    """
    values = np.asarray(values, dtype=float)
    if values.ndim != 2 or values.shape[0] < 2 or values.shape[1] < 1 \
            or not np.all(np.isfinite(values)):
        raise ValueError(f"values must be finite with shape (N, K), N >= 2, got "
                         f"{values.shape}")
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    N, K = values.shape
    mean, ci, p = t_interval(values.mean(axis=1), dim, level)
    mean_verdict = CONSISTENT
    if p < 1 - level:
        mean_verdict = OVERCONFIDENT if mean > dim else UNDERCONFIDENT
    lo, hi = chi2_bounds(N, dim, level)
    per_step = values.mean(axis=0)
    above, below = int(np.sum(per_step > hi)), int(np.sum(per_step < lo))
    fraction = (above + below) / K
    k_eff = effective_steps(values)
    cp = _beta_interval(fraction * k_eff, k_eff, level)
    steps_verdict = CONSISTENT
    if cp[0] > 1 - level:
        steps_verdict = OVERCONFIDENT if above >= below else UNDERCONFIDENT
    if N < MIN_RUNS:
        verdict = NO_VERDICT
    elif mean_verdict != CONSISTENT:
        verdict = mean_verdict
    else:
        verdict = CONSISTENT if steps_verdict == CONSISTENT else INCONCLUSIVE
    return {"dim": int(dim), "runs": N, "steps": K, "min_runs": MIN_RUNS,
            "test_level": _sig(1 - level), "mean": mean, "mean_ci": list(ci),
            "mean_p": p, "mean_verdict": mean_verdict, "band": [lo, hi],
            "steps_above": above, "steps_below": below,
            "steps_outside_fraction": fraction, "steps_effective": _sig(k_eff),
            "steps_outside_ci": list(cp), "steps_verdict": steps_verdict,
            "verdict": verdict, "per_step": [_sig(v) for v in per_step]}


def whiteness_test(z: np.ndarray, lags: tuple[int, ...] = LAGS, level: float = LEVEL
                   ) -> dict[str, Any] | None:
    """Whiteness of normalized innovations (see the module docstring).

    Parameters
    ----------
    z : ndarray, shape (N, K, m)
        Whitened innovations ``S^-1/2 nu`` of N runs and K steps.
    lags : tuple of int
        Candidate lags; those with ``2 l <= K`` are tested.
    level : float

    Returns
    -------
    dict or None
        ``lags``, ``autocorrelation`` (the run average at each lag), ``sd`` (its null
        standard deviation), ``z`` (standardized), ``statistic`` (sum of ``z^2``), ``p``
        (``chi2(len(lags))`` tail) and ``verdict`` (``"white"`` or ``"correlated"``); None
        when no lag fits.
    """
    z = np.asarray(z, dtype=float)
    if z.ndim != 3 or z.shape[0] < 1 or not np.all(np.isfinite(z)):
        raise ValueError(f"z must be finite with shape (N, K, m), got {z.shape}")
    N, K, m = z.shape
    used = [int(lag) for lag in lags if 1 <= lag and 2 * lag <= K]
    if not used:
        return None
    energy = np.sum(z * z, axis=(1, 2))
    if np.any(energy == 0):
        raise ValueError("a run has all-zero innovations: whiteness undefined")
    r = np.array([np.mean(np.sum(z[:, :-lag] * z[:, lag:], axis=(1, 2)) / energy)
                  for lag in used])
    sd = np.sqrt((K - np.array(used)) / (N * K**2 * m))
    score = r / sd
    statistic = float(np.sum(score**2))
    p = float(chi2.sf(statistic, len(used)))
    return {"lags": used, "autocorrelation": [_sig(v) for v in r],
            "sd": [_sig(v) for v in sd], "z": [_sig(v) for v in score],
            "statistic": statistic, "p": p,
            "verdict": "white" if p >= 1 - level else "correlated"}


def whiten(innovation: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """``L^-1 nu`` with ``S = L L^T`` (Cholesky), for any leading shape."""
    chol = np.linalg.cholesky(covariance)
    return np.linalg.solve(chol, innovation[..., None])[..., 0]


def verdict_text(test: dict[str, Any] | None) -> str:
    """``"<verdict>: <mean> [<ci>] vs <dim>, p <p>; step test: <pct> of steps outside
    [<ci>] <its verdict>"`` or ``"-"``."""
    if test is None:
        return "-"
    lo, hi = test["mean_ci"]
    flo, fhi = test["steps_outside_ci"]
    verdict = test["verdict"]
    if verdict == NO_VERDICT:
        verdict = f"no verdict ({test['runs']} runs < {test['min_runs']})"
    text = (f"{verdict}: mean test {test['mean']:.3g} [{lo:.3g}, {hi:.3g}] vs {test['dim']}, "
            f"p {test['mean_p']:.2g}")
    if test["verdict"] == NO_VERDICT:
        text += f" (alone it would read {test['mean_verdict']})"
    text += (f"; step test (diagnostic): {100 * test['steps_outside_fraction']:.1f} % of "
             f"steps outside [{100 * flo:.1f}, {100 * fhi:.1f}] "
             f"({test['steps_effective']:.3g} effective steps), {test['steps_verdict']}")
    return text
