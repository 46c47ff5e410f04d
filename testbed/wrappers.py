"""Gymnasium wrappers that put an estimator in the loop."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from filters import Estimator
from testbed.metrics import EpisodeMetrics


class FilterInLoop(gym.Wrapper):
    """Feed every measurement and applied action to an estimator; observe the estimate.

    A policy acting on this wrapper's observations is an output-feedback controller: it sees
    the estimate ``x_hat`` (shape (n,)), never the true state. ``info`` keeps
    ``measurement`` (the sensor vector), ``state`` (truth), ``estimate``, ``covariance``
    (or None) and ``error = estimate - state``. :meth:`metrics` returns the running
    :class:`~testbed.metrics.EpisodeMetrics`.

    Parameters
    ----------
    env : gymnasium.Env
        An environment whose ``info`` has ``state``, ``t``, ``disturbance`` and
        ``action_applied`` (all testbed envs).
    estimator : filters.Estimator
        Anything with ``x``, ``P``, ``step(y, u)`` and ``reset(x0, P0)``.
    input_transform : callable ``(u_applied, x_hat) -> u_model``, optional
        Maps the applied action to the estimator model's input (e.g. subtract the gravity
        voltage so a linear model sees only the unbalanced part).
    measurement_index : sequence of int, optional
        Channels of the sensor vector given to the estimator (default: all).
    output_matrix, ratio_weight : ndarray, optional
        ``L`` and ``R`` of the noise-output ratio (see :class:`EpisodeMetrics`).

    Notes
    -----
    ``reset(options={"estimator": {"x0": ..., "P0": ...}, ...})`` restarts the estimator
    from the given prior (default: the prior it had when wrapped); the other option keys go
    to the environment.
    """

    def __init__(self, env: gym.Env, estimator: Estimator, *,
                 input_transform: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                 measurement_index: Sequence[int] | None = None,
                 output_matrix: np.ndarray | None = None,
                 ratio_weight: np.ndarray | None = None):
        super().__init__(env)
        self.estimator = estimator
        self.input_transform = input_transform
        P = estimator.P  # None for estimators without a covariance
        self._prior = (np.array(estimator.x, copy=True),
                       None if P is None else np.array(P, copy=True))
        n = self._prior[0].shape[-1]
        self.observation_space = spaces.Box(-np.inf, np.inf, (n,), np.float64)
        inner = env.unwrapped
        self._index = None if measurement_index is None else np.asarray(measurement_index)
        self.state_names = list(getattr(inner, "state_names", [f"x{i}" for i in range(n)]))
        sensors = getattr(inner, "sensors", None)
        measured = list(getattr(sensors, "measured_state", None)
                        or getattr(sensors, "measured_state_index", []))
        self._metrics = EpisodeMetrics(self.state_names, float(getattr(inner, "dt_s", 1.0)),
                                       measured, output_matrix, ratio_weight)

    @property
    def measurement_index(self) -> np.ndarray | None:
        """Sensor channels given to the estimator (None: all)."""
        return self._index

    def metrics(self) -> EpisodeMetrics:
        """Metrics of the current episode."""
        return self._metrics

    def _augment(self, info: dict[str, Any], y: np.ndarray) -> dict[str, Any]:
        x_hat = np.array(self.estimator.x, copy=True)
        P = self.estimator.P
        info = dict(info)
        info["measurement"] = y
        info["estimate"] = x_hat
        info["covariance"] = None if P is None else np.array(P, copy=True)
        info["error"] = x_hat - info["state"]
        return info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the environment, the estimator and the metrics."""
        options = dict(options or {})
        prior = options.pop("estimator", None) or {}
        unknown = set(prior) - {"x0", "P0"}
        if unknown:
            raise ValueError(f"unknown options['estimator'] keys {sorted(unknown)}; expected "
                             "'x0' and/or 'P0'")
        y, info = self.env.reset(seed=seed, options=options or None)
        self.estimator.reset(prior.get("x0", self._prior[0]), prior.get("P0", self._prior[1]))
        prime = getattr(self.estimator, "prime", None)  # filters that use the first sample
        if prime is not None:
            prime(y if self._index is None else y[self._index])
        self._metrics.reset(info["state"])
        return np.array(self.estimator.x, copy=True), self._augment(info, y)

    def step(self, action):
        """Step the environment, then the estimator on the new measurement."""
        y, reward, terminated, truncated, info = self.env.step(action)
        u = info["action_applied"]
        if self.input_transform is not None:
            u = self.input_transform(u, self.estimator.x)
        y_est = y if self._index is None else y[self._index]
        self.estimator.step(y_est, u)
        info = self._augment(info, y)
        self._metrics.update(info["state"], info["estimate"], info["covariance"], y,
                             info.get("disturbance"))
        return info["estimate"].copy(), reward, terminated, truncated, info
