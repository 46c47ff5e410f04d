"""A stiff integrator for the continuous filters: the L-stable second-order Rosenbrock method.

The continuous filters integrate their Riccati and state equations over each sample interval
with the observation held. With accurate sensors the gain ``P C^T R^-1`` makes the error
dynamics fast (rates of 10^4 1/s against a 10 ms period), and the explicit RK4 steps of
:mod:`filters.hinf_polynomial` need about ``rate * dt`` substeps per period to stay stable and
accurate. An L-stable implicit method has no stability limit: its substeps follow the
accuracy of the slow modes, while the fast ones relax to their quasi-steady state as they do
in the exact solution.

:func:`rosenbrock2` is the two-stage method ROS2 of Verwer, Spee, Blom and Hundsdorfer
(1999), ``gamma = 1 + 1/sqrt(2)``::

    W = I - gamma h J,     J ~ dF/ds at (t_n, s_n)
    W k1 = F(t_n, s_n)
    W k2 = F(t_n + h, s_n + h k1) - 2 k1
    s_(n+1) = s_n + (3/2) h k1 + (1/2) h k2

It is L-stable and of order 2 for *any* matrix ``J`` (a W-method; the time derivative
``dF/dt`` is not needed; on a right-hand side that varies in time within the stiff regime
the error of the fast components' quasi-steady state is then O(h): the continuous filters
hold ``y`` and ``u`` over a period and have constant coefficients on the rigs), so the
Jacobian here is a forward difference of ``F`` evaluated in one batched call per substep
(``d`` perturbed states per batch member), and its error costs stability margin, never
order. Tested on linear systems against the matrix exponential (order 2, also in the stiff
regime, where RK4 at the same step diverges) and on the polynomial filter against RK4.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from filters._linalg import FloatArray

__all__ = ["GAMMA", "rosenbrock2"]

#: ``gamma`` of ROS2 (L-stable; ``1 - 1/sqrt(2)`` is A-stable only).
GAMMA = 1.0 + 1.0 / math.sqrt(2.0)
#: Relative forward-difference step of the Jacobian (about ``sqrt(machine epsilon)``).
FD_STEP = 1.5e-8


def _inverse_w(rhs: Callable[[float, FloatArray], FloatArray], t: float, s: FloatArray,
               f: FloatArray, h: float, typical: FloatArray) -> FloatArray:
    """``(I - GAMMA h J)^-1`` with ``J`` the forward-difference Jacobian of ``rhs`` at ``s``.

    ``s``, ``f``: shape (..., d); ``typical`` (..., d): magnitudes below which a component's
    difference step is not scaled down. Returns (..., d, d).
    """
    d = s.shape[-1]
    step = FD_STEP * np.maximum(np.abs(s), typical)
    perturbed = s[..., None, :] + np.eye(d) * step[..., None, :]  # row j: s + step_j e_j
    columns = (rhs(t, perturbed) - f[..., None, :]) / step[..., :, None]  # (..., j, i)
    W = np.eye(d) - (GAMMA * h) * columns.swapaxes(-1, -2)
    return np.linalg.inv(W)


def rosenbrock2(rhs: Callable[[float, FloatArray], FloatArray], s: FloatArray, t0_s: float,
                h_s: float, substeps: int, typical: FloatArray,
                after_substep: Callable[[int, float, FloatArray], FloatArray] | None = None
                ) -> FloatArray:
    """Integrate ``ds/dt = rhs(t, s)`` over ``substeps`` ROS2 steps of ``h_s`` (see module).

    Parameters
    ----------
    rhs : callable ``(t, S) -> dS/dt``
        Right-hand side on a batch of states ``S`` of shape ``(..., d)``; it is also called
        with one more axis before the last, ``(..., d, d)`` (the Jacobian's perturbed
        states), and must broadcast over it.
    s : ndarray, shape (..., d)
        State at ``t0_s``; leading axes are independent systems.
    t0_s, h_s : float
        Start time and substep in s.
    substeps : int
    typical : ndarray, shape (d,) or (..., d)
        Positive magnitudes of the components (difference steps are ``FD_STEP *
        max(|s_j|, typical_j)``).
    after_substep : callable ``(i, t_end_s, s) -> s``, optional
        Called after substep ``i`` (ending at ``t_end_s``) with the new state; returns the
        state to continue from (e.g. symmetrized), may raise to stop.

    Returns
    -------
    ndarray, shape (..., d)
        The state at ``t0_s + substeps * h_s``.
    """
    typical = np.broadcast_to(typical, s.shape)
    for i in range(substeps):
        t = t0_s + i * h_s
        f = rhs(t, s)
        Winv = _inverse_w(rhs, t, s, f, h_s, typical)
        k1 = (Winv @ f[..., None])[..., 0]
        k2 = (Winv @ (rhs(t + h_s, s + h_s * k1) - 2.0 * k1)[..., None])[..., 0]
        s = s + (1.5 * h_s) * k1 + (0.5 * h_s) * k2
        if after_substep is not None:
            s = after_substep(i, t0_s + (i + 1) * h_s, s)
    return s
