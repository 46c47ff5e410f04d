"""The design model: what a filter designer knows about a rig, its sensors and its period.

An estimator factory (:mod:`testbed.estimators`) receives a :class:`DesignModel` and nothing
else: the rig's nominal linear model (never the simulated, possibly mismatched truth), the
configured sensors' linear model, noise covariances, the prior, names and units.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from filters import DiscreteLinearSystem, LinearSystem
from testbed.design.held_noise import rig_held_noise
from testbed.design.matched import (
    ChannelEffects,
    build_matched_design,
    channel_effects,
    consider_parameters,
)
from testbed.design.model import DesignModel, InputStates, designer_extras
from testbed.sensors import Sensor

__all__ = ["DESIGN_PROFILES", "ChannelEffects", "DesignModel", "InputStates", "build_design",
           "build_matched_design", "channel_effects", "consider_parameters",
           "design_from_linearization", "rate_noise"]


def build_design(rig, sensors: Sensor, dt_s: float, A: np.ndarray, B: np.ndarray,
                 Q: np.ndarray, x0: np.ndarray, P0: np.ndarray, *,
                 disturbance_matrix: np.ndarray | None = None,
                 input_transform: Callable | None = None,
                 output_matrix: np.ndarray | None = None,
                 extras: dict[str, Any] | None = None,
                 input_noise_cov: np.ndarray | None = None,
                 held_noise: bool = False) -> DesignModel:
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
    discrete = plant.discretize(dt_s)
    held = rig_held_noise(rig, dt_s, np.asarray(A, float), np.asarray(Q, float)) \
        if held_noise else None
    if held is not None:
        discrete = DiscreteLinearSystem(F=discrete.F, B=discrete.B, H=discrete.H, Q=held,
                                        R=discrete.R, dt_s=dt_s, D=discrete.D)
    return DesignModel(
        dt_s=float(dt_s), continuous=plant, discrete=discrete,
        x0=np.asarray(x0, float), P0=np.asarray(P0, float),
        state_names=tuple(rig.state_names), state_units=tuple(rig.state_units),
        input_names=tuple(rig.action_names), input_units=tuple(rig.action_units),
        measurement_names=tuple(sensors.names), measurement_units=tuple(sensors.units),
        measurement_index=index, sensors=model, output_matrix=np.asarray(output_matrix, float),
        disturbance_matrix=disturbance_matrix, input_transform=input_transform,
        extras={"cubic_model": type(rig).cubic_model,
                "parameter_mismatch": _mismatch(rig), **designer_extras(rig), **(extras or {})})


def _mismatch(rig) -> Any:
    """The rig's :class:`~testbed.rigs.base.ParameterMismatch` (None without one)."""
    return rig.parameter_mismatch()


def rate_noise(n_states: int, n_joints: int, intensity: float,
               disturbance: Any = None, *, name: str = "process_noise_floor"
               ) -> tuple[np.ndarray, np.ndarray | None]:
    """A design's process noise: ``intensity`` on each velocity row (unmodelled
    accelerations), plus the disturbance's white-noise intensity; and its ``G``.

    Parameters
    ----------
    n_states, n_joints : int
        The state ``[positions (n_joints), velocities]``.
    intensity : float
        Per velocity row, (unit/s)^2 / s: finite and >= 0.
    disturbance : testbed.rigs.disturbances.Disturbance, optional
    name : str
        The design option ``intensity`` comes from (named by the error).

    Returns
    -------
    Q : ndarray, shape (n, n)
    G : ndarray, shape (n, s), or None

    Raises
    ------
    ValueError
        ``intensity`` negative or not finite.
    """
    if not (np.isfinite(intensity) and intensity >= 0):
        raise ValueError(f"{name} must be finite and >= 0, got {intensity}")
    Q = np.zeros((n_states, n_states))
    Q[n_joints:, n_joints:] += intensity * np.eye(n_states - n_joints)
    G = None
    if disturbance is not None:
        if disturbance.intensity is not None:
            Q = Q + disturbance.intensity
        G = disturbance.G
    return Q, G


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
    nominal = rig.params  # the designer's rig: nominal, or a twin's values
    A, B = rig.linearize()
    Q, G = rate_noise(rig.n_states, len(rig.joints), process_noise, disturbance,
                      name="process_noise")

    def relative_input(u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
        return u - rig.operating_input(nominal, x_hat)

    return build_design(rig, sensors, dt_s, A, B, Q, rig.default_x0(),
                        prior_std**2 * np.eye(rig.n_states), disturbance_matrix=G,
                        input_transform=relative_input)


#: Design profiles: ``matched`` (the model of the rig as its profile declares it) and
#: ``paper`` (the papers' model whatever the profile: a deliberate model-mismatch study).
DESIGN_PROFILES = ("matched", "paper")
