"""The estimator protocol: :class:`Estimator` and its small optional protocols.

One contract for the filters of this library and for any user's estimator (the testbed's
plug-ins, ``--filter module:factory``). :class:`Estimator` is what every estimator has; the
optional protocols name what some have, and the testbed uses it where it is there:

========================  ==================================================================
:class:`Estimator`        ``x``, ``P`` (or None), ``reset(x0, P0)``, ``step(y, u)``
:class:`Innovations`      ``innovation``, ``innovation_cov`` after a step (``testbed score``:
                          NIS, ANIS, whiteness)
:class:`Batched`          ``batched = True``: ``x``, ``y``, ``u``, ``P`` carry a leading batch
                          axis and one instance runs a whole Monte-Carlo batch
:class:`Primed`           ``prime(y)``: use the first sample (at reset)
:class:`ChannelRequest`   ``channels``: other channels of the sensor vector (indices, or
                          ``"all"``)
:class:`DesignFacts`      ``design_meta``: design facts for outputs (``gamma``, ...)
:class:`Named`            ``name``: a short label (the command line, ``testbed score``'s tables)
:class:`Timed`            ``t_s``: time of the last processed measurement (every filter here)
========================  ==================================================================

All are :func:`typing.runtime_checkable` (``isinstance`` checks that the members exist, not
their types or shapes). Every filter of :mod:`filters` is an :class:`Estimator`,
:class:`Named`, :class:`Timed` and (for the Kalman-type filters) :class:`Innovations`.
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

__all__ = ["Batched", "ChannelRequest", "DesignFacts", "Estimator", "Innovations", "Named",
           "Primed", "Timed"]


@runtime_checkable
class Estimator(Protocol):
    """What every state estimator has.

    Attributes
    ----------
    x : numpy.ndarray, shape (n,) or (N, n)
        Current (a-posteriori) state estimate; a leading axis is a batch
        (:class:`Batched`).
    P : numpy.ndarray, shape (n, n) or (N, n, n), or None
        Error covariance of ``x`` (None: the estimator has none; no NEES then).

    Notes
    -----
    ``step(y, u)`` is the in-the-loop call: ``u`` (shape ``(k,)`` or ``(N, k)``, or
    ``None`` for zero input) was applied over the last sample interval and ``y`` (shape
    ``(m,)`` or ``(N, m)``) is measured at its end; it returns the new ``x``.
    ``reset(x0, P0)`` restarts from a prior (``P0`` may be None for an estimator without a
    covariance).
    """

    @property
    def x(self) -> npt.NDArray[np.float64]: ...

    @property
    def P(self) -> npt.NDArray[np.float64] | None: ...

    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> npt.NDArray[np.float64]: ...

    def reset(self, x0: npt.ArrayLike, P0: npt.ArrayLike | None) -> None: ...


@runtime_checkable
class Innovations(Protocol):
    """After a step: the innovation ``nu = y - y_predicted`` (m,) or (N, m) and its
    covariance ``S`` (m, m) or (N, m, m) (None before the first step)."""

    innovation: npt.NDArray[np.float64] | None
    innovation_cov: npt.NDArray[np.float64] | None


@runtime_checkable
class Batched(Protocol):
    """``batched = True`` (a class attribute): every array carries a leading batch axis
    ``N`` and one instance runs ``N`` independent members. Without it the testbed runs one
    instance per member."""

    batched: ClassVar[bool]


@runtime_checkable
class Primed(Protocol):
    """``prime(y)``: use the first sample ``y`` (taken at reset, before the first step)."""

    def prime(self, y: npt.ArrayLike) -> None: ...


@runtime_checkable
class ChannelRequest(Protocol):
    """``channels``: the channels of the sensor vector the estimator wants instead of the
    design's (indices, or ``"all"``; e.g. the deterministic ``y2`` of ``ms-hinf``)."""

    channels: Any


@runtime_checkable
class DesignFacts(Protocol):
    """``design_meta``: design facts for outputs. ``gamma``: the attenuation level an
    H-infinity design claims; ``gamma_channel = "scenario"``: it bounds the gain from the
    scenario's disturbance to ``z = output_matrix x``; ``gamma_kind``: ``"discrete"`` (a
    bound on the sampled loop) or ``"continuous-observation"`` (which does not certify the
    sampled loop)."""

    design_meta: dict[str, Any]


@runtime_checkable
class Named(Protocol):
    """``name``: a short identifier (``"kalman"``, ``"fp-ekf"``), used as the estimator's
    label on the command line and in ``testbed score``'s tables and figures."""

    name: ClassVar[str]


@runtime_checkable
class Timed(Protocol):
    """``t_s``: filter time in seconds (of the last processed measurement; 0 after reset)."""

    @property
    def t_s(self) -> float: ...
