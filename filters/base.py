"""Structural protocol shared by all estimators in :mod:`filters`."""

from __future__ import annotations

from typing import ClassVar, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

__all__ = ["Estimator"]


@runtime_checkable
class Estimator(Protocol):
    """What the testbed needs from a state estimator.

    Attributes
    ----------
    name : str
        Class-level identifier used on the command line and in logs
        (e.g. ``"kalman"``, ``"kalman-bucy"``).
    x : numpy.ndarray, shape (..., n)
        Current (a-posteriori) state estimate; leading axes are an optional batch.
    P : numpy.ndarray, shape (..., n, n)
        Current error covariance of ``x``.
    t_s : float
        Filter time in seconds (time of the last processed measurement).

    Notes
    -----
    ``step(y, u)`` is the in-the-loop call: ``u`` (shape ``(k,)`` or ``(..., k)``, or
    ``None`` for zero input) was applied over the last sample interval and ``y``
    (shape ``(m,)`` or ``(..., m)``) is measured at its end. It returns the new ``x``.
    ``reset(x0, P0)`` re-initializes state, covariance and ``t_s = 0``.
    """

    name: ClassVar[str]

    @property
    def x(self) -> npt.NDArray[np.float64]: ...

    @property
    def P(self) -> npt.NDArray[np.float64]: ...

    @property
    def t_s(self) -> float: ...

    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> npt.NDArray[np.float64]: ...

    def reset(self, x0: npt.ArrayLike, P0: npt.ArrayLike) -> None: ...
