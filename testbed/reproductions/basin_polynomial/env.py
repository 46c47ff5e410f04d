"""``testbed/PolynomialCubic-v0``: the cubic polynomial system of Basin, Shi &
Calderon-Alvarez (n.d.) as a Gymnasium environment (see docs/references.md).

A plain ODE plant (no MuJoCo) under the same contract as the MuJoCo rigs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from filters import real_array
from filters.polynomial_model import EscapeTest
from testbed.envs.plant_env import PlantEnv, PlantSensors
from testbed.reproductions.basin_polynomial.plant import PolynomialPlant
from testbed.reproductions.basin_polynomial.scenario import paper_model, paper_w

DISTURBANCES = ("paper", "white", "none")


class PolynomialCubicEnv(PlantEnv):
    """The cubic system of Basin, Shi & Calderon-Alvarez (n.d.), Section IV, integrated with RK4.

    ``dx1/dt = x2``, ``dx2/dt = 0.1 x2^2 + (0.1 + 0.1 sin 50t) x2^3 + w1 + u``,
    ``y = x1 + w2``, ``z = x`` (eqs. (22)-(24); the input ``u`` is an extension, 0 gives the
    paper's system). The cubic term is positive: the state escapes in finite time (about
    1.78 s from the paper's ``x0 = [1, 1]`` with its disturbance). The model, for filters,
    is :attr:`model` (:func:`testbed.reproductions.basin_polynomial.scenario.paper_model` with
    ``E = [0, 1]^T``); the plant :class:`~testbed.reproductions.basin_polynomial.plant.
    PolynomialPlant`. The common contract (validation, escape, info) is :class:`PlantEnv`'s.

    ===========  =====  =====================================================
    space        shape  content
    ===========  =====  =====================================================
    action       (1,)   input ``u`` added to ``dx2/dt`` (1/s^2), in [-10, 10]
    observation  (1,)   ``y = x1 + w2`` averaged over the last control period
    ===========  =====  =====================================================

    After :meth:`reset` the observation is ``x1(0) + w2(0)`` (deterministic part); with white
    ``w2`` of intensity ``q2`` a sample has variance ``q2 / dt_s``. ``info["disturbance"]``:
    ``[w1, w2]`` averaged over the step. Reward ``-(x1^2 + x2^2)``. The escape test (an
    :class:`~filters.polynomial_model.EscapeTest` after every RK4 substep: a bound, default
    1e8, and a growth test, more than +10 % in one substep above 100) terminates the
    episode; truncated after 1400 steps = 1.4 s, the paper's horizon (registration).

    Arguments: ``dt_s`` (control period, default 0.001 s) and ``substeps`` (RK4 steps per
    period, default 10); ``disturbance``: ``"paper"`` (``w1 = 1/(1+t)^2``, ``w2 =
    2/(2+t)^2``), ``"white"`` (white noise of intensities ``noise_intensity = (q1, q2)``,
    drawn from the env's seeded generator), ``"none"``, or a callable ``t_s -> [w1, w2]``;
    ``escape_bound`` and ``growth_rtol`` of the escape test. ``reset(options={"x0": (2,)})``:
    default the paper's ``[1, 1]``.
    """

    metadata = {"render_modes": [], "render_fps": 1000}

    def __init__(
        self,
        dt_s: float = 0.001,
        substeps: int = 10,
        disturbance: str | Callable[[float], np.ndarray] = "paper",
        noise_intensity: tuple[float, float] = (1.0, 1.0),
        escape_bound: float = 1e8,
        growth_rtol: float = 0.1,
        render_mode: str | None = None,
    ):
        q = real_array(noise_intensity, "noise_intensity", finite=False)
        if q.shape != (2,) or not np.all(np.isfinite(q)) or np.any(q < 0):
            raise ValueError(f"noise_intensity must be two finite non-negative intensities "
                             f"(q1, q2), got {noise_intensity!r}")
        if callable(disturbance):
            w = disturbance
        elif disturbance in DISTURBANCES:
            w = paper_w if disturbance == "paper" else None
        else:
            raise ValueError(f"disturbance must be one of {DISTURBANCES} or a callable "
                             f"t_s -> [w1, w2], got {disturbance!r}")
        white = disturbance == "white"
        self.model = paper_model(E=np.array([[0.0], [1.0]]))
        system = PolynomialPlant(self.model, EscapeTest(bound=escape_bound,
                                                        growth_rtol=growth_rtol),
                                 dt_s=dt_s, substeps=substeps, w=w,  # checks both
                                 noise_intensity=q if white else None)
        sensors = PlantSensors(["y"], np.array([[1.0, 0.0]]),
                               np.array([[q[1] if white and q[1] > 0 else 1.0]]),
                               per_sample=False, name="output")
        self._setup(system, sensors, action_limit=10.0, action_names=["u [1/s^2]"],
                    state_names=["x1", "x2"], x0=np.array([1.0, 1.0]),
                    escape_bound=system.escape.bound, render_mode=render_mode)

    def _first(self, x0: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
        w = self.plant.w
        return self.plant.observe(x0, 0), {"disturbance": np.zeros(2) if w is None else w(0.0)}

    def _reward(self, x: np.ndarray) -> float:
        return -float(x[0] * x[0] + x[1] * x[1])
