"""The rig's MuJoCo model over one control period (:class:`MujocoProcessModel`) and the rig's
physical input of a design state (:class:`PhysicalInput`): the process model of the
nonlinear filters on a design whose state is the rig's, and the part every other process
model steps (:mod:`testbed.estimators.nonlinear` describes the whole design model).

This module imports no rig module: the designer's rig comes with the design.
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING, Any

import mujoco
import mujoco.rollout
import numpy as np

from testbed.design import DesignModel, InputStates
from testbed.estimators.jacobians import (
    differences,
    linearization_steps,
    period_tangent,
    perturbed,
)

if TYPE_CHECKING:  # the designer's rig: its class comes with the design (extras["rig_type"])
    from testbed.rigs.base import Rig

_FULL = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
_CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
_XFRC = int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)
#: Default finite-difference step of the Jacobians (state units).
FD_EPS = 1e-6
#: Jacobian methods of :class:`MujocoProcessModel`.
JACOBIAN_METHODS = ("step", "rollout", "transition")



def _offset(model: mujoco.MjModel, spec: int, component: int) -> int:
    """Offset of one component in a ``spec`` state vector (components in bit order)."""
    return sum(mujoco.mj_stateSize(model, 1 << k) for k in range(component.bit_length() - 1)
               if spec & (1 << k))


def can_touch(model: mujoco.MjModel) -> bool:
    """Whether any two geoms of ``model`` may collide: an explicit contact pair, or a geom
    pair whose ``contype`` and ``conaffinity`` bits meet (MuJoCo's filter)."""
    if model.npair:
        return True
    contype = np.asarray(model.geom_contype)
    conaffinity = np.asarray(model.geom_conaffinity)
    return bool(np.any((contype[:, None] & conaffinity[None, :]) != 0))


class MujocoProcessModel:
    """``x_{k+1} = f(x_k, u_k)``: a rig's MuJoCo model over one control period.

    Parameters
    ----------
    rig : testbed.rigs.base.Rig
        The designer's rig (nominal parameters); its ``model`` is stepped, not changed.
    dt_s : float
        Control period, a whole number of the model's physics steps.
    eps : float
        Finite-difference step of the Jacobian (state units).
    centered : bool
        Central differences (``2 n`` perturbed rollouts per row) or forward differences
        (default: ``n``, half the cost; first-order accurate in ``eps``, an error of order
        ``eps`` relative, far below what a filter notices).
    jacobian : {"step", "rollout", "transition"}
        ``"step"`` (default): the one-physics-step derivatives at ``jacobian_points``
        linearization steps of each row's trajectory, held in between and composed over the
        period (:mod:`testbed.estimators.jacobians`: ``1 + n`` single physics steps per row
        and point, all in one rollout call); ``"rollout"``: finite differences of the whole
        control-period map, all perturbed initial states of all rows in one
        :func:`mujoco.rollout.rollout` call (``n`` extra periods per row); ``"transition"``:
        the product of MuJoCo's per-physics-step transition derivatives
        (:func:`mujoco.mjd_transitionFD`) along each row's trajectory (the reference, a
        Python loop per row and physics step).
    jacobian_points : int
        ``"step"``: linearization points per control period, ``1 .. frame_skip`` (1: the
        derivatives at the period's start held over it; ``frame_skip``: the exact product of
        the per-step derivatives).
    nthread : int
        Threads of the rollout calls (0: the calling thread). The result does not depend on
        it: each rollout is independent and deterministic.

    Attributes
    ----------
    frame_skip : int
        Physics steps per control period.
    n, k : int
        State and input dimensions.

    Raises
    ------
    ValueError
        ``dt_s`` is not a whole number of physics steps, the model has degrees of freedom or
        actuator states outside the rig's state, or the rig sets its input per physics step
        (:attr:`Rig.needs_substep`); a bad ``eps``, ``jacobian`` or ``nthread``.
    """

    def __init__(self, rig: Rig, dt_s: float, *, eps: float = FD_EPS,
                 centered: bool = False, jacobian: str = "step", jacobian_points: int = 1,
                 nthread: int = 0) -> None:
        model = rig.model
        step = float(model.opt.timestep)
        frame_skip = int(round(float(dt_s) / step))
        if frame_skip < 1 or not np.isclose(frame_skip * step, float(dt_s), rtol=1e-9, atol=0):
            raise ValueError(f"dt_s must be a whole number of the model's physics steps "
                             f"({step:g} s), got {dt_s!r}")
        j = len(rig.joints)
        if model.nq != j or model.nv != j or model.na != 0:
            raise ValueError(f"rig {rig.name!r}: the nonlinear design model needs a MuJoCo model "
                             f"whose state is the rig's (nq = nv = {j}, na = 0), got nq = "
                             f"{model.nq}, nv = {model.nv}, na = {model.na}")
        if rig.needs_substep:
            raise ValueError(f"rig {rig.name!r}: a per-physics-step input (substep_ctrl) is not "
                             "in the nonlinear design model; use the rig's first profile")
        if not (np.isfinite(eps) and eps > 0):
            raise ValueError(f"eps must be positive and finite, got {eps!r}")
        if jacobian not in JACOBIAN_METHODS:
            raise ValueError(f"jacobian must be one of {JACOBIAN_METHODS}, got {jacobian!r}")
        if (isinstance(nthread, bool) or not isinstance(nthread, int | float | np.integer)
                or not float(nthread).is_integer() or nthread < 0):
            raise ValueError(f"nthread must be an integer >= 0, got {nthread!r}")
        if not can_touch(model):
            # no geom pair can collide: skip the collision phase of every rollout (the same
            # states bitwise, about 19 % less physics time on the helicopter)
            model = copy.deepcopy(model)
            model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        self.rig, self.model, self.frame_skip, self.eps = rig, model, frame_skip, float(eps)
        self.centered, self.method, self.nthread = bool(centered), jacobian, int(nthread)
        self.n, self.k = rig.n_states, rig.n_actions
        self._j = j
        self._data = mujoco.MjData(model)
        self._datas = [mujoco.MjData(model) for _ in range(max(self.nthread, 1))]
        self._data1 = [self._data]  # the calling thread's (nthread 0 or 1)
        self._constants = rig.member_constants(rig.params)
        mujoco.mj_resetData(model, self._data)
        self._template = np.zeros(mujoco.mj_stateSize(model, _FULL))
        mujoco.mj_getState(model, self._data, self._template, _FULL)
        qpos = _offset(model, _FULL, int(mujoco.mjtState.mjSTATE_QPOS))
        qvel = _offset(model, _FULL, int(mujoco.mjtState.mjSTATE_QVEL))
        #: Columns of the rig state in a FULLPHYSICS state vector.
        self._gather = np.concatenate([qpos + rig.qpos_adr, qvel + rig.dof_adr])
        #: Rows/columns of the rig state in mjd_transitionFD's tangent space.
        self._tangent = np.concatenate([rig.dof_adr, model.nv + rig.dof_adr])
        keys = rig.actuation(np.zeros((1, self.k)), self._constants[None]).keys()
        unknown = set(keys) - {"ctrl", "xfrc"}
        if unknown:
            raise ValueError(f"rig {rig.name!r}: unsupported actuation outputs {sorted(unknown)}")
        self._spec = (_CTRL if "ctrl" in keys else 0) | (_XFRC if "xfrc" in keys else 0)
        self._ncontrol = mujoco.mj_stateSize(model, self._spec) if self._spec else 0
        self._A = np.zeros((2 * model.nv + model.na, 2 * model.nv + model.na))
        #: The physics steps of a period at which ``"step"`` linearizes.
        self.linearization = linearization_steps(frame_skip, jacobian_points)
        self.points = int(self.linearization.size)
        self._broadcast: dict[int, np.ndarray] = {}
        self._buffers: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._initial: dict[int, np.ndarray] = {}  # FULLPHYSICS initial states per row count
        self._models: dict[int, list[mujoco.MjModel]] = {}
        self._cache: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._pool: Any = None  # mujoco.rollout.Rollout with nthread threads, made on use

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_buffers"], state["_pool"] = {}, None  # scratch and threads: not copied
        state["_initial"] = {}
        state["_models"], state["_broadcast"] = {}, {}
        return state

    # ------------------------------------------------------------------ inputs
    def controls(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """MuJoCo inputs of absolute inputs ``u`` (M, k) (:meth:`Rig.actuation` at the
        nominal member constants): ``"ctrl"`` (M, nu) and/or ``"xfrc"`` (M, nbody, 6)."""
        constants = self._broadcast.get(len(u))
        if constants is None:  # (a read-only view, one per row count)
            constants = self._broadcast[len(u)] = np.broadcast_to(
                self._constants, (len(u), len(self._constants)))
        return self.rig.actuation(np.asarray(u, float), constants)

    def _control_vectors(self, inputs: dict[str, np.ndarray], M: int) -> np.ndarray:
        parts = []
        if "ctrl" in inputs:
            parts.append(np.asarray(inputs["ctrl"], float).reshape(M, -1))
        if "xfrc" in inputs:
            parts.append(np.asarray(inputs["xfrc"], float).reshape(M, -1))
        return np.concatenate(parts, axis=1) if parts else np.zeros((M, 0))

    # ------------------------------------------------------------------ model
    def rollout(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """States after one control period from ``x`` (M, n) under inputs ``u``.

        Parameters
        ----------
        x : ndarray, shape (M, n)
        u : ndarray, shape (M, k) or (M, frame_skip, k)
            Absolute inputs, held over the period or one per physics step.

        Returns
        -------
        ndarray, shape (M, n)
            All ``M`` rows from one :func:`mujoco.rollout.rollout` call.
        """
        M = len(x)
        state0 = self._initial.get(M)
        if state0 is None:  # one per row count: the template's other entries never change
            state0 = self._initial[M] = np.tile(self._template, (M, 1))
        state0[:, self._gather] = x
        u = np.asarray(u, float)
        w = u[:, None, :] if u.ndim == 2 else u
        return self.roll(state0, w, self.frame_skip)[:, -1][:, self._gather]

    def roll(self, state0: np.ndarray, w: np.ndarray, nstep: int) -> np.ndarray:
        """Full physics states of ``nstep`` physics steps from ``state0`` under inputs ``w``.

        Parameters
        ----------
        state0 : ndarray, shape (M, nstate)
            ``mjSTATE_FULLPHYSICS`` initial states.
        w : ndarray, shape (M, nstep, k) or (M, 1, k)
            Absolute rig inputs per physics step (or held).
        nstep : int

        Returns
        -------
        ndarray, shape (M, nstep, nstate)
            One :func:`mujoco.rollout.rollout` call; a scratch buffer of this model, valid
            until its next rollout of the same shape.
        """
        M = len(state0)
        control = None
        if self._spec:
            if w.shape[1] == 1:
                control = np.repeat(self._control_vectors(self.controls(w[:, 0]), M)[:, None, :],
                                    nstep, axis=1)
            else:
                flat = w.reshape(M * nstep, self.k)
                control = self._control_vectors(self.controls(flat), M * nstep).reshape(
                    M, nstep, self._ncontrol)
        key = (M, nstep)
        if key not in self._buffers:
            self._buffers[key] = (np.zeros((M, nstep, len(self._template))),
                                  np.zeros((M, nstep, self.model.nsensordata)))
        state, sensordata = self._buffers[key]
        models = self._models.get(M)
        if models is None:
            models = self._models[M] = [self.model] * M
        if self._pool is None:  # this model's own, kept (nthread 0: the calling thread)
            self._pool = mujoco.rollout.Rollout(nthread=self.nthread if self.nthread > 1 else 0)
        self._pool.rollout(models, self._datas if self.nthread > 1 else self._data1, state0,
                           control, control_spec=self._spec, skip_checks=True, nstep=nstep,
                           state=state, sensordata=sensordata)
        return state

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``f(x, u)``: states after one control period, shape (M, n).

        Parameters
        ----------
        x : ndarray, shape (M, n)
            States (design coordinates).
        u : ndarray, shape (M, k)
            Absolute inputs held over the period.

        Notes
        -----
        All ``M`` rows in one :func:`mujoco.rollout.rollout` call, unless :meth:`jacobian`
        has just been evaluated at the same ``(x, u)``.
        """
        cache = self._cache
        if cache is not None and np.array_equal(cache[0], x) and np.array_equal(cache[1], u):
            return cache[2].copy()
        return self.rollout(x, u)

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``F(x, u) = df/dx``, shape (M, n, n), by finite differences (:attr:`method`).

        ``"step"``: the tangent recursion of the one-step derivatives
        (:func:`testbed.estimators.jacobians.period_tangent`, :attr:`points` per period).
        ``"rollout"``: forward (or :attr:`centered`) differences of the control-period map,
        step :attr:`eps`, every perturbed initial state of every row in one rollout call.
        ``"transition"``: for each row the product ``A_s ... A_1`` of the transition
        derivatives (:func:`mujoco.mjd_transitionFD`) of the ``frame_skip`` physics steps
        along the row's own trajectory, in the rig's state order. Either way ``f(x, u)`` is
        cached for the next :meth:`__call__` at the same arguments.
        """
        if self.method == "step":
            x, u = np.asarray(x, float), np.asarray(u, float)
            out, J = period_tangent(self, x, u[:, None, :], None, self.n)
            self._cache = (x.copy(), u.copy(), out)
            return J
        if self.method == "rollout":
            M, n = x.shape
            points = perturbed(np.asarray(x, float), self.eps, self.centered)
            P = points.shape[1]
            ub = np.repeat(np.asarray(u, float), P, axis=0)
            values = self.rollout(points.reshape(M * P, n), ub).reshape(M, P, n)
            self._cache = (np.array(x, copy=True), np.array(u, copy=True), values[:, 0].copy())
            return differences(values, self.eps, self.centered)
        return self._jacobian_transition(x, u)

    def _jacobian_transition(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        model, data, A, gather = self.model, self._data, self._A, self._tangent
        M, j = len(x), self._j
        inputs = self.controls(u)
        ctrl = inputs.get("ctrl")
        xfrc = inputs.get("xfrc")
        J = np.empty((M, self.n, self.n))
        out = np.empty((M, self.n))
        rig = self.rig
        for i in range(M):
            mujoco.mj_resetData(model, data)
            data.qpos[rig.qpos_adr] = x[i, :j]
            data.qvel[rig.dof_adr] = x[i, j:]
            if ctrl is not None:
                data.ctrl[:] = ctrl[i]
            if xfrc is not None:
                data.xfrc_applied[:] = xfrc[i]
            Ji = None
            for _ in range(self.frame_skip):
                mujoco.mjd_transitionFD(model, data, self.eps, self.centered, A, None, None,
                                        None)
                Ji = A.copy() if Ji is None else A @ Ji
                mujoco.mj_step(model, data)
            J[i] = Ji[np.ix_(gather, gather)]
            out[i, :j] = data.qpos[rig.qpos_adr]
            out[i, j:] = data.qvel[rig.dof_adr]
        self._cache = (np.array(x, copy=True), np.array(u, copy=True), out)
        return J


def gravity(model: mujoco.MjModel) -> float:
    """The magnitude of the model's gravity (``opt.gravity``), m/s^2."""
    return float(np.linalg.norm(model.opt.gravity))


class PhysicalInput:
    """The rig's physical input ``w`` of a design state and input (design coordinates).

    ``w = o(x) + S_u (u - [o(x), 0]) + S_e e`` with ``o`` the rig's operating input at the
    nominal parameters (zero without an input transform), ``e`` the design's extra
    (actuator) states and ``S_u``, ``S_e`` the design's :class:`InputStates` (default
    ``S_u = [I, 0]``: ``w`` is ``u``'s rig columns). ``u`` is absolute (the loop's input in
    design coordinates plus ``[o(x_hat), 0]``: :class:`AbsoluteInput`).

    Parameters
    ----------
    rig : Rig
        The designer's rig.
    design : DesignModel
    """

    def __init__(self, rig: Rig, design: DesignModel) -> None:
        self.rig, self.params = rig, rig.params
        self.nr, self.kr, self.k = rig.n_states, rig.n_actions, len(design.input_names)
        extra = (design.extras.get("augmentation") or {}).get("extra", []) \
            if design.augmented else []
        self.ne = len(extra)
        spec = design.extras.get("input_states")
        if self.ne and not isinstance(spec, InputStates):
            raise ValueError(f"the design's extra states {extra} need "
                             "design.extras['input_states'] (how they reach the rig's input) "
                             "for the nonlinear filters")
        if spec is None:
            spec = InputStates(from_input=np.eye(self.kr, self.k),
                               from_states=np.zeros((self.kr, 0)),
                               relative=np.zeros((0, self.kr)))
        spec.check(self.kr, self.k, self.ne)
        self.spec = spec
        self.offsets = design.input_transform is not None
        #: ``w`` is ``u``'s rig columns (no extra states, ``S_u = [I, 0]``).
        self.plain = self.ne == 0 and np.array_equal(spec.from_input, np.eye(self.kr, self.k))

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        """``dw/d[p, e]`` (M, k_rig, n_rig + n_e) at rig states ``p`` (M, n_rig): ``[(I -
        S_u,r) do/dp, S_e]`` (``w`` is linear in ``e``, in ``u`` and in ``o(p)``; ``S_u,r`` the
        rig's input columns of ``S_u``), ``do/dp`` by central differences of ``o`` (step
        :data:`FD_EPS`)."""
        M, nr, kr = len(p), self.nr, self.kr
        out = np.zeros((M, kr, nr + self.ne))
        out[:, :, nr:] = self.spec.from_states
        if self.offsets:
            q = perturbed(p, FD_EPS, True)
            o = self.offset(q.reshape(-1, nr)).reshape(M, q.shape[1], kr)
            from_input = np.eye(kr) - np.asarray(self.spec.from_input, float)[:, :kr]
            out[:, :, :nr] = from_input @ differences(o, FD_EPS, True)
        return out

    def offset(self, p: np.ndarray) -> np.ndarray:
        """``o(x)`` (M, k_rig) of the rig states ``p`` (M, n_rig)."""
        if not self.offsets:
            return np.zeros((len(p), self.kr))
        return np.asarray(self.rig.operating_input(self.params, p), float)

    def relative(self, p: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``u - [o(x), 0]``, shape (M, k)."""
        rel = np.array(u, float, copy=True)
        rel[:, :self.kr] -= self.offset(p)
        return rel

    def __call__(self, p: np.ndarray, e: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``w`` (M, k_rig) of rig states ``p`` (M, n_rig), extra states ``e`` (M, n_e)
        and absolute inputs ``u`` (M, k)."""
        if self.plain:
            return u[:, :self.kr]
        rel = self.relative(p, u)
        return self.offset(p) + rel @ self.spec.from_input.T + e @ self.spec.from_states.T
