"""Schmidt-Kalman filter: a Kalman filter that *considers* unknown constants.

A constant that the data cannot estimate well, or that a designer does not want estimated
(a sensor's sensitivity error drawn once per run, an input's scale error), is not white
noise: treated as white it makes a filter overconfident, because its error does not average
out over a run. The Schmidt ("consider") filter (Schmidt 1966; Simon, *Optimal State
Estimation*, 2006, section 7.5) carries each such constant ``s_c`` (mean 0, standard
deviation ``std_c``) in the covariance, with its cross-covariances to the state, and never
updates it: the state's gain accounts for it, its own gain is zero.

The model is the linear one of :class:`~filters.models.DiscreteLinearSystem` with the
constants entering bilinearly::

    x_{k+1} = F x_k + B u_k + sum_c s_c (M_c x_k + N_c u_k) + w_k
    y_k     = H x_k + D u_k + sum_c s_c (G_c x_k + J_c u_k) + v_k

(a channel ``i`` with sensitivity error ``s``: ``G = e_i H_i``, ``J = e_i D_i``; an input
``j`` measured with scale error ``s``: ``N = -B e_j e_j^T``, ``J = -D e_j e_j^T``). The
sensitivities ``M_c x + N_c u`` and ``G_c x + J_c u`` are evaluated at the estimate (the
constants' mean is zero, so the state's prediction is the linear one); with every ``std_c =
0`` the filter is the Kalman filter of ``system``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import numpy.typing as npt

from filters._linalg import FloatArray, matrix
from filters.errors import LossOfDefinitenessError
from filters.kalman import _SampledFilter
from filters.models import DiscreteLinearSystem

__all__ = ["ConsiderParameter", "SchmidtKalmanFilter"]


@dataclass(frozen=True, eq=False)
class ConsiderParameter:
    """One unknown constant ``s`` (mean 0) and how it enters the model.

    Attributes
    ----------
    std : float
        Standard deviation of ``s`` (its prior; never updated).
    name : str
        For messages and covariance labels.
    transition_state, transition_input : ndarray, shapes (n, n), (n, k), optional
        ``M``, ``N``: ``x_{k+1} += s (M x_k + N u_k)`` (default zero).
    measurement_state, measurement_input : ndarray, shapes (m, n), (m, k), optional
        ``G``, ``J``: ``y_k += s (G x_k + J u_k)`` (default zero).
    """

    std: float
    name: str = "s"
    transition_state: npt.ArrayLike | None = None
    transition_input: npt.ArrayLike | None = None
    measurement_state: npt.ArrayLike | None = None
    measurement_input: npt.ArrayLike | None = None


class SchmidtKalmanFilter(_SampledFilter):
    """Discrete Kalman filter with Schmidt consider constants (batched like
    :class:`~filters.kalman.KalmanFilter`).

    Parameters
    ----------
    system : DiscreteLinearSystem
        ``F, B, H, D, Q, R`` (``Q``, ``R`` without the constants' effect).
    x0 : array_like, shape (n,) or (..., n)
    P0 : array_like, shape (n, n) or (..., n, n)
        Prior of the state; the constants are independent of it (prior ``diag(std^2)``).
    parameters : sequence of ConsiderParameter

    Attributes
    ----------
    x, P : ndarray, shapes (..., n), (..., n, n)
        The state's estimate and its marginal covariance (the constants' included).
    joint_covariance : ndarray, shape (..., n + p, n + p)
        Of ``[x, s]``.
    innovation, innovation_cov, gain : ndarray or None
        Of the last update: shapes (..., m), (..., m, m), (..., n, m).
    """

    name: ClassVar[str] = "schmidt-kalman"

    def __init__(self, system: DiscreteLinearSystem, x0: npt.ArrayLike, P0: npt.ArrayLike,
                 parameters: Sequence[ConsiderParameter]) -> None:
        if not isinstance(system, DiscreteLinearSystem):
            raise ValueError(f"system must be a DiscreteLinearSystem, got "
                             f"{type(system).__name__}")
        self._sys = system
        n, m, k = system.F.shape[0], system.H.shape[0], system.B.shape[1]
        self._n, self._m, self._k, self._dt = n, m, k, system.dt_s
        params = list(parameters)
        stds = []
        blocks = {"M": [], "N": [], "G": [], "J": []}
        for i, c in enumerate(params):
            if not isinstance(c, ConsiderParameter):
                raise ValueError(f"parameters[{i}] must be a ConsiderParameter, got "
                                 f"{type(c).__name__}")
            std = float(c.std)
            if not (np.isfinite(std) and std >= 0):
                raise ValueError(f"parameters[{i}] ({c.name}): std must be finite and >= 0, "
                                 f"got {c.std}")
            stds.append(std)
            for key, value, shape in (("M", c.transition_state, (n, n)),
                                      ("N", c.transition_input, (n, k)),
                                      ("G", c.measurement_state, (m, n)),
                                      ("J", c.measurement_input, (m, k))):
                blocks[key].append(np.zeros(shape) if value is None else
                                   matrix(f"parameters[{i}] ({c.name})", value, shape))
        self._p = len(params)
        self._names = tuple(c.name for c in params)
        self._std = np.array(stds)
        p = self._p
        self._M = np.stack(blocks["M"]) if p else np.zeros((0, n, n))
        self._N = np.stack(blocks["N"]) if p else np.zeros((0, n, k))
        self._G = np.stack(blocks["G"]) if p else np.zeros((0, m, n))
        self._J = np.stack(blocks["J"]) if p else np.zeros((0, m, k))
        self.reset(x0, P0)

    @property
    def system(self) -> DiscreteLinearSystem:
        """The linear model."""
        return self._sys

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the consider constants, in the order of ``joint_covariance``."""
        return self._names

    def reset(self, x0: npt.ArrayLike, P0: npt.ArrayLike) -> None:
        """Re-initialize the state's estimate and covariance (the constants' prior is
        ``diag(std^2)``, uncorrelated with the state); ``t_s = 0``."""
        super().reset(x0, P0)
        n, p = self._n, self._p
        Pa = np.zeros((*self._batch, n + p, n + p))
        Pa[..., :n, :n] = self._P
        Pa[..., n:, n:] = np.diag(self._std**2)
        self._Pa = Pa
        self.innovation_cov: FloatArray | None = None
        self.gain: FloatArray | None = None

    @property
    def joint_covariance(self) -> FloatArray:
        """Covariance of ``[x, s]``, shape ``(..., n + p, n + p)`` (a copy)."""
        return np.array(self._Pa)

    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """Predict over the last interval with ``u``, then update with ``y`` measured at its
        end; returns the new ``x``.

        Raises
        ------
        ValueError
            ``y`` or ``u`` of the wrong shape or not finite.
        LossOfDefinitenessError
            The innovation covariance is not positive definite (state unchanged).
        FiniteEscapeError
            The estimate became non-finite (state unchanged).
        """
        y_arr = self._vector("y", y, self._m)
        u_arr = self._input(u)
        s = self._sys
        n, p = self._n, self._p
        batch = self._batch
        x = self._x
        u_full = (np.zeros((*batch, self._k)) if u_arr is None
                  else np.broadcast_to(u_arr, (*batch, self._k)))
        # predict: the sensitivities of the transition at the prior estimate
        Fa = np.zeros((*batch, n + p, n + p))
        Fa[..., :n, :n] = s.F
        Fa[..., n:, n:] = np.eye(p)
        if p:
            Fa[..., :n, n:] = (np.einsum("cij,...j->...ic", self._M, x)
                               + np.einsum("cij,...j->...ic", self._N, u_full))
        x_pred = x @ s.F.T + u_full @ s.B.T
        Pa = Fa @ self._Pa @ np.swapaxes(Fa, -1, -2)
        Pa[..., :n, :n] += s.Q
        # update: the measurement's sensitivities at the predicted estimate
        Ha = np.zeros((*batch, self._m, n + p))
        Ha[..., :n] = s.H
        if p:
            Ha[..., n:] = (np.einsum("cij,...j->...ic", self._G, x_pred)
                           + np.einsum("cij,...j->...ic", self._J, u_full))
        innovation = y_arr - x_pred @ s.H.T - u_full @ s.D.T
        PHt = Pa @ np.swapaxes(Ha, -1, -2)
        S = Ha @ PHt + s.R
        S = 0.5 * (S + np.swapaxes(S, -1, -2))
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise LossOfDefinitenessError("innovation covariance not positive definite",
                                          time=self._time(self._steps + 1),
                                          quantity="innovation_cov", value=S) from None
        # K = P H^T S^-1 on the state's rows only (the constants are never updated)
        Z = np.linalg.solve(L, np.swapaxes(PHt[..., :n, :], -1, -2))
        K = np.swapaxes(np.linalg.solve(np.swapaxes(L, -1, -2), Z), -1, -2)
        x_new = x_pred + np.einsum("...ij,...j->...i", K, innovation)
        self._check_state(x_new, self._steps + 1)
        Ka = np.zeros((*batch, n + p, self._m))
        Ka[..., :n, :] = K
        IKH = np.eye(n + p) - Ka @ Ha
        Pa = IKH @ Pa @ np.swapaxes(IKH, -1, -2) + Ka @ s.R @ np.swapaxes(Ka, -1, -2)
        Pa = 0.5 * (Pa + np.swapaxes(Pa, -1, -2))
        self._Pa = Pa
        self.innovation, self.innovation_cov, self.gain = innovation, S, K
        self._commit(np.array(x_new), np.array(Pa[..., :n, :n]), self._steps + 1)
        return self._x

