"""The discrete process noise of a simulated rig: accelerations held over the control period.

The simulator applies white noise ``b dW`` and the rigs' step noise as joint accelerations
held over each control period (Euler-Maruyama: ``a = b xi / sqrt(dt)``,
:mod:`testbed.rigs.disturbances`), integrated by MuJoCo's physics steps. Over one period the
state then changes by ``E a`` with ``E`` the response of the period map to a held
acceleration, so the per-sample noise covariance is ``E (Q_v / dt) E^T`` (``Q_v``: the
intensity on the velocity rows). This is not the covariance of continuous white noise
(Van Loan's integral): a held acceleration moves positions and velocities together (their
correlation is nearly one per joint, against 0.87 for continuous noise), which a Kalman filter
designed with the continuous covariance mistakes for noise it cannot see through the
encoders: its rate covariance is then 15-50 % too large (the helicopter's reference filter's
NEES 3.30 of 4).
"""

from __future__ import annotations

import mujoco
import numpy as np


def held_acceleration_map(A: np.ndarray, n_joints: int, dt_s: float, physics_dt_s: float,
                          implicit: bool = True) -> np.ndarray | None:
    """``E``: the state change over one control period per unit held joint acceleration.

    The linear model ``x' = A x + [0; I] a`` integrated as MuJoCo integrates it over the
    period's physics steps of ``h``: semi-implicit Euler (``v+ = v + h W (A_v x + a)``,
    ``p+ = p + h v+``) with ``W = (I - h A_vv)^-1`` for the implicit integrators (damping
    implicit), ``W = I`` for ``Euler``. From the linear model rather than differences of the
    physics: Coulomb friction and stops make the physics' response to a small acceleration at
    rest zero, not the response to the noise's.

    Parameters
    ----------
    A : ndarray, shape (n, n)
        Continuous linearization, ``x = [positions (n_joints), velocities]``.
    n_joints : int
    dt_s, physics_dt_s : float
        Control period and physics step, s.
    implicit : bool
        The physics integrates damping implicitly (:func:`implicit_damping`).

    Returns
    -------
    ndarray, shape (n, n - n_joints), or None
        None when ``dt_s`` is not a whole number of physics steps.
    """
    steps = int(round(dt_s / physics_dt_s))
    if steps < 1 or not np.isclose(steps * physics_dt_s, dt_s):
        return None
    A = np.asarray(A, float)
    n, j = A.shape[0], int(n_joints)
    h = float(physics_dt_s)
    nv = n - j
    W = np.linalg.inv(np.eye(nv) - h * A[j:, j:]) if implicit else np.eye(nv)
    M = np.zeros((n, n))
    M[j:, :] = h * W @ A[j:, :]
    M[j:, j:] += np.eye(nv)
    M[:j, :] = np.eye(n)[:j] + h * M[j:, :]
    N = np.zeros((n, nv))
    N[j:] = h * W
    N[:j] = h * N[j:]
    E = np.zeros((n, nv))
    for _ in range(steps):
        E = M @ E + N
    return E


def implicit_damping(model: mujoco.MjModel) -> bool | None:
    """Whether the physics integrates damping implicitly: ``implicit``, ``implicitfast``, and
    ``Euler`` unless ``eulerdamp`` is disabled (MuJoCo's default Euler is implicit in the
    joint damping); None for ``RK4`` (not a semi-implicit Euler step)."""
    kind = int(model.opt.integrator)
    if kind in (int(mujoco.mjtIntegrator.mjINT_IMPLICIT),
                int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST)):
        return True
    if kind == int(mujoco.mjtIntegrator.mjINT_EULER):
        return not model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    return None


def held_noise_covariance(E: np.ndarray, intensity: np.ndarray, n_joints: int,
                          dt_s: float) -> np.ndarray:
    """Per-sample covariance ``E (Q_v / dt) E^T`` of white noise held over the period.

    Parameters
    ----------
    E : ndarray, shape (n, n - n_joints)
        :func:`held_acceleration_map`.
    intensity : ndarray, shape (n, n)
        Continuous intensity with zero position rows and columns.
    n_joints : int
    dt_s : float

    Returns
    -------
    ndarray, shape (n, n), symmetric
    """
    Qv = np.asarray(intensity, float)[n_joints:, n_joints:]
    Qd = E @ (Qv / dt_s) @ E.T
    return 0.5 * (Qd + Qd.T)


