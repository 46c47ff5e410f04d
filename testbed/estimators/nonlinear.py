"""Nonlinear design models: the rig's own MuJoCo model, at nominal parameters, as ``f`` and ``h``.

The extended and the unscented Kalman filter (:class:`filters.ExtendedKalmanFilter`,
:class:`filters.UnscentedKalmanFilter`; registered as ``ekf`` and ``ukf`` in
:mod:`testbed.estimators`) need the rig's nonlinear model where the linear filters use
``design.discrete``. What the designer knows is the same as for the linear design model
(:mod:`testbed.estimators.design`): the rig's MJCF with NOMINAL parameters (a fresh rig of the
design's
class in its first profile, never the simulated, possibly mismatched or ``hardware`` truth),
the sensors' model and the noise covariances ``Q``, ``R`` of ``design.discrete``.

Process model :class:`MujocoProcessModel`
    ``f(x, u)``: the nominal model stepped over one control period (``frame_skip`` physics
    steps of the designer's copy, the input held: zero-order hold), all rows of ``x`` in one
    :func:`mujoco.rollout.rollout` call (the UKF's sigma points of every member at once).
    ``F(x, u)``: the Jacobian ``df/dx``, the product of MuJoCo's finite-difference
    transition derivatives (:func:`mujoco.mjd_transitionFD`, forward or central differences)
    of the physics steps along the step's own trajectory; it also yields ``f(x, u)``, which
    ``f`` then returns from a cache (the EKF evaluates ``F`` before ``f``).
Measurement model :class:`MeasurementModel`
    ``h(x, u) = C x + D u`` with the sensors' linear model at ``design.measurement_index``
    (``design.sensors``), except channels whose nonlinear form is known
    (:data:`NONLINEAR_CHANNELS`: the helicopter IMU's ``gyro_yaw = yaw_rate cos(pitch)`` and
    ``accel_x = g sin(pitch)``, the vehicle's ``lateral_accel = a_y cos(roll) + g sin(roll)``),
    which are used as they are, with their analytic Jacobians.
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

State mapping: ``x = [positions of rig.joints, their velocities]`` (the design's state
names), written into ``qpos``/``qvel`` of a reset ``MjData`` (time 0, zero warm start); the
model must have no other degrees of freedom and no actuator states (``na = 0``: the
``hardware`` profile's motor lag is not in the nominal model). The gravity and the joint
limits of the MJCF are in ``f`` (the helicopter's pitch stop included).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import mujoco
import mujoco.rollout
import numpy as np

from filters import ExtendedKalmanFilter, UnscentedKalmanFilter
from testbed.estimators import EstimatorWrapper
from testbed.estimators.design import DesignModel
from testbed.rigs.base import GRAVITY_M_S2, Rig

_FULL = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
_CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
_XFRC = int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)
#: Default finite-difference step of :func:`mujoco.mjd_transitionFD` (state units).
FD_EPS = 1e-6


def _offset(model: mujoco.MjModel, spec: int, component: int) -> int:
    """Offset of one component in a ``spec`` state vector (components in bit order)."""
    return sum(mujoco.mj_stateSize(model, 1 << k) for k in range(component.bit_length() - 1)
               if spec & (1 << k))


class MujocoProcessModel:
    """``x_{k+1} = f(x_k, u_k)``: a rig's MuJoCo model over one control period.

    Parameters
    ----------
    rig : testbed.rigs.base.Rig
        The designer's rig (nominal parameters); its ``model`` is stepped, not changed.
    dt_s : float
        Control period, a whole number of the model's physics steps.
    eps : float
        Finite-difference step of :func:`mujoco.mjd_transitionFD`.
    centered : bool
        Central differences (``2 (2 nv)`` extra physics steps per physics step of the period)
        or forward differences (default: ``2 nv``, half the cost; first-order accurate in
        ``eps``, an error of order ``eps`` relative, far below what a filter notices).

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
        (:attr:`Rig.needs_substep`).
    """

    def __init__(self, rig: Rig, dt_s: float, *, eps: float = FD_EPS,
                 centered: bool = False) -> None:
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
        self.rig, self.model, self.frame_skip, self.eps = rig, model, frame_skip, float(eps)
        self.centered = bool(centered)
        self.n, self.k = rig.n_states, rig.n_actions
        self._j = j
        self._data = mujoco.MjData(model)
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
        self._buffers: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._cache: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

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
        All ``M`` rows in one :func:`mujoco.rollout.rollout` call (one thread, the model's
        own step), unless :meth:`jacobian` has just been evaluated at the same ``(x, u)``.
        """
        cache = self._cache
        if cache is not None and np.array_equal(cache[0], x) and np.array_equal(cache[1], u):
            return cache[2].copy()
        M = len(x)
        state0 = np.tile(self._template, (M, 1))
        state0[:, self._gather] = x
        nstep = self.frame_skip
        control = None
        if self._spec:
            control = np.ascontiguousarray(np.broadcast_to(
                self._control_vectors(self.controls(u), M)[:, None, :],
                (M, nstep, self._ncontrol)))
        if M not in self._buffers:
            self._buffers[M] = (np.zeros((M, nstep, len(self._template))),
                                np.zeros((M, nstep, self.model.nsensordata)))
        state, sensordata = self._buffers[M]
        mujoco.rollout.rollout([self.model] * M, [self._data], state0, control,
                               control_spec=self._spec, skip_checks=True, nstep=nstep,
                               state=state, sensordata=sensordata)
        return state[:, -1][:, self._gather]

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``F(x, u) = df/dx``, shape (M, n, n), by :func:`mujoco.mjd_transitionFD`.

        For each row: the product ``A_s ... A_1`` of the transition derivatives of the
        ``frame_skip`` physics steps (:attr:`centered` differences, step :attr:`eps`) along
        the row's own
        trajectory, in the rig's state order. The trajectory's end, ``f(x, u)``, is cached
        for the next :meth:`__call__` at the same arguments.
        """
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


#: Measurement channels used in their nonlinear form, by ``(rig name, channel name)``:
#: ``(value (x (M, n), u (M, k)) -> (M,), gradient (x, u) -> (M, n))``.
NONLINEAR_CHANNELS: dict[tuple[str, str], tuple[Callable[..., np.ndarray],
                                                  Callable[..., np.ndarray]]] = {
    # helicopter IMU at the pivot (testbed.rigs.helicopter.imu): x = [pitch, yaw, rates]
    ("helicopter", "gyro_yaw"): (
        lambda x, u: x[:, 3] * np.cos(x[:, 0]),
        lambda x, u: np.stack([-x[:, 3] * np.sin(x[:, 0]), np.zeros(len(x)),
                               np.zeros(len(x)), np.cos(x[:, 0])], axis=1)),
    ("helicopter", "accel_x"): (
        lambda x, u: GRAVITY_M_S2 * np.sin(x[:, 0]),
        lambda x, u: np.stack([GRAVITY_M_S2 * np.cos(x[:, 0])] + [np.zeros(len(x))] * 3,
                              axis=1)),
    # vehicle lateral accelerometer (testbed.rigs.vehicle_roll.sensors): x = [roll, rate]
    ("vehicle-roll", "lateral_accel"): (
        lambda x, u: u[:, 0] * np.cos(x[:, 0]) + GRAVITY_M_S2 * np.sin(x[:, 0]),
        lambda x, u: np.stack([-u[:, 0] * np.sin(x[:, 0]) + GRAVITY_M_S2 * np.cos(x[:, 0]),
                               np.zeros(len(x))], axis=1)),
}


class MeasurementModel:
    """``y = h(x, u)`` of the design's modelled channels (``design.measurement_index``).

    Linear rows ``C x + D u`` from ``design.sensors``; the channels of
    :data:`NONLINEAR_CHANNELS` for this rig replace theirs.

    Parameters
    ----------
    design : DesignModel
    rig_name : str

    Attributes
    ----------
    names : tuple of str
        The modelled channels, in ``y`` order.
    nonlinear : tuple of str
        Those used in their nonlinear form.
    """

    def __init__(self, design: DesignModel, rig_name: str) -> None:
        index = np.asarray(design.measurement_index, int)
        self.names = tuple(design.measurement_names[i] for i in index)
        self.C = np.array(design.sensors.C[index], float)
        self.D = np.array(design.sensors.D[index], float)
        self._rows = [(row, *NONLINEAR_CHANNELS[(rig_name, name)])
                      for row, name in enumerate(self.names)
                      if (rig_name, name) in NONLINEAR_CHANNELS]
        self.nonlinear = tuple(self.names[row] for row, _, _ in self._rows)

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``h(x, u)``, shape (M, m), for ``x`` (M, n) and ``u`` (M, k)."""
        y = x @ self.C.T + u @ self.D.T
        for row, value, _ in self._rows:
            y[:, row] = value(x, u)
        return y

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``H(x, u) = dh/dx``, shape (M, m, n)."""
        H = np.repeat(self.C[None], len(x), axis=0)
        for row, _, grad in self._rows:
            H[:, row] = grad(x, u)
        return H


class AbsoluteInput(EstimatorWrapper):
    """A nonlinear filter fed the absolute input: ``u + operating_input(nominal, x_hat)``.

    The loop subtracts the operating input at the estimate before the step
    (``design.input_transform``); this adds it back at the same estimate (the inner filter's
    ``x`` before the step), so the process model sees the applied input.

    Parameters
    ----------
    inner : estimator with batched ``x`` (N, n) (or (n,))
    offset : callable ``x_hat (N, n) -> (N, k)``, or None
        None: ``u`` is passed on unchanged (a design without an input transform).
    k : int
        Input dimension.
    """

    batched = True

    def __init__(self, inner: Any, offset: Callable[[np.ndarray], np.ndarray] | None, k: int):
        super().__init__(inner)
        self.offset, self.k = offset, int(k)

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Step the inner filter with ``u + offset(x)`` (``u = None``: zero)."""
        if self.offset is None:
            return self.inner.step(y, u)
        x = np.asarray(self.inner.x)
        xb = x if x.ndim == 2 else x[None]
        extra = np.asarray(self.offset(xb), float)
        extra = extra if x.ndim == 2 else extra[0]
        u_abs = extra if u is None else np.asarray(u, float) + extra
        return self.inner.step(y, u_abs)


