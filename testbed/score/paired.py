"""Paired comparisons of estimators on common random numbers.

Every estimator of a score runs on the same per-run seeds, so run ``i`` of estimator A and of
the reference B share the noise (and, with ``feedback = "truth"``, the trajectory). The
per-run differences ``d_i = MSE_A,i - MSE_B,i`` are independent across runs, and their spread
excludes the noise common to both: intervals on ``d`` are far narrower than the marginal
intervals of the two MSEs when the runs' MSEs are correlated (docs/scoring.md).

For each state, :func:`paired_comparison` gives the **primary result**, the ratio
``r = mean MSE_A / mean MSE_B`` with a delta-method interval on ``log r`` (Student's t
quantile), and beside it Student's t interval and p-value of ``mean d``, the Wilcoxon
signed-rank p-value (raw), the effect size ``mean d / sd d`` and the correlation of the runs'
MSEs. Against a practical-equivalence **margin** ``m`` (:data:`MARGIN`, 2 %: the ratio within
``[1 - m, 1 + m]`` is "no practical difference"), two p-values of the log-ratio t statistic:

- ``p_difference``: the two-sided minimum-effect test of ``r in [1 - m, 1 + m]`` (twice the
  smaller of the one-sided p-values of ``r >= 1 - m`` and ``r <= 1 + m``);
- ``p_equivalence``: the two one-sided tests (TOST; Schuirmann 1987) of ``r <= 1 - m`` and
  ``r >= 1 + m``, the larger of their p-values (equivalence at 5 % when the 90 % interval of
  ``r`` lies inside the margin).

:func:`compare_family` adjusts both kinds over a **fixed family** by Holm's step-down
procedure (Holm 1979): ``2 M`` hypotheses, a difference and an equivalence hypothesis for
each of the ``M`` comparisons of the family, so that every claim printed (better, worse,
equivalent) has a family-wise error rate of at most 5 %. The family is declared, not the
run's: for a score, every state x every estimator of the suite's lineup
(:data:`testbed.score.suite.LINEUP`) compared with the reference on one scenario, plus the
estimator itself when it is not in the lineup; comparisons of the family that the run did
not score enter with p = 1. Holm's adjusted p-values only grow when a p-value grows, so a run
that scores part of the lineup can turn a verdict into "inconclusive", never into another
claim, and in a run of the whole lineup no verdict depends on which other estimators were
scored. :func:`decide` states the verdict: ``"better"`` / ``"worse"`` (lower / higher MSE by
more than the margin: the adjusted ``p_difference`` below 0.05), ``"equivalent"`` (the
adjusted ``p_equivalence`` below 0.05) or ``"inconclusive"``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.stats import t, wilcoxon

from testbed.score.consistency import t_interval
from testbed.score.stats import LEVEL

BETTER, WORSE, EQUIVALENT, INCONCLUSIVE = "better", "worse", "equivalent", "inconclusive"
#: Practical-equivalence margin on the MSE ratio: ``[1 - MARGIN, 1 + MARGIN]``.
MARGIN = 0.02


def paired_comparison(a: np.ndarray, b: np.ndarray, level: float = LEVEL,
                      margin: float = MARGIN) -> dict[str, Any]:
    """Per-run values ``a`` (estimator) against ``b`` (reference) on the same runs.

    Parameters
    ----------
    a, b : ndarray, shape (N,), N >= 2, finite
        Per-run MSE (or any per-run loss; lower is better).
    level : float
    margin : float
        Practical-equivalence margin of the ratio.

    Returns
    -------
    dict
        ``runs``; ``ratio`` (``mean a / mean b``; None when a mean is 0) and ``ratio_ci``
        (delta method on ``log(mean a) - log(mean b)`` with Student's t quantile), the
        primary result; ``margin``, ``p_difference`` and ``p_equivalence`` (raw,
        :func:`margin_tests`); ``mean_difference``, ``difference_ci`` (t), ``p_t`` (raw),
        ``p_wilcoxon`` (raw), ``effect_size`` (``mean d / sd d``; None when ``sd d = 0``),
        ``correlation`` (of ``a`` and ``b``; None when one is constant).
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
    ratio, ratio_ci, se_log = None, None, 0.0
    if ma > 0 and mb > 0:
        ratio = ma / mb
        cov = np.cov(a, b, ddof=1)
        var_log = (cov[0, 0] / ma**2 + cov[1, 1] / mb**2 - 2 * cov[0, 1] / (ma * mb)) / n
        se_log = float(np.sqrt(max(var_log, 0.0)))
        half = float(t.ppf(0.5 + level / 2, n - 1) * se_log)
        ratio_ci = [ratio * float(np.exp(-half)), ratio * float(np.exp(half))]
    p_difference, p_equivalence = margin_tests(ma, mb, se_log, n, margin)
    return {"runs": n, "ratio": ratio, "ratio_ci": ratio_ci, "margin": margin,
            "p_difference": p_difference, "p_equivalence": p_equivalence,
            "mean_difference": mean, "difference_ci": list(ci), "p_t": p_t,
            "p_wilcoxon": p_w, "effect_size": mean / sd if sd > 0 else None,
            "correlation": corr}


def margin_tests(mean_a: float, mean_b: float, se_log: float, runs: int,
                 margin: float = MARGIN) -> tuple[float, float]:
    """Raw p-values of the margin tests of ``r = mean_a / mean_b`` (module docstring).

    Parameters
    ----------
    mean_a, mean_b : float
        Mean losses (>= 0).
    se_log : float
        Standard error of ``log r`` (0: known exactly).
    runs : int
        ``N``; the t statistic has ``N - 1`` degrees of freedom.
    margin : float
        In (0, 1).

    Returns
    -------
    p_difference : float
        Two-sided minimum-effect test of ``r in [1 - margin, 1 + margin]``.
    p_equivalence : float
        Two one-sided tests (Schuirmann 1987) of ``r <= 1 - margin`` and
        ``r >= 1 + margin``: the larger p.
    """
    if not 0 < margin < 1:
        raise ValueError(f"margin must be in (0, 1), got {margin}")
    lo, hi = np.log1p(-margin), np.log1p(margin)
    if mean_a <= 0 or mean_b <= 0:  # both zero: equal; one zero: outside any margin
        return (1.0, 0.0) if mean_a == mean_b else (0.0, 1.0)
    x = float(np.log(mean_a / mean_b))
    if se_log == 0.0:
        inside = lo < x < hi
        return (1.0, 0.0) if inside else (0.0, 1.0)
    df = runs - 1
    p_above_lo = float(t.sf((x - lo) / se_log, df))  # H0: r <= 1 - m (rejected: r > 1 - m)
    p_below_hi = float(t.cdf((x - hi) / se_log, df))  # H0: r >= 1 + m (rejected: r < 1 + m)
    p_better = float(t.cdf((x - lo) / se_log, df))  # H0: r >= 1 - m
    p_worse = float(t.sf((x - hi) / se_log, df))  # H0: r <= 1 + m
    return min(1.0, 2 * min(p_better, p_worse)), max(p_above_lo, p_below_hi)


def holm(pvalues: list[float], family_size: int | None = None) -> list[float]:
    """Holm-Bonferroni adjusted p-values (Holm 1979), in the order given.

    The j-th smallest of ``M`` p-values is multiplied by ``M - j + 1``; the adjusted values
    are made monotone and capped at 1. Rejecting where the adjusted value is below ``a``
    controls the family-wise error rate at ``a``. ``family_size`` (``M >= len(pvalues)``)
    declares a larger family whose other members were not tested: they enter with p = 1
    (conservative: Holm's adjusted values never decrease when a p-value grows).
    """
    p = np.asarray(pvalues, dtype=float)
    if p.ndim != 1 or np.any((p < 0) | (p > 1)) or np.any(~np.isfinite(p)):
        raise ValueError(f"p-values must be in [0, 1], got {pvalues}")
    size = len(p) if family_size is None else int(family_size)
    if size < len(p):
        raise ValueError(f"family_size must be at least the {len(p)} p-values, got {size}")
    full = np.concatenate([p, np.ones(size - len(p))])
    m = len(full)
    order = np.argsort(full, kind="stable")
    adjusted = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * full[order]))
    out = np.empty(m)
    out[order] = adjusted
    return out[: len(p)].tolist()


