"""Jacobians of a MuJoCo model's control-period map from its one-physics-step derivatives.

The control period of the nonlinear design models (:mod:`testbed.estimators.nonlinear`) is
``N = frame_skip`` physics steps ``s_{i+1} = phi(s_i, w_i)`` of the rig state ``s`` under the
rig's physical input ``w_i``. Its Jacobian with respect to a vector ``z`` on which the start
state and the inputs depend (``ds_0/dz = [I, 0]``, ``dw_i/dz`` given) is the tangent
recursion

    T_0 = [I, 0],     T_{i+1} = A_i T_i + B_i dw_i/dz,     ds_N/dz = T_N,

with ``A_i = dphi/ds``, ``B_i = dphi/dw`` at ``(s_i, w_i)``. Finite differences of the whole
period (``jacobian="rollout"``) cost ``1 + dim z`` rollouts of ``N`` steps per row; here
``A`` and ``B`` are the forward (or central) differences of ONE physics step, taken at
``points`` linearization steps ``0, N/points, ...`` of each row's own nominal trajectory and
held over the steps up to the next one: ``points = N`` is the exact product of the
per-step derivatives (as :func:`mujoco.mjd_transitionFD` along the trajectory), ``points =
1`` the linearization at the period's start held over the period (``A^N``, ``sum A^i B``),
``(1 + n_rig + k_rig) points`` single physics steps per row instead of ``(1 + dim z) N``.
Every single step of every row is one :func:`mujoco.rollout.rollout` call (``nstep = 1``),
after one call for the rows' nominal trajectories.

The error of holding the linearization is of the order of the change of ``A`` over the
held steps times their length (first order in the period for ``points = 1``);
``docs/performance.md`` gives it measured on the rigs and its effect on the filters.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class SteppedModel(Protocol):
    """What the Jacobians read of a process model
    (:class:`~testbed.estimators.mujoco_model.MujocoProcessModel` is one)."""

    n: int  # rig states
    k: int  # rig inputs
    eps: float
    centered: bool
    frame_skip: int
    linearization: np.ndarray  # the physics steps the linearization is taken at
    _gather: np.ndarray  # the rig states' columns of a full physics state
    _template: np.ndarray  # a full physics state the rig states are written into

    def roll(self, state0: np.ndarray, w: np.ndarray, nstep: int) -> np.ndarray:
        """Full physics states of ``nstep`` physics steps from ``state0`` under ``w``."""

#: ``eps I_d`` by ``(d, eps)`` (read-only).
_STEPS: dict[tuple[int, float], np.ndarray] = {}


def perturbed(x: np.ndarray, eps: float, centered: bool) -> np.ndarray:
    """Rows ``x`` followed by their coordinate perturbations, for finite differences.

    Parameters
    ----------
    x : ndarray, shape (M, d)
    eps : float
    centered : bool

    Returns
    -------
    ndarray, shape (M, 1 + d, d) or (M, 1 + 2 d, d)
        Row ``i``: ``[x_i, x_i + eps e_1 ... x_i + eps e_d]`` (then ``x_i - eps e_j`` when
        ``centered``).
    """
    M, d = x.shape
    steps = _STEPS.get((d, eps))
    if steps is None:
        steps = _STEPS[(d, eps)] = eps * np.eye(d)
        steps.flags.writeable = False
    parts = [x[:, None, :], x[:, None, :] + steps]
    if centered:
        parts.append(x[:, None, :] - steps)
    return np.concatenate(parts, axis=1)


def differences(values: np.ndarray, eps: float, centered: bool) -> np.ndarray:
    """Jacobians from the values at :func:`perturbed` points.

    Parameters
    ----------
    values : ndarray, shape (M, 1 + d, r) or (M, 1 + 2 d, r)

    Returns
    -------
    ndarray, shape (M, r, d)
    """
    d = (values.shape[1] - 1) // (2 if centered else 1)
    if centered:
        J = (values[:, 1:1 + d] - values[:, 1 + d:]) / (2.0 * eps)
    else:
        J = (values[:, 1:1 + d] - values[:, :1]) / eps
    return np.swapaxes(J, 1, 2)


def linearization_steps(frame_skip: int, points: int) -> np.ndarray:
    """The physics steps at which the period is linearized: ``points`` of ``0``, ..., ``N - 1``,
    evenly spread from 0 (``floor(j N / points)``).

    Parameters
    ----------
    frame_skip : int
        ``N``, physics steps per control period.
    points : int
        ``1 <= points <= N``.

    Returns
    -------
    ndarray of int, shape (points,)

    Raises
    ------
    ValueError
        ``points`` is not an integer in ``[1, N]``.
    """
    if (isinstance(points, bool) or not isinstance(points, int | float | np.integer)
            or not float(points).is_integer() or not 1 <= points <= frame_skip):
        raise ValueError(f"jacobian_points must be an integer in [1, {frame_skip}] (the "
                         f"physics steps of a control period), got {points!r}")
    points = int(points)
    return ((2 * np.arange(points) + 1) * frame_skip - points) // (2 * points)


def step_derivatives(process: SteppedModel, states: np.ndarray, w: np.ndarray,
                     inputs: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """``A = ds'/ds`` and ``B = ds'/dw`` of one physics step at full physics states.

    Parameters
    ----------
    process : MujocoProcessModel
        The model (its ``eps``, ``centered``, rig-state columns and rollout).
    states : ndarray, shape (R, nstate)
        MuJoCo ``mjSTATE_FULLPHYSICS`` states.
    w : ndarray, shape (R, k_rig)
        The rig's physical inputs of the step.
    inputs : bool
        Also ``B`` (False: ``B`` is None and the inputs are not perturbed).

    Returns
    -------
    A : ndarray, shape (R, n_rig, n_rig)
    B : ndarray, shape (R, n_rig, k_rig) or None
        In the rig's state order; forward (or central) differences with step
        ``process.eps`` of one :func:`mujoco.rollout.rollout` call of ``nstep = 1`` over
        every perturbed row.
    """
    R, nstate = states.shape
    nr, kr, eps = process.n, process.k, process.eps
    q = nr + (kr if inputs else 0)
    P = 1 + (2 * q if process.centered else q)
    S = np.repeat(states[:, None, :], P, axis=1)
    W = np.repeat(np.asarray(w, float)[:, None, :], P, axis=1)
    signs = (1.0, -1.0) if process.centered else (1.0,)
    for side, sign in enumerate(signs):
        first = 1 + side * q
        S[:, first + np.arange(nr), process._gather] += sign * eps
        if inputs:
            W[:, first + nr + np.arange(kr), np.arange(kr)] += sign * eps
    out = process.roll(S.reshape(R * P, nstate), W.reshape(R * P, 1, kr), 1)
    J = differences(out[:, 0][:, process._gather].reshape(R, P, nr), eps, process.centered)
    return J[:, :, :nr], (J[:, :, nr:] if inputs else None)


def period_tangent(process: SteppedModel, p: np.ndarray, W: np.ndarray,
                   dW: np.ndarray | None, d: int) -> tuple[np.ndarray, np.ndarray]:
    """The state after one control period and its Jacobian by the tangent recursion.

    Parameters
    ----------
    process : MujocoProcessModel
    p : ndarray, shape (M, n_rig)
        Rig states at the period's start.
    W : ndarray, shape (M, N, k_rig) or (M, 1, k_rig)
        Physical inputs of the ``N = frame_skip`` physics steps (or held over them).
    dW : ndarray, shape (M, N, k_rig, d), or None
        ``dw_i/dz`` (None: the inputs do not depend on ``z``).
    d : int
        ``dim z >= n_rig``; ``z``'s first ``n_rig`` entries are the start state.

    Notes
    -----
    The linearization steps are ``process.linearization`` (:func:`linearization_steps` of
    the model's ``jacobian_points``).

    Returns
    -------
    p_next : ndarray, shape (M, n_rig)
        The nominal rollout's end state (bitwise :meth:`MujocoProcessModel.rollout`'s).
    T : ndarray, shape (M, n_rig, d)
        ``dp_next/dz``.
    """
    M, nr = p.shape
    N = process.frame_skip
    steps = process.linearization
    state0 = np.tile(process._template, (M, 1))
    state0[:, process._gather] = p
    traj = process.roll(state0, W, N)
    p_next = traj[:, -1][:, process._gather]
    S = len(steps)
    at = np.empty((M, S, state0.shape[1]))
    for j, s in enumerate(steps):
        at[:, j] = state0 if s == 0 else traj[:, s - 1]
    w_at = W[:, steps] if W.shape[1] > 1 else np.repeat(W, S, axis=1)
    A, B = step_derivatives(process, at.reshape(M * S, -1), w_at.reshape(M * S, -1),
                            inputs=dW is not None)
    A = A.reshape(M, S, nr, nr)
    B = None if B is None else B.reshape(M, S, nr, -1)
    if S == 1:  # T_N = A^N [I, 0] + sum_i A^(N-1-i) B dw_i, the powers by doubling
        A1 = A[:, 0]
        powers = _powers(A1, N)  # (M, N, nr, nr): A^0 .. A^(N-1)
        T = np.zeros((M, nr, d))
        T[:, :, :nr] = powers[:, -1] @ A1
        if B is not None:  # one product per member: [A^(N-1) .. A^0] [B dw_0; ..; B dw_N-1]
            kr = B.shape[3]
            BdW = B[:, 0] @ dW.transpose(0, 2, 1, 3).reshape(M, kr, N * d)  # (M, nr, N d)
            BdW = BdW.reshape(M, nr, N, d).transpose(0, 2, 1, 3).reshape(M, N * nr, d)
            T += powers[:, ::-1].transpose(0, 2, 1, 3).reshape(M, nr, N * nr) @ BdW
        return p_next, T
    segment = (np.arange(N) * S) // N  # the segment of each physics step
    T = np.zeros((M, nr, d))
    T[:, :, :nr] = np.eye(nr)
    for i in range(N):
        T = A[:, segment[i]] @ T
        if B is not None:
            T += B[:, segment[i]] @ dW[:, i]
    return p_next, T


def _powers(A: np.ndarray, count: int) -> np.ndarray:
    """``A^0``, ..., ``A^(count - 1)`` of a stack ``A`` (M, r, r): shape (M, count, r, r), by
    doubling (``log2(count)`` stacked products)."""
    M, r, _ = A.shape
    out = np.empty((M, count, r, r))
    out[:, 0] = np.eye(r)
    k, Ak = 1, A
    while k < count:
        c = min(k, count - k)
        # A^k [A^0 | .. | A^(c-1)]: one product per member
        H = out[:, :c].transpose(0, 2, 1, 3).reshape(M, r, c * r)
        out[:, k:k + c] = (Ak @ H).reshape(M, r, c, r).transpose(0, 2, 1, 3)
        k += c
        if k < count:
            Ak = Ak @ Ak
    return out