def nominal_rig(design: DesignModel) -> Rig:
    """The designer's rig: the design's rig class at nominal parameters, first profile.

    The class and physics step come from ``design.extras["rig_type"]`` and
    ``["physics_dt_s"]`` (set by the design builders of :mod:`testbed.estimators.design`
    from the rig that designed).

    Raises
    ------
    ValueError
        The design names no MuJoCo rig.
    """
    rig_type, physics_dt_s = design.extras.get("rig_type"), design.extras.get("physics_dt_s")
    if not (isinstance(rig_type, type) and issubclass(rig_type, Rig)):
        raise ValueError("the nonlinear filters need the rig's MuJoCo model: the design names "
                         "no rig (design.extras['rig_type'], set by "
                         "testbed.estimators.design.build_design)")
    if physics_dt_s is None:
        return rig_type()
    return rig_type(physics_dt_s=float(physics_dt_s))


def nonlinear_models(design: DesignModel, *, eps: float = FD_EPS, centered: bool = False
                     ) -> tuple[Rig, MujocoProcessModel, MeasurementModel]:
    """The nominal rig, its process model at ``design.dt_s`` and the measurement model.

    Raises
    ------
    ValueError
        The design's state is not the rig's joint state (e.g. an augmented design).
    """
    rig = nominal_rig(design)
    if tuple(design.state_names) != tuple(rig.state_names):
        raise ValueError(f"the nonlinear filters model the rig's state {list(rig.state_names)}; "
                         f"this design's state is {list(design.state_names)}")
    process = MujocoProcessModel(rig, design.dt_s, eps=eps, centered=centered)
    return rig, process, MeasurementModel(design, rig.name)


def nonlinear_estimator(design: DesignModel, kind: str, *, eps: float = FD_EPS,
                        centered: bool = False, alpha: float = 1e-3, beta: float = 2.0,
                        kappa: float = 0.0) -> AbsoluteInput:
    """An EKF (``kind="ekf"``) or UKF (``"ukf"``) on the rig's nominal MuJoCo model.

    ``Q``, ``R`` and the prior are the design's (``design.discrete``, ``x0``, ``P0``); the
    filter reads the channels ``design.measurement_index`` (the caller selects them).

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

    Returns
    -------
    AbsoluteInput
        The batched filter (``x`` (N, n) after a batched reset) with the input correction.
    """
    rig, process, measure = nonlinear_models(design, eps=eps, centered=centered)
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
    params = rig.params
    return AbsoluteInput(est, lambda x: rig.operating_input(params, x), k)
