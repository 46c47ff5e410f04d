"""A rig's continuous-time linearization by central differences of MuJoCo's ``mj_forward``
(:meth:`testbed.rigs.base.Rig.linearize`), and its actuators' steady state."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np


def linearize(rig: Any, x_op: np.ndarray | None = None, u_op: np.ndarray | None = None,
              eps: float = 1e-6, motor_states: bool = False
              ) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time ``(A, B)`` of ``x' = f(x, u)`` by central differences of MuJoCo.

    Accelerations come from ``mj_forward`` (no integrator involved) at the current
    parameters, without step noise. Actuators with dynamics (the ``hardware`` profile's
    motor lag: MuJoCo ``act`` states of ``filter``/``filterexact`` actuators) are at their
    steady state ``act = ctrl`` unless ``motor_states``.

    Parameters
    ----------
    rig : testbed.rigs.base.Rig
    x_op : ndarray, shape (n,), optional
        Operating state; default :meth:`~testbed.rigs.base.Rig.linearization_point`'s.
    u_op : ndarray, shape (nu,), optional
        Operating input; default :meth:`~testbed.rigs.base.Rig.operating_input` at ``x_op``.
    eps : float
        Finite-difference step (state and input units).
    motor_states : bool
        Append MuJoCo's actuator states (``na`` of them, at their steady state) to the
        state: ``x = [positions, velocities, act]``.

    Returns
    -------
    A : ndarray, shape (n, n) or (n + na, n + na) with ``motor_states``
    B : ndarray, shape (n, nu) or (n + na, nu)
    """
    n, k, j = rig.n_states, rig.n_actions, len(rig.joints)
    x_op = rig.linearization_point() if x_op is None else np.asarray(x_op, float)
    if x_op.shape != (n,) or not np.all(np.isfinite(x_op)):
        raise ValueError(f"x_op must be a finite array of shape ({n},), got {x_op!r}")
    u_op = (rig.operating_input(rig.params, x_op[None])[0] if u_op is None
            else np.asarray(u_op, float))
    if u_op.shape != (k,) or not np.all(np.isfinite(u_op)):
        raise ValueError(f"u_op must be a finite array of shape ({k},), got {u_op!r}")
    scratch = mujoco.MjData(rig.model)
    constants = rig.member_constants(rig.params)[None]
    na = rig.model.na if motor_states else 0

    def f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        scratch.qpos[rig.qpos_adr] = x[:j]
        scratch.qvel[rig.dof_adr] = x[j:n]
        inputs = rig.actuation(u[None], constants)
        if "ctrl" in inputs:
            scratch.ctrl[:] = inputs["ctrl"][0]
        if "xfrc" in inputs:
            scratch.xfrc_applied[:] = inputs["xfrc"][0]
        if rig.model.na:
            scratch.act[:] = x[n:] if na else rig.steady_act(scratch.ctrl)
        mujoco.mj_forward(rig.model, scratch)
        out = [x[j:n], scratch.qacc[rig.dof_adr]]
        return np.concatenate(out + [scratch.act_dot.copy()] if na else out)

    x_full = x_op
    if na:
        ctrl = rig.actuation(u_op[None], constants).get("ctrl", np.zeros((1, 0)))[0]
        x_full = np.concatenate([x_op, rig.steady_act(ctrl)])
    A, B = np.zeros((n + na, n + na)), np.zeros((n + na, k))
    for i in range(n + na):
        dx = np.zeros(n + na)
        dx[i] = eps
        A[:, i] = (f(x_full + dx, u_op) - f(x_full - dx, u_op)) / (2 * eps)
    for i in range(k):
        du = np.zeros(k)
        du[i] = eps
        B[:, i] = (f(x_full, u_op + du) - f(x_full, u_op - du)) / (2 * eps)
    return A, B


def steady_act(rig: Any, ctrl: np.ndarray) -> np.ndarray:
    """MuJoCo actuator states at rest under a constant ``ctrl`` (nu,): shape (na,).

    ``act = ctrl`` for first-order ``filter``/``filterexact`` actuators (the motor lag of
    the ``hardware`` profile); other actuator dynamics raise ``NotImplementedError``.
    """
    act = np.zeros(rig.model.na)
    lag = (int(mujoco.mjtDyn.mjDYN_FILTER), int(mujoco.mjtDyn.mjDYN_FILTEREXACT))
    for i in range(rig.model.nu):
        adr, num = rig.model.actuator_actadr[i], rig.model.actuator_actnum[i]
        if num == 0:
            continue
        if rig.model.actuator_dyntype[i] not in lag or num != 1:
            raise NotImplementedError(f"rig {rig.name!r}: no steady state for actuator "
                                      f"{i} (dyntype {rig.model.actuator_dyntype[i]})")
        act[adr] = ctrl[i]
    return act
