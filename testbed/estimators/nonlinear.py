"""Nonlinear design models: the rig's own MuJoCo model, at nominal parameters, as ``f`` and ``h``.

The extended and the unscented Kalman filter (:class:`filters.ExtendedKalmanFilter`,
:class:`filters.UnscentedKalmanFilter`; registered as ``ekf`` and ``ukf`` in
:mod:`testbed.estimators`) need the rig's nonlinear model where the linear filters use
``design.discrete``. What the designer knows is the same as for the linear design model
(:mod:`testbed.design`): the rig's MJCF with NOMINAL parameters (a fresh rig of the
design's class in its first profile, never the simulated, possibly mismatched or
``hardware`` truth), the sensors' model and the noise covariances ``Q``, ``R`` of
``design.discrete``.

Process model :class:`MujocoProcessModel` (a design whose state is the rig's)
    ``f(x, u)``: the nominal model stepped over one control period (``frame_skip`` physics
    steps of the designer's copy, the input held: zero-order hold), all rows of ``x`` in one
    :func:`mujoco.rollout.rollout` call (the UKF's sigma points of every member at once).
    ``F(x, u)``: the Jacobian ``df/dx`` by finite differences of the whole period, every
    perturbed initial state of every row in the same single rollout call (forward or central
    differences); ``jacobian="transition"`` takes the product of MuJoCo's per-physics-step
    transition derivatives (:func:`mujoco.mjd_transitionFD`) along each row's trajectory
    instead (the reference the tests compare with). Either also yields ``f(x, u)``, which
    ``f`` then returns from a cache (the EKF evaluates ``F`` before ``f``).
Process model :class:`AugmentedProcessModel` (a matched, augmented design)
    The rig's states through the MuJoCo model, composed with the design's extra (actuator)
    states, which drive the MuJoCo input per physics step (:class:`PhysicalInput`,
    ``design.extras["input_states"]``), its bias random walks and delay states (the design's
    own rows: one source of truth for their dynamics, ``Q`` and ``R``); the first delay state
    of a nonlinear channel takes the channel's nonlinear value.
Measurement model :class:`MeasurementModel`
    ``h(x, u) = H x + D u`` with ``design.discrete``'s rows, except channels whose nonlinear
    form the sensors declare (``SensorModel.nonlinear``: the helicopter IMU's ``gyro_yaw =
    yaw_rate cos(pitch)`` and ``accel_x = g sin(pitch)``, the vehicle's ``lateral_accel = a_y
    cos(roll) + g sin(roll)``) and read the rig's states directly, which are used as they
    are, with their analytic Jacobians (``g`` is the model's ``opt.gravity``).
Input
    The loop gives an estimator ``u`` in the design model's coordinates
    (``design.input_transform(u_applied, x_hat)`` with ``x_hat`` the estimate before the
    step). Every rig's design takes the input relative to :meth:`Rig.operating_input` at the
    estimate (the helicopter: minus the voltage compensating gravity; zero for the others),
    so :class:`AbsoluteInput` adds ``operating_input(nominal, x_hat)`` back before the filter
    runs ``f``: ``f`` sees the voltage the motors got (a design without an input transform
    gets ``u`` unchanged). (A vehicle-roll design with measured
    ``a_y`` replaces ``u`` by the measurement: its operating input is zero, so ``f`` gets the
    measured ``a_y``.)

State mapping: ``x = [positions of rig.joints, their velocities, extra states...]`` (the
design's state names), the rig's part written into ``qpos``/``qvel`` of a reset ``MjData``
(time 0, zero warm start); the MuJoCo model must have no other degrees of freedom and no
actuator states (``na = 0``: a ``hardware`` profile's motor lag is the design's extra states,
not the nominal model's). The gravity and the joint limits of the MJCF are in ``f`` (the
helicopter's pitch stop included).

This module imports no rig module: the designer's rig class comes with the design
(``design.extras["rig_type"]``).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import mujoco
import mujoco.rollout
import numpy as np
from scipy.linalg import expm

from filters import ExtendedKalmanFilter, UnscentedKalmanFilter
from testbed.design import DesignModel, InputStates
from testbed.estimators import EstimatorWrapper
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
        self.points = int(linearization_steps(frame_skip, jacobian_points).size)
        self._buffers: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._models: dict[int, list[mujoco.MjModel]] = {}
        self._cache: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._pool: Any = None  # mujoco.rollout.Rollout with nthread threads, made on use

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_buffers"], state["_pool"] = {}, None  # scratch and threads: not copied
        state["_models"] = {}
        return state

    # ------------------------------------------------------------------ inputs
    def controls(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """MuJoCo inputs of absolute inputs ``u`` (M, k) (:meth:`Rig.actuation` at the
        nominal member constants): ``"ctrl"`` (M, nu) and/or ``"xfrc"`` (M, nbody, 6)."""
        constants = np.broadcast_to(self._constants, (len(u), len(self._constants)))
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
        state0 = np.tile(self._template, (M, 1))
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
                control = np.ascontiguousarray(np.broadcast_to(
                    self._control_vectors(self.controls(w[:, 0]), M)[:, None, :],
                    (M, nstep, self._ncontrol)))
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
        if self.nthread > 1:  # this model's own pool (not the module-wide persistent one)
            if self._pool is None:
                self._pool = mujoco.rollout.Rollout(nthread=self.nthread)
            self._pool.rollout(models, self._datas, state0, control,
                               control_spec=self._spec, skip_checks=True, nstep=nstep,
                               state=state, sensordata=sensordata)
        else:
            mujoco.rollout.rollout(models, [self._data], state0, control,
                                   control_spec=self._spec, skip_checks=True, nstep=nstep,
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
            out, J = period_tangent(self, x, u[:, None, :], None, self.n, self.points)
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

    @property
    def plain(self) -> bool:
        """``w`` is ``u``'s rig columns (no extra states, ``S_u = [I, 0]``)."""
        return self.ne == 0 and np.array_equal(self.spec.from_input, np.eye(self.kr, self.k))

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


