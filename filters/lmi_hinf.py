"""LMI-designed H-infinity filter for linear discrete stochastic systems (Theorem 4 of
Zhang, Deng & Zhang (2018)).

Reference: T. Zhang, F. Deng, W. Zhang, "Robust H-infinity filtering for nonlinear
discrete-time stochastic systems" (2018), Section 4; see docs/references.md.

System (paper eq. (44)) and the names used here::

    x_{k+1} = A x_k + B v_k + (A_w x_k + B_w v_k) w_k        paper: A, B, C, D
    y_k     = C_y x_k + D_y v_k                              paper: K, L
    z_k     = C_z x_k + D_z v_k                              paper: G, M

``w_k`` is a scalar i.i.d. sequence with ``E w = 0``, ``E w^2 = 1``; ``v_k`` is the
disturbance (energy-bounded, ``l2``). Shapes: state ``n``, disturbance ``n_v``, measurement
``n_y``, estimated output ``n_z``.

Filter (45), with the misprint corrected (see docs/references.md: the paper prints ``A x_k``;
the error system (46) it derives requires ``A xhat_k``)::

    xhat_{k+1} = A xhat_k + Khat (y_k - C_y xhat_k),     zhat_k = C_z xhat_k      (45)

``Khat`` is ``gain`` here (``n x n_y``). With ``eta = [x; x - xhat]`` the augmented system is
(46)::

    eta_{k+1} = At eta + Bt v + (Ct eta + Dt v) w,     ztilde = z - zhat = Gt eta + Mt v
    At = [[A, 0], [0, A - Khat C_y]],  Bt = [B; B - Khat D_y],  Ct = [[A_w, 0], [A_w, 0]],
    Dt = [B_w; B_w],  Gt = [0, C_z],  Mt = D_z.

Corollary 5: if ``P > 0`` makes the matrix ``PP`` of the GARI (47) negative definite::

    PP = [[At'P At + Ct'P Ct - P + Gt'Gt,  At'P Bt + Ct'P Dt + Gt'Mt],
          [*,                              Bt'P Bt + Dt'P Dt + Mt'Mt - gamma^2 I]]  < 0

then (46) is internally (mean-square) stable and, for ``eta_0 = 0``,
``sum_k E|ztilde_k|^2 <= gamma^2 sum_k E|v_k|^2`` (7). For ``eta_0 != 0`` the proof (13)
gives ``sum_k E|ztilde_k|^2 <= gamma^2 sum_k E|v_k|^2 + eta_0' P eta_0``.

Theorem 4 takes ``P = diag(P1, P2)`` and ``P_K = P2 Khat``; LMI (48) in ``(P1, P2, P_K)``
(block order ``x, e, v, At-rows x, e, Ct-rows x, e, z``)::

    [[-P1, 0,   0,      A'P1, 0,                 A_w'P1, A_w'P2, 0    ],
     [*,  -P2,  0,      0,    A'P2 - C_y'P_K',   0,      0,      C_z' ],
     [*,   *,  -g^2 I,  B'P1, B'P2 - D_y'P_K',   B_w'P1, B_w'P2, D_z' ],
     [*,   *,   *,     -P1,   0,                 0,      0,      0    ],
     [*,   *,   *,      *,   -P2,                0,      0,      0    ],
     [*,   *,   *,      *,    *,                -P1,     0,      0    ],
     [*,   *,   *,      *,    *,                 *,     -P2,     0    ],
     [*,   *,   *,      *,    *,                 *,      *,     -I    ]]  < 0      (48)

Misprint corrected: the printed row 2, column 8 entry ``G`` is ``G'`` (``C_z'``, a column
block; see docs/references.md). ``Khat = P2^-1 P_K``. The suboptimal mixed H2/H-infinity
filter minimizes ``trace(P1 + P2)`` subject to (48).

What this module adds to the paper
----------------------------------
* Strict inequalities are imposed with an explicit RELATIVE ``margin``: the balanced LMI
  ``S (48) S <= -margin I`` and ``P1 >= margin s1 I``, ``P2 >= margin s2 I``, where ``s1``,
  ``s2`` are the natural sizes of ``P1``, ``P2`` and ``S`` scales every block of (48) to order
  one (``gamma^-1`` on the ``v`` block; :func:`balancing`). The solver works on the balanced
  problem (unknowns ``P1 / s1``, ``P2 / s2``, ``P_K / s2``); without this, problems whose
  ``P1`` and ``P2`` differ by 1e6 in size (the vehicle rig) defeat CLARABEL. When the
  disturbance can be (nearly) decoupled from the estimated output, the infimum of gamma is
  (nearly) 0 and ``gamma_min`` is set by the margin (roughly ``~ sqrt(margin)``).
* Every returned design is checked a posteriori without the solver
  (:func:`check_design`): ``PP < 0`` at the returned ``(P, Khat)`` (computed from (46)
  directly, not from (48)), ``P1, P2 > 0``, and the mean-square spectral radius
  ``rho(At (x) At + Ct (x) Ct) < 1`` (``E[eta eta']`` evolves by
  ``X -> At X At' + Ct X Ct'``). A solution the check rejects is not reported as feasible.
* Without multiplicative noise (``A_w = B_w = 0``) the plant block of (48) certifies only
  the plant's own stability; ``plant_block=False`` solves the error block alone
  (:func:`error_block_matrix`: the discrete bounded-real lemma of the error system, exact),
  which designs filters for plants that are not Schur stable (free integrators under a
  feedback controller) and gives the same infimum of gamma on stable ones. Its a-posteriori
  check adds the error system's H-infinity norm computed without the LMI
  (:func:`error_hinf_norm`). The argument is in :func:`design_lmi_hinf`'s Notes.
* Infeasibility is a result (:class:`LMIHInfDesign` with ``status`` and the solver's status
  string), never an exception.
* :func:`minimal_gamma` bisects on ``gamma`` (the feasible set grows with ``gamma``) to a
  stated relative tolerance; the returned ``gamma_min`` is always a verified feasible value.
* :func:`output_error_moments` propagates the exact first and second moments of (46) for a
  given initial state and disturbance sequence: the expected cumulative sums that a Monte
  Carlo estimates.

Solvers: cvxpy with CLARABEL (its equilibration off: the problem is balanced already), SCS
as fallback (when CLARABEL raises, returns ``infeasible_inaccurate`` or no solution, or its
solution does not pass the a-posteriori check). Compiled problems are cached per system
object (:func:`_problem`), so repeated solves on one system cost 3-10 ms instead of 20-60 ms.
"""

from __future__ import annotations

import threading
import time
import warnings
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from filters._linalg import FloatArray, matrix, positive_time, readonly, to_float_array
from filters.errors import FiniteEscapeError
from filters.kalman import _SampledFilter

__all__ = [
    "DesignCheck",
    "GammaSearch",
    "LMIHInfDesign",
    "LMIHInfFilter",
    "StochasticLinearSystem",
    "balancing",
    "certify_gain",
    "check_design",
    "design_above",
    "design_lmi_hinf",
    "design_on_grid",
    "error_block_matrix",
    "error_gari_matrix",
    "error_hinf_norm",
    "error_system",
    "gamma_grid",
    "gari_matrix",
    "lmi_gamma_for_solution",
    "minimal_gamma",
    "minimal_gamma_sdp",
    "ms_spectral_radius",
    "output_error_moments",
    "design_lmi_matrix",
]

#: Default relative strictness margin of (48) and of ``P1, P2 > 0`` (see :func:`balancing`).
DEFAULT_MARGIN = 1e-6
#: Default relative tolerance of the gamma bisection: ``gamma_min / lower - 1 <= rtol``.
DEFAULT_RTOL = 1e-3
_SOLVERS = ("CLARABEL", "SCS")
#: Solver options: SCS is a first-order method; bounded so a fallback costs < ~0.5 s on small
#: problems, and tight enough that its solutions can pass the a-posteriori check.
#: CLARABEL's own equilibration is off: the problem is balanced already (`balancing`), and
#: on the vehicle rig its equilibration made CLARABEL fail at some gamma.
_SOLVER_OPTIONS: dict[str, dict[str, Any]] = {
    "CLARABEL": {"equilibrate_enable": False},
    "SCS": {"max_iters": 10000, "eps_abs": 1e-9, "eps_rel": 1e-9},
}
#: The ``"h2-unique"`` design solves to tight tolerances (stated here): its gain must not
#: depend on BLAS rounding; a solve that cannot reach them reports "optimal_inaccurate" and
#: :func:`design_on_grid` moves to the next level.
_UNIQUE_OPTIONS: dict[str, dict[str, Any]] = {
    "CLARABEL": {"equilibrate_enable": False, "tol_gap_abs": 1e-11, "tol_gap_rel": 1e-11,
                 "tol_feas": 1e-11, "tol_ktratio": 1e-9, "max_iter": 500},
    "SCS": {"max_iters": 10000, "eps_abs": 1e-9, "eps_rel": 1e-9},
}
_SEARCH_OPTIONS: dict[str, dict[str, Any]] = {
    "CLARABEL": {"equilibrate_enable": False},
    "SCS": {"max_iters": 2500, "eps_abs": 1e-9, "eps_rel": 1e-9},
}
OBJECTIVES = ("feasibility", "h2", "h2-unique")
#: Weight of the strictly convex term of the ``"h2-unique"`` objective (see `_Theorem4Problem`).
UNIQUE_WEIGHT = 1e-1
#: Mantissas of the gamma grid of :func:`design_on_grid` (1, 2, 5 per decade).
GRID_MANTISSAS = (1.0, 2.0, 5.0)
#: Bracketing step of the gamma search (a decade: few solves for gamma_min far from 1).
_BRACKET = 10.0


