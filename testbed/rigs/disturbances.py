"""Disturbances in the paper's units, applied to a rig's joints as generalized forces.

A :class:`Disturbance` describes ``G w(t) dt + b dW`` in the state equation
``dx = (A x + B u + G w) dt + b dW`` with ``x = [positions, velocities]``. Only velocity rows
may be non-zero (a force cannot move a position directly); they are joint accelerations in
rad/s^2, which the environment turns into generalized forces ``M(q) a`` (through the mass
matrix) so that the nonlinear rig feels exactly the acceleration the paper's model does at
the current pose.

The white noise ``b dW`` (``W`` a standard Wiener process: unit intensity) is applied by
Euler-Maruyama on the control period ``dt``: ``a = b xi / sqrt(dt)``, ``xi ~ N(0, I)``, held
over the period, so the velocity increment has covariance ``b b^T dt``. ``w(t)`` is evaluated
at the start of each control period and held (zero-order hold).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np


@dataclass
class Disturbance:
    """Deterministic signal ``G w(t)`` plus white noise ``b dW`` on the velocity rows.

    Parameters
    ----------
    G : ndarray, shape (n, s), optional
        Input matrix of the deterministic disturbance (paper units: rad/s^2 per unit of w).
    w : callable ``t_s -> ndarray (s,)``, optional
        The disturbance signal; required with ``G``.
    b : ndarray, shape (n, p), optional
        White-noise input matrix; the process-noise intensity is ``b b^T``.
    n_positions : int
        Number of position states (rows of ``G`` and ``b`` that must be zero).
    """

    G: np.ndarray | None = None
    w: Callable[[float], np.ndarray] | None = None
    b: np.ndarray | None = None
    n_positions: int = 2
    #: The signal differs between members: the simulator asks ``member_signal(t_s, members)``
    #: (:class:`SampledDisturbance`) instead of ``w(t_s)``.
    per_member: ClassVar[bool] = False

    def __post_init__(self) -> None:
        if self.G is not None and self.w is None:
            raise ValueError("G needs the signal w (deterministic disturbance G w(t))")
        for name, M in (("G", self.G), ("b", self.b)):
            if M is None:
                continue
            M = np.atleast_2d(np.asarray(M, dtype=float))
            if M.ndim != 2 or not np.all(np.isfinite(M)):
                raise ValueError(f"{name} must be a finite 2-D matrix, got {M!r}")
            if np.any(M[: self.n_positions] != 0):
                raise ValueError(f"{name}: rows of position states must be zero; a disturbance "
                                 "acts as a force (velocity rows only)")
            setattr(self, name, M)
        if self.w is not None:
            w0 = np.asarray(self.w(0.0), dtype=float)
            if w0.ndim != 1:
                raise ValueError(f"w(t) must return a 1-D array, got shape {w0.shape}")
        if self.G is not None:
            if w0.shape != (self.G.shape[1],):
                raise ValueError(f"w(t) must return shape ({self.G.shape[1]},) to match G, "
                                 f"got {w0.shape}")

    @property
    def active(self) -> bool:
        """True when any disturbance (deterministic or white noise) is configured."""
        return self.G is not None or self.b is not None

    @property
    def has_deterministic(self) -> bool:
        """True when a deterministic ``G w(t)`` is present (the T ratio is then defined)."""
        return self.G is not None

    @property
    def has_signal(self) -> bool:
        """True when a signal ``w(t)`` exists (it may enter only measurements, without ``G``)."""
        return self.w is not None

    @property
    def intensity(self) -> np.ndarray | None:
        """Process-noise intensity ``b b^T``, shape (n, n), or None."""
        return None if self.b is None else self.b @ self.b.T

    def signal(self, t_s: float) -> np.ndarray:
        """``w(t)``, shape (s,); empty when there is no deterministic part."""
        if self.w is None:
            return np.zeros(0)
        return np.asarray(self.w(t_s), dtype=float)

    def acceleration(self, t_s: float, dt_s: float, rng: np.random.Generator,
                     w: np.ndarray | None = None) -> np.ndarray:
        """Joint accelerations to apply over ``[t, t + dt)``, shape (n - n_positions,).

        Parameters
        ----------
        t_s : float
            Start of the control period.
        dt_s : float
            Control period (Euler-Maruyama step of the white noise).
        rng : numpy.random.Generator
            Source of the white noise (the environment's ``np_random``).
        w : ndarray, shape (s,), optional
            Pre-computed ``w(t_s)``.
        """
        n_vel = None
        accel = 0.0
        if self.G is not None:
            w = self.signal(t_s) if w is None else w
            accel = self.G[self.n_positions:] @ w
            n_vel = self.G.shape[0] - self.n_positions
        if self.b is not None:
            xi = rng.standard_normal(self.b.shape[1])
            accel = accel + self.b[self.n_positions:] @ xi / np.sqrt(dt_s)
            n_vel = self.b.shape[0] - self.n_positions
        if n_vel is None:
            return np.zeros(0)
        return np.asarray(accel, dtype=float)


class SampledDisturbance(Disturbance):
    """``G w_k`` from sampled values, one sequence per simulated member (plus optional ``b dW``).

    ``w`` is held over each control period (zero-order hold): ``w(t) = values[i, k]`` for
    member ``i`` at ``t = k dt_s``, zero after the last sample. The simulator asks
    :meth:`member_signal` for the members it steps, so a batch can evaluate different
    disturbances on otherwise identical members (common random numbers). :attr:`values` may
    be overwritten in place between episodes.

    Parameters
    ----------
    G : ndarray, shape (n, s), optional
        Input matrix (velocity rows only); None when ``w`` enters only the measurements.
    values : ndarray, shape (N, K, s)
        ``w_k`` of each of the N members for steps ``k = 0 .. K-1``.
    dt_s : float
        Control period, s.
    b : ndarray, shape (n, p), optional
        White-noise input matrix (as in :class:`Disturbance`).
    n_positions : int
    """

    per_member: ClassVar[bool] = True

    def __init__(self, G: np.ndarray | None, values: np.ndarray, dt_s: float,
                 b: np.ndarray | None = None, n_positions: int = 2):
        values = np.asarray(values, dtype=float)
        if values.ndim != 3 or not np.all(np.isfinite(values)):
            raise ValueError(f"values must be a finite array of shape (N, K, s), got shape "
                             f"{values.shape}")
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be a positive finite period in s, got {dt_s}")
        self.values = values
        self.dt_s = float(dt_s)
        super().__init__(G=G, w=lambda t_s: self.member_signal(np.array([t_s]),
                                                               np.array([0]))[0],
                         b=b, n_positions=n_positions)

    def member_signal(self, t_s: np.ndarray, members: np.ndarray) -> np.ndarray:
        """``w`` of each member at its time, shape (k, s) (zero past the last sample).

        Parameters
        ----------
        t_s : ndarray, shape (k,)
        members : ndarray of int, shape (k,)
        """
        N, K, s = self.values.shape
        members = np.asarray(members, dtype=int)
        if members.size and (members.min() < 0 or members.max() >= N):
            raise ValueError(f"members {members.tolist()} outside the {N} sampled sequences")
        steps = np.rint(np.asarray(t_s, dtype=float) / self.dt_s).astype(int)
        out = np.zeros((len(steps), s))
        inside = steps < K
        out[inside] = self.values[members[inside], steps[inside]]
        return out


def scenario_disturbance(rig: Any, name: Any = None, process_noise: float = 0.0,
                         ambient_noise: float = 0.0) -> Disturbance | None:
    """The scenario's disturbance: a named signal ``G w(t)``, ``process_noise b dW`` and
    ``ambient_noise b_a dW_a``.

    Parameters
    ----------
    rig : testbed.rigs.base.Rig
    name : str, Disturbance or None
        A key of :attr:`~testbed.rigs.base.Rig.disturbance_signals` (``None``/``"none"``: no
        signal).
    process_noise : float
        Scale of :meth:`~testbed.rigs.base.Rig.process_noise_matrix` (0: none).
    ambient_noise : float
        Scale of :meth:`~testbed.rigs.base.Rig.ambient_noise_matrix` (0: none; ignored by rigs
        without one).

    Returns
    -------
    testbed.rigs.disturbances.Disturbance or None
    """
    try:
        ambient = float(ambient_noise)
    except (TypeError, ValueError):
        raise ValueError(f"ambient_noise must be a number, got {ambient_noise!r}") from None
    if not (np.isfinite(ambient) and ambient >= 0):
        raise ValueError(f"ambient_noise must be finite and >= 0, got {ambient_noise}")
    b_ambient = rig.ambient_noise_matrix() if ambient > 0 else None
    if isinstance(name, Disturbance):
        if process_noise:
            raise ValueError("process_noise applies to a named disturbance, not to a "
                             "Disturbance object")
        if b_ambient is None:
            return name
        b = b_ambient * ambient if name.b is None else np.hstack([name.b, b_ambient * ambient])
        with_ambient = copy.copy(name)  # keeps subclasses (e.g. SampledDisturbance)
        with_ambient.b = b
        return with_ambient
    try:
        scale = float(process_noise)
    except (TypeError, ValueError):
        raise ValueError(f"process_noise must be a number, got {process_noise!r}") from None
    if not (np.isfinite(scale) and scale >= 0):
        raise ValueError(f"process_noise must be finite and >= 0, got {process_noise}")
    G = w = b = None
    if name not in (None, "none"):
        if name not in rig.disturbance_signals:
            raise ValueError(f"unknown disturbance {name!r} for rig {rig.name!r}; expected "
                             f"one of {sorted(rig.disturbance_signals) or ['none']}")
        G, w = rig.disturbance_signals[name]()
    if scale > 0:
        b0 = rig.process_noise_matrix()
        if b0 is None:
            raise ValueError(f"rig {rig.name!r} has no process-noise model; "
                             "process_noise must be 0")
        b = b0 * scale
    if b_ambient is not None:
        b = b_ambient * ambient if b is None else np.hstack([b, b_ambient * ambient])
    if w is None and b is None:
        return None
    return Disturbance(G=G, w=w, b=b, n_positions=len(rig.joints))