class MeasurementModel:
    """``y = h(x, u)`` of the design's modelled channels (``design.measurement_index``).

    The rows of ``design.discrete`` (``H x + D u``: linear channels, bias and delay states),
    except the channels the sensors declare nonlinear (``design.sensors.nonlinear``) that
    read the rig's states directly (not through delay states): their rig-state part is the
    nonlinear function of the rig state and the physical input ``w``
    (:class:`PhysicalInput`), the rest of their row (bias states) stays. A delayed nonlinear
    channel is nonlinear in its first delay state's transition instead
    (:class:`AugmentedProcessModel`).

    Parameters
    ----------
    design : DesignModel
    rig : Rig, optional
        The designer's rig (its gravity and operating input); default: a nominal one
        (:func:`nominal_rig`).

    Attributes
    ----------
    names : tuple of str
        The modelled channels, in ``y`` order.
    nonlinear : tuple of str
        Those used in their nonlinear form here.
    """

    def __init__(self, design: DesignModel, rig: Rig | None = None) -> None:
        rig = nominal_rig(design) if rig is None else rig
        index = np.asarray(design.measurement_index, int)
        self.names = tuple(design.measurement_names[i] for i in index)
        self.C = np.array(design.discrete.H, float)
        self.D = np.zeros((len(index), len(design.input_names))) if design.discrete.D is None \
            else np.array(design.discrete.D, float)
        self.g = gravity(rig.model)
        self.input = PhysicalInput(rig, design)
        nr, ne = self.input.nr, self.input.ne
        self._d = nr + ne
        delays = (design.extras.get("augmentation") or {}).get("delays", {}) \
            if design.augmented else {}
        declared = design.sensors.nonlinear
        self._rows = [(row, *declared[name]) for row, name in enumerate(self.names)
                      if name in declared and not delays.get(name)]
        self.nonlinear = tuple(self.names[row] for row, *_ in self._rows)

    def _split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nr = self.input.nr
        return x[:, :nr], x[:, nr:self._d]

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``h(x, u)``, shape (M, m), for ``x`` (M, n) and ``u`` (M, k)."""
        y = x @ self.C.T + u @ self.D.T
        if self._rows:
            p, e = self._split(x)
            w = self.input(p, e, u)
            rest = x[:, self._d:]
            for row, value, _, _ in self._rows:
                y[:, row] = value(p, w, self.g) + rest @ self.C[row, self._d:]
        return y

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``H(x, u) = dh/dx``, shape (M, m, n).

        The nonlinear rows: analytic gradients in the rig states; with extra states or
        input offsets (``w`` depends on the state) the rig/extra-state block by central
        differences of ``w`` (step :data:`FD_EPS`).
        """
        H = np.repeat(self.C[None], len(x), axis=0)
        if not self._rows:
            return H
        p, e = self._split(x)
        w = self.input(p, e, u)
        nr = self.input.nr
        dw = None
        if not self.input.plain:  # dw / d[p, e] (M, k_rig, nr + ne)
            pe = x[:, :self._d]
            pts = perturbed(pe, FD_EPS, True)
            M, P, d = pts.shape
            flat = pts.reshape(M * P, d)
            ws = self.input(flat[:, :nr], flat[:, nr:], np.repeat(u, P, axis=0))
            dw = differences(ws.reshape(M, P, -1), FD_EPS, True)
        for row, _, grad_x, grad_w in self._rows:
            H[:, row, :self._d] = 0.0
            H[:, row, :nr] = grad_x(p, w, self.g)
            if dw is not None:
                H[:, row, :self._d] += np.einsum("mk,mkd->md", grad_w(p, w, self.g), dw)
        return H


