"""Estimators around estimators (:class:`EstimatorWrapper`, :class:`ChannelSelect`) and the
channels the loop gives an estimator (:func:`channels_for`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from testbed.design import DesignModel
from testbed.estimators import optional


class EstimatorWrapper:
    """An estimator around another: ``x``, ``P``, ``reset``, ``step`` and every other member
    (``prime``, ``design_meta``, ``innovation``...) are the inner estimator's unless a
    subclass changes them.

    Parameters
    ----------
    inner : estimator
    """

    def __init__(self, inner: Any):
        self.inner = inner

    @property
    def x(self) -> np.ndarray:
        """The inner estimate."""
        return self.inner.x

    @property
    def P(self) -> np.ndarray | None:
        """The inner covariance."""
        return self.inner.P

    @property
    def shared_P(self) -> np.ndarray | None:
        """The covariance the inner batch's members share (its ``shared_P``), or None."""
        return optional.shared_covariance(self.inner)

    def reset(self, x0: Any, P0: Any) -> None:
        """Reset the inner estimator."""
        self.inner.reset(x0, P0)

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Step the inner estimator."""
        return self.inner.step(y, u)

    def __getattr__(self, name: str) -> Any:
        if name == "inner":  # not set yet (copying, unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.inner, name)


class ChannelSelect(EstimatorWrapper):
    """An estimator reading only some channels of ``y`` (batch-transparent).

    Takes the full sensor vector (``m`` channels: it selects) or the selected channels
    (what the loop gives an estimator whose ``channels`` are ``index``: passed through).

    Parameters
    ----------
    inner : estimator
    index : ndarray of int
        Channels of the sensor vector given to ``inner``.
    m : int, optional
        Channels of the full sensor vector (default: ``max(index) + 1``).
    request : bool
        Set :attr:`channels` to ``index``: the loop then gives the estimator these channels
        (beyond ``design.measurement_index``, e.g. the deterministic ``y2`` of ``ms-hinf``).
    """

    def __init__(self, inner: Any, index: np.ndarray, m: int | None = None,
                 request: bool = False):
        super().__init__(inner)
        self.index = np.asarray(index, dtype=int)
        self.m = int(self.index.max()) + 1 if m is None else int(m)
        self.batched = optional.is_batched(inner)
        if request:
            self.channels = self.index

    def _pick(self, y: np.ndarray) -> np.ndarray:
        y = np.asarray(y)
        if y.shape[-1] == len(self.index) and len(self.index) != self.m:
            return y  # already the selected channels
        return y[..., self.index]

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Step the inner estimator on ``y[..., index]``."""
        return self.inner.step(self._pick(y), u)

    def __getattr__(self, name: str) -> Any:
        if name == "prime" and "inner" in self.__dict__:  # only when the inner one primes
            prime = self.inner.prime
            return lambda y: prime(self._pick(y))
        return super().__getattr__(name)


def channels_for(estimator: Any, design: DesignModel) -> np.ndarray | None:
    """The channels of the sensor vector the loop gives ``estimator``: its own
    ``channels`` attribute (indices, or ``"all"``) or ``design.measurement_index``
    (None: every channel)."""
    asked = optional.requested_channels(estimator)
    if isinstance(asked, str):
        if asked != "all":
            raise ValueError(f"estimator channels must be indices or 'all', got {asked!r}")
        return None
    index = design.measurement_index if asked is None else np.asarray(asked, dtype=int)
    if np.array_equal(index, np.arange(len(design.measurement_names))):
        return None
    return np.asarray(index, dtype=int)
