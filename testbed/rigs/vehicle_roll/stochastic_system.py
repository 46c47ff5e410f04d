"""The LMI H-infinity design of the vehicle roll rig in the loop (Zhang et al., Theorem 4).

The design system adds to the physical model what the rig has and the paper's model does
not: the known lateral acceleration as an input and the multiplicative damping noise
``C_R + D_n w_k`` through the derivative of the exact ZOH discretization. The rig's design
model exposes :func:`vehicle_lmi_system` as ``extras["lmi_system"]``; ``--filter lmi-hinf``
designs on it (:mod:`testbed.estimators.stochastic_system`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import expm_frechet

from filters.lmi_hinf import StochasticLinearSystem
from testbed.rigs.vehicle_roll.model import VehicleRollParams, paper_model, physical_model


def zoh_with_damping_derivative(params: VehicleRollParams, dt_s: float
                                 ) -> tuple[np.ndarray, ...]:
    """``(A_d, B_d, dA_d/dC_R, dB_d/dC_R)`` of the physical model's exact ZOH discretization."""
    A_c, B_c = physical_model(params)
    n, k = B_c.shape
    M = np.zeros((n + k, n + k))
    M[:n, :n] = A_c
    M[:n, n:] = B_c
    E = np.zeros_like(M)
    E[1, 1] = -1.0 / params.roll_inertia  # d A_c / d C_R
    expM, dexpM = expm_frechet(M * dt_s, E * dt_s)
    return expM[:n, :n], expM[:n, n:], dexpM[:n, :n], dexpM[:n, n:]


def vehicle_design_system(design: Any, params: VehicleRollParams | None = None,
                          a_y_std: float = 0.1) -> tuple[StochasticLinearSystem, np.ndarray,
                                                         np.ndarray]:
    """The LMI design system of the rig in the loop with a known lateral acceleration.

    The applied ``a_y`` is a known input (``B_u``, feedthrough ``D_u`` of the sensors). The
    H-infinity disturbance ``v`` collects, each scaled to unit size: the ``a_y`` error
    (``a_y_std`` m/s^2 per step, through ``B_u``), the sensors' white noise per channel
    (standard deviations of their ``R``), and for the ``paper`` channels the paper's ``v``
    through ``L`` (amplitude 0.01).

    Parameters
    ----------
    design : testbed.design.DesignModel
        The vehicle rig's design model (its stochastic channels, ``dt_s``).
    params : VehicleRollParams, optional
        The designer's parameters (nominal by default).
    a_y_std : float
        Size of the ``a_y`` error, m/s^2.

    Returns
    -------
    system : StochasticLinearSystem
    input_matrix : ndarray, shape (2, 1)
        ``B_u`` (ZOH of the physical ``B``).
    feedthrough : ndarray, shape (n_y, 1)
    """
    p = params or VehicleRollParams()
    A, B, dA, dB = zoh_with_damping_derivative(p, design.dt_s)
    index = design.measurement_index
    C = design.sensors.C[index]
    R = design.sensors.R[np.ix_(index, index)]
    D_u = design.sensors.D[index]
    m = C.shape[0]
    std = np.sqrt(np.clip(np.diag(R), 0.0, None))
    cols_B = [B[:, 0] * a_y_std]
    cols_Bw = [p.damping_noise * dB[:, 0] * a_y_std]
    cols_D = [D_u[:, 0] * a_y_std]
    for i in range(m):
        if std[i] > 0:
            e = np.zeros(m)
            e[i] = std[i]
            cols_B.append(np.zeros(2))
            cols_Bw.append(np.zeros(2))
            cols_D.append(e)
    amplitude = design.extras.get("lmi_amplitude")
    if amplitude is not None:
        cols_B.append(np.zeros(2))
        cols_Bw.append(np.zeros(2))
        cols_D.append(paper_model().L[:, 0] * amplitude)
    system = StochasticLinearSystem(
        A=A, B=np.column_stack(cols_B), C_y=C, C_z=np.array([[1.0, 0.0]]),
        A_w=p.damping_noise * dA, B_w=np.column_stack(cols_Bw), D_y=np.column_stack(cols_D))
    return system, B, D_u


def vehicle_lmi_system(design: Any) -> tuple[StochasticLinearSystem, np.ndarray, np.ndarray]:
    """The rig's LMI design system for ``--filter lmi-hinf`` (``design.extras["lmi_system"]``):
    :func:`vehicle_design_system` with the design's ``a_y_std``; the family designs on it
    (Theorem 4, :func:`testbed.estimators.stochastic_system.verified_estimator`).

    Returns
    -------
    system : StochasticLinearSystem
    B_u : ndarray, shape (2, 1)
        The known input's matrix.
    D_u : ndarray, shape (m, 1)
        Its feedthrough.
    """
    return vehicle_design_system(design, a_y_std=design.extras.get("a_y_std", 0.1))
