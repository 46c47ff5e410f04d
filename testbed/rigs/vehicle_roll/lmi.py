"""The LMI H-infinity design of the vehicle roll rig in the loop (Zhang et al., Theorem 4).

The design system adds to the physical model what the rig has and the paper's model does
not: the known lateral acceleration as an input and the multiplicative damping noise
``C_R + D_n w_k`` through the derivative of the exact ZOH discretization. The rig's design
model exposes :func:`vehicle_lmi_estimator` as ``extras["lmi_system"]`` (``--filter
lmi-hinf``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import expm_frechet

from filters.lmi_hinf import LMIHInfFilter, StochasticLinearSystem
from testbed.estimators.lmi import verified_estimator
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
    design : testbed.estimators.design.DesignModel
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


def vehicle_lmi_estimator(design: Any, *, gamma: float | None = None,
                          gamma_factor: float = 5.0, objective: str = "h2-unique"
                          ) -> tuple[LMIHInfFilter, dict[str, Any]]:
    """The filter (45) for the vehicle rig in the loop (``--filter lmi-hinf``).

    Designs on :func:`vehicle_design_system` by Theorem 4 at ``gamma`` (default
    the first accurate verified 1-2-5 grid level above ``gamma_factor * gamma_min``,
    :func:`filters.lmi_hinf.design_on_grid`) with the strictly convex mixed H2/H-infinity
    objective.

    Returns
    -------
    estimator : LMIHInfFilter
        With the known input ``a_y`` (``input_matrix``, ``feedthrough``) and ``dt_s``.
    meta : dict
        ``gamma_min``, ``gamma``, ``gain``, ``status``, ``spectral_radius`` for outputs.

    Raises
    ------
    ValueError
        If no verified design exists (the solver status is in the message).
    """
    a_y_std = design.extras.get("a_y_std", 0.1)
    system, B_u, D_u = vehicle_design_system(design, a_y_std=a_y_std)
    estimator, meta = verified_estimator(system, design, gamma=gamma, gamma_factor=gamma_factor,
                                         objective=objective, input_matrix=B_u,
                                         feedthrough=D_u)
    meta["a_y_std"] = a_y_std
    return estimator, meta
