"""filters: pure-numpy/scipy state estimators for the testbed.

This package depends only on numpy and scipy (never on ``testbed``, mujoco or
gymnasium). Units: seconds for time; all arrays are ``float64``.

Public API
----------
Models
    :class:`LinearSystem` (continuous time, noise intensities) and
    :class:`DiscreteLinearSystem` (discrete time, noise covariances).
Estimators (satisfy the :class:`Estimator` protocol)
    :class:`KalmanFilter` (``name = "kalman"``) and
    :class:`KalmanBucyFilter` (``name = "kalman-bucy"``).
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
from filters.kalman import KalmanBucyFilter, KalmanFilter
from filters.models import DiscreteLinearSystem, LinearSystem

__all__ = [
    "DiscreteLinearSystem",
    "Estimator",
    "FilterError",
    "FiniteEscapeError",
    "KalmanBucyFilter",
    "KalmanFilter",
    "LinearSystem",
    "LossOfDefinitenessError",
    "MeanSquareHInfFilter",
    "check_covariance",
]
