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
    ``F(x, u)``: the Jacobian ``df/dx`` (default ``jacobian="step"``) from the derivatives
    of ONE physics step at the period's midpoint of each row's own trajectory, held over the
    period and composed with the inputs' dependence on the state
    (:mod:`testbed.estimators.jacobians`; ``jacobian_points`` linearization points per
    period, all ``frame_skip`` of them for the exact product): ``1 + n + k`` single physics
    steps per row beside the period's own ``frame_skip``. ``jacobian="rollout"`` (the method
    before, ``n`` extra periods per row) takes finite differences of the whole period, every
    perturbed initial state of every row in the same single rollout call (forward or central
    differences); ``jacobian="transition"`` the product of MuJoCo's per-physics-step
    transition derivatives (:func:`mujoco.mjd_transitionFD`) along each row's trajectory
    (the reference the tests compare with, a Python loop). Each also yields ``f(x, u)``,
    which ``f`` then returns from a cache (the EKF evaluates ``F`` before ``f``).
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

Where: :mod:`testbed.estimators.mujoco_model` (:class:`MujocoProcessModel`,
:class:`PhysicalInput`), :mod:`testbed.estimators.augmented`
(:class:`AugmentedProcessModel`), :mod:`testbed.estimators.jacobians` (the Jacobian of the
period from one-physics-step derivatives); this module has the measurement model, the input
correction and the factories, and re-exports the rest.

These modules import no rig module: the designer's rig class comes with the design
(``design.extras["rig_type"]``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from filters import ExtendedKalmanFilter, UnscentedKalmanFilter
from testbed.design import DesignModel
from testbed.estimators import EstimatorWrapper
from testbed.estimators.augmented import AugmentedProcessModel
from testbed.estimators.jacobians import differences, perturbed
from testbed.estimators.mujoco_model import (
    FD_EPS,
    JACOBIAN_METHODS,
    MujocoProcessModel,
    PhysicalInput,
    can_touch,
    gravity,
)

if TYPE_CHECKING:  # the designer's rig: its class comes with the design (extras["rig_type"])
    from testbed.rigs.base import Rig


@runtime_checkable
class MujocoRigType(Protocol):
    """What the nonlinear family needs of the designer's rig class (a
    :class:`testbed.rigs.base.Rig` subclass has it): its MuJoCo model file and its operating
    input. Checked on the class with ``issubclass``."""

    def resolved_xml_path(self) -> Path: ...

    def operating_input(self, params: Any, x: np.ndarray) -> np.ndarray: ...


__all__ = ["FD_EPS", "JACOBIAN_METHODS", "AbsoluteInput", "AugmentedProcessModel",
           "MeasurementModel", "MujocoProcessModel", "MujocoRigType", "PhysicalInput", "can_touch",
           "differences", "gravity", "nominal_rig", "nonlinear_estimator", "nonlinear_models",
           "perturbed"]


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
        dw = None if self.input.plain else self.input.jacobian(p)  # dw/d[p, e]
        for row, _, grad_x, grad_w in self._rows:
            H[:, row, :self._d] = 0.0
            H[:, row, :nr] = grad_x(p, w, self.g)
            if dw is not None:
                H[:, row, :self._d] += np.einsum("mk,mkd->md", grad_w(p, w, self.g), dw)
        return H


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
        if extra.shape[1] < self.k:  # [o(x), 0] (np.pad's values, without its overhead)
            padded = np.zeros((len(extra), self.k))
            padded[:, :extra.shape[1]] = extra
            extra = padded
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
    if not (isinstance(rig_type, type) and issubclass(rig_type, MujocoRigType)):
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
                        kappa: float = 0.0, sigma_points: str = "simplex", w0: float = 0.0,
                        jacobian: str = "step", jacobian_points: int = 1,
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
    sigma_points : {"scaled", "simplex"}
        The UKF's sigma-point set: Julier's (2003) ``n + 2`` spherical simplex points
        (default; on a matched design ``d + 2`` distinct MuJoCo rollouts per member instead
        of ``2 d + 1``, ``d`` the rig and actuator states) or the ``2n + 1`` scaled points
        (:class:`filters.UnscentedKalmanFilter`); ``w0`` the simplex set's centre weight.
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
                                    alpha=alpha, beta=beta, kappa=kappa,
                                    sigma_points=sigma_points, w0=w0, k=k, dt_s=design.dt_s)
    else:
        raise ValueError(f"kind must be 'ekf' or 'ukf', got {kind!r}")
    if design.input_transform is None:  # the loop passes the applied input unchanged
        return AbsoluteInput(est, None, k)
    params, nr = rig.params, rig.n_states
    return AbsoluteInput(est, lambda x: rig.operating_input(params, x[:, :nr]), k)
