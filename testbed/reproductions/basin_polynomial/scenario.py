"""Basin, Shi & Calderon-Alvarez (n.d.), Section IV: the central H-infinity filter on a cubic
polynomial system (see docs/references.md).

Every printed value of the example, verbatim. The system (22)-(24)::

    dx1/dt = x2
    dx2/dt = 0.1 x2^2 + (0.1 + 0.1 sin 50t) x2^3 + w1                    (22)
    y = x1 + w2                                                          (23)
    z = [x1, x2]                                                         (24)

i.e. ``a1 = [[0, 1], [0, 0]]``, ``a2[1, 1, 1] = 0.1``, ``a3[1, 1, 1, 1] = 0.1 + 0.1 sin 50t``
(0-based indices), ``B = [[0, 0], [1, 0]]``, ``C = [1, 0]``, ``D = [0, 1]``, ``L = I``;
(C3) holds (``D B^T = 0``, ``D D^T = 1``). ``x0 = [1, 1]``, ``R = I``, ``gamma = 1.05``,
``w1 = 1/(1 + t)^2``, ``w2 = 2/(2 + t)^2``, horizon 1.4, both filters from ``x_f(0) = 0``,
``P(0) = R^-1``.

The printed filters (26) and (28) contain ``-(1 - gamma^-2) P C^T C P`` only: they are
(13) with ``L = C = [1 0]`` (:attr:`PolynomialHinfScenario.printed_gain_L`), not with the
example's ``L = I``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from filters.polynomial_model import PolynomialModel


def cubic_coefficient(t_s: float) -> float:
    """``0.1 + 0.1 sin(50 t)``, the coefficient of ``x2^3`` in (22) (period 0.126 s)."""
    return 0.1 + 0.1 * np.sin(50.0 * t_s)


def _a3(t_s: float) -> np.ndarray:
    a3 = np.zeros((2, 2, 2, 2))
    a3[1, 1, 1, 1] = cubic_coefficient(t_s)
    return a3


def paper_model(L: np.ndarray | None = None, E: np.ndarray | None = None) -> PolynomialModel:
    """The system (22)-(24) as a :class:`~filters.polynomial_model.PolynomialModel`.

    Parameters
    ----------
    L : ndarray, shape (q, 2), optional
        Output matrix; default ``I`` (24). ``[[1, 0]]`` gives the printed (26)/(28).
    E : ndarray, shape (2, k), optional
        Control input (extension; the paper has none).

    Returns
    -------
    PolynomialModel
        ``n = 2``, ``p = 2`` (``w = [w1, w2]``), ``m = 1``.
    """
    a1 = np.array([[0.0, 1.0], [0.0, 0.0]])
    a2 = np.zeros((2, 2, 2))
    a2[1, 1, 1] = 0.1
    return PolynomialModel(a1=a1, a2=a2, a3=_a3, B=np.array([[0.0, 0.0], [1.0, 0.0]]),
                           C=np.array([[1.0, 0.0]]), D=np.array([[0.0, 1.0]]),
                           L=np.eye(2) if L is None else L, E=E)


def paper_w(t_s: float) -> np.ndarray:
    """The printed L2 disturbance ``[1/(1+t)^2, 2/(2+t)^2]``, shape (2,)."""
    return np.array([1.0 / (1.0 + t_s) ** 2, 2.0 / (2.0 + t_s) ** 2])


@dataclass(frozen=True)
class PolynomialHinfScenario:
    """The example of Basin, Shi & Calderon-Alvarez (n.d.): eqs. (22)-(28) and the values below.

    Attributes
    ----------
    model : PolynomialModel
        (22)-(24), ``L = I``.
    x0 : ndarray, shape (2,)
        True initial state.
    xf0 : ndarray, shape (2,)
        Initial estimate of both filters.
    R : ndarray, shape (2, 2)
        Weight of ``x0`` in (10); ``P(0) = R^-1``.
    gamma : float
    horizon_s : float
        "The filtering horizon is set to T = 1.4".
    printed_gain_L : ndarray, shape (1, 2)
        The ``L`` for which (13) gives the printed (26) (and the linear Riccati the
        printed (28)).
    curve_times : tuple of float
        Times at which the reproduction reports the ratio curve (Fig. 1, below), s.
    paper_T_poly, paper_T_linearized : float
        The printed ``||T_zw||`` at ``T = 1.4`` for (25)-(26) and (27)-(28).
    """

    model: PolynomialModel = field(default_factory=paper_model)
    x0: np.ndarray = field(default_factory=lambda: np.array([1.0, 1.0]))
    xf0: np.ndarray = field(default_factory=lambda: np.zeros(2))
    R: np.ndarray = field(default_factory=lambda: np.eye(2))
    gamma: float = 1.05
    horizon_s: float = 1.4
    printed_gain_L: np.ndarray = field(default_factory=lambda: np.array([[1.0, 0.0]]))
    curve_times: tuple[float, ...] = (0.25, 0.5, 0.75, 0.9, 1.0)
    paper_T_poly: float = 0.952
    paper_T_linearized: float = 1.079

    w = staticmethod(paper_w)  # the printed L2 disturbance
