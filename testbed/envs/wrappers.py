"""Gymnasium wrappers that put an estimator in the loop."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from filters import Estimator
from filters.base import Batched, Primed
from testbed.envs.common import env_declarations
from testbed.estimators import optional
from testbed.experiment.loop import EstimatorStage, check_estimate
from testbed.experiment.metrics import EpisodeMetrics
from testbed.plugins import factory_name


class FilterInLoop(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Feed every measurement and applied action to an estimator; observe the estimate.

    A policy acting on this wrapper's observations is an output-feedback controller: it sees
    the estimate ``x_hat`` (shape (n,)), never the true state. ``info`` keeps
    ``measurement`` (the sensor vector), ``state`` (truth), ``estimate``, ``covariance``
    (or None) and ``error = estimate - state``. :meth:`metrics` returns the running
    :class:`~testbed.experiment.metrics.EpisodeMetrics`.

    The estimator step is the runner's (:class:`testbed.experiment.loop.EstimatorStage`): the same
    input
    transform, priming and metrics, for one episode. :meth:`from_design` builds the estimator
    the way the runner does, from the rig's design model.

    Parameters
    ----------
    env : gymnasium.Env
        An environment whose ``info`` has ``state``, ``t``, ``disturbance`` and
        ``action_applied`` (all testbed envs).
    estimator : filters.Estimator
        Anything with ``x`` (n,), ``P`` ((n, n) or None), ``step(y, u)`` and
        ``reset(x0, P0)``; an optional ``prime(y)`` receives the first sample.
    input_transform : callable ``(u_applied (nu,), x_hat (n,)) -> u_model``, optional
        Maps the applied action to the estimator model's input (e.g. subtract the gravity
        voltage so a linear model sees only the unbalanced part).
    measurement_index : sequence of int, optional
        Channels of the sensor vector given to the estimator (default: all).
    physical_index : sequence of int, optional
        The rig's physical states in the estimator's state (an augmented design's
        ``design.physical_index``; default: all): the observation, ``info["estimate"]``,
        ``info["covariance"]`` and the metrics are theirs (the marginal covariance block).
    output_matrix, ratio_weight : ndarray, optional
        ``L`` and ``R`` of the noise-output ratio (see :class:`EpisodeMetrics`).

    design : DesignModel, optional
        With ``estimator`` given as a name or factory: the design model to build it from
        (default: the environment's, as :meth:`from_design`).
    estimator_options : dict, optional
        With ``estimator`` given as a name or factory: the factory's options.

    Notes
    -----
    ``estimator`` may also be a registered name, ``"module:factory"`` or a factory: the
    wrapper is then built like :meth:`from_design` and its spec (``env.spec``) recreates it
    (``gymnasium.make(env.spec)``). Wrappers pickle and deep-copy into independent working
    copies.

    ``reset(options={"estimator": {"x0": ..., "P0": ...}, ...})`` restarts the estimator
    from the given prior (default: the prior it had when wrapped); the other option keys go
    to the environment. Both are checked before anything is reset. A ``FilterError`` raised
    by the estimator inside :meth:`step` leaves the wrapper needing :meth:`reset` (the
    environment has advanced, the estimate has not); a further ``step`` says so.
    """

    def __init__(self, env: gym.Env, estimator: Estimator | str | Callable = "kalman", *,
                 input_transform: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                 measurement_index: Sequence[int] | None = None,
                 physical_index: Sequence[int] | None = None,
                 output_matrix: np.ndarray | None = None,
                 ratio_weight: np.ndarray | None = None, design: Any = None,
                 estimator_options: dict[str, Any] | None = None):
        gym.utils.RecordConstructorArgs.__init__(
            self, estimator=estimator, input_transform=input_transform,
            measurement_index=measurement_index, physical_index=physical_index,
            output_matrix=output_matrix, ratio_weight=ratio_weight, design=design,
            estimator_options=estimator_options)
        if isinstance(estimator, str) or (callable(estimator)
                                          and optional.lacks(estimator, ("step",))):
            if input_transform is not None or output_matrix is not None:
                raise ValueError("input_transform and output_matrix come from the design "
                                 "when the estimator is given by name or factory")
            if measurement_index is not None or physical_index is not None:
                raise ValueError("measurement_index and physical_index come from the design "
                                 "when the estimator is given by name or factory")
            (estimator, input_transform, output_matrix, measurement_index,
             physical_index) = _from_design(env, estimator, design,
                                            dict(estimator_options or {}))
        elif design is not None or estimator_options:
            raise ValueError("design and estimator_options apply to an estimator given by "
                             "name or factory, not to an estimator object")
        gym.Wrapper.__init__(self, env)
        self.estimator = estimator
        P = estimator.P  # None for estimators without a covariance
        x0 = np.array(estimator.x, dtype=float, copy=True)
        n = x0.shape[-1] if physical_index is None else len(physical_index)
        self.observation_space = spaces.Box(-np.inf, np.inf, (n,), np.float64)
        inner = env.unwrapped
        self._index = None if measurement_index is None else np.asarray(measurement_index)
        declared = env_declarations(inner)
        self.state_names = list([f"x{i}" for i in range(n)] if declared.state_names is None
                                else declared.state_names)
        metrics = EpisodeMetrics(self.state_names,
                                 float(1.0 if declared.dt_s is None else declared.dt_s),
                                 declared.measured, output_matrix, ratio_weight)
        self._stage = EstimatorStage(estimator, input_transform, metrics,
                                     (x0, None if P is None else np.array(P, copy=True)),
                                     physical_index=physical_index)
        self._needs_reset = True

    @classmethod
    def from_design(cls, env: gym.Env, estimator: Any = "kalman", *, design: Any = None,
                    **options: Any) -> FilterInLoop:
        """Wrap a testbed rig environment with an estimator built from its design model.

        Parameters
        ----------
        env : testbed.envs.RigEnv (possibly wrapped)
        estimator : str or callable
            A registered name (``"kalman"``, ...), ``"package.module:factory"``, or a factory
            ``(design, **options) -> Estimator`` (see :mod:`testbed.estimators`).
        design : testbed.design.DesignModel, optional
            Default: ``rig.design_model(sensors, dt_s, disturbance)`` of the environment.
        **options
            Passed to the estimator factory.
        """
        return cls(env, estimator, design=design, estimator_options=options)

    @property
    def input_transform(self) -> Callable | None:
        """The input transform applied before the estimator step (or None)."""
        return self._stage.input_transform

    @property
    def measurement_index(self) -> np.ndarray | None:
        """Sensor channels given to the estimator (None: all)."""
        return self._index

    def metrics(self) -> EpisodeMetrics:
        """Metrics of the current episode."""
        return self._stage.metrics

    def _select(self, y: np.ndarray) -> np.ndarray:
        return y if self._index is None else y[self._index]

    def _augment(self, info: dict[str, Any], y: np.ndarray) -> dict[str, Any]:
        x_hat = np.array(self._stage.x, copy=True)
        P = self._stage.P
        info = dict(info)
        info["measurement"] = y
        info["estimate"] = x_hat
        info["covariance"] = None if P is None else np.array(P, copy=True)
        info["error"] = x_hat - info["state"]
        return info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the environment, the estimator and the metrics (options checked first)."""
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be a dict or None, got {type(options).__name__}")
        options = dict(options or {})
        x0, P0 = self._stage.priors(1, [options.pop("estimator", None)])
        x0 = x0[0]
        P0 = P0 if P0 is None or np.ndim(P0) == 2 else P0[0]
        _check_prior(x0, P0, self._stage.prior[0].shape[-1])
        y, info = self.env.reset(seed=seed, options=options or None)
        self._stage.reset(self._select(y), info["state"], x0, P0)
        self._needs_reset = False
        return np.array(self._stage.x, copy=True), self._augment(info, y)

    def step(self, action):
        """Step the environment, then the estimator on the new measurement."""
        if self._needs_reset:
            raise RuntimeError("FilterInLoop.step called before reset() (or after the "
                               "estimator failed): call reset() first")
        y, reward, terminated, truncated, info = self.env.step(action)
        try:
            self._stage.step(self._select(y), info["action_applied"], info["state"],
                             info.get("disturbance"))
        except Exception:
            self._needs_reset = True
            raise
        info = self._augment(info, y)
        return info["estimate"].copy(), reward, terminated, truncated, info


def _from_design(env: gym.Env, estimator: Any, design: Any,
                 options: dict[str, Any]) -> tuple[Any, Any, Any, Any, Any]:
    """The estimator built from the design model the runner's way (the design for its
    profile, the checks after the factory), its input transform, output matrix, the
    channels it takes and the physical states of its design."""
    from testbed import estimators

    inner = env.unwrapped
    if design is None:
        declared = vars(env_declarations(inner))
        missing = [a for a in ("rig", "sensors", "dt_s", "sim") if declared[a] is None]
        if missing:
            raise ValueError(f"FilterInLoop.from_design needs a testbed rig environment "
                             f"(RigEnv: with {', '.join(missing)}); "
                             f"{type(inner).__name__} has no {', '.join(missing)}: pass "
                             "design=DesignModel(...) or wrap an estimator object with "
                             "FilterInLoop(env, estimator)")
        design = inner.rig.design_model(inner.sensors, inner.dt_s,
                                        inner.sim.known_disturbance)
    design, _ = estimators.design_for(estimator, design)
    est = estimators.build(estimator, design, **options)
    name = factory_name(estimator)
    check_estimate(name, est.x, optional.covariance(est), design.n, "after the factory")
    channels = estimators.channels_for(est, design)
    if isinstance(est, Batched) and est.batched:
        est = _BatchOfOne(est)  # the runner's batched arithmetic: bitwise its results
    transform = None
    if design.input_transform is not None:
        transform = _RowTransform(design.input_transform)
    return (est, transform, design.output_matrix[:, design.physical], channels,
            design.physical)


class _RowTransform:
    """A batched input transform ``(u (N, nu), x_hat (N, n))`` applied to one row (a class,
    not a closure: wrappers pickle)."""

    def __init__(self, batched: Callable[[np.ndarray, np.ndarray], np.ndarray]):
        self.batched = batched

    def __call__(self, u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
        return self.batched(u[None], np.asarray(x_hat)[None])[0]


class _BatchOfOne:
    """A batch-capable estimator run as a batch of one, seen as a single estimator."""

    def __init__(self, inner: Any):
        self.inner = inner
        if isinstance(inner, Primed):  # (else no prime: the loop does not prime it)
            self.prime = self._prime

    @property
    def x(self) -> np.ndarray:
        """Estimate, shape (n,)."""
        return np.asarray(self.inner.x).reshape(-1)

    @property
    def P(self) -> np.ndarray | None:
        """Covariance (n, n) or None."""
        P = self.inner.P
        return None if P is None else np.asarray(P).reshape(P.shape[-2:])

    def reset(self, x0: np.ndarray, P0: np.ndarray | None) -> None:
        """Reset the batch of one from ``x0`` (n,) and ``P0`` (n, n)."""
        self.inner.reset(np.asarray(x0, float)[None], P0)

    def _prime(self, y: np.ndarray) -> None:
        self.inner.prime(np.asarray(y)[None])

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """One step of the batch of one; returns the estimate (n,)."""
        self.inner.step(np.asarray(y)[None], None if u is None else np.asarray(u)[None])
        return self.x


def _check_prior(x0: np.ndarray, P0: np.ndarray | None, n: int) -> None:
    """``ValueError`` unless ``x0`` is finite (n,) and ``P0`` is None or finite symmetric."""
    if x0.shape != (n,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"options['estimator']['x0'] must be a finite array of shape ({n},), "
                         f"got {x0!r}")
    if P0 is not None:
        P0 = np.asarray(P0)
        if P0.shape != (n, n) or not np.all(np.isfinite(P0)) or not np.allclose(P0, P0.T):
            raise ValueError(f"options['estimator']['P0'] must be a finite symmetric ({n}, {n}) "
                             f"array, got shape {P0.shape}")