class AugmentedProcessModel:
    """``f(x, u)`` of a matched (augmented) design: the rig's MuJoCo model composed with the
    design's extra (actuator), bias and delay states.

    State ``x = [p (rig states), e (extra states), rest (biases, delays, input memory)]``
    (:func:`testbed.design.build_matched_design`'s order); ``u`` absolute
    (:class:`AbsoluteInput`).

    - ``e``: the design's continuous ``A_ee``, ``B_e`` (the matched linear design, one
      source of truth), exactly discretized per physics step: ``e_{i+1} = Phi e_i + Gamma
      (u - [o(x_k), 0])``; the physical input of physics step ``i`` is ``w_i = o(x_k) + S_u
      (u - [o(x_k), 0]) + S_e e_i`` (:class:`PhysicalInput`, ``o`` the operating input at the
      period's start). Extra states relative to the operating input (the helicopter's
      ``dact = act - V_g(pitch)``, :attr:`InputStates.relative`) are re-referenced to the
      period's end state: ``e_{k+1} = e_N + R (o(x_k) - o(x_{k+1}))``.
    - ``p``: the nominal MuJoCo model stepped ``frame_skip`` physics steps with the inputs
      ``w_i`` (:meth:`MujocoProcessModel.rollout`; gravity and joint limits in the MJCF, so a
      design input that stands for a stop's reaction is not a MuJoCo input).
    - ``rest``: the rows of ``design.discrete`` (``F``, ``B``), except the first delay state
      of a channel the sensors declare nonlinear (``SensorModel.nonlinear``), which takes the
      channel's nonlinear value
      ``h(p_k, w_0)`` (``w`` of the input memory when the design keeps one).

    Rows of ``x`` that share ``[p, e]`` and ``u`` bitwise are rolled out once.

    Jacobian ``F(x, u)``: the ``[p, e]`` columns of the ``[p, e]`` rows and of the
    nonlinear delay rows by finite differences (step ``eps``, forward or ``centered``) over
    one rollout of every perturbed state of every row; the other entries exactly from
    ``design.discrete.F``.

    Parameters
    ----------
    design : DesignModel
        Augmented (``design.physical_index`` set).
    process : MujocoProcessModel
        The nominal rig's model at ``design.dt_s``.
    """

    def __init__(self, design: DesignModel, process: MujocoProcessModel) -> None:
        rig = process.rig
        self.process, self.rig = process, rig
        self.input = PhysicalInput(rig, design)
        nr, ne = self.input.nr, self.input.ne
        self.nr, self.ne, self.d, self.n = nr, ne, nr + ne, design.n
        self.k = len(design.input_names)
        self.eps, self.centered = process.eps, process.centered
        Ac = np.asarray(design.continuous.A, float)
        Bc = np.asarray(design.continuous.B, float)
        e = slice(nr, nr + ne)
        if np.any(Ac[e, :nr]) or np.any(Ac[e, nr + ne:]):
            raise ValueError("the design's extra states must evolve on their own (A_ee, B_e): "
                             "rows of A couple them to other states")
        h = float(process.model.opt.timestep)
        N = process.frame_skip
        # [Phi Gamma; 0 I] per physics step (exact ZOH), and its powers 0..N
        blk = np.zeros((ne + self.k, ne + self.k))
        blk[:ne, :ne], blk[:ne, ne:] = Ac[e, e], Bc[e]
        step = expm(blk * h)
        powers = [np.eye(ne + self.k)]
        for _ in range(N):
            powers.append(step @ powers[-1])
        stack = np.stack(powers)  # (N + 1, ne + k, ne + k)
        self._Phi = np.ascontiguousarray(stack[:, :ne, :ne])  # (N + 1, ne, ne)
        self._Gam = np.ascontiguousarray(stack[:, :ne, ne:])  # (N + 1, ne, k)
        F = np.asarray(design.discrete.F, float)
        self._F_rest = F[self.d:]
        self._B_rest = np.asarray(design.discrete.B, float)[self.d:]
        self.g = gravity(process.model)
        names = list(design.state_names)
        delays = (design.extras.get("augmentation") or {}).get("delays", {})
        mem = [i for i, nm_ in enumerate(names) if i >= self.d and nm_.endswith("_prev")
               and nm_[:-5] in design.input_names]
        self._memory = np.array(mem, int) if len(mem) == self.k else None
        self._rows = []
        declared = design.sensors.nonlinear
        for ch, d in delays.items():
            if d and ch in declared:
                self._rows.append((names.index(f"{ch}_delay1") - self.d, *declared[ch]))
        self.nonlinear = tuple(ch for ch, d in delays.items() if d and ch in declared)
        self._cache: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def _inputs(self, x: np.ndarray, u: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The physical inputs of a period's physics steps from ``x``'s ``[p, e]`` columns.

        Returns
        -------
        W : ndarray, shape (M, N, k_rig), or (M, 1, k_rig) for a plain input (held)
        E_N : ndarray, shape (M, n_e), or None (plain)
            The extra states at the period's end, before re-referencing.
        off : ndarray, shape (M, k_rig), or None (plain)
            The operating input at the period's start.
        """
        nr, inp = self.nr, self.input
        if inp.plain:
            return u[:, None, :inp.kr], None, None
        p, e = x[:, :nr], x[:, nr:self.d]
        off = inp.offset(p)
        rel = inp.relative(p, u)
        # e_i, i = 0..N: Phi^i e + Gamma_i rel
        E = np.einsum("iab,mb->mia", self._Phi, e) + np.einsum("iak,mk->mia", self._Gam, rel)
        base = off + rel @ inp.spec.from_input.T  # (M, k_rig)
        W = base[:, None, :] + E[:, :-1] @ inp.spec.from_states.T  # (M, N, k_rig)
        return W, E[:, -1], off

    def _ends(self, p_next: np.ndarray, E_N: np.ndarray, off: np.ndarray) -> np.ndarray:
        """The extra states at the period's end, re-referenced to ``p_next`` (M, n_e)."""
        relative = self.input.spec.relative
        if np.any(relative):
            return E_N + (off - self.input.offset(p_next)) @ relative.T
        return E_N

    def _pe(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The ``[p, e]`` part of ``f`` (M, d) and the first physical input ``w_0``."""
        W, E_N, off = self._inputs(x, u)
        p_next = self.process.rollout(x[:, :self.nr], W)
        if E_N is None:
            return p_next, W[:, 0]
        return np.concatenate([p_next, self._ends(p_next, E_N, off)], axis=1), W[:, 0]

    def _pe_unique(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_pe` with each bitwise-distinct ``([p, e], u)`` row rolled out once (the
        UKF's sigma points along the bias and delay states share the mean's)."""
        if len(x) < 2:
            return self._pe(x, u)
        key = np.ascontiguousarray(np.concatenate([x[:, :self.d], u], axis=1))
        rows = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1])))[:, 0]
        _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
        if len(first) == len(x):
            return self._pe(x, u)
        pe, w0 = self._pe(x[first], u[first])
        return pe[inverse], w0[inverse]

    def _full(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        pe, w0 = self._pe_unique(x, u)
        return np.concatenate([pe, self._rest(x, u, w0)], axis=1)

    def _rest(self, x: np.ndarray, u: np.ndarray, w0: np.ndarray) -> np.ndarray:
        """The bias, delay and memory rows of ``f`` (M, n - d), ``w0`` the first physical
        input of the period (M, k_rig)."""
        rest = x @ self._F_rest.T + u @ self._B_rest.T
        if self._rows:
            p = x[:, :self.nr]
            w = w0
            if self._memory is not None:  # the delayed channel sees the remembered input
                mem = x[:, self._memory]
                w = self.input(p, x[:, self.nr:self.d], mem)
            for row, value, _, _ in self._rows:
                rest[:, row] = value(p, w, self.g)
        return rest

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``f(x, u)``, shape (M, n), for ``x`` (M, n) and absolute ``u`` (M, k)."""
        cache = self._cache
        if cache is not None and np.array_equal(cache[0], x) and np.array_equal(cache[1], u):
            return cache[2].copy()
        return self._full(np.asarray(x, float), np.asarray(u, float))

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``F(x, u) = df/dx``, shape (M, n, n); caches ``f(x, u)`` for :meth:`__call__`.

        The ``[p, e]`` block as the process model's :attr:`MujocoProcessModel.method` says
        (``"step"``: :meth:`_jacobian_step`; otherwise finite differences of the whole
        period); the other entries as the class docstring says.
        """
        x, u = np.asarray(x, float), np.asarray(u, float)
        if self.process.method == "step":
            return self._jacobian_step(x, u)
        M, n, d = len(x), self.n, self.d
        pts = perturbed(x[:, :d], self.eps, self.centered)
        P = pts.shape[1]
        X = np.repeat(x[:, None, :], P, axis=1)
        X[:, :, :d] = pts
        values = self._full(X.reshape(M * P, n), np.repeat(u, P, axis=0)).reshape(M, P, n)
        self._cache = (x.copy(), u.copy(), values[:, 0].copy())
        J = np.zeros((M, n, n))
        J[:, d:] = self._F_rest
        J[:, :d, :d] = differences(values[:, :, :d], self.eps, self.centered)
        if self._rows:
            rows = np.array([d + row for row, *_ in self._rows])
            J[:, rows] = 0.0
            J[:, rows, :d] = differences(values[:, :, rows], self.eps, self.centered)
            if self._memory is not None:
                for row in rows:
                    J[:, row, self._memory] = self._memory_gradient(x, u, row - d)
        return J

    def _jacobian_step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """:meth:`jacobian` by the tangent recursion of the one-physics-step derivatives
        (:func:`testbed.estimators.jacobians.period_tangent`): ``dw_i/d[p, e]``, the end
        extra states' and the nonlinear delay rows' derivatives by finite differences of
        their closed forms (no physics), the rig block from ``1 + n_rig + k_rig`` single
        physics steps per row and linearization point."""
        M, n, d, nr = len(x), self.n, self.d, self.nr
        eps, centered = self.eps, self.centered
        pts = perturbed(x[:, :d], eps, centered)
        P = pts.shape[1]
        uu = np.repeat(u, P, axis=0)
        Wf, ENf, offf = self._inputs(pts.reshape(M * P, d), uu)
        Wp = Wf.reshape(M, P, *Wf.shape[1:])
        W = Wp[:, 0]
        dW = None
        if ENf is not None:
            N, kr = W.shape[1:]
            dW = differences(Wp.reshape(M, P, N * kr), eps, centered).reshape(M, N, kr, d)
        p_next, T = period_tangent(self.process, x[:, :nr], W, dW, d, self.process.points)
        if ENf is None:
            pe_next, J_pe = p_next, T
        else:
            relative = self.input.spec.relative
            ne = ENf.shape[1]
            G = ENf + offf @ relative.T  # E_N + R o(p): its derivative in [p, e]
            J_e = differences(G.reshape(M, P, ne), eps, centered)
            if np.any(relative):  # - R do/dp(p_next) T
                q = perturbed(p_next, eps, centered)
                o = self.input.offset(q.reshape(-1, nr)).reshape(M, q.shape[1], -1)
                J_e = J_e - relative @ (differences(o, eps, centered) @ T)
            E_N, off = ENf.reshape(M, P, ne)[:, 0], offf.reshape(M, P, -1)[:, 0]
            pe_next = np.concatenate([p_next, self._ends(p_next, E_N, off)], axis=1)
            J_pe = np.concatenate([T, J_e], axis=1)
        X = np.repeat(x[:, None, :], P, axis=1)
        X[:, :, :d] = pts
        rest = self._rest(X.reshape(M * P, n), uu, Wf[:, 0]).reshape(M, P, n - d)
        self._cache = (x.copy(), u.copy(), np.concatenate([pe_next, rest[:, 0]], axis=1))
        J = np.zeros((M, n, n))
        J[:, :d, :d] = J_pe
        J[:, d:] = self._F_rest
        if self._rows:
            rows = np.array([row for row, *_ in self._rows])
            J[:, d + rows] = 0.0
            J[:, d + rows, :d] = differences(rest[:, :, rows], eps, centered)
            if self._memory is not None:
                for row in rows:
                    J[:, d + row, self._memory] = self._memory_gradient(x, u, row)
        return J

    def _memory_gradient(self, x: np.ndarray, u: np.ndarray, row: int) -> np.ndarray:
        """d(first delay state)/d(input memory) of a nonlinear delayed channel (M, k)."""
        value = next(v for r, v, _, _ in self._rows if r == row)
        mem = x[:, self._memory]
        pts = perturbed(mem, FD_EPS, True)
        M, P, k = pts.shape
        p = np.repeat(x[:, :self.nr], P, axis=0)
        e = np.repeat(x[:, self.nr:self.d], P, axis=0)
        w = self.input(p, e, pts.reshape(M * P, k))
        vals = value(p, w, self.g).reshape(M, P, 1)
        return differences(vals, FD_EPS, True)[:, 0]


class AbsoluteInput(EstimatorWrapper):
    """A nonlinear filter fed the absolute input: ``u + [operating_input(nominal, x_hat), 0]``.

    The loop subtracts the operating input at the estimate before the step
    (``design.input_transform``); this adds it back at the same estimate (the inner filter's
    ``x`` before the step), so the process model sees the applied input. Inputs after the
    rig's own (a matched design's extra inputs) pass unchanged.

    Parameters
    ----------
    inner : estimator with batched ``x`` (N, n) (or (n,))
    offset : callable ``x_hat (N, n) -> (N, k_rig)``, or None
        None: ``u`` is passed on unchanged (a design without an input transform).
    k : int
        Input dimension.
    """

    batched = True

    def __init__(self, inner: Any, offset: Callable[[np.ndarray], np.ndarray] | None, k: int):
        super().__init__(inner)
        self.offset, self.k = offset, int(k)

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Step the inner filter with ``u + [offset(x), 0]`` (``u = None``: zero)."""
        if self.offset is None:
            return self.inner.step(y, u)
        x = np.asarray(self.inner.x)
        xb = x if x.ndim == 2 else x[None]
        extra = np.asarray(self.offset(xb), float)
        if extra.shape[1] < self.k:
            extra = np.pad(extra, ((0, 0), (0, self.k - extra.shape[1])))
        extra = extra if x.ndim == 2 else extra[0]
        u_abs = extra if u is None else np.asarray(u, float) + extra
        return self.inner.step(y, u_abs)


def nominal_rig(design: DesignModel) -> Rig:
    """The designer's rig: the design's rig class at its nominal parameters and options, first
    profile.

    The class, physics step, parameters and options come from ``design.extras["rig_type"]``,
    ``["physics_dt_s"]``, ``["rig_params"]`` and ``["rig_options"]`` (set by the design
    builders of :mod:`testbed.design` from the rig that designed).

    Raises
    ------
    ValueError
        The design names no MuJoCo rig.
    """
    rig_type, physics_dt_s = design.extras.get("rig_type"), design.extras.get("physics_dt_s")
    if not (isinstance(rig_type, type) and hasattr(rig_type, "xml_path")
            and callable(getattr(rig_type, "operating_input", None))):
        raise ValueError("the nonlinear filters need the rig's MuJoCo model: the design names "
                         "no rig (design.extras['rig_type'], set by "
                         "testbed.design.build_design)")
    params, options = design.extras.get("rig_params"), design.extras.get("rig_options")
    kwargs: dict[str, Any] = {"options": options} if options else {}  # as rigs.base.build_rig
    if physics_dt_s is not None:
        kwargs["physics_dt_s"] = float(physics_dt_s)
    return rig_type(params, **kwargs)


def nonlinear_models(design: DesignModel, *, eps: float = FD_EPS, centered: bool = False,
                     jacobian: str = "step", jacobian_points: int = 1, nthread: int = 0
                     ) -> tuple[Rig, MujocoProcessModel | AugmentedProcessModel,
                                MeasurementModel]:
    """The nominal rig, the process model at ``design.dt_s`` and the measurement model.

    A design whose state is the rig's gets :class:`MujocoProcessModel`; an augmented
    (matched) design :class:`AugmentedProcessModel` on it.

    Raises
    ------
    ValueError
        The design's (physical) states are not the rig's joint state.
    """
    rig = nominal_rig(design)
    names = tuple(design.state_names[i] for i in design.physical) if design.augmented \
        else tuple(design.state_names)
    if names != tuple(rig.state_names):
        raise ValueError(f"the nonlinear filters model the rig's state {list(rig.state_names)}; "
                         f"this design's state is {list(design.state_names)}")
    process = MujocoProcessModel(rig, design.dt_s, eps=eps, centered=centered,
                                 jacobian=jacobian, jacobian_points=jacobian_points,
                                 nthread=nthread)
    measure = MeasurementModel(design, rig)
    if design.augmented:
        if not np.array_equal(design.physical, np.arange(rig.n_states)):
            raise ValueError("the nonlinear filters need the rig's states first in an "
                             f"augmented design, got physical_index {design.physical_index}")
        return rig, AugmentedProcessModel(design, process), measure
    return rig, process, measure


def nonlinear_estimator(design: DesignModel, kind: str, *, eps: float = FD_EPS,
                        centered: bool = False, alpha: float = 1e-3, beta: float = 2.0,
                        kappa: float = 0.0, jacobian: str = "step", jacobian_points: int = 1,
                        nthread: int = 0) -> AbsoluteInput:
    """An EKF (``kind="ekf"``) or UKF (``"ukf"``) on the rig's nominal MuJoCo model.

    ``Q``, ``R`` and the prior are the design's (``design.discrete``, ``x0``, ``P0``); the
    filter reads the channels ``design.measurement_index`` (the caller selects them). On an
    augmented (matched) design the filter's state is the design's (:class:`
    AugmentedProcessModel`).

    Parameters
    ----------
    design : DesignModel
    kind : {"ekf", "ukf"}
    eps : float
        Finite-difference step of the EKF's Jacobian.
    centered : bool
        Central or forward (default) differences for the EKF's Jacobian.
    alpha, beta, kappa : float
        The UKF's sigma-point parameters (Wan & van der Merwe's defaults).
    jacobian : {"step", "rollout", "transition"}
        The EKF's Jacobian method (:class:`MujocoProcessModel`); ``jacobian_points`` its
        linearization points per period (``"step"``).
    nthread : int
        Threads of the rollout calls (0: the calling thread; results do not depend on it).

    Returns
    -------
    AbsoluteInput
        The batched filter (``x`` (N, n) after a batched reset) with the input correction.
    """
    rig, process, measure = nonlinear_models(design, eps=eps, centered=centered,
                                             jacobian=jacobian,
                                             jacobian_points=jacobian_points, nthread=nthread)
    plant = design.discrete
    k = len(design.input_names)
    if kind == "ekf":
        est: Any = ExtendedKalmanFilter(process, process.jacobian, measure, measure.jacobian,
                                        plant.Q, plant.R, design.x0, design.P0, k=k,
                                        dt_s=design.dt_s)
    elif kind == "ukf":
        est = UnscentedKalmanFilter(process, measure, plant.Q, plant.R, design.x0, design.P0,
                                    alpha=alpha, beta=beta, kappa=kappa, k=k, dt_s=design.dt_s)
    else:
        raise ValueError(f"kind must be 'ekf' or 'ukf', got {kind!r}")
    est.batched = True
    if design.input_transform is None:  # the loop passes the applied input unchanged
        return AbsoluteInput(est, None, k)
    params, nr = rig.params, rig.n_states
    return AbsoluteInput(est, lambda x: rig.operating_input(params, x[:, :nr]), k)
