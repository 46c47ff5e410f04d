"""Wang & Fang (2006), Section IV: variance-constrained robust H-infinity filter with parabolic
poles.

Every printed value of the example, verbatim; the example's ``E = [0.1 0.1]^T`` is Theorem 1's
``H`` (see docs/references.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from filters.analysis import Parabola, UncertainPlant
from filters.variance_continuous import ParabolicDesignParameters


def _a(rows: list) -> np.ndarray:
    return np.array(rows, dtype=float)


@dataclass(frozen=True)
class VarianceConstrainedContinuousScenario:
    """The example of Wang & Fang (2006) (matrices, requirements, design values, printed results).

    Attributes
    ----------
    A, C, D1, D2, M1, M2, N, L : ndarray
        Shapes (2, 2), (1, 2), (2, 2), (1, 2), (2, 1), (1, 1), (1, 2), (1, 2).
    a, b : float
        Parabola ``P(0.5, 0.5)``.
    gamma : float
        H-infinity bound 0.1.
    sigma2 : ndarray, shape (2,)
        Variance bounds ``[0.3, 0.7]``.
    eps1, eps2, delta1, delta2 : float
        0.58, 0.58, 0.01, 0.01.
    H : ndarray, shape (2, 1)
        ``[0.1, 0.1]^T`` (printed as ``E``).
    paper_Q1, paper_Q2 : ndarray, shape (2, 2)
        The printed solutions of (16), (17).
    paper_K1, paper_G1, paper_K2, paper_G2 : ndarray
        The printed filters for ``U = 1`` and ``U = -1``, shapes (2, 1) and (2, 2).
    """

    A: np.ndarray = field(default_factory=lambda: _a([[-2.5, 0.3], [0.4, -1.5]]))
    C: np.ndarray = field(default_factory=lambda: _a([[0.1, 0.1]]))
    D1: np.ndarray = field(default_factory=lambda: _a([[0.1, 0.0], [0.0, 0.1]]))
    D2: np.ndarray = field(default_factory=lambda: _a([[0.6, 0.2]]))
    M1: np.ndarray = field(default_factory=lambda: _a([[0.8], [0.8]]))
    M2: np.ndarray = field(default_factory=lambda: _a([[0.8]]))
    N: np.ndarray = field(default_factory=lambda: _a([[0.1, 0.1]]))
    L: np.ndarray = field(default_factory=lambda: _a([[0.1, 0.1]]))
    a: float = 0.5
    b: float = 0.5
    gamma: float = 0.1
    sigma2: np.ndarray = field(default_factory=lambda: _a([0.3, 0.7]))
    eps1: float = 0.58
    eps2: float = 0.58
    delta1: float = 0.01
    delta2: float = 0.01
    H: np.ndarray = field(default_factory=lambda: _a([[0.1], [0.1]]))
    paper_Q1: np.ndarray = field(default_factory=lambda: _a([[1.2682, -0.0031],
                                                             [-0.0031, 1.6053]]))
    paper_Q2: np.ndarray = field(default_factory=lambda: _a([[0.2476, -0.0255],
                                                             [-0.0255, 0.5789]]))
    paper_K1: np.ndarray = field(default_factory=lambda: _a([[0.3868], [0.3025]]))
    paper_G1: np.ndarray = field(default_factory=lambda: _a([[-2.2816, 0.1753],
                                                             [0.7458, -1.4981]]))
    paper_K2: np.ndarray = field(default_factory=lambda: _a([[0.4869], [0.4106]]))
    paper_G2: np.ndarray = field(default_factory=lambda: _a([[-2.3886, 0.1702],
                                                             [0.6293, -1.5101]]))

    @property
    def plant(self) -> UncertainPlant:
        """The continuous-time uncertain plant (1)-(3)."""
        return UncertainPlant(self.A, self.C, self.D1, self.D2, self.M1, self.M2, self.N,
                              self.L, discrete=False)

    @property
    def region(self) -> Parabola:
        """``P(a, b)``."""
        return Parabola(self.a, self.b)

    def parameters(self, U: float = 1.0) -> ParabolicDesignParameters:
        """Theorem 1's parameters with the orthogonal ``U`` (1 or -1)."""
        return ParabolicDesignParameters(self.a, self.b, self.gamma, self.eps1, self.eps2,
                                         self.delta1, self.delta2, self.H, [[U]])

    def published(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The printed filters: name -> (K, G)."""
        return {"K1, G1 (U = 1)": (self.paper_K1, self.paper_G1),
                "K2, G2 (U = -1)": (self.paper_K2, self.paper_G2)}
