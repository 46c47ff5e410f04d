"""Zhang, Deng & Zhang (2018), Examples 5.1 and 5.2 as data: systems, signals, printed values, run
settings (see docs/references.md).

Example 5.2 (vehicle roll, Theorem 4) in the names of :class:`filters.lmi_hinf.
StochasticLinearSystem` (paper (44) letters in brackets)::

    x_{k+1} = A x + B v + A_w x w        (52): A, B, C
    y_k     = C_y x + D_y v              (52): H, L   [(44): K, L]
    z_k     = C_z x                      (52): M      [(44): G]

in two versions: (52) verbatim (:func:`paper_system`: the forward-Euler model without ``g``
in ``A[1, 0]``) and the physically consistent model of the MuJoCo rig (:func:`rig_system`:
exact zero-order hold of the physical linearization, with ``g``). For the rig in the loop with
any vehicle sensor suite: :func:`testbed.rigs.vehicle_roll.stochastic_system.vehicle_lmi_system`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from filters.lmi_hinf import (
    DEFAULT_MARGIN,
    LMIHInfDesign,
    StochasticLinearSystem,
)
from testbed.rigs.vehicle_roll import (
    PAPER_PERIOD_S,
    VehicleRollParams,
    paper_disturbance,
    paper_model,
)
from testbed.rigs.vehicle_roll.stochastic_system import zoh_with_damping_derivative

#: Printed solution of (48) and the printed gain (Example 5.2).
PAPER_P1 = np.array([[0.0114, 0.0002], [0.0002, 0.0002]])
PAPER_P2 = np.array([[7.5939, 0.1379], [0.1379, 0.0029]])
PAPER_P_K = np.array([[-6.3529, 2.8009], [-0.1137, 0.0503]])
PAPER_K_HAT = np.array([[-0.9194, 0.3965], [4.5617, -1.5241]])


def paper_system(params: VehicleRollParams | None = None) -> StochasticLinearSystem:
    """(52) as the system (44): ``A, B, C_y = H, C_z = M, A_w = C, D_y = L`` (no ``B_w``, ``D_z``).

    Returns
    -------
    StochasticLinearSystem
        n = 2, n_v = 1, n_y = 2, n_z = 1.
    """
    m = paper_model(params)
    return StochasticLinearSystem(A=m.A, B=m.B, C_y=m.H, C_z=m.M, A_w=m.C, D_y=m.L)


def rig_system(params: VehicleRollParams | None = None,
               dt_s: float = PAPER_PERIOD_S) -> StochasticLinearSystem:
    """The MuJoCo rig with the ``paper-decay`` manoeuvre (``a_y = v_k``, m/s^2) and the
    ``paper`` suite (``y = H x + L v``), as (44): ``A_w``, ``B_w`` are ``D_n`` times the
    derivatives of ``(A, B)`` with respect to ``C_R`` (Frechet derivative of the matrix
    exponential).

    Parameters
    ----------
    params : VehicleRollParams, optional
        Physical parameters (default Table 1).
    dt_s : float
        Control period, s.

    Returns
    -------
    StochasticLinearSystem
        ``A = expm(A_c T)``, ``B = ZOH(B_c)`` (rad, rad/s per m/s^2 of ``v = a_y``),
        ``A_w = D_n dA/dC_R``, ``B_w = D_n dB/dC_R``, ``C_y = H``, ``D_y = L``, ``C_z = [1, 0]``.
    """
    p = params or VehicleRollParams()
    A, B, dA, dB = zoh_with_damping_derivative(p, dt_s)
    m = paper_model(p)
    return StochasticLinearSystem(A=A, B=B, C_y=m.H, C_z=m.M, A_w=p.damping_noise * dA,
                                  B_w=p.damping_noise * dB, D_y=m.L)


def identify_rig_step(params: VehicleRollParams | None = None, dt_s: float = PAPER_PERIOD_S,
                      physics_dt_s: float = 0.001, eps: float = 1e-6
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The MuJoCo rig's one-control-step map ``x+ = A x + B a_y`` by central differences.

    Steps :class:`~testbed.rigs.vehicle_roll.VehicleRollRig` (nominal damping, ``w = 0``)
    from perturbed states and inputs, so the result includes MuJoCo's integrator
    (``implicitfast`` at ``physics_dt_s``). Compare with :func:`rig_system` (exact ZOH).

    Returns
    -------
    A : ndarray, shape (2, 2)
    B : ndarray, shape (2, 1)
    """
    import mujoco

    from testbed.rigs.vehicle_roll import VehicleRollRig

    rig = VehicleRollRig(params, physics_dt_s=physics_dt_s)
    nstep = int(round(dt_s / physics_dt_s))

    def f(x: np.ndarray, a_y: float) -> np.ndarray:
        mujoco.mj_resetData(rig.model, rig.data)
        rig.data.xfrc_applied[:] = rig.actuation(np.array([[a_y]]),
                                                 rig.member_constants(rig.params)[None])["xfrc"][0]
        rig.set_state(x)
        mujoco.mj_step(rig.model, rig.data, nstep=nstep)
        return rig.get_state()

    A = np.zeros((2, 2))
    for i in range(2):
        dx = np.zeros(2)
        dx[i] = eps
        A[:, i] = (f(dx, 0.0) - f(-dx, 0.0)) / (2 * eps)
    B = ((f(np.zeros(2), eps) - f(np.zeros(2), -eps)) / (2 * eps))[:, None]
    return A, B


