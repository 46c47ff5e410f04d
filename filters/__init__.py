"""filters: state estimators and their designs, usable on your own matrices.

This package depends only on numpy, scipy and (for LMI designs) cvxpy, never on
``testbed``, mujoco or gymnasium. Units: seconds for time; all arrays are ``float64``.

Public API
----------
Models
    :class:`LinearSystem` (continuous time, noise intensities),
    :class:`DiscreteLinearSystem` (discrete time, noise covariances) and
    :class:`PolynomialModel` (degree <= 3, tensor coefficients).
Estimators (satisfy the :class:`Estimator` protocol)
    :class:`KalmanFilter` (``"kalman"``), :class:`KalmanBucyFilter` (``"kalman-bucy"``),
    :class:`ExtendedKalmanFilter` (``"ekf"``) and :class:`UnscentedKalmanFilter` (``"ukf"``,
    Julier & Uhlmann; Wan & van der Merwe) on user callables ``f``, ``h``,
    :class:`MeanSquareHInfFilter` (Basin et al., ``"ms-hinf"``),
    :class:`PolynomialHInfFilter`, :class:`NonOrthonormalPolynomialHInfFilter` and
    :class:`LinearizedHInfFilter` (Basin et al.), :class:`LinearFilter` (fixed gains
    ``xhat' = G xhat + K y``, ``"linear-gain"``: the variance-constrained designs).
Designs
    :func:`design_lmi_hinf` / :func:`minimal_gamma` (Theorem 4 LMI (48) with
    cvxpy; filter (45) as :class:`LMIHInfFilter`, ``"lmi-hinf"``), :func:`design_parabolic`
    (Wang & Fang 2006, Theorem 1), :func:`design_discrete` (Liu, Deng & Wang); their
    optimizer-based searches :func:`search_parabolic_design` and :func:`search_discrete_design`
    (a :class:`DesignSearchRecord`; candidates verified over the uncertainty).
Analysis
    :mod:`filters.analysis`: noise-output ratio, :func:`hinf_norm` (Hamiltonian/symplectic
    bisection), error covariances, pole regions, :func:`robust_filter_analysis` over
    norm-bounded uncertainty (:class:`UncertainPlant`).
Errors
    :class:`FilterError`, :class:`LossOfDefinitenessError`,
    :class:`FiniteEscapeError`, :class:`SubstepLimitError` and :func:`check_covariance`.
Input conversion
    :func:`real_array`: user input as a real ``float64`` array or a ``ValueError`` naming the
    argument (complex values, non-numeric containers, integers beyond the float range);
    :class:`TimeFunction`: a constant or a function of time, checked for shape and finiteness;
    :func:`positive_time`: a time step in seconds, finite and positive;
    :func:`all_finite`: whether an array's entries are all finite (one BLAS call for float64).
"""

from filters._linalg import TimeFunction, all_finite, positive_time, real_array, zoh
from filters.analysis import UncertainPlant, hinf_norm, robust_filter_analysis
from filters.base import Estimator
from filters.ekf import ExtendedKalmanFilter
from filters.errors import (
    FilterError,
    FiniteEscapeError,
    LossOfDefinitenessError,
    SubstepLimitError,
    check_covariance,
)
from filters.hinf_mean_square import MeanSquareHInfFilter
from filters.hinf_polynomial import (
    LinearizedHInfFilter,
    NonOrthonormalPolynomialHInfFilter,
    PolynomialHInfFilter,
)
from filters.kalman import MAX_AUTO_SUBSTEPS, CovarianceMemo, KalmanBucyFilter, KalmanFilter
from filters.lmi_hinf import (
    DesignCheck,
    GammaSearch,
    LMIHInfDesign,
    LMIHInfFilter,
    StochasticLinearSystem,
    certify_gain,
    check_design,
    design_lmi_hinf,
    minimal_gamma,
)
from filters.models import DiscreteLinearSystem, LinearSystem
from filters.polynomial_model import EscapeTest, PolynomialModel
from filters.ukf import UnscentedKalmanFilter
from filters.variance_constrained import DesignSearchRecord, LinearFilter, VarianceDesign
from filters.variance_continuous import (
    ParabolicDesignParameters,
    design_parabolic,
    search_parabolic_design,
)
from filters.variance_discrete import (
    DiscreteDesignParameters,
    design_discrete,
    search_discrete_design,
)

__all__ = [
    "zoh",
    "TimeFunction",
    "positive_time",
    "MAX_AUTO_SUBSTEPS",
    "CovarianceMemo",
    "DesignCheck",
    "DesignSearchRecord",
    "DiscreteDesignParameters",
    "DiscreteLinearSystem",
    "EscapeTest",
    "Estimator",
    "ExtendedKalmanFilter",
    "FilterError",
    "FiniteEscapeError",
    "GammaSearch",
    "KalmanBucyFilter",
    "KalmanFilter",
    "LMIHInfDesign",
    "LMIHInfFilter",
    "LinearFilter",
    "LinearSystem",
    "LinearizedHInfFilter",
    "LossOfDefinitenessError",
    "MeanSquareHInfFilter",
    "NonOrthonormalPolynomialHInfFilter",
    "ParabolicDesignParameters",
    "PolynomialHInfFilter",
    "PolynomialModel",
    "StochasticLinearSystem",
    "SubstepLimitError",
    "UncertainPlant",
    "UnscentedKalmanFilter",
    "VarianceDesign",
    "certify_gain",
    "all_finite",
    "check_covariance",
    "check_design",
    "design_discrete",
    "design_lmi_hinf",
    "design_parabolic",
    "hinf_norm",
    "minimal_gamma",
    "real_array",
    "robust_filter_analysis",
    "search_discrete_design",
    "search_parabolic_design",
]