# --------------------------------------------------------------------------- system
@dataclass(frozen=True, eq=False)
class StochasticLinearSystem:
    """The linear discrete stochastic system (44) of the paper (see the module docstring).

    Parameters
    ----------
    A : array_like, shape (n, n)
        State matrix (paper ``A``).
    B : array_like, shape (n, n_v)
        Disturbance input (paper ``B``).
    C_y : array_like, shape (n_y, n)
        Measurement matrix (paper ``K``).
    C_z : array_like, shape (n_z, n)
        Estimated output (paper ``G``).
    A_w : array_like, shape (n, n), optional
        Multiplicative state-noise matrix (paper ``C``); default zero.
    B_w : array_like, shape (n, n_v), optional
        Multiplicative disturbance-noise matrix (paper ``D``); default zero.
    D_y : array_like, shape (n_y, n_v), optional
        Disturbance in the measurement (paper ``L``); default zero.
    D_z : array_like, shape (n_z, n_v), optional
        Disturbance in the output (paper ``M``); default zero.

    Raises
    ------
    ValueError
        A matrix is non-finite or has a shape inconsistent with ``A`` and ``B`` (named).

    Notes
    -----
    All matrices are stored as read-only ``float64`` copies. Units are those of the model
    (the papers' examples are dimensionless or SI per sample).
    """

    A: FloatArray
    B: FloatArray
    C_y: FloatArray
    C_z: FloatArray
    A_w: FloatArray | None = None
    B_w: FloatArray | None = None
    D_y: FloatArray | None = None
    D_z: FloatArray | None = None

    def __post_init__(self) -> None:
        A = matrix("A", self.A, (None, None), what="a finite square matrix")
        n = A.shape[0]
        if A.shape != (n, n) or n == 0:
            raise ValueError(f"A must be a finite square matrix with shape (n, n), n >= 1, "
                             f"got shape {A.shape}")
        B = matrix("B", self.B, (n, None), labels=("n", "n_v"))
        nv = B.shape[1]
        if nv == 0:
            raise ValueError("B must have at least one column (n_v >= 1)")
        C_y = matrix("C_y", self.C_y, (None, n), labels=("n_y", "n"))
        C_z = matrix("C_z", self.C_z, (None, n), labels=("n_z", "n"))
        ny, nz = C_y.shape[0], C_z.shape[0]
        if ny == 0 or nz == 0:
            raise ValueError(f"C_y and C_z need at least one row, got shapes {C_y.shape}, "
                             f"{C_z.shape}")

        def opt(name: str, value: object, shape: tuple[int, int], labels: tuple[str, str]):
            if value is None:
                return np.zeros(shape)
            return matrix(name, value, shape, labels=labels)

        fields = {
            "A": A, "B": B, "C_y": C_y, "C_z": C_z,
            "A_w": opt("A_w", self.A_w, (n, n), ("n", "n")),
            "B_w": opt("B_w", self.B_w, (n, nv), ("n", "n_v")),
            "D_y": opt("D_y", self.D_y, (ny, nv), ("n_y", "n_v")),
            "D_z": opt("D_z", self.D_z, (nz, nv), ("n_z", "n_v")),
        }
        for key, value in fields.items():
            object.__setattr__(self, key, readonly(value))

    @property
    def n(self) -> int:
        """State dimension."""
        return self.A.shape[0]

    @property
    def n_v(self) -> int:
        """Disturbance dimension."""
        return self.B.shape[1]

    @property
    def n_y(self) -> int:
        """Measurement dimension."""
        return self.C_y.shape[0]

    @property
    def n_z(self) -> int:
        """Estimated-output dimension."""
        return self.C_z.shape[0]

    def gain_shape(self) -> tuple[int, int]:
        """Shape ``(n, n_y)`` of the filter gain ``Khat``."""
        return (self.n, self.n_y)


def _gain(system: StochasticLinearSystem, gain: npt.ArrayLike) -> FloatArray:
    return matrix("gain", gain, system.gain_shape(), labels=("n", "n_y"))


# --------------------------------------------------------------- a-posteriori checks
def error_system(system: StochasticLinearSystem, gain: npt.ArrayLike
                 ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
                            FloatArray]:
    """Matrices of the augmented system (46) for the filter (45) with gain ``Khat``.

    Parameters
    ----------
    system : StochasticLinearSystem
    gain : array_like, shape (n, n_y)

    Returns
    -------
    At, Bt, Ct, Dt, Gt, Mt : ndarray
        Shapes ``(2n, 2n)``, ``(2n, n_v)``, ``(2n, 2n)``, ``(2n, n_v)``, ``(n_z, 2n)``,
        ``(n_z, n_v)``; ``eta = [x; x - xhat]``.
    """
    K = _gain(system, gain)
    s = system
    n = s.n
    Z = np.zeros((n, n))
    At = np.block([[s.A, Z], [Z, s.A - K @ s.C_y]])
    Bt = np.vstack([s.B, s.B - K @ s.D_y])
    Ct = np.block([[s.A_w, Z], [s.A_w, Z]])
    Dt = np.vstack([s.B_w, s.B_w])
    Gt = np.hstack([np.zeros((s.n_z, n)), s.C_z])
    Mt = s.D_z.copy()
    return At, Bt, Ct, Dt, Gt, Mt


def gari_matrix(system: StochasticLinearSystem, gain: npt.ArrayLike, P: npt.ArrayLike,
                gamma: float) -> FloatArray:
    """The matrix ``PP`` of Corollary 5 / GARI (47), computed from (46) directly.

    Parameters
    ----------
    system : StochasticLinearSystem
    gain : array_like, shape (n, n_y)
    P : array_like, shape (2n, 2n)
        Lyapunov matrix of ``V(eta) = eta' P eta`` (Theorem 4: ``diag(P1, P2)``).
    gamma : float
        Attenuation level.

    Returns
    -------
    ndarray, shape (2n + n_v, 2n + n_v)
        Symmetric; ``PP < 0`` with ``P > 0`` certifies the filter (Corollary 5).
    """
    At, Bt, Ct, Dt, Gt, Mt = error_system(system, gain)
    N = 2 * system.n
    P = matrix("P", P, (N, N), labels=("2n", "2n"))
    P = 0.5 * (P + P.T)
    g2 = float(gamma) ** 2
    top_left = At.T @ P @ At + Ct.T @ P @ Ct - P + Gt.T @ Gt
    top_right = At.T @ P @ Bt + Ct.T @ P @ Dt + Gt.T @ Mt
    bottom = Bt.T @ P @ Bt + Dt.T @ P @ Dt + Mt.T @ Mt - g2 * np.eye(system.n_v)
    PP = np.block([[top_left, top_right], [top_right.T, bottom]])
    return 0.5 * (PP + PP.T)


def ms_spectral_radius(At: npt.ArrayLike, Ct: npt.ArrayLike) -> float:
    """Mean-square spectral radius ``rho(At (x) At + Ct (x) Ct)`` of ``eta+ = (At + Ct w) eta``.

    Below 1 iff the second moment ``E[eta eta']`` (``X -> At X At' + Ct X Ct'``, ``E w^2 = 1``)
    decays to zero for every initial state: mean-square stability.

    Parameters
    ----------
    At, Ct : array_like, shape (N, N)

    Returns
    -------
    float
    """
    At = np.asarray(At, dtype=float)
    Ct = np.asarray(Ct, dtype=float)
    L = np.kron(At, At) + np.kron(Ct, Ct)
    return float(np.max(np.abs(np.linalg.eigvals(L))))


def design_lmi_matrix(system: StochasticLinearSystem, P1: npt.ArrayLike, P2: npt.ArrayLike,
                      P_K: npt.ArrayLike, gamma: float) -> FloatArray:
    """The left-hand side of Theorem 4's LMI (48) evaluated with numpy (no solver).

    Parameters
    ----------
    system : StochasticLinearSystem
    P1, P2 : array_like, shape (n, n)
    P_K : array_like, shape (n, n_y)
    gamma : float

    Returns
    -------
    ndarray, shape (6n + n_v + n_z, 6n + n_v + n_z)
        Symmetric; block order ``x, e, v, At-rows x, e, Ct-rows x, e, z`` (module docstring).
    """
    s = system
    n, nv, ny, nz = s.n, s.n_v, s.n_y, s.n_z
    P1 = matrix("P1", P1, (n, n))
    P2 = matrix("P2", P2, (n, n))
    PK = matrix("P_K", P_K, (n, ny), labels=("n", "n_y"))
    sizes = [n, n, nv, n, n, n, n, nz]
    upper = {
        (0, 0): -P1, (0, 3): s.A.T @ P1, (0, 5): s.A_w.T @ P1, (0, 6): s.A_w.T @ P2,
        (1, 1): -P2, (1, 4): s.A.T @ P2 - s.C_y.T @ PK.T, (1, 7): s.C_z.T,
        (2, 2): -float(gamma) ** 2 * np.eye(nv), (2, 3): s.B.T @ P1,
        (2, 4): s.B.T @ P2 - s.D_y.T @ PK.T, (2, 5): s.B_w.T @ P1, (2, 6): s.B_w.T @ P2,
        (2, 7): s.D_z.T, (3, 3): -P1, (4, 4): -P2, (5, 5): -P1, (6, 6): -P2,
        (7, 7): -np.eye(nz),
    }
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    M = np.zeros((offsets[-1], offsets[-1]))
    for (i, j), block in upper.items():
        M[offsets[i]:offsets[i + 1], offsets[j]:offsets[j + 1]] = block
        if i != j:
            M[offsets[j]:offsets[j + 1], offsets[i]:offsets[i + 1]] = np.asarray(block).T
    return 0.5 * (M + M.T)


def lmi_gamma_for_solution(system: StochasticLinearSystem, P1: npt.ArrayLike,
                           P2: npt.ArrayLike, P_K: npt.ArrayLike) -> float | None:
    """Smallest ``gamma`` for which given ``(P1, P2, P_K)`` satisfy (48) (e.g. printed values).

    (48) is ``M0 - gamma^2 E_v < 0`` with ``E_v`` selecting the ``v`` block; by the Schur
    complement it holds iff the rest ``R`` of the matrix is negative definite and
    ``gamma^2 > lambda_max(M_vv - M_vr R^-1 M_rv)``.

    Returns
    -------
    float or None
        The infimum (strict inequality above it); None if no ``gamma`` works (``R`` is not
        negative definite, or ``P1``/``P2`` not positive definite).
    """
    s = system
    n, nv = s.n, s.n_v
    M = design_lmi_matrix(s, P1, P2, P_K, 0.0)
    v = np.arange(2 * n, 2 * n + nv)
    r = np.setdiff1d(np.arange(M.shape[0]), v)
    R = M[np.ix_(r, r)]
    if np.linalg.eigvalsh(R)[-1] >= 0.0:
        return None
    if min(np.linalg.eigvalsh(np.asarray(P1, float))[0],
           np.linalg.eigvalsh(np.asarray(P2, float))[0]) <= 0.0:
        return None
    S = M[np.ix_(v, v)] - M[np.ix_(v, r)] @ np.linalg.solve(R, M[np.ix_(r, v)])
    return float(np.sqrt(max(float(np.linalg.eigvalsh(0.5 * (S + S.T))[-1]), 0.0)))


