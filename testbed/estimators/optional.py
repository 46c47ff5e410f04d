"""The optional parts of an estimator (:mod:`filters.base`'s small protocols), read in one
place: an estimator (a plug-in's included) may lack any of them.

:data:`DEFAULTS` is the table of the optional parts and what an estimator without one has;
:data:`REQUIRED` the members every estimator has (:class:`filters.base.Estimator`; ``P`` is
optional here: None for an estimator without a covariance). One function looks them up
(:func:`_part`); each function below returns what the estimator has, or the table's
default: no covariance (``P`` None), not batched, no innovations, no design facts, the
design's channels, no priming, no shared covariance, no covariance memo.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

#: An estimator's optional parts by attribute, and the value of one that lacks it.
DEFAULTS: dict[str, Any] = {
    "P": None,  # filters.base.Estimator: the covariance, None without one (no NEES)
    "batched": False,  # filters.base.Batched
    "innovation": None,  # filters.base.Innovations
    "innovation_cov": None,
    "design_meta": None,  # filters.base.DesignFacts
    "channels": None,  # filters.base.ChannelRequest: None, the design's channels
    "prime": None,  # filters.base.Primed
    "shared_P": None,  # the covariance a batch's members share (filters.KalmanFilter)
    "share_covariance_memo": None,  # takes a study's filters.CovarianceMemo (KalmanFilter)
    "inner": None,  # the estimator a wrapper wraps (testbed.estimators.EstimatorWrapper)
}
#: What every estimator has (:class:`filters.base.Estimator`, its covariance optional).
REQUIRED = ("x", "reset", "step")
#: ``_part``'s default: the table's.
_TABLE = object()
#: A member that is not there.
_ABSENT = object()


def _part(est: Any, name: str, default: Any = _TABLE) -> Any:
    """``est``'s member ``name``, or ``default`` (the table's, :data:`DEFAULTS`) without."""
    return getattr(est, name, DEFAULTS[name] if default is _TABLE else default)


def lacks(est: Any, names: Sequence[str] = REQUIRED) -> list[str]:
    """The members of ``names`` (default :data:`REQUIRED`) that ``est`` does not have, in
    order (empty: it has them all)."""
    return [name for name in names if _part(est, name, _ABSENT) is _ABSENT]


def covariance(est: Any) -> np.ndarray | None:
    """``est.P`` ((n, n) or (N, n, n)), None for an estimator without a covariance."""
    return _part(est, "P")


def is_batched(est: Any) -> bool:
    """Whether ``est`` declares ``batched = True`` (:class:`filters.base.Batched`)."""
    return bool(_part(est, "batched"))


def innovations(est: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(est.innovation, est.innovation_cov)`` of its last step
    (:class:`filters.base.Innovations`), None for what it lacks."""
    return _part(est, "innovation"), _part(est, "innovation_cov")


def design_facts(est: Any) -> dict[str, Any] | None:
    """``design_meta`` of the estimator or of the one it wraps (``inner``)
    (:class:`filters.base.DesignFacts`), None without."""
    return _part(_part(est, "inner", est), "design_meta")


def requested_channels(est: Any) -> Any:
    """``est.channels`` (indices or ``"all"``; :class:`filters.base.ChannelRequest`), None:
    the design's."""
    return _part(est, "channels")


def primer(est: Any) -> Callable[[np.ndarray], None] | None:
    """``est.prime`` (:class:`filters.base.Primed`), None when it does not prime."""
    return _part(est, "prime")


def shared_covariance(est: Any) -> np.ndarray | None:
    """The covariance (n, n) every member of ``est``'s batch shares
    (:attr:`filters.kalman.KalmanFilter.shared_P`), None when they do not (or it cannot
    tell)."""
    return _part(est, "shared_P")


def share_covariance_memo(est: Any, memo: Any) -> bool:
    """Give ``est`` a study's covariance memo if it takes one
    (:meth:`filters.kalman.KalmanFilter.share_covariance_memo`); whether it took it."""
    share = _part(est, "share_covariance_memo")
    if not callable(share):
        return False
    share(memo)
    return True