def decide(comparison: dict[str, Any], level: float = LEVEL) -> str:
    """The verdict from the Holm-adjusted p-values ``p_holm_difference`` and
    ``p_holm_equivalence`` of a comparison: ``"better"`` / ``"worse"`` (the ratio below
    ``1 - margin`` / above ``1 + margin``) when the first is below ``1 - level``,
    ``"equivalent"`` when the second is, else ``"inconclusive"``."""
    if comparison["p_holm_difference"] < 1 - level:
        ratio = comparison["ratio"]
        if ratio is None:
            return BETTER if comparison["mean_difference"] < 0 else WORSE
        return BETTER if ratio < 1 else WORSE
    if comparison["p_holm_equivalence"] < 1 - level:
        return EQUIVALENT
    return INCONCLUSIVE


def adjust(comparisons: dict[Any, dict[str, Any]], family_size: int,
           level: float = LEVEL) -> None:
    """Holm over a declared family of ``family_size`` comparisons (``2 family_size``
    hypotheses: difference and equivalence), of which ``comparisons`` (any keys to
    :func:`paired_comparison` results) were scored; each gets ``p_holm_difference``,
    ``p_holm_equivalence``, ``p_holm`` (that of its verdict's claim; for "inconclusive" the
    smaller), ``family_size`` and ``verdict`` (in place)."""
    keys = list(comparisons)
    if family_size < len(keys):
        raise ValueError(f"family_size must be at least the {len(keys)} comparisons, got "
                         f"{family_size}")
    raw = [comparisons[k]["p_difference"] for k in keys] + [
        comparisons[k]["p_equivalence"] for k in keys]
    adjusted = holm(raw, 2 * family_size)
    for i, key in enumerate(keys):
        c = comparisons[key]
        c["p_holm_difference"], c["p_holm_equivalence"] = adjusted[i], adjusted[len(keys) + i]
        c["family_size"] = int(family_size)
        c["verdict"] = decide(c, level)
        c["p_holm"] = (c["p_holm_equivalence"] if c["verdict"] == EQUIVALENT
                       else c["p_holm_difference"] if c["verdict"] in (BETTER, WORSE)
                       else min(c["p_holm_difference"], c["p_holm_equivalence"]))


