"""Statistics of a scored Monte-Carlo study: RMSE with confidence intervals, NEES and the
per-step chi-square band (:func:`testbed.stats.chi2_bounds`, re-exported here; the
consistency tests and their verdicts are in :mod:`testbed.stats`, re-exported by
:mod:`testbed.score.consistency`; the paired comparisons in :mod:`testbed.score.paired`).

Definitions (``N`` runs, ``K`` steps, state dimension ``n``; see docs/scoring.md):

- per-run RMSE of state ``j``: ``r_ij = sqrt(mean_k e_ijk^2)``; the score's RMSE is the pooled
  ``sqrt(mean_i r_ij^2)`` with a 95 % interval from Student's t on the mean of ``r_ij^2``
  (the square root of the interval of the mean-square error);
- ``NEES_ik = e_ik^T P_ik^-1 e_ik``; the two-sided 95 % band of the N-run average at one
  step is ``chi2.ppf([0.025, 0.975], N n) / N`` (Bar-Shalom et al.'s test of the N-run
  average);
- ``NIS_ik = nu_ik^T S_ik^-1 nu_ik`` with the innovation dimension ``m`` likewise.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import t

from testbed.experiment.metrics import nees as nees_of
from testbed.stats import LEVEL, chi2_bounds

__all__ = ["LEVEL", "chi2_bounds", "nees", "rmse_ci"]


def rmse_ci(per_run_rmse: np.ndarray, level: float = LEVEL) -> tuple[float, tuple[float, float]]:
    """Pooled RMSE over runs and its confidence interval.

    Parameters
    ----------
    per_run_rmse : ndarray, shape (N,)
        RMSE of each run (time-RMS), N >= 2.
    level : float

    Returns
    -------
    rmse : float
        ``sqrt(mean(r^2))``.
    ci : (float, float)
        ``sqrt`` of Student's t interval of ``mean(r^2)`` (lower end clipped at 0).
    """
    r = np.asarray(per_run_rmse, dtype=float)
    if r.ndim != 1 or len(r) < 2 or not np.all(np.isfinite(r)):
        raise ValueError(f"per_run_rmse must be finite with shape (N,), N >= 2, got {r.shape}")
    mse = r**2
    mean = float(np.mean(mse))
    half = float(t.ppf(0.5 + level / 2, len(r) - 1) * np.std(mse, ddof=1) / np.sqrt(len(r)))
    return float(np.sqrt(mean)), (float(np.sqrt(max(mean - half, 0.0))),
                                  float(np.sqrt(mean + half)))


def nees(error: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Normalized estimation error squared of every run and step.

    Parameters
    ----------
    error : ndarray, shape (N, K, n)
    covariance : ndarray, shape (N, K, n, n)

    Returns
    -------
    ndarray, shape (N, K)

    Raises
    ------
    ValueError
        A covariance is not positive definite (step and run named).
    """
    try:  # (the check; the value is the Monte Carlo's own formula)
        np.linalg.cholesky(covariance)
    except np.linalg.LinAlgError:
        bad = [(i, k) for i in range(error.shape[0]) for k in range(error.shape[1])
               if np.any(np.linalg.eigvalsh(covariance[i, k]) <= 0)]
        i, k = bad[0] if bad else (-1, -1)
        raise ValueError(f"covariance not positive definite (run {i}, step {k}): NEES "
                         "undefined") from None
    return nees_of(error, covariance)
