"""Basin, Elvira-Ceja & Sanchez (n.d.), Section IV: the mean-square H-infinity filter on the
2-DOF helicopter.

Every printed value of the example, verbatim (with the corrections of
:func:`testbed.rigs.helicopter.paper_model`; see docs/references.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from testbed.rigs.helicopter import (
    PAPER_GAMMA,
    PAPER_INITIAL_WEIGHT,
    LinearModel,
    basin_helicopter_w,
    paper_model,
)


@dataclass(frozen=True)
class MsHinfHelicopterScenario:
    """The example of Basin, Elvira-Ceja & Sanchez (n.d.): eqs. (12)-(18) and the values below.

    Attributes
    ----------
    model : LinearModel
        A, B, b, G, C1 = C2 = L, h, H.
    x0 : ndarray, shape (4,)
        True initial state (pitch on its stop, -0.7069 rad = -40.5 deg).
    m0 : ndarray, shape (4,)
        Initial estimate.
    P0 : ndarray, shape (4, 4)
    R : ndarray, shape (4, 4)
        Weight of the initial condition in (6); ``S(0) = R^-1``.
    u : ndarray, shape (2,)
        Constant motor voltages, V.
    gamma : float
    horizon_s : float
    paper_T_max : float
        "the maximum value of the noise-output H-infinity norm T is 0.208".
    """

    model: LinearModel = field(default_factory=paper_model)
    x0: np.ndarray = field(default_factory=lambda: np.array([-0.7069, 0.0, 0.0, 0.0]))
    m0: np.ndarray = field(default_factory=lambda: np.array([0.1745, -0.5236, -0.15, -0.4]))
    P0: np.ndarray = field(default_factory=lambda: np.diag([10.0, 10.0, 15.0, 5.0]))
    R: np.ndarray = field(default_factory=lambda: PAPER_INITIAL_WEIGHT.copy())
    u: np.ndarray = field(default_factory=lambda: np.array([12.495, -3.835]))
    gamma: float = PAPER_GAMMA
    horizon_s: float = 80.0
    paper_T_max: float = 0.208

    w = staticmethod(basin_helicopter_w)  # the printed L2 disturbance w(t)
