"""The design model: what a filter designer knows about a rig, its sensors and its period
(:class:`DesignModel`), how a matched design's extra states reach the rig's input
(:class:`InputStates`), and the designer's rig as the nonlinear filters rebuild it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from filters import DiscreteLinearSystem, LinearSystem
from testbed.records import field_values
from testbed.sensors import SensorModel


@dataclass
class DesignModel:
    """Linear models, noise, prior and names of one rig + sensors + control period.

    Attributes
    ----------
    dt_s : float
        Control (sampling) period, s.
    continuous : filters.LinearSystem
        ``dx = (A x + B u) dt + dW``, ``cov = Q dt``; ``y dt = C x dt + D u dt + dV`` with
        intensity ``R`` (= per-sample covariance times ``dt_s``). Only the stochastic
        channels (``measurement_index``).
    discrete : filters.DiscreteLinearSystem
        Exact zero-order-hold discretization at ``dt_s``: ``F, B, H, Q, R`` with ``Q``, ``R``
        per-sample covariances.
    x0 : ndarray, shape (n,)
        Prior mean.
    P0 : ndarray, shape (n, n)
        Prior covariance.
    state_names, state_units, input_names, input_units : tuple of str
    measurement_names, measurement_units : tuple of str
        All sensor channels (the ``y`` an estimator's ``step`` receives).
    measurement_index : ndarray of int
        Channels of ``y`` that ``continuous``/``discrete`` model (the stochastic ones; not
        the channels an input is computed from, ``sensors.inputs``).
    sensors : SensorModel
        Linear model of every channel (``C``, ``D``, ``R``, ``Hw``, ``stochastic``).
    output_matrix : ndarray, shape (q, n)
        ``L`` of the estimated output ``z = L x`` (the tracked states).
    disturbance_matrix : ndarray, shape (n, s) or None
        ``G`` of the deterministic disturbance ``G w(t)`` in the state equation.
    input_transform : callable ``(u (k, nu), x_hat (k, n)) -> (k, nu)``
        Applied by the loop before ``u`` reaches the estimator (e.g. minus the voltage that
        compensates gravity at the estimate): ``u`` of ``step`` is in the model's coordinates.
    extras : dict
        Rig-specific design data (paper models, LMI design systems); ``cubic_model`` is the
        rig's :meth:`~testbed.rigs.base.Rig.cubic_model` and ``parameter_mismatch`` its
        :meth:`~testbed.rigs.base.Rig.parameter_mismatch` (both set by :func:`build_design`).
        A matched design (:func:`build_matched_design`) has no ``parameter_mismatch`` (its
        states are not the linearization's) but ``matched_mismatch``
        (:class:`~testbed.design.mismatch.MatchedMismatch`: derivatives of its own discrete
        model, the design rebuilt at scaled parameters). It keeps the rig's paper design in
        ``extras["paper_design"]`` (the fallback of estimator families that cannot use an
        augmented model, and the controller's model).
    physical_index : ndarray of int, shape (n_rig,), or None
        Where the rig's physical states (``x = [positions, velocities]``, the rig's order)
        sit in the design state. None: the design state *is* the rig's state. An augmented
        design (actuator, sensor-bias and delay states) sets it; the loop and the metrics
        compare ``x[..., physical_index]`` with the truth and use the marginal covariance
        ``P[..., physical_index, physical_index]``.
    """

    dt_s: float
    continuous: LinearSystem
    discrete: DiscreteLinearSystem
    x0: np.ndarray
    P0: np.ndarray
    state_names: tuple[str, ...]
    state_units: tuple[str, ...]
    input_names: tuple[str, ...]
    input_units: tuple[str, ...]
    measurement_names: tuple[str, ...]
    measurement_units: tuple[str, ...]
    measurement_index: np.ndarray
    sensors: SensorModel
    output_matrix: np.ndarray
    disturbance_matrix: np.ndarray | None = None
    input_transform: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    extras: dict[str, Any] = field(default_factory=dict)
    physical_index: np.ndarray | None = None

    @property
    def n(self) -> int:
        """State dimension."""
        return len(self.state_names)

    @property
    def physical(self) -> np.ndarray:
        """:attr:`physical_index`, or every state when the design is not augmented."""
        if self.physical_index is None:
            return np.arange(self.n)
        return np.asarray(self.physical_index, dtype=int)

    @property
    def augmented(self) -> bool:
        """Whether the design state has more than the rig's physical states."""
        return self.physical_index is not None and len(self.physical_index) != self.n

    @property
    def deterministic_index(self) -> np.ndarray:
        """Channels that are noise-free functions of ``x`` and ``w`` (``y2 = C2 x + H w``)."""
        return np.flatnonzero(~self.sensors.stochastic & ~self.sensors.inputs)


@dataclass(frozen=True, eq=False)
class InputStates:
    """How a matched design's extra states reach the rig's physical input (for the
    nonlinear filters; :class:`testbed.estimators.nonlinear.PhysicalInput`).

    The rig's input over a control period is ``w = o(x) + from_input (u - [o(x), 0]) +
    from_states e`` with ``o`` the rig's operating input (zero for a design without an input
    transform) and ``e`` the extra states (after the rig's in the design state). Extra states
    that are inputs relative to the operating input (a motor's lagged voltage above the
    gravity-compensating one) have ``relative = I`` on those rows: ``e + relative o(x)`` is
    absolute.

    Attributes
    ----------
    from_input : ndarray, shape (k_rig, k)
    from_states : ndarray, shape (k_rig, n_e)
    relative : ndarray, shape (n_e, k_rig)
    """

    from_input: np.ndarray
    from_states: np.ndarray
    relative: np.ndarray

    def check(self, k_rig: int, k: int, n_e: int) -> None:
        """Raise ``ValueError`` unless the shapes are ``(k_rig, k)``, ``(k_rig, n_e)`` and
        ``(n_e, k_rig)`` and the entries finite."""
        for name, shape in (("from_input", (k_rig, k)), ("from_states", (k_rig, n_e)),
                            ("relative", (n_e, k_rig))):
            value = np.asarray(field_values(self)[name], float)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise ValueError(f"InputStates.{name} must be finite with shape {shape}, got "
                                 f"shape {value.shape}")


def designer_extras(rig) -> dict[str, Any]:
    """The designer's rig as the nonlinear filters rebuild it: its class, physics step,
    nominal parameters and options (``extras["rig_type"]``, ``["physics_dt_s"]``,
    ``["rig_params"]``, ``["rig_options"]``)."""
    return {"rig_type": type(rig), "physics_dt_s": float(rig.model.opt.timestep),
            "rig_params": rig.params, "rig_options": dict(rig.options or {})}
