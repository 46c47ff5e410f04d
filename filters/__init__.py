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
    :class:`MeanSquareHInfFilter` (seed-000, ``"ms-hinf"``),
    :class:`PolynomialHInfFilter`, :class:`NonOrthonormalPolynomialHInfFilter` and
    :class:`LinearizedHInfFilter` (seed-001).
Analysis
    :mod:`filters.analysis` (noise-output ratio, norms, covariances, pole regions).
Errors
    :class:`FilterError`, :class:`LossOfDefinitenessError`,
    :class:`FiniteEscapeError` and :func:`check_covariance`.
"""

from filters.base import Estimator
from filters.errors import (
    FilterError,
    FiniteEscapeError,
    LossOfDefinitenessError,
    check_covariance,
)
from filters.hinf_mean_square import MeanSquareHInfFilter
from filters.hinf_polynomial import (
    LinearizedHInfFilter,
    NonOrthonormalPolynomialHInfFilter,
    PolynomialHInfFilter,
)
from filters.kalman import KalmanBucyFilter, KalmanFilter
from filters.models import DiscreteLinearSystem, LinearSystem
from filters.polynomial_model import EscapeTest, PolynomialModel

__all__ = [
    "DiscreteLinearSystem",
    "EscapeTest",
    "Estimator",
    "FilterError",
    "FiniteEscapeError",
    "KalmanBucyFilter",
    "KalmanFilter",
    "LinearSystem",
    "LinearizedHInfFilter",
    "LossOfDefinitenessError",
    "MeanSquareHInfFilter",
    "NonOrthonormalPolynomialHInfFilter",
    "PolynomialHInfFilter",
    "PolynomialModel",
    "check_covariance",
]