def acts_on_velocities(intensity: np.ndarray, n_joints: int) -> bool:
    """Whether a noise intensity has zero position rows and columns (a force's noise)."""
    Q = np.asarray(intensity, float)
    return not (np.any(Q[:n_joints]) or np.any(Q[:, :n_joints]))


def rig_held_noise(rig, dt_s: float, A: np.ndarray, Q: np.ndarray) -> np.ndarray | None:
    """The per-sample covariance of a rig's physical noise as the simulator applies it.

    Parameters
    ----------
    rig : testbed.rigs.base.Rig
    dt_s : float
        Control period, s.
    A, Q : ndarray, shapes (n0, n0)
        A design's continuous model and intensity; their first ``rig.n_states`` rows and
        columns (the physical states) are used.

    Returns
    -------
    ndarray, shape (n_rig, n_rig), or None
        None for a rig without MuJoCo physics, an integrator other than Euler or the
        implicit ones, a period that is not a whole number of physics steps, or a ``Q``
        with position rows (not a force's noise).
    """
    n, j = rig.n_states, len(rig.joints)
    model = rig.model
    if model is None or not j or not acts_on_velocities(Q[:n, :n], j):
        return None
    implicit = implicit_damping(model)
    if implicit is None:
        return None
    E = held_acceleration_map(A[:n, :n], j, dt_s, float(model.opt.timestep), implicit)
    return None if E is None else held_noise_covariance(E, Q[:n, :n], j, dt_s)


#: Values of the rigs' ``process_noise_model`` design option.
PROCESS_NOISE_MODELS = ("auto", "held", "continuous")


def _check_model(process_noise_model: str) -> None:
    if process_noise_model not in PROCESS_NOISE_MODELS:
        raise ValueError(f"process_noise_model must be one of {PROCESS_NOISE_MODELS}, got "
                         f"{process_noise_model!r}")


def uses_held_noise(process_noise_model: str, paper_profile: bool) -> bool:
    """Whether a rig's design discretizes its process noise as the simulator holds it.

    Parameters
    ----------
    process_noise_model : {"auto", "held", "continuous"}
        ``"held"``: the per-sample covariance of the noise held over each physics step
        (:func:`rig_held_noise`, what the simulator applies); ``"continuous"``: Van Loan's
        integral of the continuous intensity (the papers' ``Q``: the reference filter as
        the papers design it); ``"auto"``: held on the ``paper`` profile, continuous on the
        ``hardware`` profile for all of ``Q`` (where the held covariance, measured, made the
        hardware helicopter's reference filter overconfident: NEES 30 of 4); the matched
        design of the ``hardware`` profile holds the rig's white noise alone
        (:func:`matched_held_noise`).
    paper_profile : bool
        The rig runs its ``paper`` profile.

    Raises
    ------
    ValueError
        An unknown ``process_noise_model``.
    """
    _check_model(process_noise_model)
    if process_noise_model == "auto":
        return paper_profile
    return process_noise_model == "held"


def matched_held_noise(disturbance, process_noise_model: str) -> np.ndarray | None:
    """The part of a matched (``hardware``) design's ``Q`` the simulator holds over its
    physics steps (``build_matched_design(held_intensity=...)``).

    Parameters
    ----------
    disturbance : testbed.rigs.disturbances.Disturbance or None
        The scenario's disturbance; its white noise ``b b^T`` is what the simulator holds.
    process_noise_model : {"auto", "held", "continuous"}
        ``"continuous"``: None (Van Loan's covariance for all of ``Q``, as the papers).

    Returns
    -------
    ndarray, shape (n_rig, n_rig), or None
        ``b b^T`` (None without white noise). The process-noise floor stays continuous: on
        the hardware profile it stands for the accelerations the linear model leaves out
        (friction, stops, deadband), which are not white noise held over the period.
    """
    _check_model(process_noise_model)
    if process_noise_model == "continuous" or disturbance is None:
        return None
    return disturbance.intensity
