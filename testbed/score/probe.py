"""The scoring harness's transparent estimator wrapper: step time and normalized
innovations (NIS, whitened innovations) of every step."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from filters.base import Innovations
from testbed.estimators import EstimatorWrapper
from testbed.score.consistency import whiten


class Probe(EstimatorWrapper):
    """A transparent wrapper that times ``step`` and collects normalized innovations.

    ``innovation`` (N, m) and ``innovation_cov`` (N, m, m), when the estimator exposes both
    after a step (the optional members of the estimator protocol), give
    ``NIS = nu^T S^-1 nu`` per member and the whitened innovation ``L^-1 nu`` (``S = L L^T``)
    for the whiteness test.

    Parameters
    ----------
    inner : batched estimator
    """

    batched = True

    def __init__(self, inner: Any):
        super().__init__(inner)
        self.elapsed_ns = 0
        self.calls = 0
        self.nis: list[np.ndarray] = []
        self.whitened: list[np.ndarray] = []
        self.nis_dim: int | None = None
        self.nis_missing = False
        self.nis_error: str | None = None

    def reset(self, x0: Any, P0: Any) -> None:
        """Reset the inner estimator and the records."""
        self.inner.reset(x0, P0)
        self.elapsed_ns, self.calls, self.nis, self.nis_missing = 0, 0, [], False
        self.whitened, self.nis_error = [], None

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Step the inner estimator (timed), then record its NIS and whitened innovation."""
        start = time.perf_counter_ns()
        x = self.inner.step(y, u)
        self.elapsed_ns += time.perf_counter_ns() - start
        self.calls += 1
        nu, S = ((self.inner.innovation, self.inner.innovation_cov)
                 if isinstance(self.inner, Innovations) else (None, None))
        if nu is None or S is None:
            self.nis_missing = True
        elif not self.nis_missing:
            nu = np.asarray(nu, dtype=float).reshape(len(x), -1)
            S = np.broadcast_to(np.asarray(S, dtype=float), (*nu.shape, nu.shape[1]))
            try:
                z = whiten(nu, S)
            except np.linalg.LinAlgError:
                self.nis_missing = True
                self.nis_error = (f"innovation covariance not positive definite at step "
                                  f"{self.calls}: NIS and whiteness not computed")
                return x
            self.whitened.append(z)
            self.nis.append(np.sum(z * z, axis=-1))
            self.nis_dim = nu.shape[1]
        return x

