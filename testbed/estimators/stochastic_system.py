"""Zhang et al.'s LMI H-infinity filter designed from any rig's design model.

The rig-specific design (``design.extras["lmi_system"]``, the vehicle roll rig with its
multiplicative damping noise) takes precedence in :func:`testbed.estimators.lmi_hinf`; every
other rig gets the system (44) built here from the discrete design model::

    x_(k+1) = F x_k + B_u u_k + [G_d, Q^(1/2), 0] v_k
    y_k     = H x_k + D_u u_k + [0,   0,  R^(1/2)] v_k          (the stochastic channels)
    z_k     = L x_k                                             (design.output_matrix)

``G_d`` is the zero-order hold of the design's disturbance matrix ``G`` (the scenario's
``w``, held over each period, as the simulator applies it), ``Q^(1/2)``, ``R^(1/2)``
factors of the process and measurement noise covariances; no multiplicative noise
(``A_w = B_w = 0``: the design model has none). With ``G`` present, ``v = [w; 0; 0]`` is a
sub-channel of the design's ``v``, so the certified ``gamma`` bounds the gain from the
scenario's ``w`` to ``z`` (``design_meta["gamma_channel"] = "scenario"``).

Assumption of Theorem 4 (it bounds the augmented state ``[x; e]``): the plant is
(mean-square) stable, ``rho(F) < 1``. A design model with a free integrator (the
helicopter's pitch and yaw angles) does not meet it, but without multiplicative noise
(``A_w = B_w = 0``, as here) the plant block of LMI (48) certifies only the plant's own
stability: the filter knows the input, so its error ``e+ = (F - Khat H) e + (B - Khat D_y) v``
does not depend on the plant state or on the controller (the scored loop's LQR closes the
plant loop; the filter's certificate does not need to know it). Such a design model is
therefore designed with the error block alone (:func:`filters.lmi_hinf.design_lmi_hinf`,
``plant_block=False``; its Notes give the argument), and the design is verified by the error
system's H-infinity norm computed without the LMI (``design_meta["error_hinf_norm"]``).
Stable design models keep the full LMI (48) (the same infimum of gamma; the numbers of the
stable rigs are unchanged). What is then not certified: the plant state's boundedness, which
is the controller's business. ``plant_block`` forces either form; the full form on an
unstable design model is refused, naming the spectral radius.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from filters import zoh
from filters.lmi_hinf import (
    LMIHInfDesign,
    LMIHInfFilter,
    StochasticLinearSystem,
    design_lmi_hinf,
    design_on_grid,
    minimal_gamma,
)
from testbed.estimators import memo
from testbed.records import field_values


def _factor(M: np.ndarray) -> np.ndarray:
    """Columns ``V`` with ``V V^T = M`` for a PSD ``M`` (zero directions dropped)."""
    values, vectors = np.linalg.eigh(0.5 * (M + M.T))
    keep = values > 1e-12 * max(float(values.max(initial=0.0)), 1e-300)
    return vectors[:, keep] * np.sqrt(values[keep])


def spectral_radius(design: Any) -> float:
    """``rho(F)`` of the discrete design model."""
    return float(np.max(np.abs(np.linalg.eigvals(design.discrete.F))))


def design_system(design: Any, *, stable: bool = True) -> tuple[StochasticLinearSystem, bool]:
    """The system (44) of a design model (see the module docstring).

    Parameters
    ----------
    design : testbed.design.DesignModel
    stable : bool
        Require ``rho(F) < 1`` (the full LMI (48), and the plant of vc-discrete).

    Returns
    -------
    system : StochasticLinearSystem
    scenario_channel : bool
        True when ``v`` contains the scenario's disturbance ``w`` (``G`` given).

    Raises
    ------
    ValueError
        ``stable`` and ``rho(F) >= 1`` (Theorem 4 needs a stable plant), naming the
        spectral radius.
    """
    plant = design.discrete
    F = plant.F
    rho = spectral_radius(design)
    if stable and not rho < 1.0 - 1e-9:
        raise ValueError(f"filter 'lmi-hinf' (Zhang et al. Theorem 4) needs a stable design "
                         f"model, but the spectral radius of its F is {rho:.6g} (free "
                         "integrators): Theorem 4 bounds the plant state too")
    n, m = plant.n, plant.m
    blocks = []
    G = design.disturbance_matrix
    if G is not None and np.any(G):
        blocks.append(zoh(design.continuous.A, G, design.dt_s)[1])
    blocks.append(_factor(plant.Q))
    B = np.hstack(blocks)
    Rf = _factor(plant.R)
    system = StochasticLinearSystem(
        A=F, B=np.hstack([B, np.zeros((n, Rf.shape[1]))]), C_y=plant.H,
        C_z=design.output_matrix,
        D_y=np.hstack([np.zeros((m, B.shape[1])), Rf]))
    return system, len(blocks) == 2


def lmi_estimator(design: Any, *, gamma: float | None = None, gamma_factor: float = 5.0,
                  objective: str = "h2-unique", max_steps: int = 12,
                  plant_block: bool | None = None) -> tuple[LMIHInfFilter, dict[str, Any]]:
    """The filter (45) on :func:`design_system`, at ``gamma`` or at the first level of the
    1-2-5 grid above ``gamma_factor gamma_min`` whose design is accurate and verifies.

    ``gamma_min`` comes from :func:`filters.lmi_hinf.minimal_gamma`; the grid and the strictly
    convex ``"h2-unique"`` objective (:func:`filters.lmi_hinf.design_on_grid`) make the
    chosen filter the same on every machine (near ``gamma_min`` the mixed H2/H-infinity
    solution is too ill-conditioned for a reproducible choice).

    ``plant_block`` (default: True when ``rho(F) < 1``, else False) chooses the full LMI
    (48) or its error block (module docstring).

    Returns
    -------
    estimator : LMIHInfFilter
        With the known input (``B_u``, ``D_u``) and ``dt_s``.
    meta : dict
        ``gamma``, ``gamma_min``, ``gain``, ``status``, ``spectral_radius``,
        ``plant_block``, ``plant_spectral_radius``, ``certificate``, ``error_hinf_norm``
        (error-block designs), and ``gamma_channel = "scenario"`` when the scenario's ``w``
        is part of ``v``.

    Raises
    ------
    ValueError
        The full LMI asked for on an unstable design model, or no verified design (the
        solver status named).
    """
    rho = spectral_radius(design)
    if plant_block is None:
        plant_block = rho < 1.0 - 1e-9
    system, scenario_channel = design_system(design, stable=bool(plant_block))
    plant = design.discrete
    if not plant_block:
        states = undetectable_states(design)
        if states:
            raise ValueError(
                "filter 'lmi-hinf': the error-block design of LMI (48) needs (F, H) "
                f"detectable, but a mode of F on or outside the unit circle moves {states} "
                "unseen by the measurements: no gain makes the error system stable"
                + (" (on the matched design; --design-profile paper designs from the "
                   "paper's model)" if design.augmented else ""))
    estimator, meta = verified_estimator(system, design, gamma=gamma, gamma_factor=gamma_factor,
                                         objective=objective, input_matrix=plant.B,
                                         feedthrough=plant.D, max_steps=max_steps,
                                         plant_block=bool(plant_block))
    meta["design"] = "generic (testbed.estimators.stochastic_system)"
    meta["plant_spectral_radius"] = rho
    meta["certificate"] = (
        "Zhang et al. Theorem 4, LMI (48), on the discrete design model" if plant_block else
        f"the error block of Zhang et al.'s LMI (48) (A_w = B_w = 0: the plant block only "
        f"certifies the plant's stability, and rho(F) = {rho:.6g}): the discrete "
        "bounded-real lemma of the filter's error system, whose H-infinity norm is "
        "recomputed without the LMI")
    if scenario_channel:
        meta["gamma_channel"] = "scenario"
    return estimator, meta


def undetectable_modes(A: np.ndarray, C: np.ndarray, tol: float = 1e-9) -> list[complex]:
    """Eigenvalues ``lambda`` of ``A`` with ``|lambda| >= 1`` that ``C`` does not see (PBH:
    ``rank [lambda I - A; C] < n``): no output injection stabilizes them.

    Parameters
    ----------
    A : ndarray, shape (n, n)
    C : ndarray, shape (m, n)
    tol : float
        Relative singular-value tolerance of the rank test.

    Returns
    -------
    list of complex
        Empty iff ``(A, C)`` is detectable.
    """
    n = A.shape[0]
    out = []
    for lam in np.linalg.eigvals(A):
        if abs(lam) < 1.0 - 1e-9:
            continue
        M = np.vstack([lam * np.eye(n) - A, C])
        sv = np.linalg.svd(M, compute_uv=False)
        if sv[-1] <= tol * max(float(sv[0]), 1.0):
            out.append(complex(lam))
    return out


def undetectable_states(design: Any, tol: float = 1e-9, share: float = 0.05) -> list[str]:
    """Names of the states an undetectable mode of a design model moves.

    The directions ``v`` with ``(lambda I - F) v = 0``, ``H v = 0`` for the eigenvalues
    ``|lambda| >= 1`` of :func:`undetectable_modes`; a state is named when its share of
    ``|v|^2`` in some direction is at least ``share``.

    Parameters
    ----------
    design : testbed.design.DesignModel
    tol : float
        Relative singular-value tolerance.
    share : float
        Smallest share of a direction's squared norm that names a state.

    Returns
    -------
    list of str
        Empty iff ``(F, H)`` is detectable.
    """
    F, H = np.asarray(design.discrete.F, float), np.asarray(design.discrete.H, float)
    n = F.shape[0]
    names: list[str] = []
    for lam in sorted(set(np.round(undetectable_modes(F, H, tol), 9)), key=abs):
        M = np.vstack([lam * np.eye(n) - F, H.astype(complex)])
        _, sv, Vh = np.linalg.svd(M)
        for v in Vh[np.flatnonzero(sv <= tol * max(float(sv[0]), 1.0))]:
            w = np.abs(v) ** 2 / np.sum(np.abs(v) ** 2)
            names += [design.state_names[i] for i in np.flatnonzero(w >= share)
                      if design.state_names[i] not in names]
    return names


def _mode(m: complex) -> str:
    return f"{m.real:.6g}" if abs(m.imag) <= 1e-12 * max(abs(m), 1.0) else f"{m:.6g}"


def verified_estimator(system: StochasticLinearSystem, design: Any, *, gamma: float | None,
                       gamma_factor: float, objective: str, input_matrix: np.ndarray | None,
                       feedthrough: np.ndarray | None, max_steps: int = 12,
                       plant_block: bool = True) -> tuple[LMIHInfFilter, dict[str, Any]]:
    """Theorem 4's filter (45) on ``system``: at ``gamma``, or at the first accurate verified
    level of the 1-2-5 grid above ``gamma_factor gamma_min``
    (:func:`filters.lmi_hinf.design_on_grid`), verified a posteriori.

    Shared by the generic design (:func:`lmi_estimator`) and the rigs' own LMI design
    systems (the vehicle roll rig's, with its multiplicative damping noise).

    Parameters
    ----------
    system : StochasticLinearSystem
    design : testbed.design.DesignModel
        For ``x0`` and ``dt_s``.
    gamma : float or None
    gamma_factor : float
    objective : str
    input_matrix, feedthrough : ndarray, optional
        The known input's ``B_u`` (n, k) and ``D_u`` (m, k).
    max_steps : int
        Grid levels tried at most.
    plant_block : bool
        False: the error block of (48) only (:func:`filters.lmi_hinf.design_lmi_hinf`).

    Returns
    -------
    estimator : LMIHInfFilter
    meta : dict
        ``gamma_min`` (None when ``gamma`` was given), ``gamma``, ``gain``, ``status``,
        ``spectral_radius``, ``objective``.

    Raises
    ------
    ValueError
        LMI (48) infeasible for every gamma, or no verified design (the solver status named).
    """
    if not plant_block:
        modes = undetectable_modes(system.A, system.C_y)
        if modes:
            raise ValueError("the error-block design of LMI (48) needs (F, H) detectable, but "
                             f"the modes {[_mode(m) for m in modes]} of F are not stable and "
                             "not seen by the measurements: no gain makes the error system "
                             "stable")
    fields = field_values(system)
    digest = memo.key(*(fields[name] for name in _SYSTEM_FIELDS), gamma,
                      gamma_factor, objective, max_steps, plant_block)
    gamma_min, lmi = memo.memoized("lmi-hinf", digest, lambda: _search(
        system, gamma=gamma, gamma_factor=gamma_factor, objective=objective,
        max_steps=max_steps, plant_block=plant_block), valid=_is_search_result)
    if not lmi.feasible:
        raise ValueError(f"no verified lmi-hinf design at gamma = {lmi.gamma:.6g}: status "
                         f"{lmi.status} (solver: {lmi.solver_status})")
    estimator = LMIHInfFilter.from_design(system, lmi, x0=design.x0, input_matrix=input_matrix,
                                          feedthrough=feedthrough, dt_s=design.dt_s)
    meta = {"gamma_min": gamma_min, "gamma": lmi.gamma, "gamma_kind": "discrete",
            "gain": lmi.gain.tolist(),
            "status": lmi.status, "spectral_radius": lmi.check.spectral_radius,
            "objective": objective, "plant_block": plant_block}
    if not plant_block:
        meta["error_hinf_norm"] = lmi.check.error_hinf_norm
    return estimator, meta


#: The fields of a :class:`filters.lmi_hinf.StochasticLinearSystem` a design depends on.
_SYSTEM_FIELDS = ("A", "B", "C_y", "C_z", "A_w", "B_w", "D_y", "D_z")


def _is_search_result(value: Any) -> bool:
    """Whether ``value`` has the shape of :func:`_search`'s result (a memo entry's check)."""
    return (isinstance(value, tuple) and len(value) == 2
            and (value[0] is None or isinstance(value[0], float))
            and isinstance(value[1], LMIHInfDesign))


def _search(system: StochasticLinearSystem, *, gamma: float | None, gamma_factor: float,
            objective: str, max_steps: int, plant_block: bool) -> tuple[float | None, Any]:
    """``(gamma_min, design)`` of :func:`verified_estimator` (``gamma_min`` None when
    ``gamma`` is given); memoized there (:mod:`testbed.estimators.memo`)."""
    if gamma is not None:
        return None, design_lmi_hinf(system, float(gamma), objective=objective,
                                     plant_block=plant_block)
    search = minimal_gamma(system, plant_block=plant_block)
    if search.gamma_min is None:
        what = "LMI (48)" if plant_block else "the error block of LMI (48)"
        raise ValueError(f"{what} infeasible for every gamma up to 1e8 ({search.status})")
    lmi, _ = design_on_grid(system, gamma_factor * search.gamma_min, objective=objective,
                            max_steps=max_steps, plant_block=plant_block)
    return search.gamma_min, lmi


def sampled_two_channel_system(design: Any) -> tuple[StochasticLinearSystem, np.ndarray,
                                                     np.ndarray]:
    """Basin et al.'s two-channel problem at the sampling period (the hold equivalent).

    The continuous problem of :class:`filters.MeanSquareHInfFilter` (Basin et al. Theorem 1):
    ``dx = (A x + B u + G w) dt + dW``, a stochastic channel ``y1`` and the deterministic
    ``y2 = C2 x + Hw w``, output ``z = L x``. With ``u`` and ``w`` held over each period (as
    the simulator applies them) its exact discretization is :func:`design_system`'s plant
    ``x(k+1) = F x + B_u u + [G_d, Q^1/2, 0] v`` with the sampled channels::

        y1(k) = H x(k)  + D u + [0,  0, R^1/2] v(k)
        y2(k) = C2 x(k) + D2 u + [Hw, 0, 0    ] v(k)      (the held w(k) at the sample)

    Returns
    -------
    system : StochasticLinearSystem
        ``C_y = [H; C2]``, ``D_y`` as above.
    feedthrough : ndarray, shape (m1 + m2, k)
        ``[D; D2]`` of the known input.
    channels : ndarray of int
        The sensor channels ``y1`` then ``y2`` (``measurement_index``, then the
        deterministic ones).

    Raises
    ------
    ValueError
        No deterministic channel or no disturbance matrix ``G`` (the problem's data).
    """
    det = design.deterministic_index
    G = design.disturbance_matrix
    if len(det) == 0 or G is None or not np.any(G):
        raise ValueError("filter 'ms-hinf' (sampled): needs a deterministic channel "
                         "y2 = C2 x + H w and the disturbance G w(t) (helicopter: disturbance "
                         "'basin-helicopter')")
    base, _ = design_system(design, stable=False)
    s = G.shape[1]
    Hw = np.asarray(design.sensors.Hw[det], float)
    if Hw.shape[1] < s:
        Hw = np.pad(Hw, ((0, 0), (0, s - Hw.shape[1])))
    elif Hw.shape[1] > s:
        raise ValueError(f"filter 'ms-hinf' (sampled): the sensors' Hw has {Hw.shape[1]} "
                         f"disturbance columns, the design's G {s}")
    D_y2 = np.hstack([Hw, np.zeros((len(det), base.n_v - s))])
    system = StochasticLinearSystem(A=base.A, B=base.B,
                                    C_y=np.vstack([base.C_y, design.sensors.C[det]]),
                                    C_z=base.C_z, D_y=np.vstack([base.D_y, D_y2]))
    feedthrough = np.vstack([design.discrete.D, design.sensors.D[det]])
    channels = np.concatenate([design.measurement_index, det]).astype(int)
    return system, feedthrough, channels


def sampled_ms_hinf_estimator(design: Any, *, gamma: float | None = None,
                              gamma_factor: float = 5.0, objective: str = "h2-unique",
                              max_steps: int = 12) -> tuple[LMIHInfFilter, dict[str, Any]]:
    """The sampled-data counterpart of Basin et al.'s mean-square H-infinity filter
    (``ms-hinf`` with ``sampled=True``).

    Basin et al.'s gamma is stated for continuous observation and certifies no sampled loop.
    This option designs for what the rig gives, the samples of ``y1`` and ``y2`` with ``w``
    held (:func:`sampled_two_channel_system`): a discrete H-infinity filter (45) whose gain
    comes from LMI (48) (its error block when ``rho(F) >= 1``, see
    :func:`filters.lmi_hinf.design_lmi_hinf`), so its ``gamma`` is a discrete bound from
    ``v = [w; noise]`` to ``z - zhat``, hence from the scenario's ``w``: a certificate of the
    sampled loop on the design model, which the harness compares with the loop's measured
    linearized gain (``gamma_kind = "discrete"``). What it is not: Basin et al.'s filter
    (no Riccati equation in continuous time, a constant gain); it answers the same problem
    (same channels, disturbance and output) at the sampling period.

    Returns
    -------
    estimator : LMIHInfFilter
    meta : dict
        As :func:`lmi_estimator`'s, ``design`` naming the sampled-data counterpart.

    Raises
    ------
    ValueError
        Missing channels, or no verified design.
    """
    system, feedthrough, _ = sampled_two_channel_system(design)
    rho = spectral_radius(design)
    plant_block = rho < 1.0 - 1e-9
    estimator, meta = verified_estimator(system, design, gamma=gamma, gamma_factor=gamma_factor,
                                         objective=objective, input_matrix=design.discrete.B,
                                         feedthrough=feedthrough, max_steps=max_steps,
                                         plant_block=plant_block)
    meta.update(
        design="sampled-data counterpart of ms-hinf (testbed.estimators.stochastic_system)",
        gamma_channel="scenario", plant_spectral_radius=rho,
        certificate=("discrete H-infinity filter for Basin et al.'s two-channel problem at the "
                     "sampling period (y1, y2 sampled, w held: the exact ZOH model), gain from "
                     + ("LMI (48)" if plant_block else "the error block of LMI (48)")))
    return estimator, meta


def ms_hinf_sampled(design: Any, gamma: float | None = None, gamma_factor: float = 5.0) -> Any:
    """``ms-hinf`` with ``sampled=True`` as a factory of its own, for ``testbed score
    --estimator testbed.estimators.stochastic_system:ms_hinf_sampled``."""
    from testbed.estimators import ms_hinf

    return ms_hinf(design, gamma=gamma, sampled=True, gamma_factor=gamma_factor)