def compare_family(per_run: dict[str, np.ndarray], reference: np.ndarray,
                   level: float = LEVEL, family_size: int | None = None,
                   margin: float = MARGIN) -> dict[str, dict[str, Any]]:
    """Every estimator of ``per_run`` (name to per-run loss) against ``reference``, Holm over
    a family of ``family_size`` comparisons (default: those given) (:func:`adjust`)."""
    out = {name: paired_comparison(values, reference, level, margin)
           for name, values in per_run.items()}
    adjust(out, len(out) if family_size is None else family_size, level)
    return out


def comparison_text(comparison: dict[str, Any], unit: str = "") -> str:
    """``"<verdict>: ratio <r> [<ci>] (margin +-<m> %), p_holm <p>; d = <mean> [<ci>]
    <unit>"`` (``p_holm``: Holm-adjusted over the comparison's family)."""
    text = f"{comparison['verdict']}: "
    if comparison["ratio"] is not None:
        rlo, rhi = comparison["ratio_ci"]
        text += f"ratio {comparison['ratio']:.4g} [{rlo:.4g}, {rhi:.4g}]"
    else:
        text += "ratio undefined (a zero MSE)"
    lo, hi = comparison["difference_ci"]
    return (text + f" (margin +-{100 * comparison['margin']:g} %), p_holm "
            f"{comparison['p_holm']:.2g}; "
            f"d = {comparison['mean_difference']:.3g} [{lo:.3g}, {hi:.3g}]"
            f"{' ' + unit if unit else ''}")
