"""The papers' own numpy plants: one protocol and one batch-first loop.

A paper whose plant is not a MuJoCo rig (the nonlinear system of Zhang, Deng & Zhang
(2018), the uncertain linear plants of Wang & Fang (2006) and Liu, Deng & Wang (n.d.), the
cubic system of Basin, Shi & Calderon-Alvarez (n.d.), the linear helicopter model of Basin,
Elvira-Ceja & Sanchez (n.d.); see docs/references.md) gives it as a :class:`NumpyPlant`
(the plants live with their reproductions, ``testbed/reproductions/<family>/plant.py``;
the helicopter's is a polynomial plant of degree 1):

- ``dt_s``; ``noise(rng, batch)``: one step's random draws for a batch (None for a
  noise-free plant);
- ``observe(x, k)``: the measurement at step ``k`` before any step (a reset's observation);
- ``step(x, k, u, noise) -> (x_next, y, extras)``: step ``k -> k + 1`` for states of shape
  ``(..., n)``; ``y`` is the measurement delivered at the end of the step (the testbed
  convention: a filter's ``step(y)`` returns ``xhat_{k+1}``), ``extras`` what an env adds to
  its ``info``. A finite escape raises :class:`~filters.errors.FiniteEscapeError` (nothing
  non-finite is returned).

:func:`rollout` runs a plant and any number of the library's estimators together: the Monte
Carlo and the recordings of every reproduction with such a plant.
:class:`testbed.envs.plant_env.PlantEnv` is the Gymnasium face of one plant.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from filters.base import Primed
from filters.errors import FilterError, FiniteEscapeError


class NumpyPlant(Protocol):
    """A paper's own plant, stepped for states of shape ``(..., n)`` (module docstring)."""

    dt_s: float

    def noise(self, rng: np.random.Generator | None, batch: tuple[int, ...]) -> Any:
        """One step's random draws for states of shape ``batch + (n,)`` (None: none)."""

    def observe(self, x: np.ndarray, k: int) -> np.ndarray:
        """The measurement at step ``k`` without a step, shape ``(..., p)``."""

    def step(self, x: np.ndarray, k: int, u: np.ndarray | None, noise: Any
             ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        """Step ``k -> k + 1``: ``(x_next (..., n), y (..., p), extras)``."""


@dataclass
class Rollout:
    """What :func:`rollout` gathered (rows ``0..N``; ``N`` is shorter after an escape).

    Attributes
    ----------
    t_s : ndarray, shape (N + 1,)
    x : ndarray, shape (..., N + 1, n)
        States, batch axes first.
    y : ndarray, shape (..., N, p)
        ``y[..., k, :]``: the measurement delivered at the end of step ``k``.
    estimates, covariances : dict of ndarray
        Per estimator: ``(..., K + 1, n)`` and ``(..., K + 1, n, n)`` (covariances of the
        estimators that have one); ``K = N`` unless it failed.
    failures : dict
        Estimator name -> ``(k, FilterError)``: step ``k`` raised; the estimator keeps its
        state at step ``k`` and its rows end there.
    escape : FiniteEscapeError or None
        The plant's escape that ended the run.
    """

    t_s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    estimates: dict[str, np.ndarray]
    covariances: dict[str, np.ndarray]
    failures: dict[str, tuple[int, FilterError]]
    escape: FiniteEscapeError | None


def rollout(plant: NumpyPlant, x0: np.ndarray, n_steps: int, *,
            noise: np.random.Generator | Callable[[int], Any] | None = None,
            u: Callable[[int], np.ndarray] | None = None,
            estimators: dict[str, Any] | None = None, record: bool = True,
            on_step: Callable[[int, np.ndarray, dict[str, np.ndarray]], None] | None = None,
            ) -> Rollout:
    """Step a plant for a batch of runs with estimators in the loop.

    Each step ``k``: the plant goes ``x_k -> x_{k+1}`` and delivers ``y``; every estimator
    is stepped on it (``step(y)``, or ``step(y, u_k)`` with ``u``) and holds ``xhat_{k+1}``.
    An estimator with ``prime`` (:class:`filters.LMIHInfFilter`) first gets
    ``plant.observe(x0, 0)``. The arithmetic is the estimators' own: a batch ``x0`` of shape
    ``(R, n)`` uses their batched form, ``(n,)`` their single form.

    Parameters
    ----------
    plant : NumpyPlant
    x0 : ndarray, shape (..., n)
    n_steps : int
    noise : numpy.random.Generator or callable ``k -> draws``, optional
        A generator draws each step's noise through ``plant.noise`` (as the env does); a
        callable gives step ``k``'s draws (e.g. a column of a pre-drawn array); None:
        ``plant.noise(None, batch)``.
    u : callable ``k -> (..., nu)``, optional
        The plant's input over step ``k``, also given to the estimators.
    estimators : dict, optional
        Name -> estimator, or ``(estimator, select)`` with ``select(y)`` the channels it gets.
    record : bool
        Keep the states, measurements, estimates and covariances (False: ``on_step`` only).
    on_step : callable ``(k, x_{k+1}, {name: xhat_{k+1}}) -> None``, optional
        Called after each step (e.g. to accumulate error moments without recording).

    Returns
    -------
    Rollout
    """
    x = np.array(x0, dtype=float)
    batch = x.shape[:-1]
    ests = {name: e if isinstance(e, tuple) else (e, None)
            for name, e in (estimators or {}).items()}
    draw = (noise if callable(noise) and not isinstance(noise, np.random.Generator)
            else lambda _k: plant.noise(noise, batch))
    y0 = None
    xs, ys = [x], []
    hist: dict[str, list] = {}
    covs: dict[str, list] = {}
    for name, (est, select) in ests.items():
        if isinstance(est, Primed):
            y0 = plant.observe(x, 0) if y0 is None else y0
            est.prime(y0 if select is None else select(y0))
        hist[name] = [np.array(est.x)]
        if est.P is not None:
            covs[name] = [np.array(est.P)]
    failures: dict[str, tuple[int, FilterError]] = {}
    escape = None
    for k in range(n_steps):
        uk = None if u is None else u(k)
        try:
            x, y, _ = plant.step(x, k, uk, draw(k))
        except FiniteEscapeError as exc:
            escape = exc
            break
        now = {}
        for name, (est, select) in ests.items():
            if name in failures:
                continue
            ye = y if select is None else select(y)
            try:
                now[name] = est.step(ye) if uk is None else est.step(ye, uk)
            except FilterError as exc:
                failures[name] = (k, exc)
                continue
            if record:
                hist[name].append(np.array(now[name]))
                if name in covs:
                    covs[name].append(np.array(est.P))
        if record:
            xs.append(x)
            ys.append(y)
        if on_step is not None:
            on_step(k, x, now)
    done = len(ys) if record else 0

    def stack(rows: list, tail: int) -> np.ndarray:
        arr = np.array(rows) if rows else np.empty((0, *batch, tail))
        return np.ascontiguousarray(np.moveaxis(arr, 0, len(batch)))  # batch-first

    return Rollout(
        t_s=np.arange(done + 1) * plant.dt_s,
        x=stack(xs, x.shape[-1]), y=stack(ys, 0),
        estimates={name: stack(rows, x.shape[-1]) for name, rows in hist.items()},
        covariances={name: np.ascontiguousarray(np.moveaxis(np.array(rows), 0, len(batch)))
                     for name, rows in covs.items()},
        failures=failures, escape=escape)
