"""The optional parts of an estimator (:mod:`filters.base`'s small protocols), read in one
place: an estimator (a plug-in's included) may lack any of them.

Each function returns what the estimator has, or the documented default: no covariance
(``P`` None), not batched, no innovations, no design facts, the design's channels, no
priming.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np


def covariance(est: Any) -> np.ndarray | None:
    """``est.P`` ((n, n) or (N, n, n)), None for an estimator without a covariance."""
    return getattr(est, "P", None)


def is_batched(est: Any) -> bool:
    """Whether ``est`` declares ``batched = True`` (:class:`filters.base.Batched`)."""
    return bool(getattr(est, "batched", False))


def innovations(est: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(est.innovation, est.innovation_cov)`` of its last step
    (:class:`filters.base.Innovations`), None for what it lacks."""
    return getattr(est, "innovation", None), getattr(est, "innovation_cov", None)


def design_facts(est: Any) -> dict[str, Any] | None:
    """``design_meta`` of the estimator or of the one it wraps (``inner``)
    (:class:`filters.base.DesignFacts`), None without."""
    return getattr(getattr(est, "inner", est), "design_meta", None)


def requested_channels(est: Any) -> Any:
    """``est.channels`` (indices or ``"all"``; :class:`filters.base.ChannelRequest`), None:
    the design's."""
    return getattr(est, "channels", None)


def primer(est: Any) -> Callable[[np.ndarray], None] | None:
    """``est.prime`` (:class:`filters.base.Primed`), None when it does not prime."""
    return getattr(est, "prime", None)