@dataclass(frozen=True)
class DesignCheck:
    """A-posteriori verification of a design, computed without the solver.

    Attributes
    ----------
    gari_max_eig : float
        Largest eigenvalue of ``PP`` (Corollary 5); must be ``< 0``.
    gari_max_eig_relative : float
        ``gari_max_eig / max|eig(PP)|`` (scale-free).
    P_min_eig : float
        Smallest eigenvalue of ``P = diag(P1, P2)``; must be ``> 0``.
    P_condition : float
        Condition number of ``P``.
    spectral_radius : float
        :func:`ms_spectral_radius` of (46); must be ``< 1``.
    lmi_max_eig : float
        Largest eigenvalue of (48) (:func:`design_lmi_matrix`) at ``P_K = P2 Khat``.
    lmi_balanced_max_eig : float
        Largest eigenvalue of ``S (48) S`` (:func:`balancing`): the relative margin achieved
        (``<= -margin`` for an exact solver).
    P_balanced_min_eig : float
        ``min(lambda_min(P1) / s1, lambda_min(P2) / s2)`` (``>= margin`` for an exact solver).
    gari_negative_definite, positive_definite, mean_square_stable : bool
    ok : bool
        All three (and, for an error-block design, ``error_hinf_norm < gamma``).
    plant_block : bool
        False for an error-block design (:func:`design_lmi_hinf` with ``plant_block=False``):
        then ``P`` is ``P2``, ``PP`` is the error system's bounded-real matrix
        (:func:`error_gari_matrix`), ``spectral_radius`` is ``rho(Ae (x) Ae) = rho(Ae)^2``
        of the error system alone and the LMI entries are those of :func:`error_block_matrix`.
    error_hinf_norm : float or None
        Error-block designs: the H-infinity norm of the error system
        ``Ae = A - Khat C_y, Be = B - Khat D_y, C_z, D_z`` computed independently of the LMI
        and its solver (:func:`filters.analysis.hinf_norm`: bisection on the symplectic
        pencil, relative tolerance 1e-7); must be below ``gamma``. None for full designs.
    """

    gari_max_eig: float
    gari_max_eig_relative: float
    P_min_eig: float
    P_condition: float
    spectral_radius: float
    lmi_max_eig: float
    lmi_balanced_max_eig: float
    P_balanced_min_eig: float
    gari_negative_definite: bool
    positive_definite: bool
    mean_square_stable: bool
    ok: bool
    plant_block: bool = True
    error_hinf_norm: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly copy."""
        return dict(self.__dict__)


def check_design(system: StochasticLinearSystem, gain: npt.ArrayLike,
                 P1: npt.ArrayLike | None, P2: npt.ArrayLike, gamma: float, *,
                 plant_block: bool = True) -> DesignCheck:
    """Verify ``(Khat, P1, P2, gamma)`` a posteriori (Corollary 5 and mean-square stability).

    Parameters
    ----------
    system : StochasticLinearSystem
    gain : array_like, shape (n, n_y)
    P1 : array_like, shape (n, n), or None
        Ignored (may be None) when ``plant_block`` is False.
    P2 : array_like, shape (n, n)
    gamma : float
    plant_block : bool
        False: verify an error-block design (see :func:`design_lmi_hinf`): the error
        system's bounded-real matrix (:func:`error_gari_matrix`) negative definite with
        ``P2 > 0``, ``A - Khat C_y`` Schur stable, and its H-infinity norm computed
        independently (:func:`filters.analysis.hinf_norm`) below ``gamma``.

    Returns
    -------
    DesignCheck

    Raises
    ------
    ValueError
        ``plant_block=False`` on a system with multiplicative noise (named).
    """
    if not plant_block:
        return _check_error_block(system, gain, P2, gamma)
    if P1 is None:
        raise ValueError("check_design: P1 is needed (plant_block=True)")
    n = system.n
    P1 = matrix("P1", P1, (n, n))
    P2 = matrix("P2", P2, (n, n))
    P = np.zeros((2 * n, 2 * n))
    P[:n, :n] = 0.5 * (P1 + P1.T)
    P[n:, n:] = 0.5 * (P2 + P2.T)
    PP = gari_matrix(system, gain, P, gamma)
    eig = np.linalg.eigvalsh(PP)
    eP = np.linalg.eigvalsh(P)
    At, _, Ct, *_ = error_system(system, gain)
    rho = ms_spectral_radius(At, Ct)
    gmax = float(eig[-1])
    neg = bool(gmax < 0.0)
    pos = bool(eP[0] > 0.0)
    stable = bool(rho < 1.0)
    scale = float(np.abs(eig).max()) or 1.0
    cond = float(eP[-1] / eP[0]) if eP[0] > 0 else 1e300
    lmi = design_lmi_matrix(system, P1, P2, P[n:, n:] @ _gain(system, gain), gamma)
    (s1, s2), diag = balancing(system, gamma)
    balanced = lmi * np.outer(diag, diag)
    p_bal = min(float(np.linalg.eigvalsh(P[:n, :n])[0]) / s1,
                float(np.linalg.eigvalsh(P[n:, n:])[0]) / s2)
    return DesignCheck(gari_max_eig=gmax, gari_max_eig_relative=gmax / scale,
                       P_min_eig=float(eP[0]), P_condition=min(cond, 1e300),
                       spectral_radius=rho,
                       lmi_max_eig=float(np.linalg.eigvalsh(lmi)[-1]),
                       lmi_balanced_max_eig=float(np.linalg.eigvalsh(balanced)[-1]),
                       P_balanced_min_eig=p_bal,
                       gari_negative_definite=neg,
                       positive_definite=pos, mean_square_stable=stable,
                       ok=neg and pos and stable)


def _require_no_multiplicative_noise(system: StochasticLinearSystem) -> None:
    if np.any(system.A_w) or np.any(system.B_w):
        raise ValueError("plant_block=False needs A_w = B_w = 0: with multiplicative noise "
                         "the error is driven by the plant state (Ct = [[A_w, 0], [A_w, 0]] "
                         "in (46)), so the plant block of (48) is part of the error's "
                         "certificate")


def error_gari_matrix(system: StochasticLinearSystem, gain: npt.ArrayLike, P2: npt.ArrayLike,
                      gamma: float) -> FloatArray:
    """Bounded-real matrix of the error system alone (``A_w = B_w = 0``)::

        [[Ae'P2 Ae - P2 + C_z'C_z,  Ae'P2 Be + C_z'D_z],
         [*,                        Be'P2 Be + D_z'D_z - gamma^2 I]]

    with ``Ae = A - Khat C_y``, ``Be = B - Khat D_y``: the error block of ``PP`` (47) at
    ``P = diag(0, P2)``. Negative definite with ``P2 > 0`` iff (discrete bounded-real
    lemma) ``Ae`` is Schur stable and ``||C_z (zI - Ae)^-1 Be + D_z||_inf < gamma``.

    Parameters
    ----------
    system : StochasticLinearSystem
    gain : array_like, shape (n, n_y)
    P2 : array_like, shape (n, n)
    gamma : float

    Returns
    -------
    ndarray, shape (n + n_v, n + n_v)
        Symmetric.
    """
    s = system
    K = _gain(s, gain)
    P2 = matrix("P2", P2, (s.n, s.n))
    P2 = 0.5 * (P2 + P2.T)
    Ae, Be = s.A - K @ s.C_y, s.B - K @ s.D_y
    top_left = Ae.T @ P2 @ Ae - P2 + s.C_z.T @ s.C_z
    top_right = Ae.T @ P2 @ Be + s.C_z.T @ s.D_z
    bottom = Be.T @ P2 @ Be + s.D_z.T @ s.D_z - float(gamma) ** 2 * np.eye(s.n_v)
    PP = np.block([[top_left, top_right], [top_right.T, bottom]])
    return 0.5 * (PP + PP.T)


def error_block_matrix(system: StochasticLinearSystem, P2: npt.ArrayLike, P_K: npt.ArrayLike,
                       gamma: float) -> FloatArray:
    """The error block of LMI (48) evaluated with numpy (block order ``e, v, At-rows e, z``)::

        [[-P2, 0,       A'P2 - C_y'P_K',  C_z'],
         [*,  -g^2 I,   B'P2 - D_y'P_K',  D_z'],
         [*,   *,      -P2,               0   ],
         [*,   *,       *,               -I   ]]  < 0

    (rows and columns ``x``, ``At``-rows ``x`` and ``Ct``-rows of (48) removed; with
    ``A_w = B_w = 0`` the ``Ct`` rows are zero). By the Schur complement it is
    :func:`error_gari_matrix` ``< 0`` with ``Khat = P2^-1 P_K``.

    Returns
    -------
    ndarray, shape (2n + n_v + n_z, 2n + n_v + n_z)
    """
    s = system
    n, nv, ny, nz = s.n, s.n_v, s.n_y, s.n_z
    P2 = matrix("P2", P2, (n, n))
    PK = matrix("P_K", P_K, (n, ny), labels=("n", "n_y"))
    sizes = [n, nv, n, nz]
    upper = {(0, 0): -P2, (0, 2): s.A.T @ P2 - s.C_y.T @ PK.T, (0, 3): s.C_z.T,
             (1, 1): -float(gamma) ** 2 * np.eye(nv), (1, 2): s.B.T @ P2 - s.D_y.T @ PK.T,
             (1, 3): s.D_z.T, (2, 2): -P2, (3, 3): -np.eye(nz)}
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    M = np.zeros((offsets[-1], offsets[-1]))
    for (i, j), block in upper.items():
        M[offsets[i]:offsets[i + 1], offsets[j]:offsets[j + 1]] = block
        if i != j:
            M[offsets[j]:offsets[j + 1], offsets[i]:offsets[i + 1]] = np.asarray(block).T
    return 0.5 * (M + M.T)


def error_hinf_norm(system: StochasticLinearSystem, gain: npt.ArrayLike, *,
                    rtol: float = 1e-7) -> float:
    """H-infinity norm of the filter's error system ``e+ = Ae e + Be v``,
    ``ztilde = C_z e + D_z v`` (``Ae = A - Khat C_y``, ``Be = B - Khat D_y``), computed
    without the LMI (:func:`filters.analysis.hinf_norm`, symplectic-pencil bisection).

    Meaningful as the filter's attenuation when ``A_w = B_w = 0`` (then the error does not
    depend on the plant state). ``inf`` when ``Ae`` is not Schur stable.

    Parameters
    ----------
    system : StochasticLinearSystem
    gain : array_like, shape (n, n_y)
    rtol : float
        Relative tolerance of the norm.

    Returns
    -------
    float
    """
    from filters.analysis import hinf_norm

    s = system
    K = _gain(s, gain)
    return float(hinf_norm(s.A - K @ s.C_y, s.B - K @ s.D_y, s.C_z, s.D_z, discrete=True,
                           rtol=rtol))


def _check_error_block(system: StochasticLinearSystem, gain: npt.ArrayLike,
                       P2: npt.ArrayLike, gamma: float) -> DesignCheck:
    _require_no_multiplicative_noise(system)
    s = system
    n = s.n
    K = _gain(s, gain)
    P2 = matrix("P2", P2, (n, n))
    P2 = 0.5 * (P2 + P2.T)
    PP = error_gari_matrix(s, K, P2, gamma)
    eig = np.linalg.eigvalsh(PP)
    eP = np.linalg.eigvalsh(P2)
    Ae = s.A - K @ s.C_y
    rho = ms_spectral_radius(Ae, np.zeros_like(Ae))
    gmax = float(eig[-1])
    neg, pos, stable = bool(gmax < 0.0), bool(eP[0] > 0.0), bool(rho < 1.0)
    norm = error_hinf_norm(s, K) if stable else float("inf")
    scale = float(np.abs(eig).max()) or 1.0
    cond = float(eP[-1] / eP[0]) if eP[0] > 0 else 1e300
    lmi = error_block_matrix(s, P2, P2 @ K, gamma)
    (_, s2), diag = balancing(s, gamma, plant_block=False)
    balanced = lmi * np.outer(diag, diag)
    return DesignCheck(gari_max_eig=gmax, gari_max_eig_relative=gmax / scale,
                       P_min_eig=float(eP[0]), P_condition=min(cond, 1e300),
                       spectral_radius=rho, lmi_max_eig=float(np.linalg.eigvalsh(lmi)[-1]),
                       lmi_balanced_max_eig=float(np.linalg.eigvalsh(balanced)[-1]),
                       P_balanced_min_eig=float(eP[0]) / s2,
                       gari_negative_definite=neg, positive_definite=pos,
                       mean_square_stable=stable,
                       ok=neg and pos and stable and bool(norm < float(gamma)),
                       plant_block=False, error_hinf_norm=norm)


# ------------------------------------------------------------------------ design
@dataclass(frozen=True, eq=False)
class LMIHInfDesign:
    """Outcome of one LMI (48) solve: a verified filter, or why there is none.

    Attributes
    ----------
    status : str
        ``"feasible"`` (solver found a solution, :func:`check_design` accepted it and (48)
        holds with at least half the relative margin: solver inaccuracy tolerance),
        ``"infeasible"`` (a solver reported infeasibility and no solver found a verified
        solution; ``solver_status`` tells ``"infeasible"`` from ``"infeasible_inaccurate"``),
        ``"unverified"`` (solutions were returned but the a-posteriori check rejected them,
        with every solver tried) or ``"solver_error"`` (no solver returned anything).
    solver_status : str
        The cvxpy status string of the solver whose result is reported (e.g. ``"optimal"``,
        ``"infeasible"``, ``"optimal_inaccurate"``, or the exception text).
    solver : str or None
        ``"CLARABEL"`` or ``"SCS"``.
    gamma : float
        Attenuation level the LMI was solved for.
    objective : str
        ``"feasibility"`` or ``"h2"`` (``min trace(P1 + P2)``).
    margin : float
        Relative strictness margin used (:func:`balancing`).
    gain : ndarray, shape (n, n_y), or None
        ``Khat = P2^-1 P_K`` (paper's ``Khat``).
    P1, P2 : ndarray, shape (n, n), or None
    P_K : ndarray, shape (n, n_y), or None
    trace : float or None
        ``trace(P1 + P2)``.
    solve_s : float
        Wall time of the solve(s), s (problem construction included when built for this
        call).
    check : DesignCheck or None
        The a-posteriori verification (None when there is no solution).
    fixed_gain : bool
        True for an analysis (:func:`certify_gain`): ``gain`` was given, ``P_K = P2 gain``.
    attempts : tuple of (str, str)
        ``(solver, status or error)`` of every solver call, in order.
    plant_block : bool
        False for an error-block design (``P1`` is None, ``trace`` is ``trace(P2)``).
    """

    status: str
    solver_status: str
    solver: str | None
    gamma: float
    objective: str
    margin: float
    gain: FloatArray | None = None
    P1: FloatArray | None = None
    P2: FloatArray | None = None
    P_K: FloatArray | None = None
    trace: float | None = None
    solve_s: float = 0.0
    check: DesignCheck | None = None
    fixed_gain: bool = False
    attempts: tuple[tuple[str, str], ...] = field(default_factory=tuple)
    plant_block: bool = True

    @property
    def feasible(self) -> bool:
        """True iff a verified solution was found."""
        return self.status == "feasible"

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly summary (arrays as nested lists, no NaN)."""
        def arr(a: FloatArray | None) -> list | None:
            return None if a is None else np.asarray(a).tolist()

        return {
            "status": self.status, "solver_status": self.solver_status, "solver": self.solver,
            "gamma": self.gamma, "objective": self.objective, "margin": self.margin,
            "gain": arr(self.gain), "P1": arr(self.P1), "P2": arr(self.P2),
            "P_K": arr(self.P_K), "trace": self.trace, "solve_s": self.solve_s,
            "check": None if self.check is None else self.check.as_dict(),
            "fixed_gain": self.fixed_gain,
            "attempts": [list(a) for a in self.attempts],
            "plant_block": self.plant_block,
        }


def balancing(system: StochasticLinearSystem, gamma: float | None = None, *,
              plant_block: bool = True) -> tuple[tuple[float, float], FloatArray]:
    """Natural sizes of the unknowns of (48), which define the RELATIVE strictness margin.

    ``s2`` is the mean eigenvalue of the output Gramian ``sum_k A'^k C_z'C_z A^k`` (what
    ``P2`` must dominate); ``s1`` that of ``sum_k A'^k (s2 A_w'A_w) A^k`` (``P1`` is only
    pushed up by the noise coupling; at least ``1e-6 s2``). Both are 1 when ``A`` is not
    Schur stable (then (48) is infeasible anyway). The balancing matrix is
    ``S = diag(s1^-1/2 I, s2^-1/2 I, gamma^-1 I, s1^-1/2 I, s2^-1/2 I, s1^-1/2 I, s2^-1/2 I, I)``
    in the block order of (48): ``S (48) S`` has diagonal blocks of order one.

    Error-block problems (``plant_block=False``, :func:`error_block_matrix`): ``S =
    diag(s2^-1/2 I, gamma^-1 I, s2^-1/2 I, I)`` in the block order ``e, v, At-rows e, z``;
    ``s1 = 1`` (unused); ``s2`` is the output Gramian's mean eigenvalue of the error system
    ``A - K0 C_y`` (whatever ``A``'s stability), ``K0`` the steady-state Kalman predictor gain
    for the noise ``[B; D_y] v`` (regularized by ``1e-9`` of its scale; 1 if that fails).

    Parameters
    ----------
    system : StochasticLinearSystem
    gamma : float, optional
        Scale of the ``v`` block (1 if None).
    plant_block : bool
        False: the error-block problem's sizes and diagonal.

    Returns
    -------
    (s1, s2) : tuple of float
    diag : ndarray, shape (6n + n_v + n_z,), or (2n + n_v + n_z,) without the plant block
        The diagonal of ``S``.
    """
    from scipy.linalg import solve_discrete_lyapunov

    s = system
    n = s.n
    s1 = s2 = 1.0
    if not plant_block:
        s2 = _error_scale(s)
        d2 = 1.0 / np.sqrt(s2)
        dv = 1.0 if gamma is None else 1.0 / float(gamma)
        return (1.0, s2), np.repeat([d2, dv, d2, 1.0], [n, s.n_v, n, s.n_z])
    if np.max(np.abs(np.linalg.eigvals(s.A))) < 1.0:
        try:
            G = solve_discrete_lyapunov(s.A.T, s.C_z.T @ s.C_z)
            W = solve_discrete_lyapunov(s.A.T, s.A_w.T @ s.A_w)
            t2 = float(np.trace(G)) / n
            if np.isfinite(t2) and t2 > 0:
                s2 = t2
                s1 = max(s2 * float(np.trace(W)) / n, 1e-6 * s2)
        except (np.linalg.LinAlgError, ValueError):
            s1 = s2 = 1.0
    d1, d2 = 1.0 / np.sqrt(s1), 1.0 / np.sqrt(s2)
    dv = 1.0 if gamma is None else 1.0 / float(gamma)
    sizes = [n, n, s.n_v, n, n, n, n, s.n_z]
    diag = np.repeat([d1, d2, dv, d1, d2, d1, d2, 1.0], sizes)
    return (s1, s2), diag


def _error_scale(system: StochasticLinearSystem) -> float:
    """``s2`` of an error-block problem (see :func:`balancing`)."""
    from scipy.linalg import solve_discrete_are, solve_discrete_lyapunov

    s = system
    A = s.A
    Q, R, S = s.B @ s.B.T, s.D_y @ s.D_y.T, s.B @ s.D_y.T
    qs = max(float(np.trace(Q)) / s.n, 1e-300)
    rs = max(float(np.trace(R)) / s.n_y, qs)
    Qr, Rr = Q + 1e-9 * qs * np.eye(s.n), R + 1e-9 * rs * np.eye(s.n_y)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # scipy's LinAlgWarning on marginal A
            X = solve_discrete_are(A.T, s.C_y.T, Qr, Rr, s=S)
        K0 = np.linalg.solve(s.C_y @ X @ s.C_y.T + Rr, (A @ X @ s.C_y.T + S).T).T
        Ae = A - K0 @ s.C_y
        if not np.max(np.abs(np.linalg.eigvals(Ae))) < 1.0 - 1e-9:
            return 1.0
        G = solve_discrete_lyapunov(Ae.T, s.C_z.T @ s.C_z)
        t2 = float(np.trace(G)) / s.n
    except (np.linalg.LinAlgError, ValueError):
        return 1.0
    return t2 if np.isfinite(t2) and t2 > 0 else 1.0



def _symmetric_bmat(upper: dict[tuple[int, int], Any], sizes: list[int]) -> Any:
    """The symmetric block matrix (cvxpy expression) whose upper blocks ``(i, j)``, ``i <= j``,
    are ``upper`` (missing blocks zero; the lower ones transposed), symmetrized exactly."""
    import cvxpy as cp

    rows = [[upper[(i, j)] if (i, j) in upper else
             upper[(j, i)].T if (j, i) in upper else np.zeros((ri, cj))
             for j, cj in enumerate(sizes)] for i, ri in enumerate(sizes)]
    lmi = cp.bmat(rows)
    return 0.5 * (lmi + lmi.T)

class _Theorem4Problem:
    """LMI (48), balanced, as a parametrized cvxpy problem (``1/gamma`` is a parameter:
    compile once, re-solve at any gamma).

    Parameters
    ----------
    system : StochasticLinearSystem
    objective : {"feasibility", "h2", "h2-unique"}
        ``"h2-unique"`` adds ``UNIQUE_WEIGHT (|X1|_F^2 + |X2|_F^2 + |Y|_F^2)`` over the
        balanced unknowns to the ``"h2"`` trace: strictly convex, so the solution (and the
        gain) is unique and moves continuously with the data. Without it the trace objective
        leaves the gain undetermined along flat directions, and BLAS rounding (another
        OpenBLAS kernel) moves the solver to another filter.
    margin : float
    fixed_gain : array_like, shape (n, n_y), optional
        Analysis of a given gain: adds ``P_K = P2 gain`` (linear in ``P2``).
    minimize_gamma : bool
        Make ``gamma^2`` a variable and minimize it (:func:`minimal_gamma_sdp`).
    plant_block : bool
        False: the error block of (48) only (:func:`error_block_matrix`, unknowns ``P2``,
        ``P_K``; see :func:`design_lmi_hinf`).
    """

    def __init__(self, system: StochasticLinearSystem, objective: str = "feasibility",
                 margin: float = DEFAULT_MARGIN, fixed_gain: npt.ArrayLike | None = None,
                 minimize_gamma: bool = False, plant_block: bool = True):
        import cvxpy as cp

        if objective not in OBJECTIVES:
            raise ValueError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
        margin = float(margin)
        if not (np.isfinite(margin) and margin >= 0):
            raise ValueError(f"margin must be finite and >= 0, got {margin}")
        self.system = system
        self.objective = objective
        self.margin = margin
        self.plant_block = bool(plant_block)
        self.fixed_gain = None if fixed_gain is None else _gain(system, fixed_gain)
        if not self.plant_block:
            _require_no_multiplicative_noise(system)
        s = system
        n, nv, ny, nz = s.n, s.n_v, s.n_y, s.n_z
        (s1, s2), _ = balancing(s, plant_block=self.plant_block)
        self.scales = (s1, s2)
        # scaled unknowns (X1, X2, Y ~ O(1)): P1 = s1 X1, P2 = s2 X2, P_K = s2 Y
        X1 = cp.Variable((n, n), symmetric=True, name="X1")
        X2 = cp.Variable((n, n), symmetric=True, name="X2")
        Y = cp.Variable((n, ny), name="Y")
        # the balanced LMI S (48) S (see `balancing`) in X1, X2, Y; its v rows and columns
        # carry 1/gamma (a parameter), so its v block is -I; minimize_gamma keeps gamma^2
        # as a variable and leaves the v block unscaled
        if minimize_gamma:
            g2 = cp.Variable(nonneg=True, name="gamma_sq")
            dv: Any = 1.0
            vv: Any = -g2 * np.eye(nv)
        else:
            g2 = None
            dv = cp.Parameter(nonneg=True, name="inv_gamma")
            vv = -np.eye(nv)
        r1, r2 = np.sqrt(s1), np.sqrt(s2)
        AT, AwT = s.A.T, s.A_w.T
        if not self.plant_block:
            self._build_error_block(X2, Y, dv, vv, g2, r2, minimize_gamma)
            return
        sizes = [n, n, nv, n, n, n, n, nz]
        # D P1 D = X1 for the P1-scaled rows/columns (d1^2 s1 = 1), and the cross terms pick
        # up sqrt ratios: d1 d2 s2 = r2 / r1 etc.
        upper: dict[tuple[int, int], Any] = {
            (0, 0): -X1, (0, 3): AT @ X1, (0, 5): AwT @ X1, (0, 6): (r2 / r1) * (AwT @ X2),
            (1, 1): -X2, (1, 4): AT @ X2 - s.C_y.T @ Y.T, (1, 7): s.C_z.T / r2,
            (2, 2): vv, (2, 3): dv * r1 * (s.B.T @ X1),
            (2, 4): dv * r2 * (s.B.T @ X2 - s.D_y.T @ Y.T),
            (2, 5): dv * r1 * (s.B_w.T @ X1), (2, 6): dv * r2 * (s.B_w.T @ X2),
            (2, 7): dv * s.D_z.T,
            (3, 3): -X1, (4, 4): -X2, (5, 5): -X1, (6, 6): -X2, (7, 7): -np.eye(nz),
        }
        lmi = _symmetric_bmat(upper, sizes)
        cons = [lmi << -margin * np.eye(sum(sizes)), X1 >> margin * np.eye(n),
                X2 >> margin * np.eye(n)]
        if self.fixed_gain is not None:
            cons.append(Y == X2 @ self.fixed_gain)
        if minimize_gamma:
            obj = cp.Minimize(g2)
        elif objective == "feasibility":
            obj = cp.Minimize(0)
        elif objective == "h2":
            obj = cp.Minimize(cp.trace(s1 * X1 + s2 * X2) / (n * s2))
        else:
            obj = cp.Minimize(cp.trace(s1 * X1 + s2 * X2) / (n * s2) + UNIQUE_WEIGHT * (
                cp.sum_squares(X1) + cp.sum_squares(X2) + cp.sum_squares(Y)))
        self._inv_gamma = None if minimize_gamma else dv
        self._problem = cp.Problem(obj, cons)
        self._vars = (X1, X2, Y)
        self._lock = threading.Lock()
        self._g2 = g2

    def _build_error_block(self, X2: Any, Y: Any, dv: Any, vv: Any, g2: Any, r2: float,
                           minimize_gamma: bool) -> None:
        """The balanced error block ``S (error_block_matrix) S`` (see :func:`balancing`)."""
        import cvxpy as cp

        s = self.system
        n, nv, nz = s.n, s.n_v, s.n_z
        sizes = [n, nv, n, nz]
        upper: dict[tuple[int, int], Any] = {
            (0, 0): -X2, (0, 2): s.A.T @ X2 - s.C_y.T @ Y.T, (0, 3): s.C_z.T / r2,
            (1, 1): vv, (1, 2): dv * r2 * (s.B.T @ X2 - s.D_y.T @ Y.T), (1, 3): dv * s.D_z.T,
            (2, 2): -X2, (3, 3): -np.eye(nz),
        }
        lmi = _symmetric_bmat(upper, sizes)
        margin = self.margin
        cons = [lmi << -margin * np.eye(sum(sizes)), X2 >> margin * np.eye(n)]
        if self.fixed_gain is not None:
            cons.append(Y == X2 @ self.fixed_gain)
        if minimize_gamma:
            obj = cp.Minimize(g2)
        elif self.objective == "feasibility":
            obj = cp.Minimize(0)
        elif self.objective == "h2":
            obj = cp.Minimize(cp.trace(X2) / n)
        else:
            obj = cp.Minimize(cp.trace(X2) / n + UNIQUE_WEIGHT * (
                cp.sum_squares(X2) + cp.sum_squares(Y)))
        self._inv_gamma = None if minimize_gamma else dv
        self._problem = cp.Problem(obj, cons)
        self._vars = (None, X2, Y)
        self._lock = threading.Lock()
        self._g2 = g2

    def solve(self, gamma: float, solvers: tuple[str, ...] = _SOLVERS, *,
              search: bool = False) -> LMIHInfDesign:
        """Thread-safe wrapper of :meth:`_solve` (the compiled problem is shared)."""
        with self._lock:
            return self._solve(gamma, solvers, search=search)

    def _solve(self, gamma: float, solvers: tuple[str, ...] = _SOLVERS, *,
               search: bool = False) -> LMIHInfDesign:
        """Solve at ``gamma`` and verify; see :class:`LMIHInfDesign`.

        Solver policy: a solver's ``"infeasible"`` is final. The next solver is tried after
        an exception, an ``"infeasible_inaccurate"``, no solution, or a solution the check
        rejects. With ``search=True`` (the bisection) ``"infeasible_inaccurate"`` is final
        too and SCS runs with a 2500-iteration cap: near the boundary CLARABEL often reports
        it or fails, and a full SCS fallback costs ~0.3 s per call.
        """
        import cvxpy as cp

        gamma = float(gamma)
        if not (np.isfinite(gamma) and gamma > 0):
            raise ValueError(f"gamma must be a positive finite number, got {gamma}")
        if self._inv_gamma is not None:
            self._inv_gamma.value = 1.0 / gamma
        start = time.perf_counter()
        attempts: list[tuple[str, str]] = []
        reported: LMIHInfDesign | None = None
        infeasible: LMIHInfDesign | None = None
        for solver in solvers:
            options = (_SEARCH_OPTIONS if search else _UNIQUE_OPTIONS
                       if self.objective == "h2-unique" else _SOLVER_OPTIONS).get(solver, {})
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)  # "may be inaccurate"
                    self._problem.solve(solver=solver, **options)
                status = str(self._problem.status)
            except (cp.error.SolverError, ValueError, ArithmeticError) as exc:
                attempts.append((solver, f"error: {exc}"))
                continue
            except BaseException as exc:  # noqa: BLE001 (a Rust solver's panic, see below)
                # CLARABEL's Rust panics (pyo3 PanicException, a BaseException: measured with
                # OPENBLAS_CORETYPE=Haswell, "Eigval error" in its eigen-decomposition) are a
                # solver failure like any other: the next solver is tried
                if type(exc).__name__ != "PanicException":
                    raise
                attempts.append((solver, f"error: solver panic: {exc}"))
                continue
            attempts.append((solver, status))
            if status.startswith("infeasible"):
                infeasible = infeasible or self._result("infeasible", status, solver, gamma)
                if status == "infeasible" or search:
                    break
                continue
            X1, X2, Y = (None if v is None else v.value for v in self._vars)
            if (self.plant_block and X1 is None) or X2 is None or Y is None or not (
                    (X1 is None or np.isfinite(X1).all()) and np.isfinite(X2).all()
                    and np.isfinite(Y).all()):
                continue
            s1, s2 = self.scales
            P1 = None if X1 is None else s1 * X1
            P2, PK = s2 * X2, s2 * Y
            result = self._verified(P1, P2, PK, status, solver, gamma)
            if result.feasible:
                reported = result
                break
            if reported is None:
                reported = result  # keep the first unverified solution, try the next solver
        elapsed = time.perf_counter() - start
        if reported is None or (not reported.feasible and infeasible is not None):
            reported = infeasible
        if reported is None:
            last = attempts[-1][1] if attempts else "not run"
            reported = self._result("solver_error", last, None, gamma)
        return _replace(reported, solve_s=elapsed, attempts=tuple(attempts))

    def _result(self, status: str, solver_status: str, solver: str | None,
                gamma: float) -> LMIHInfDesign:
        return LMIHInfDesign(status=status, solver_status=solver_status, solver=solver,
                             gamma=gamma, objective=self.objective, margin=self.margin,
                             fixed_gain=self.fixed_gain is not None,
                             plant_block=self.plant_block)

    def _verified(self, P1: FloatArray | None, P2: FloatArray, PK: FloatArray,
                  solver_status: str, solver: str, gamma: float) -> LMIHInfDesign:
        P1 = None if P1 is None else 0.5 * (P1 + P1.T)
        P2 = 0.5 * (P2 + P2.T)
        if self.fixed_gain is not None:
            gain = self.fixed_gain.copy()
        else:
            try:
                gain = np.linalg.solve(P2, PK)
            except np.linalg.LinAlgError:
                return self._result("unverified", solver_status, solver, gamma)
        if not np.isfinite(gain).all():
            return self._result("unverified", solver_status, solver, gamma)
        check = check_design(self.system, gain, P1, P2, gamma, plant_block=self.plant_block)
        # the certificate (check.ok) and the margin the problem was posed with (half of it
        # tolerated for solver inaccuracy), so gamma_min does not depend on the solver used
        half = 0.5 * self.margin
        ok = (check.ok and check.lmi_balanced_max_eig <= -half
              and check.P_balanced_min_eig >= half)
        return LMIHInfDesign(status="feasible" if ok else "unverified",
                             solver_status=solver_status, solver=solver, gamma=gamma,
                             objective=self.objective, margin=self.margin,
                             gain=readonly(gain), P1=None if P1 is None else readonly(P1),
                             P2=readonly(P2), P_K=readonly(np.array(PK)),
                             trace=float(np.trace(P2) + (0.0 if P1 is None else np.trace(P1))),
                             check=check, fixed_gain=self.fixed_gain is not None,
                             plant_block=self.plant_block)


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_CACHE_LOCK = threading.Lock()


