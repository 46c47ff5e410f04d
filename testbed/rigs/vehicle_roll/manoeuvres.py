"""Driving manoeuvres as lateral-acceleration profiles ``a_y(t)`` (m/s^2, + to the left).

Each manoeuvre is a small frozen dataclass with a ``name`` and parameters; calling it with a
time (s, a float or an array) returns ``a_y`` (same shape). They are kinematic profiles of the
vehicle's lateral acceleration, not a vehicle model: tyre and yaw dynamics are left out.

============================  ================================================================
name                          profile
============================  ================================================================
``step-steer``                ramp to a constant ``a_y`` (ISO 7401-style step steer)
``sine-sweep``                linear chirp between two frequencies
``double-lane-change``        ``v^2 y''(x)`` along a path shaped like ISO 3888-1
``paper-decay``               Zhang et al.'s disturbance ``v_k = 0.01 * 0.9^k`` as ``a_y``
============================  ================================================================

Use :func:`make_manoeuvre` (``make_manoeuvre("sine-sweep", f1_hz=2.0)``) or the classes;
:data:`MANOEUVRES` maps names to classes.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from testbed.records import field_items

TimeLike = float | np.ndarray


def _check(obj: object, *, positive: tuple[str, ...] = (), non_negative: tuple[str, ...] = ()
           ) -> None:
    """Validate the fields of a manoeuvre dataclass: all finite, some (strictly) positive."""
    cls = type(obj).__name__
    for f, value in field_items(obj):
        if not isinstance(value, (int, float, np.floating, np.integer)) or isinstance(value, bool):
            raise ValueError(f"{cls}.{f.name} must be a number, got {value!r}")
        if not np.isfinite(value):
            raise ValueError(f"{cls}.{f.name} must be finite, got {value}")
        if f.name in positive and value <= 0:
            raise ValueError(f"{cls}.{f.name} must be positive, got {value}")
        if f.name in non_negative and value < 0:
            raise ValueError(f"{cls}.{f.name} must be non-negative, got {value}")


def _output(t_s: TimeLike, value: np.ndarray) -> TimeLike:
    return float(value) if np.ndim(t_s) == 0 else value


@dataclass(frozen=True)
class StepSteer:
    """Step steer: ``a_y`` ramps linearly from 0 to ``amplitude_m_s2`` and stays there.

    ``a_y(t) = A clip((t - t_start) / rise_time, 0, 1)``. The default 4 m/s^2 is the
    steady-state lateral acceleration of ISO 7401's step-steer test.

    Parameters
    ----------
    amplitude_m_s2 : float
        Final lateral acceleration, m/s^2 (sign: direction of the turn, + left).
    t_start_s : float
        Start of the ramp, s.
    rise_time_s : float
        Ramp duration, s (> 0).
    """

    name: ClassVar[str] = "step-steer"
    amplitude_m_s2: float = 4.0
    t_start_s: float = 1.0
    rise_time_s: float = 0.2

    def __post_init__(self) -> None:
        _check(self, positive=("rise_time_s",), non_negative=("t_start_s",))

    def __call__(self, t_s: TimeLike) -> TimeLike:
        """``a_y`` in m/s^2 at time(s) ``t_s`` (s), same shape as ``t_s``."""
        t = np.asarray(t_s, dtype=float)
        return _output(t_s, self.amplitude_m_s2 * np.clip((t - self.t_start_s)
                                                          / self.rise_time_s, 0.0, 1.0))


@dataclass(frozen=True)
class SineSweep:
    """Sinusoidal sweep (linear chirp) of the lateral acceleration.

    For ``0 <= tau = t - t_start <= duration``:
    ``a_y = A sin(2 pi (f0 tau + (f1 - f0) tau^2 / (2 duration)))``, zero outside. It starts
    at zero; it also ends at zero when ``duration (f0 + f1) / 2`` is an integer number of
    cycles (16 with the defaults).

    Parameters
    ----------
    amplitude_m_s2 : float
        Peak lateral acceleration, m/s^2.
    f0_hz, f1_hz : float
        Start and end frequencies, Hz (> 0). The roll modes of the nominal vehicle are at
        0.16 Hz and 4.8 Hz (poles -1.0 and -30.2 1/s).
    duration_s : float
        Sweep duration, s.
    t_start_s : float
        Start of the sweep, s.
    """

    name: ClassVar[str] = "sine-sweep"
    amplitude_m_s2: float = 3.0
    f0_hz: float = 0.2
    f1_hz: float = 3.0
    duration_s: float = 10.0
    t_start_s: float = 0.0

    def __post_init__(self) -> None:
        _check(self, positive=("f0_hz", "f1_hz", "duration_s"), non_negative=("t_start_s",))

    def __call__(self, t_s: TimeLike) -> TimeLike:
        """``a_y`` in m/s^2 at time(s) ``t_s`` (s), same shape as ``t_s``."""
        tau = np.asarray(t_s, dtype=float) - self.t_start_s
        phase = 2 * np.pi * (self.f0_hz * tau
                             + (self.f1_hz - self.f0_hz) * tau**2 / (2 * self.duration_s))
        inside = (tau >= 0) & (tau <= self.duration_s)
        return _output(t_s, np.where(inside, self.amplitude_m_s2 * np.sin(phase), 0.0))


@dataclass(frozen=True)
class DoubleLaneChange:
    """Double lane change along a path shaped like the ISO 3888-1 track.

    The vehicle drives at constant ``speed_m_s`` along ``x = speed (t - t_start)`` (``x = 0``
    at the start of the 15 m entry lane) on the lateral path::

        y(x) = D/2 [tanh(z1) - tanh(z2)],   z_i = 2.4 (x - x_i) / L_i

    (the tanh shape of Falcone et al. 2007's reference path, made to return to the original
    lane): the change to the offset lane is centred on the 30 m section 2
    (``x_1 = 15 + 30/2 = 30 m``, ``L_1 = 30 m``), the return on the 25 m section 4
    (``x_2 = 15 + 30 + 25 + 25/2 = 82.5 m``, ``L_2 = 25 m``), the lateral offset is
    ``D = 3.5 m``. Over ``z in [-1.2, 1.2]`` each tanh covers 83 % of its offset. The lateral
    acceleration is the path's curvature times ``v^2`` in the small-heading approximation::

        a_y(t) = v^2 y''(x(t))

    At the ISO 3888-1 test speed of 80 km/h the peaks are 4.3 m/s^2 (change) and 6.2 m/s^2
    (return), inside the +-8 m/s^2 limit. The profile is smooth and defined for all ``t``
    (0.01 m/s^2 at ``t = 0`` with the default ``t_start_s = 1``; above 0.05 m/s^2 from 0.44 s
    to 6.4 s).

    Parameters
    ----------
    speed_m_s : float
        Vehicle speed, m/s (default 80 km/h).
    offset_m : float
        Lateral offset of the middle lane, m (+ left).
    x_change_m, change_length_m : float
        Centre and length of the first transition, m.
    x_return_m, return_length_m : float
        Centre and length of the return transition, m.
    t_start_s : float
        Time at which the vehicle enters the track (``x = 0``), s.
    """

    name: ClassVar[str] = "double-lane-change"
    speed_m_s: float = 80.0 / 3.6
    offset_m: float = 3.5
    x_change_m: float = 30.0
    change_length_m: float = 30.0
    x_return_m: float = 82.5
    return_length_m: float = 25.0
    t_start_s: float = 1.0

    SHAPE: ClassVar[float] = 2.4

    def __post_init__(self) -> None:
        _check(self, positive=("speed_m_s", "change_length_m", "return_length_m"),
               non_negative=("t_start_s",))

    def _terms(self, t_s: TimeLike) -> tuple[np.ndarray, ...]:
        x = self.speed_m_s * (np.asarray(t_s, dtype=float) - self.t_start_s)
        k1 = self.SHAPE / self.change_length_m
        k2 = self.SHAPE / self.return_length_m
        return x, k1, k2, np.tanh(k1 * (x - self.x_change_m)), np.tanh(k2 * (x - self.x_return_m))

    def lateral_position(self, t_s: TimeLike) -> TimeLike:
        """Lateral position ``y`` of the path at time(s) ``t_s``, m."""
        _, _, _, th1, th2 = self._terms(t_s)
        return _output(t_s, 0.5 * self.offset_m * (th1 - th2))

    def __call__(self, t_s: TimeLike) -> TimeLike:
        """``a_y`` in m/s^2 at time(s) ``t_s`` (s), same shape as ``t_s``."""
        if type(t_s) is float or np.ndim(t_s) == 0:  # one time (every step): Python floats
            return self._at(float(t_s))
        _, k1, k2, th1, th2 = self._terms(t_s)
        # d^2/dx^2 tanh(k (x - c)) = -2 k^2 tanh sech^2
        ypp = 0.5 * self.offset_m * (-2 * k1**2 * th1 * (1 - th1**2)
                                     + 2 * k2**2 * th2 * (1 - th2**2))
        return _output(t_s, self.speed_m_s**2 * ypp)

    def _at(self, t_s: float) -> float:
        """:meth:`__call__` at one time: numpy's ``tanh`` (the same function) and the same
        operations in the same order on Python floats instead of numpy scalars (IEEE-754
        doubles both; ``**`` is C's ``pow`` in both), without numpy's per-operation
        overhead."""
        x = self.speed_m_s * (t_s - self.t_start_s)
        k1 = self.SHAPE / self.change_length_m
        k2 = self.SHAPE / self.return_length_m
        th1 = float(np.tanh(k1 * (x - self.x_change_m)))
        th2 = float(np.tanh(k2 * (x - self.x_return_m)))
        ypp = 0.5 * self.offset_m * (-2 * k1**2 * th1 * (1 - th1**2)
                                     + 2 * k2**2 * th2 * (1 - th2**2))
        return self.speed_m_s**2 * ypp


@dataclass(frozen=True)
class PaperDecay:
    """Zhang et al.'s disturbance ``v_k = 0.01 * 0.9^k`` used as a lateral acceleration.

    ``a_y(t) = amplitude * ratio^(t / period)`` for ``t >= 0`` (``= v_k`` at ``t = k T``,
    ``T = 0.01`` s, in m/s^2), zero before.

    Parameters
    ----------
    amplitude_m_s2 : float
        Value at ``t = 0``, m/s^2.
    ratio : float
        Decay factor per period (``0 < ratio``).
    period_s : float
        The step ``T`` of the paper, s.
    """

    name: ClassVar[str] = "paper-decay"
    amplitude_m_s2: float = 0.01
    ratio: float = 0.9
    period_s: float = 0.01

    def __post_init__(self) -> None:
        _check(self, positive=("ratio", "period_s"))

    def __call__(self, t_s: TimeLike) -> TimeLike:
        """``a_y`` in m/s^2 at time(s) ``t_s`` (s), same shape as ``t_s``."""
        t = np.asarray(t_s, dtype=float)
        value = self.amplitude_m_s2 * self.ratio ** (np.maximum(t, 0.0) / self.period_s)
        return _output(t_s, np.where(t >= 0, value, 0.0))


Manoeuvre = StepSteer | SineSweep | DoubleLaneChange | PaperDecay

#: Manoeuvre name -> class.
MANOEUVRES: dict[str, type] = {cls.name: cls for cls in (StepSteer, SineSweep,
                                                         DoubleLaneChange, PaperDecay)}


def make_manoeuvre(name: str, **params: Any) -> Manoeuvre:
    """Build a manoeuvre by name.

    Parameters
    ----------
    name : {"step-steer", "sine-sweep", "double-lane-change", "paper-decay"}
    **params
        Fields of the manoeuvre's class (e.g. ``amplitude_m_s2=2.0``).

    Raises
    ------
    ValueError
        Unknown name (the valid ones are listed), unknown parameter (the valid ones are
        listed) or an invalid value.
    """
    cls = MANOEUVRES.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ValueError(f"unknown manoeuvre {name!r}; expected one of {sorted(MANOEUVRES)}")
    fields = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(params) - set(fields))
    if unknown:
        raise ValueError(f"unknown parameters {unknown} for manoeuvre {name!r}; expected "
                         f"some of {fields}")
    return cls(**params)
