"""Paired comparisons of estimators on common random numbers.

Every estimator of a score runs on the same per-run seeds, so run ``i`` of estimator A and of
the reference B share the noise (and, with ``feedback = "truth"``, the trajectory). The
per-run differences ``d_i = MSE_A,i - MSE_B,i`` are independent across runs, and their spread
excludes the noise common to both: intervals on ``d`` are far narrower than the marginal
intervals of the two MSEs when the runs' MSEs are correlated (docs/scoring.md).

For each state, :func:`paired_comparison` gives Student's t interval and p-value of
``mean d``, the Wilcoxon signed-rank p-value, the effect size ``mean d / sd d``, the
correlation of the runs' MSEs and the ratio ``mean MSE_A / mean MSE_B`` with a delta-method
interval on its logarithm. :func:`holm` adjusts the t p-values over the estimators compared
with the reference (Holm 1979), and :func:`decide` states the verdict: ``"better"`` (lower
MSE), ``"worse"`` or ``"no detectable difference"`` at the adjusted level.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.stats import t, wilcoxon

from testbed.score.consistency import t_interval
from testbed.score.stats import LEVEL

BETTER, WORSE, NO_DIFFERENCE = "better", "worse", "no detectable difference"


def paired_comparison(a: np.ndarray, b: np.ndarray, level: float = LEVEL) -> dict[str, Any]:
    """Per-run values ``a`` (estimator) against ``b`` (reference) on the same runs.

    Parameters
    ----------
    a, b : ndarray, shape (N,), N >= 2, finite
        Per-run MSE (or any per-run loss; lower is better).
    level : float

    Returns
    -------
    dict
        ``mean_difference``, ``difference_ci`` (t), ``p_t``, ``p_wilcoxon``, ``effect_size``
        (``mean d / sd d``; None when ``sd d = 0``), ``correlation`` (of ``a`` and ``b``; None
        when one is constant), ``ratio`` (``mean a / mean b``) and ``ratio_ci`` (delta method
        on ``log(mean a) - log(mean b)`` with Student's t quantile).
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim != 1 or len(a) < 2 or not (
            np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError(f"a and b must be finite with the same shape (N,), N >= 2, got "
                         f"{a.shape} and {b.shape}")
    n = len(a)
    d = a - b
    mean, ci, p_t = t_interval(d, 0.0, level)
    sd = float(np.std(d, ddof=1))
    if np.any(d != 0):
        p_w = float(wilcoxon(d, zero_method="wilcox").pvalue)
    else:
        p_w = 1.0
    sa, sb = float(np.std(a, ddof=1)), float(np.std(b, ddof=1))
    corr = float(np.corrcoef(a, b)[0, 1]) if sa > 0 and sb > 0 else None
    ma, mb = float(np.mean(a)), float(np.mean(b))
    ratio, ratio_ci = None, None
    if ma > 0 and mb > 0:
        ratio = ma / mb
        cov = np.cov(a, b, ddof=1)
        var_log = (cov[0, 0] / ma**2 + cov[1, 1] / mb**2 - 2 * cov[0, 1] / (ma * mb)) / n
        half = float(t.ppf(0.5 + level / 2, n - 1) * np.sqrt(max(var_log, 0.0)))
        ratio_ci = [ratio * float(np.exp(-half)), ratio * float(np.exp(half))]
    return {"runs": n, "mean_difference": mean, "difference_ci": list(ci), "p_t": p_t,
            "p_wilcoxon": p_w, "effect_size": mean / sd if sd > 0 else None,
            "correlation": corr, "ratio": ratio, "ratio_ci": ratio_ci}


def holm(pvalues: list[float]) -> list[float]:
    """Holm-Bonferroni adjusted p-values (Holm 1979), in the order given.

    The j-th smallest of ``m`` p-values is multiplied by ``m - j + 1``; the adjusted values
    are made monotone and capped at 1. Rejecting where the adjusted value is below ``a``
    controls the family-wise error rate at ``a``.
    """
    p = np.asarray(pvalues, dtype=float)
    if p.ndim != 1 or np.any((p < 0) | (p > 1)) or np.any(~np.isfinite(p)):
        raise ValueError(f"p-values must be in [0, 1], got {pvalues}")
    m = len(p)
    order = np.argsort(p, kind="stable")
    adjusted = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * p[order]))
    out = np.empty(m)
    out[order] = adjusted
    return out.tolist()


def decide(comparison: dict[str, Any], p_adjusted: float, level: float = LEVEL) -> str:
    """``"better"`` / ``"worse"`` (lower / higher loss than the reference) when the adjusted
    p-value is below ``1 - level``, else ``"no detectable difference"``."""
    if p_adjusted < 1 - level:
        return BETTER if comparison["mean_difference"] < 0 else WORSE
    return NO_DIFFERENCE


def compare_family(per_run: dict[str, np.ndarray], reference: np.ndarray,
                   level: float = LEVEL) -> dict[str, dict[str, Any]]:
    """Every estimator of ``per_run`` (name to per-run loss) against ``reference``, Holm over
    the family: each result gets ``p_holm`` and ``verdict``."""
    out = {name: paired_comparison(values, reference, level)
           for name, values in per_run.items()}
    names = list(out)
    for name, p in zip(names, holm([out[k]["p_t"] for k in names]), strict=True):
        out[name]["p_holm"] = p
        out[name]["verdict"] = decide(out[name], p, level)
    return out


def comparison_text(comparison: dict[str, Any], unit: str = "") -> str:
    """``"<verdict>: d = <mean> [<ci>] <unit>, ratio <r> [<ci>], p_holm <p>"``."""
    lo, hi = comparison["difference_ci"]
    text = (f"{comparison['verdict']}: d = {comparison['mean_difference']:.3g} "
            f"[{lo:.3g}, {hi:.3g}]{' ' + unit if unit else ''}")
    if comparison["ratio"] is not None:
        rlo, rhi = comparison["ratio_ci"]
        text += f", ratio {comparison['ratio']:.4g} [{rlo:.4g}, {rhi:.4g}]"
    return text + f", p_holm {comparison['p_holm']:.2g}"