@dataclass(frozen=True)
class VehicleRollLMIScenario:
    """Example 5.2's run settings (printed values where the paper gives them).

    Attributes
    ----------
    x0 : ndarray, shape (2,)
        ``[0.1, 1]`` (rad, rad/s on the rig): the paper's initial state.
    xhat0 : ndarray, shape (2,)
        ``[0, 0]``, the paper's initial estimate.
    runs : int
        100 Monte-Carlo runs, as in the paper.
    horizon_s : float
        2 s (200 steps); the paper does not state its horizon. By then the sums are within
        1e-5 of their limits (slowest error pole: 0.971, the rig design; 0.943 on (52)).
    dt_s : float
        ``T = 0.01`` s.
    gamma_factor : float
        Neither example states gamma: the filters are evaluated at
        ``gamma_used = gamma_factor * gamma_min``.
    margin : float
        Relative strictness margin of (48) (:func:`filters.lmi_hinf.balancing`).
    rtol : float
        Relative tolerance of the gamma bisection.
    """

    x0: np.ndarray = field(default_factory=lambda: np.array([0.1, 1.0]))
    xhat0: np.ndarray = field(default_factory=lambda: np.zeros(2))
    runs: int = 100
    horizon_s: float = 2.0
    dt_s: float = PAPER_PERIOD_S
    gamma_factor: float = 1.1
    margin: float = DEFAULT_MARGIN
    rtol: float = 1e-3

    v = staticmethod(paper_disturbance)  # v_k = 0.01 * 0.9^k


@dataclass(frozen=True)
class NonlinearDiscreteScenario:
    """Example 5.1's run settings. The paper gives neither ``x0`` nor ``gamma``.

    Attributes
    ----------
    x0 : ndarray, shape (2,)
        ``[1, 1]`` (with ``x0 = 0`` the state stays 0 and every sum is 0).
    gamma : float
        2.0: just above the smallest gamma (1.84) for which the corrected (35) holds on the
        default grid, so a violation of Corollary 3 is (36)'s, which does not involve gamma.
    runs : int
        1000, as in the paper.
    steps : int
        200 (the environment's episode length; the paper's horizon is not stated).
    grid_halfwidth, grid_points : float, int
        Corollary 3 is checked on ``[-2, 2]^4`` in ``(x, xhat)`` with 21 points per axis.
    """

    x0: np.ndarray = field(default_factory=lambda: np.array([1.0, 1.0]))
    gamma: float = 2.0
    runs: int = 1000
    steps: int = 200
    grid_halfwidth: float = 2.0
    grid_points: int = 21


# ----------------------------------------------------------------- CLI helper
def initial_state_weight(design: LMIHInfDesign, x0: np.ndarray, xhat0: np.ndarray) -> float:
    """``V(eta_0) = eta_0' diag(P1, P2) eta_0`` with ``eta_0 = [x0; x0 - xhat0]``.

    The proof of Lemma 2 ((13)) bounds ``sum E|ztilde|^2 <= gamma^2 sum E|v|^2 + V(eta_0)``.
    """
    x0 = np.asarray(x0, dtype=float)
    e0 = x0 - np.asarray(xhat0, dtype=float)
    return float(x0 @ design.P1 @ x0 + e0 @ design.P2 @ e0)

