"""Simulation of linear plants with norm-bounded uncertainty (the plants of Wang & Fang (2006) and
Liu, Deng & Wang (n.d.); see docs/references.md).

The model is a :class:`filters.analysis.UncertainPlant`::

    continuous: x' = (A + M1 F N) x + B u + D1 w,       y = (C + M2 F N) x + D2 w
    discrete:   x(k+1) = (A + M1 F N) x(k) + B u(k) + D1 w(k),   y(k) = (C + M2 F N) x(k) + D2 w(k)

with ``F^T F <= I`` fixed over a run and one white noise ``w`` (unit intensity, or unit
covariance per sample) driving state and measurement. ``B`` is an optional input (zero in
the papers).

Sampling (row ``k`` of a run pairs the measurement with the step ``k -> k + 1``)
--------------------------------------------------------------------------------
* discrete: ``y[k] = y(k)``, drawn with the same ``w(k)`` that drives ``x(k+1)``;
* continuous: ``y[k]`` is the average of ``y(t)`` over ``[t_k, t_k + dt]`` (integrate-and-dump;
  its noise has covariance ``D2 D2^T / dt``). ``x`` and ``int y dt`` are integrated *exactly*
  (Van Loan: one Gaussian draw per step for the joint increment), so the only approximation
  in the testbed is the filter's own sampling.

A filter ``xhat(k+1) = G xhat(k) + K y[k]`` (discrete) or its exact sampled version
(:class:`filters.variance_constrained.LinearFilter`) then estimates ``x(k+1)``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from filters import positive_time, real_array, zoh
from filters.analysis import UncertainPlant
from filters.errors import FiniteEscapeError

#: State magnitude beyond which the plant has escaped (an unstable plant or an absurd ``x0``
#: would otherwise overflow to inf and NaN).
ESCAPE_BOUND = 1e10


@dataclass(frozen=True)
class Transition:
    """One sampling step of the plant for a fixed ``F``.

    Attributes
    ----------
    Phi : ndarray, shape (n + p, n)
        Maps ``x(k)`` to ``[x(k+1); y[k]]`` (mean part).
    Gu : ndarray, shape (n + p, k)
        Maps ``u(k)`` (held over the step) to ``[x(k+1); y[k]]``.
    S : ndarray, shape (n + p, r_eff)
        Noise factor: ``[x(k+1); y[k]]`` gets ``S xi``, ``xi ~ N(0, I)``. Discrete:
        ``S = [D1; D2]`` and ``xi = w(k)``; continuous: a factor of the Van Loan covariance.
    """

    Phi: np.ndarray
    Gu: np.ndarray
    S: np.ndarray


def _noise_factor(Q: np.ndarray) -> np.ndarray:
    """``S`` with ``S S^T = Q`` for a symmetric PSD (possibly singular) ``Q``."""
    w, V = np.linalg.eigh(0.5 * (Q + Q.T))
    keep = w > 1e-14 * max(float(w.max()), 1e-300)
    return V[:, keep] * np.sqrt(w[keep])


class UncertainLinearPlant:
    """Sampled simulation of an :class:`~filters.analysis.UncertainPlant`, a
    :class:`~testbed.experiment.numpy_plant.NumpyPlant` at the uncertainty :attr:`F`
    (default 0; :meth:`at` sets another).

    Parameters
    ----------
    model : UncertainPlant
    dt_s : float
        Sample period in s (continuous plants); for a discrete plant it only labels time
        (default 1.0).
    B : ndarray, shape (n, k), optional
        Input matrix (default zeros (n, 1): the papers' plants have no input).

    Raises
    ------
    ValueError
        On a non-positive ``dt_s`` or a ``B`` of the wrong shape.
    """

    def __init__(self, model: UncertainPlant, dt_s: float = 1.0,
                 B: np.ndarray | None = None) -> None:
        self.model = model
        self.dt_s = positive_time("dt_s", dt_s)
        n = model.n
        B_ = np.zeros((n, 1)) if B is None else real_array(B, "B", finite=False)
        if B_.ndim != 2 or B_.shape[0] != n or not np.isfinite(B_).all():
            raise ValueError(f"B must be a finite matrix with shape ({n}, k), got {B_.shape}")
        self.B = B_
        self.F = model.uncertainty(None)
        self._cache: dict[bytes, Transition] = {}

    @property
    def discrete(self) -> bool:
        return self.model.discrete

    def sample_F(self, rng: np.random.Generator) -> np.ndarray:
        """A random admissible ``F``: entries uniform in ``[-1, 1]``, scaled to ``||F||_2 <= 1``.

        For a scalar ``F`` this is uniform on ``[-1, 1]``.

        Returns
        -------
        ndarray, shape (i, j)
        """
        F = rng.uniform(-1.0, 1.0, self.model.f_shape)
        norm = np.linalg.norm(F, 2) if F.size else 0.0
        return F / norm if norm > 1.0 else F

    def transition(self, F: np.ndarray | float | None) -> Transition:
        """The sampling step for ``F`` (cached per ``F``)."""
        Fm = self.model.uncertainty(F)
        key = Fm.tobytes()
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        m = self.model
        A_F, C_F = m.perturbed(Fm)
        n, p, k = m.n, m.p, self.B.shape[1]
        Dz = np.vstack([m.D1, m.D2])
        Bz = np.vstack([self.B, np.zeros((p, k))])
        if m.discrete:  # xi is w(k) itself
            Phi, Gu, S = np.vstack([A_F, C_F]), Bz, Dz
        else:
            dt = self.dt_s
            nz = n + p
            Az = np.zeros((nz, nz))
            Az[:n, :n] = A_F
            Az[n:, :n] = C_F
            Phi_z, Gu = zoh(Az, Bz, dt)  # drift and input
            # noise covariance by Van Loan
            vl = np.zeros((2 * nz, 2 * nz))
            vl[:nz, :nz] = -Az
            vl[:nz, nz:] = Dz @ Dz.T
            vl[nz:, nz:] = Az.T
            V = expm(vl * dt)
            Q = V[nz:, nz:].T @ V[:nz, nz:]
            # rows n: are int y dt over the step: divide by dt for the average
            scale = np.concatenate([np.ones(n), np.full(p, 1.0 / dt)])
            Phi = Phi_z[:, :n] * scale[:, None]
            Gu = Gu * scale[:, None]
            S = _noise_factor(Q * np.outer(scale, scale))  # which symmetrizes it
        out = Transition(Phi=Phi, Gu=Gu, S=S)
        self._cache[key] = out
        return out

    def at(self, F: np.ndarray | float | None) -> UncertainLinearPlant:
        """The plant with the run's uncertainty ``F`` (sharing the transition cache)."""
        out = copy.copy(self)
        out.F = self.model.uncertainty(F)
        return out

    def noise(self, rng: np.random.Generator | None, batch: tuple[int, ...]) -> np.ndarray:
        """The standard normal ``xi`` of one step, shape ``batch + (r_eff,)``."""
        r = self.transition(self.F).S.shape[1]
        return np.zeros((*batch, r)) if rng is None else rng.standard_normal((*batch, r))

    def observe(self, x: np.ndarray, k: int) -> np.ndarray:
        """No measurement before the first step: zeros, shape (..., p)."""
        return np.zeros((*np.shape(x)[:-1], self.model.p))

    def step(self, x: np.ndarray, k: int, u: np.ndarray | None, noise: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """One step at :attr:`F` for one plant or a batch.

        Parameters
        ----------
        x : ndarray, shape (..., n)
        k : int
        u : ndarray, shape (..., k), optional
        noise : ndarray, shape (..., r_eff)
            The standard normal ``xi`` (``S xi`` is the noise of ``[x_next; y]``).

        Returns
        -------
        x_next : ndarray, shape (..., n)
        y : ndarray, shape (..., p)
            The measurement of this step (see the module docstring).
        extras : dict
            ``{"disturbance": xi}``.

        Raises
        ------
        FiniteEscapeError
            A state beyond :data:`ESCAPE_BOUND` or a non-finite measurement.
        """
        tr = self.transition(self.F)
        n = self.model.n
        z = x @ tr.Phi.T + noise @ tr.S.T
        if u is not None:
            z = z + u @ tr.Gu.T
        x_next, y = z[..., :n], z[..., n:]
        if not (np.all(np.abs(x_next) <= ESCAPE_BOUND) and np.all(np.isfinite(y))):
            raise FiniteEscapeError(f"the state left |x| <= {ESCAPE_BOUND:g}",
                                    time=(k + 1) * self.dt_s, quantity="state", value=x_next)
        return x_next, y, {"disturbance": noise}
