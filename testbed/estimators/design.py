"""The design model: what a filter designer knows about a rig, its sensors and its period.

An estimator factory (:mod:`testbed.estimators`) receives a :class:`DesignModel` and nothing
else: the rig's nominal linear model (never the simulated, possibly mismatched truth), the
configured sensors' linear model, noise covariances, the prior, names and units.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from filters import DiscreteLinearSystem, LinearSystem
from testbed.sensors import Sensor, SensorModel


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

    @property
    def n(self) -> int:
        """State dimension."""
        return len(self.state_names)

    @property
    def deterministic_index(self) -> np.ndarray:
        """Channels that are noise-free functions of ``x`` and ``w`` (``y2 = C2 x + H w``)."""
        return np.flatnonzero(~self.sensors.stochastic & ~self.sensors.inputs)


def build_design(rig, sensors: Sensor, dt_s: float, A: np.ndarray, B: np.ndarray,
                 Q: np.ndarray, x0: np.ndarray, P0: np.ndarray, *,
                 disturbance_matrix: np.ndarray | None = None,
                 input_transform: Callable | None = None,
                 output_matrix: np.ndarray | None = None,
                 extras: dict[str, Any] | None = None,
                 input_noise_cov: np.ndarray | None = None) -> DesignModel:
    """A :class:`DesignModel` from continuous ``A, B, Q`` and the sensors' linear model.

    Parameters
    ----------
    rig : testbed.rigs.base.Rig
        Names and units.
    sensors : Sensor
    dt_s : float
    A, B, Q : ndarray, shapes (n, n), (n, nu), (n, n)
        Continuous model and process-noise intensity.
    x0, P0 : ndarray
        Prior.
    disturbance_matrix, input_transform, output_matrix, extras
        See :class:`DesignModel`; ``output_matrix`` defaults to the tracked states' rows.
    input_noise_cov : ndarray, shape (nu, nu), optional
        Per-sample covariance of the error of a measured input (the input transform's
        output): adds ``D S D^T`` to ``R`` of the channels the input enters.
    """
    model = sensors.linear_model()
    index = np.flatnonzero(model.stochastic & ~model.inputs)
    C, D, R = model.C[index], model.D[index], model.R[np.ix_(index, index)]
    if input_noise_cov is not None:
        R = R + D @ np.asarray(input_noise_cov, float) @ D.T
    has_d = bool(np.any(D))
    plant = LinearSystem(A=A, B=B, C=C, Q=Q, R=R * dt_s, D=D if has_d else None)
    if output_matrix is None:
        output_matrix = np.eye(rig.n_states)[rig.tracked_index]
    return DesignModel(
        dt_s=float(dt_s), continuous=plant, discrete=plant.discretize(dt_s),
        x0=np.asarray(x0, float), P0=np.asarray(P0, float),
        state_names=tuple(rig.state_names), state_units=tuple(rig.state_units),
        input_names=tuple(rig.action_names), input_units=tuple(rig.action_units),
        measurement_names=tuple(sensors.names), measurement_units=tuple(sensors.units),
        measurement_index=index, sensors=model, output_matrix=np.asarray(output_matrix, float),
        disturbance_matrix=disturbance_matrix, input_transform=input_transform,
        extras={"cubic_model": getattr(type(rig), "cubic_model", None),
                "parameter_mismatch": _mismatch(rig), **(extras or {})})


def _mismatch(rig) -> Any:
    """The rig's :class:`~testbed.rigs.base.ParameterMismatch` (None without one)."""
    declared = getattr(rig, "parameter_mismatch", None)
    return None if declared is None else declared()


def design_from_linearization(rig, sensors: Sensor, dt_s: float, disturbance=None, *,
                              process_noise: float = 0.01, prior_std: float = 0.1
                              ) -> DesignModel:
    """The default design model: MuJoCo's linearization with nominal parameters.

    ``A, B`` from :meth:`Rig.linearize` at the rig's linearization point; ``Q`` is the
    disturbance's white-noise intensity plus ``process_noise`` on each velocity row; the
    prior is the rig's default initial state with ``P0 = prior_std^2 I``; the input is
    taken relative to :meth:`Rig.operating_input` at the estimate.
    """
    for name, value in (("process_noise", process_noise), ("prior_std", prior_std)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {value}")
    nominal = rig.params_type()
    A, B = rig.linearize()
    n, j = rig.n_states, len(rig.joints)
    Q = np.zeros((n, n))
    Q[j:, j:] += process_noise * np.eye(n - j)
    G = None
    if disturbance is not None:
        if disturbance.intensity is not None:
            Q = Q + disturbance.intensity
        G = disturbance.G

    def relative_input(u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
        return u - rig.operating_input(nominal, x_hat)

    return build_design(rig, sensors, dt_s, A, B, Q, rig.default_x0(),
                        prior_std**2 * np.eye(n), disturbance_matrix=G,
                        input_transform=relative_input)