def _problem(system: StochasticLinearSystem, objective: str, margin: float,
             fixed_gain: npt.ArrayLike | None = None,
             plant_block: bool = True) -> _Theorem4Problem:
    """The compiled problem for ``system`` (cached while the system object lives).

    cvxpy's canonicalization costs 20-60 ms; re-solving a compiled problem at another gamma
    costs 3-10 ms. The cache is keyed by the system OBJECT (systems are immutable), the
    objective, the margin, the fixed gain's bytes and ``plant_block``.
    """
    gain = None if fixed_gain is None else _gain(system, fixed_gain)
    key = (objective, float(margin), None if gain is None else gain.tobytes(),
           bool(plant_block))
    with _CACHE_LOCK:
        per_system = _CACHE.setdefault(system, {})
        problem = per_system.get(key)
        if problem is None:
            problem = _Theorem4Problem(system, objective, margin, fixed_gain=gain,
                                       plant_block=plant_block)
            if len(per_system) >= 16:
                per_system.pop(next(iter(per_system)))
            per_system[key] = problem
    return problem


def _replace(design: LMIHInfDesign, **changes: Any) -> LMIHInfDesign:
    import dataclasses

    return dataclasses.replace(design, **changes)


def design_lmi_hinf(system: StochasticLinearSystem, gamma: float, *,
                    objective: str = "feasibility", margin: float = DEFAULT_MARGIN,
                    solvers: tuple[str, ...] = _SOLVERS,
                    plant_block: bool = True) -> LMIHInfDesign:
    """Design the filter (45) by Theorem 4: solve LMI (48) at ``gamma`` and verify.

    Parameters
    ----------
    system : StochasticLinearSystem
    gamma : float
        Attenuation level (> 0).
    objective : {"feasibility", "h2", "h2-unique"}
        ``"feasibility"``: any solution of (48); ``"h2-unique"``: ``"h2"`` made strictly
        convex (see :class:`_Theorem4Problem`); ``"h2"``: the suboptimal mixed
        H2/H-infinity filter, ``min trace(P1 + P2)`` subject to (48).
    margin : float
        Relative strictness margin: ``S (48) S <= -margin I``, ``P_i >= margin s_i I``
        (:func:`balancing`).
    solvers : tuple of str
        cvxpy solvers tried in order (default CLARABEL, then SCS).
    plant_block : bool
        False: solve the error block of (48) only (:func:`error_block_matrix`; needs
        ``A_w = B_w = 0``). See Notes.

    Returns
    -------
    LMIHInfDesign
        ``feasible`` is True only if the a-posteriori :func:`check_design` passed;
        ``solve_s`` includes building the cvxpy problem (20-60 ms) unless one was compiled
        for this system object, objective and margin before (then 3-10 ms).

    Raises
    ------
    ValueError
        ``plant_block=False`` with multiplicative noise (``A_w`` or ``B_w`` nonzero).

    Notes
    -----
    Why the plant block is optional without multiplicative noise. With ``A_w = B_w = 0``,
    ``Ct = Dt = 0`` in (46) and ``At = diag(A, A - Khat C_y)``: the error
    ``e = x - xhat`` obeys ``e+ = (A - Khat C_y) e + (B - Khat D_y) v``,
    ``ztilde = C_z e + D_z v``, whatever the plant state (the filter knows every input
    that is not ``v``; in a closed loop, whatever the controller does). In (47) with
    ``P = diag(P1, P2)`` the ``x`` rows hold ``A'P1 A - P1`` and couple to ``v`` only through
    ``B'P1 B >= 0``; so:

    * (48) feasible  =>  ``A'P1 A - P1 < 0`` (``A`` Schur stable) and the error block
      (:func:`error_block_matrix`) feasible with the same ``P2, P_K, gamma`` (a principal
      submatrix of ``PP``, minus ``B'P1 B``);
    * ``A`` Schur stable and the error block strictly feasible  =>  (48) feasible with
      ``P1 = eps X``, ``A'X A - X = -I``, for ``eps`` small enough (the Schur complement
      of the ``x`` block adds ``O(eps)`` to the ``v`` block).

    The plant block therefore certifies nothing but the plant's own stability; the error
    block alone is the discrete bounded-real lemma for the error system (with the change of
    variables ``P_K = P2 Khat``): ``||ztilde||_2^2 <= gamma^2 ||v||_2^2 + e_0'P2 e_0`` and
    ``A - Khat C_y`` Schur stable. It is the right design when the plant is not Schur
    stable (free integrators under a feedback controller): Theorem 4 as printed is then
    infeasible though the filter's error is certified. On a stable plant both give the same
    infimum of gamma (up to the margins and the solver's accuracy). The verification
    (:func:`check_design` with ``plant_block=False``) adds the error system's H-infinity
    norm computed without the LMI (``error_hinf_norm < gamma``).
    """
    start = time.perf_counter()
    problem = _problem(system, objective, margin, plant_block=plant_block)
    result = problem.solve(gamma, solvers)
    return _replace(result, solve_s=time.perf_counter() - start)


