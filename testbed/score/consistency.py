"""The consistency tests of a scored study: :mod:`testbed.stats` (where they live, below
:mod:`testbed.experiment`, whose replay of a recording tests its innovations with them),
re-exported under the score's name."""

from __future__ import annotations

from testbed.stats import (
    CONSISTENT,
    INCONCLUSIVE,
    LAGS,
    MIN_RUNS,
    NO_VERDICT,
    OVERCONFIDENT,
    UNDERCONFIDENT,
    clopper_pearson,
    consistency_test,
    effective_steps,
    t_interval,
    verdict_text,
    whiten,
    whiteness_test,
)

__all__ = ["CONSISTENT", "INCONCLUSIVE", "LAGS", "MIN_RUNS", "NO_VERDICT", "OVERCONFIDENT",
           "UNDERCONFIDENT", "clopper_pearson", "consistency_test", "effective_steps",
           "t_interval", "verdict_text", "whiten", "whiteness_test"]
