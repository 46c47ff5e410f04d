"""The examples of the variance-constrained family as data (see docs/references.md).

- Wang & Fang (2006), Section IV: variance-constrained robust H-infinity filter with parabolic
  poles (:class:`VarianceConstrainedContinuousScenario`). Every printed value of the example,
  verbatim; the example's ``E = [0.1 0.1]^T`` is Theorem 1's ``H``.
- Liu, Deng & Wang (n.d.), Section 4: discrete robust H2/H-infinity filter with variance
  constraints (:class:`VarianceConstrainedDiscreteScenario`). The text is OCR damaged; the
  values are our reading of the example. Two design values are not legible and are our
  assumptions: ``delta2 = delta1`` and ``H = 0`` (the central gain; the paper prints no
  ``H``). ``H0`` is our direction for the search over the scale of ``H``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from filters.analysis import Disk, Parabola, UncertainPlant, unit_disk
from filters.variance_continuous import ParabolicDesignParameters
from filters.variance_discrete import DiscreteDesignParameters


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


@dataclass(frozen=True)
class VarianceConstrainedDiscreteScenario:
    """The example of Liu, Deng & Wang (n.d.) (reconstructed reading).

    Attributes
    ----------
    A, C, D1, D2, M1, M2, N, L : ndarray
        Shapes (2, 2), (1, 2), (2, 2), (1, 2), (2, 1), (1, 1), (1, 2), (1, 2).
    gamma : float
        0.012 (-38.4 dB).
    sigma2 : ndarray, shape (2,)
        ``[0.02, 0.076]``.
    eps, delta1 : float
        Printed design values 1.89 and 0.31.
    delta2 : float
        Not legible; assumed equal to ``delta1``.
    H : ndarray, shape (2, 1)
        Not printed; 0 (central gain).
    paper_bound : ndarray, shape (2, 2)
        The printed matrix ``diag(0.02, 0.076)`` next to the design values (the variance bounds
        as a matrix; its role in the damaged text is unclear).
    paper_G, paper_K : ndarray, shapes (2, 2), (2, 1)
        The published filter.
    paper_covariance : dict
        The printed steady-state error covariances for ``F = 1`` and ``F = 0``.
    """

    A: np.ndarray = field(default_factory=lambda: _a([[0.8, 0.05], [-0.08, -0.5]]))
    C: np.ndarray = field(default_factory=lambda: _a([[1.0, 0.0]]))
    D1: np.ndarray = field(default_factory=lambda: _a([[0.1, 0.0], [0.0, 0.1]]))
    D2: np.ndarray = field(default_factory=lambda: _a([[0.1, 0.08]]))
    M1: np.ndarray = field(default_factory=lambda: _a([[0.1], [0.08]]))
    M2: np.ndarray = field(default_factory=lambda: _a([[0.1]]))
    N: np.ndarray = field(default_factory=lambda: _a([[0.5, 0.5]]))
    L: np.ndarray = field(default_factory=lambda: _a([[0.01, 0.01]]))
    gamma: float = 0.012
    sigma2: np.ndarray = field(default_factory=lambda: _a([0.02, 0.076]))
    eps: float = 1.89
    delta1: float = 0.31
    delta2: float = 0.31
    H: np.ndarray = field(default_factory=lambda: np.zeros((2, 1)))
    paper_bound: np.ndarray = field(default_factory=lambda: _a([[0.02, 0.0], [0.0, 0.076]]))
    paper_G: np.ndarray = field(default_factory=lambda: _a([[-0.17795, 0.09257],
                                                            [-0.01529, -0.58288]]))
    paper_K: np.ndarray = field(default_factory=lambda: _a([[0.9764], [-0.0882]]))
    paper_covariance: dict = field(default_factory=lambda: {
        "1": _a([[0.006496, -0.009493], [-0.009493, 0.015080]]),
        "0": _a([[0.006542, -0.009664], [-0.009664, 0.015734]]),
    })

    @property
    def plant(self) -> UncertainPlant:
        """The discrete-time uncertain plant (1)-(2)."""
        return UncertainPlant(self.A, self.C, self.D1, self.D2, self.M1, self.M2, self.N,
                              self.L, discrete=True)

    @property
    def region(self) -> Disk:
        """The open unit disk (asymptotic stability)."""
        return unit_disk()

    def parameters(self, U: float = 1.0) -> DiscreteDesignParameters:
        """The design parameters (printed ``gamma, eps, delta1``; assumed ``delta2``, ``H``)."""
        return DiscreteDesignParameters(self.gamma, self.eps, self.delta1, self.delta2,
                                        self.H, [[U]])

    def published(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The printed filter: name -> (K, G)."""
        return {"G, K": (self.paper_K, self.paper_G)}