def certify_gain(system: StochasticLinearSystem, gain: npt.ArrayLike, gamma: float, *,
                 objective: str = "feasibility", margin: float = DEFAULT_MARGIN,
                 solvers: tuple[str, ...] = _SOLVERS,
                 plant_block: bool = True) -> LMIHInfDesign:
    """Analysis of a given gain: find ``P1, P2`` satisfying (48) with ``P_K = P2 gain``.

    Parameters
    ----------
    system : StochasticLinearSystem
    gain : array_like, shape (n, n_y)
        E.g. a printed ``Khat``.
    gamma, objective, margin, solvers, plant_block
        As in :func:`design_lmi_hinf`.

    Returns
    -------
    LMIHInfDesign
        With ``fixed_gain=True``; feasible iff Theorem 4 (block-diagonal ``P``) certifies
        the gain at ``gamma`` (verified a posteriori).
    """
    start = time.perf_counter()
    problem = _problem(system, objective, margin, fixed_gain=gain, plant_block=plant_block)
    result = problem.solve(gamma, solvers)
    return _replace(result, solve_s=time.perf_counter() - start)


# ---------------------------------------------------------------------- gamma search
@dataclass(frozen=True, eq=False)
class GammaSearch:
    """Result of the bisection for the smallest feasible ``gamma``.

    Attributes
    ----------
    gamma_min : float or None
        Smallest verified-feasible ``gamma`` found (None: none up to ``gamma_max``).
    lower : float
        Largest ``gamma`` found infeasible (or not verified); ``gamma_min / lower - 1 <=
        rtol`` on success. 0 if the search hit ``gamma_floor`` while still feasible.
    rtol : float
        Requested relative tolerance.
    design : LMIHInfDesign or None
        The (feasibility) solution at ``gamma_min``.
    iterations : int
        LMI solves performed.
    history : tuple of (float, bool)
        ``(gamma, feasible)`` of every solve, in order.
    wall_s : float
        Total wall time including building the problem, s.
    status : str
        ``"converged"``, ``"infeasible"`` (no feasible gamma up to ``gamma_max``) or
        ``"at_floor"`` (feasible down to ``gamma_floor``: the disturbance barely reaches
        the output).
    """

    gamma_min: float | None
    lower: float
    rtol: float
    design: LMIHInfDesign | None
    iterations: int
    history: tuple[tuple[float, bool], ...]
    wall_s: float
    status: str

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly summary (without the design's matrices)."""
        return {"gamma_min": self.gamma_min, "lower": self.lower, "rtol": self.rtol,
                "iterations": self.iterations, "wall_s": self.wall_s, "status": self.status,
                "history": [list(h) for h in self.history]}


def _bisect(solve: Callable[[float], LMIHInfDesign], gamma_start: float, rtol: float,
            gamma_max: float, gamma_floor: float, max_iter: int) -> tuple:
    history: list[tuple[float, bool]] = []
    best: LMIHInfDesign | None = None

    def feasible(g: float) -> bool:
        nonlocal best
        d = solve(g)
        history.append((g, d.feasible))
        if d.feasible and (best is None or g <= best.gamma):
            best = d
        return d.feasible

    g = gamma_start
    if feasible(g):
        hi, lo = g, None
        while lo is None and len(history) < max_iter:
            g = hi / _BRACKET
            if g < gamma_floor:
                return hi, 0.0, best, history, "at_floor"
            if feasible(g):
                hi = g
            else:
                lo = g
    else:
        lo, hi = g, None
        while hi is None and len(history) < max_iter:
            g = lo * _BRACKET
            if g > gamma_max:
                return None, lo, None, history, "infeasible"
            if feasible(g):
                hi = g
            else:
                lo = g
    if lo is None or hi is None:
        return hi, lo or 0.0, best, history, "max_iter"
    while hi / lo - 1.0 > rtol and len(history) < max_iter:
        mid = float(np.sqrt(lo * hi))
        if feasible(mid):
            hi = mid
        else:
            lo = mid
    status = "converged" if hi / lo - 1.0 <= rtol else "max_iter"
    return hi, lo, best, history, status


def _search(problem: _Theorem4Problem, start: float, rtol: float, gamma_start: float | None,
            gamma_max: float, gamma_floor: float, max_iter: int,
            solvers: tuple[str, ...]) -> GammaSearch:
    rtol = float(rtol)
    if not (np.isfinite(rtol) and rtol > 0):
        raise ValueError(f"rtol must be a positive finite number, got {rtol}")
    g0 = 1.0 if gamma_start is None else float(gamma_start)
    if not (np.isfinite(g0) and g0 > 0):
        raise ValueError(f"gamma_start must be positive and finite, got {gamma_start}")
    hi, lo, best, history, status = _bisect(
        lambda g: problem.solve(g, solvers, search=True), g0, rtol,
        gamma_max, gamma_floor, max_iter)
    return GammaSearch(gamma_min=hi, lower=float(lo), rtol=rtol, design=best,
                       iterations=len(history), history=tuple(history),
                       wall_s=time.perf_counter() - start, status=status)


def design_above(system: StochasticLinearSystem, gamma_min: float, factor: float = 1.1, *,
                 objective: str = "h2", margin: float = DEFAULT_MARGIN, max_doublings: int = 10,
                 plant_block: bool = True) -> tuple[LMIHInfDesign, int]:
    """The design at ``gamma = factor * 2^j * gamma_min`` for the smallest ``j`` that verifies.

    Near ``gamma_min`` the minimum-trace (mixed H2/H-infinity) solution can be too
    ill-conditioned for the solver to return a solution that passes the a-posteriori check;
    doubling gamma moves away from the boundary.

    Returns
    -------
    design : LMIHInfDesign
        The first verified design (or the last attempt, not feasible).
    j : int
        Number of doublings used.
    """
    design = design_lmi_hinf(system, factor * gamma_min, objective=objective, margin=margin,
                             plant_block=plant_block)
    j = 0
    while not design.feasible and j < max_doublings:
        j += 1
        design = design_lmi_hinf(system, factor * 2.0**j * gamma_min, objective=objective,
                                 margin=margin, plant_block=plant_block)
    return design, j


def gamma_grid(gamma_floor: float, count: int) -> list[float]:
    """The first ``count`` values ``m 10^k >= gamma_floor`` with ``m`` in ``GRID_MANTISSAS``."""
    gamma_floor = float(gamma_floor)
    if not (np.isfinite(gamma_floor) and gamma_floor > 0):
        raise ValueError(f"gamma_floor must be positive and finite, got {gamma_floor}")
    k = int(np.floor(np.log10(gamma_floor))) - 1
    out: list[float] = []
    while len(out) < count:
        for m in GRID_MANTISSAS:
            g = float(f"{m}e{k}")
            if g >= gamma_floor * (1.0 - 1e-12) and len(out) < count:
                out.append(g)
        k += 1
    return out


def design_on_grid(system: StochasticLinearSystem, gamma_floor: float, *,
                   objective: str = "h2-unique", margin: float = DEFAULT_MARGIN,
                   max_steps: int = 12, plant_block: bool = True
                   ) -> tuple[LMIHInfDesign, int]:
    """The design at the smallest grid level ``gamma >= gamma_floor`` (1, 2, 5 per decade)
    that verifies.

    Why a grid: ``gamma_floor`` (typically ``factor * gamma_min``) moves in its last digits
    with BLAS rounding, and near ``gamma_min`` the solvers return ``"optimal_inaccurate"``
    points whose verification is a coin toss. A fixed grid makes the chosen ``gamma`` the
    same on every machine; with the strictly convex ``"h2-unique"`` objective the gain is
    then the same up to the solver's accuracy (keep ``gamma_floor`` a few times
    ``gamma_min``: measured on the vehicle roll rig, a gain entry moves by 30 % between
    OpenBLAS kernels at 2 ``gamma_min`` and by 5e-5 at 9 ``gamma_min``).

    Returns
    -------
    design : LMIHInfDesign
        The first verified design (or the last attempt, not feasible).
    step : int
        Index of the chosen grid level (0: the first level at or above ``gamma_floor``).
    """
    design = None
    for step, gamma in enumerate(gamma_grid(gamma_floor, max_steps)):
        design = design_lmi_hinf(system, gamma, objective=objective, margin=margin,
                                 plant_block=plant_block)
        if design.feasible:
            return design, step
    assert design is not None
    return design, max_steps - 1


def minimal_gamma(system: StochasticLinearSystem, *, rtol: float = DEFAULT_RTOL,
                  gamma_start: float | None = None, gamma_max: float = 1e8,
                  gamma_floor: float = 1e-8, margin: float = DEFAULT_MARGIN,
                  max_iter: int = 200, solvers: tuple[str, ...] = _SOLVERS,
                  gain: npt.ArrayLike | None = None, plant_block: bool = True) -> GammaSearch:
    """Smallest ``gamma`` for which LMI (48) is feasible (verified), by bisection.

    Bracketing: from ``gamma_start`` (default 1) divide by 10 while feasible or multiply by
    10 while infeasible; then bisect geometrically until ``gamma_min / lower - 1 <= rtol``. Only
    verified solutions (:func:`check_design`) count as feasible, so ``gamma_min`` is always a
    certified level; the true infimum of (48) lies in ``[lower, gamma_min]`` up to the
    margin and the solver's accuracy.

    Parameters
    ----------
    system : StochasticLinearSystem
    rtol : float
        Relative tolerance of the bracket.
    gamma_start : float, optional
        First level tried.
    gamma_max, gamma_floor : float
        Search limits (``status`` tells when one was hit).
    margin : float
        Relative strictness margin (see :func:`design_lmi_hinf`).
    max_iter : int
        Maximum number of LMI solves.
    solvers : tuple of str
    gain : array_like, shape (n, n_y), optional
        Search for a fixed gain instead (analysis, :func:`certify_gain`).
    plant_block : bool
        False: the error block only (see :func:`design_lmi_hinf`).

    Returns
    -------
    GammaSearch
    """
    start = time.perf_counter()
    problem = _problem(system, "feasibility", margin, fixed_gain=gain, plant_block=plant_block)
    return _search(problem, start, rtol, gamma_start, gamma_max, gamma_floor, max_iter,
                   solvers)


def minimal_gamma_sdp(system: StochasticLinearSystem, *, margin: float = 0.0,
                      gain: npt.ArrayLike | None = None, solver: str = "CLARABEL",
                      plant_block: bool = True) -> tuple[float | None, str]:
    """Cross-check of :func:`minimal_gamma`: ``min gamma^2`` s.t. (48) as one SDP.

    ``gamma^2`` enters (48) linearly, so the infimum is a single semidefinite program. The
    optimum sits on the boundary of the feasible set, where the solution is not strictly
    feasible: use it as a number to compare with, not as a design. Here the ``v`` block is
    not balanced (``gamma`` is the unknown), so with ``margin > 0`` that block's margin is
    absolute; the default ``margin = 0`` gives the infimum itself (to solver accuracy, about
    1e-4 in gamma on badly scaled problems).

    Parameters
    ----------
    system : StochasticLinearSystem
    margin : float
    gain : array_like, shape (n, n_y), optional
        Fixed gain (analysis) instead of a design.
    solver : str
    plant_block : bool
        False: the error block only (see :func:`design_lmi_hinf`).

    Returns
    -------
    gamma : float or None
        ``sqrt`` of the optimal ``gamma^2`` (None if not solved).
    status : str
        cvxpy status (or the solver error).
    """
    import cvxpy as cp

    problem = _Theorem4Problem(system, "feasibility", margin, fixed_gain=gain,
                               minimize_gamma=True, plant_block=plant_block)
    try:
        problem._problem.solve(solver=solver, **_SOLVER_OPTIONS.get(solver, {}))
    except cp.error.SolverError as exc:
        return None, f"error: {exc}"
    value = problem._g2.value
    if value is None or not np.isfinite(value):
        return None, str(problem._problem.status)
    return float(np.sqrt(max(float(value), 0.0))), str(problem._problem.status)


# --------------------------------------------------------------------- moments
def output_error_moments(system: StochasticLinearSystem, gain: npt.ArrayLike,
                         x0: npt.ArrayLike, xhat0: npt.ArrayLike, v: npt.ArrayLike
                         ) -> FloatArray:
    """Exact ``E|ztilde_k|^2`` of (46) for a deterministic ``x0``, ``xhat0`` and ``v_k``.

    Propagates the mean ``m_k = E eta_k`` and second moment ``S_k = E eta_k eta_k'``::

        m+ = At m + Bt v
        S+ = At S At' + Ct S Ct' + (At m v' Bt' + Ct m v' Dt' + transposes)
             + Bt v v' Bt' + Dt v v' Dt'                       (E w = 0, E w^2 = 1)
        E|ztilde|^2 = tr(Gt S Gt') + 2 v' Mt' Gt m + |Mt v|^2

    Parameters
    ----------
    system : StochasticLinearSystem
    gain : array_like, shape (n, n_y)
    x0, xhat0 : array_like, shape (n,)
        True initial state and the filter's initial estimate.
    v : array_like, shape (N, n_v) or (N,)
        Disturbance ``v_0 .. v_{N-1}``.

    Returns
    -------
    ndarray, shape (N,)
        ``E|ztilde_k|^2`` for ``k = 0 .. N-1`` (cumulative sums: ``numpy.cumsum``).
    """
    At, Bt, Ct, Dt, Gt, Mt = error_system(system, gain)
    x0 = to_float_array("x0", x0)
    xhat0 = to_float_array("xhat0", xhat0)
    n = system.n
    if x0.shape != (n,) or xhat0.shape != (n,):
        raise ValueError(f"x0 and xhat0 must have shape ({n},), got {x0.shape}, "
                         f"{xhat0.shape}")
    v = to_float_array("v", v)
    if v.ndim == 1:
        v = v[:, None]
    if v.ndim != 2 or v.shape[1] != system.n_v or not np.isfinite(v).all():
        raise ValueError(f"v must be finite with shape (N, {system.n_v}), got {v.shape}")
    m = np.concatenate([x0, x0 - xhat0])
    S = np.outer(m, m)
    out = np.empty(len(v))
    for k, vk in enumerate(v):
        zm = Gt @ m
        out[k] = float(np.trace(Gt @ S @ Gt.T) + 2.0 * (Mt @ vk) @ zm + (Mt @ vk) @ (Mt @ vk))
        Bv, Dv = Bt @ vk, Dt @ vk
        Am, Cm = At @ m, Ct @ m
        cross = np.outer(Am, Bv) + np.outer(Cm, Dv)
        S = At @ S @ At.T + Ct @ S @ Ct.T + cross + cross.T + np.outer(Bv, Bv) \
            + np.outer(Dv, Dv)
        S = 0.5 * (S + S.T)
        m = Am + Bv
    return out


# ------------------------------------------------------------------------ filter
class LMIHInfFilter(_SampledFilter):
    """The filter (45) as an in-the-loop estimator (``name = "lmi-hinf"``).

    ``xhat_{k+1} = A xhat_k + Khat (y_k - C_y xhat_k)`` (45, with ``A xhat_k``), written
    ``xhat_{k+1} = F xhat_k + G y_k`` with ``F = A - Khat C_y``, ``G = Khat``; optionally a
    known input ``u_k`` (applied over ``[k, k+1]``) adds ``B_u u_k`` and its feedthrough
    ``D_u u`` is removed from the measurement (not in the paper: used on the rig when the
    lateral acceleration is known).

    Timing: ``step(y_{k+1}, u_k)`` is called with the measurement at the END of the
    interval (the testbed convention), but (45) uses ``y_k`` to form ``xhat_{k+1}``. The
    filter therefore keeps the last measurement pending: ``step`` returns ``xhat_{k+1}``
    computed from the pending ``y_k`` and stores ``y_{k+1}``. The measurement at reset,
    ``y_0``, is given with :meth:`prime`; without it the first step is a pure prediction,
    ``xhat_1 = A xhat_0 (+ B_u u_0)`` (e.g. :class:`~testbed.envs.wrappers.FilterInLoop` does not
    pass ``y_0`` to estimators today).

    Parameters
    ----------
    A : array_like, shape (n, n)
        Model state matrix (paper ``A``).
    C_y : array_like, shape (n_y, n)
        Measurement matrix (paper ``K``).
    gain : array_like, shape (n, n_y)
        ``Khat``.
    x0 : array_like, shape (n,) or (..., n), optional
        Initial estimate (default 0, as in the paper); leading axes: a batch of filters.
    C_z : array_like, shape (n_z, n), optional
        Output matrix of ``zhat = C_z xhat`` (default identity).
    input_matrix : array_like, shape (n, k), optional
        ``B_u`` of a known input (default: none, ``u`` is ignored).
    feedthrough : array_like, shape (n_y, k), optional
        ``D_u`` of the known input in ``y``.
    dt_s : float, optional
        Sample period (``t_s = steps * dt_s``; steps if None).

    Attributes
    ----------
    name : str
        ``"lmi-hinf"``.
    x : ndarray, shape (..., n)
        ``xhat_k`` (read-only).
    P : None
        The filter has no covariance.
    z : ndarray, shape (..., n_z)
        ``zhat_k = C_z xhat_k``.
    """

    name: ClassVar[str] = "lmi-hinf"

    def __init__(self, A: npt.ArrayLike, C_y: npt.ArrayLike, gain: npt.ArrayLike,
                 x0: npt.ArrayLike | None = None, *, C_z: npt.ArrayLike | None = None,
                 input_matrix: npt.ArrayLike | None = None,
                 feedthrough: npt.ArrayLike | None = None, dt_s: float | None = None):
        A = matrix("A", A, (None, None), what="a finite square matrix")
        n = A.shape[0]
        if A.shape != (n, n) or n == 0:
            raise ValueError(f"A must be a finite square matrix, got shape {A.shape}")
        C_y = matrix("C_y", C_y, (None, n), labels=("n_y", "n"))
        m = C_y.shape[0]
        K = matrix("gain", gain, (n, m), labels=("n", "n_y"))
        self.A, self.C_y = readonly(A), readonly(C_y)
        self._AT = np.ascontiguousarray(A.T)
        self._setup(A - K @ C_y, K, C_z, input_matrix, feedthrough, dt_s, x0)

    @classmethod
    def from_state_space(cls, F: npt.ArrayLike, G: npt.ArrayLike,
                         x0: npt.ArrayLike | None = None, **kwargs: Any) -> LMIHInfFilter:
        """A filter ``xhat_{k+1} = F xhat_k + G y_k`` given directly (e.g. the paper's (50)).

        Parameters
        ----------
        F : array_like, shape (n, n)
        G : array_like, shape (n, n_y)
        x0 : array_like, optional
        **kwargs
            ``C_z``, ``input_matrix``, ``feedthrough``, ``dt_s`` as in the constructor.
        """
        F = matrix("F", F, (None, None), what="a finite square matrix")
        n = F.shape[0]
        G = matrix("G", G, (n, None), labels=("n", "n_y"))
        return cls(F, np.zeros((G.shape[1], n)), G, x0, **kwargs)

    @classmethod
    def from_design(cls, system: StochasticLinearSystem, design: LMIHInfDesign | npt.ArrayLike,
                    x0: npt.ArrayLike | None = None, **kwargs: Any) -> LMIHInfFilter:
        """The filter (45) of ``system`` with the gain of a design (or a gain array).

        Raises
        ------
        ValueError
            If the design is not feasible (no gain).
        """
        gain = design.gain if isinstance(design, LMIHInfDesign) else design
        if gain is None:
            raise ValueError(f"design has no gain (status {design.status!r})")  # type: ignore[union-attr]
        kwargs.setdefault("C_z", system.C_z)
        return cls(system.A, system.C_y, gain, x0, **kwargs)

    def _setup(self, F: FloatArray, G: FloatArray, C_z: npt.ArrayLike | None,
               input_matrix: npt.ArrayLike | None, feedthrough: npt.ArrayLike | None,
               dt_s: float | None, x0: npt.ArrayLike | None) -> None:
        n, m = G.shape
        self._n, self._m = n, m
        self.F, self.G = readonly(F), readonly(G)
        self._FT = np.ascontiguousarray(F.T)
        self._GT = np.ascontiguousarray(G.T)
        self.C_z = readonly(np.eye(n) if C_z is None else matrix("C_z", C_z, (None, n),
                                                                  labels=("n_z", "n")))
        if input_matrix is None:
            if feedthrough is not None:
                raise ValueError("feedthrough needs input_matrix (the known input's B_u)")
            self._k = 0
            self._Bu = None
            self._DuT = None
        else:
            Bu = matrix("input_matrix", input_matrix, (n, None), labels=("n", "k"))
            self._k = Bu.shape[1]
            self._Bu = readonly(Bu)
            self._BuT = np.ascontiguousarray(Bu.T)
            Du = None if feedthrough is None else matrix(
                "feedthrough", feedthrough, (m, self._k), labels=("n_y", "k"))
            self._DuT = None if Du is None or not np.any(Du) else np.ascontiguousarray(Du.T)
        self._dt = None if dt_s is None else positive_time("dt_s", dt_s)
        self.reset(np.zeros(n) if x0 is None else x0)

    # ------------------------------------------------------------------ state
    def reset(self, x0: npt.ArrayLike, P0: object = None) -> None:
        """Re-initialize ``xhat``, drop the pending measurement, ``t_s = 0``.

        Parameters
        ----------
        x0 : array_like, shape (n,) or (..., n)
            Initial estimate; leading axes define the batch.
        P0 : ignored
            Accepted for the :class:`~filters.base.Estimator` protocol (the filter has no
            covariance).

        Raises
        ------
        ValueError
            ``x0`` has the wrong shape or is non-finite (state unchanged).
        """
        n = self._n
        x = to_float_array("x0", x0)
        if x.ndim < 1 or x.shape[-1] != n:
            raise ValueError(f"x0 must have shape ({n},) or (..., {n}), got shape {x.shape}")
        if not np.isfinite(x).all():
            raise ValueError(f"x0 must be finite with shape (..., {n}), got non-finite entries")
        self._batch = x.shape[:-1]
        self._x = readonly(x)
        self._P = None  # type: ignore[assignment]
        self._pending: FloatArray | None = None
        self._steps = 0
        self.innovation: FloatArray | None = None

    @property
    def P(self) -> None:  # type: ignore[override]
        """None: the H-infinity filter (45) carries no covariance."""
        return None

    @property
    def z(self) -> FloatArray:
        """Estimated output ``zhat = C_z xhat``, shape ``(..., n_z)``."""
        return np.vecmat(self._x, self.C_z.T)

    @property
    def pending_measurement(self) -> FloatArray | None:
        """The measurement ``y_k`` (feedthrough removed) that the next step uses."""
        return self._pending

    def prime(self, y0: npt.ArrayLike, u: npt.ArrayLike | None = None) -> None:
        """Give the measurement ``y_0`` taken at reset (used by the first :meth:`step`).

        Parameters
        ----------
        y0 : array_like, shape (n_y,) or (..., n_y)
        u : array_like, optional
            Input acting at ``t_0`` for the feedthrough (default none).
        """
        y = self._vector("y0", y0, self._m)
        u = self._input(u)
        self._pending = self._corrected(y, u)

    def _corrected(self, y: FloatArray, u: FloatArray | None) -> FloatArray:
        if u is not None and self._DuT is not None:
            return y - np.vecmat(u, self._DuT)
        return np.array(y, dtype=float)

    def step(self, y: npt.ArrayLike, u: npt.ArrayLike | None = None) -> FloatArray:
        """Advance (45) by one sample.

        Parameters
        ----------
        y : array_like, shape (n_y,) or (..., n_y)
            Measurement ``y_{k+1}`` at the end of the interval (stored for the next step).
        u : array_like, shape (k,) or (..., k), or None
            Known input applied over the interval (ignored without ``input_matrix``).

        Returns
        -------
        ndarray, shape (..., n)
            ``xhat_{k+1} = F xhat_k + G y_k (+ B_u u_k)`` (same object as :attr:`x`).

        Raises
        ------
        ValueError
            ``y`` or ``u`` has the wrong shape or is non-finite (state unchanged).
        """
        y = self._vector("y", y, self._m)
        u = self._input(u) if self._k else None
        if self._pending is not None:
            x = np.vecmat(self._x, self._FT) + np.vecmat(self._pending, self._GT)
            self.innovation = self._pending - np.vecmat(self._x, self.C_y.T)
        else:  # no y_k yet (not primed): zero innovation
            x = np.vecmat(self._x, self._AT)
            self.innovation = None
        if u is not None:
            x = x + np.vecmat(u, self._BuT)
        if not np.isfinite(x).all():
            raise FiniteEscapeError("state estimate became non-finite",
                                    time=self._time(self._steps + 1), quantity="x", value=x)
        self._pending = self._corrected(y, u)
        self._x = readonly(x)
        self._steps += 1
        return self._x

    def _input(self, u: npt.ArrayLike | None) -> FloatArray | None:
        if self._k == 0:
            return None  # the filter has no known input: u is the rig's, not the model's
        return super()._input(u)
