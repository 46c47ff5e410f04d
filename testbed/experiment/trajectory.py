"""The record of one simulated run: what the viewer, the plots and the JSON summary read.

A :class:`Trajectory` is filled by :func:`testbed.experiment.runner.run` (or by hand) and is
consumed by :mod:`testbed.outputs.viz` (Rerun ``.rrd``), :mod:`testbed.outputs.plots` (PNG)
and the CLI.
All arrays share the leading time axis of length ``T`` (one row per control step, the
initial reset included as row 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from testbed.records import field_values


@dataclass
class Trajectory:
    """Time series of one episode.

    Attributes
    ----------
    t_s : ndarray, shape (T,)
        Time of each row in seconds.
    state : ndarray, shape (T, n)
        True state (e.g. ``[pitch, yaw, pitch_rate, yaw_rate]`` in rad, rad/s).
    state_names : list of str, length n
        Names of the state components, used as entity/legend names.
    estimate : ndarray, shape (T, n) or None
        Estimator output, when an estimator ran.
    covariance : ndarray, shape (T, n, n) or None
        Estimator error covariance, when the estimator has one.
    measurement : ndarray, shape (T, m)
        Sensor output at each row.
    measurement_names : list of str, length m
        Names of the measurement components.
    measured_state_index : list of int or None, length m
        For each measurement component, the index of the state it measures directly
        (``None`` where it measures no single state); lets plots overlay measurements
        on the state they observe.
    action : ndarray, shape (T, k)
        Applied (clipped) action; row 0 is zeros (no action before the first step).
    action_names : list of str, length k
        Names (with units) of the action components.
    setpoint : ndarray, shape (T, n_ref) or None
        Reference tracked by the controller (e.g. pitch and yaw in rad).
    body_pos : ndarray, shape (T, nbody, 3) or None
        World positions of the MuJoCo bodies (``data.xpos``), for the 3D view.
    body_quat_wxyz : ndarray, shape (T, nbody, 4) or None
        World orientations of the bodies (``data.xquat``), MuJoCo order w, x, y, z.
    meta : dict
        Free-form run description (rig, filter, seed, dt...).
    rig : Rig or None
        The simulated rig (its MuJoCo model draws the 3D view and the video); not saved.
    """

    t_s: np.ndarray
    state: np.ndarray
    state_names: list[str]
    measurement: np.ndarray
    measurement_names: list[str]
    action: np.ndarray
    action_names: list[str]
    estimate: np.ndarray | None = None
    covariance: np.ndarray | None = None
    measured_state_index: list[int | None] | None = None
    setpoint: np.ndarray | None = None
    body_pos: np.ndarray | None = None
    body_quat_wxyz: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    rig: Any = field(default=None, repr=False, compare=False)

    def unit(self, name: str, kind: str = "state") -> str:
        """Declared unit of a state (``kind="state"``), measurement channel
        (``"measurement"``) or action (``"action"``) from ``meta["units"]`` (``""`` if
        unknown). An action name may carry its unit (``"a_y [m/s^2]"``): the declaration
        of the bare name wins, else that bracketed unit."""
        units = self.meta.get("units") or {}
        if kind == "measurement":
            return units.get(f"measurement:{name}", units.get(name, ""))
        if kind == "action":
            bare, bracket, rest = name.partition(" [")
            declared = units.get(name) or units.get(bare.strip())
            if declared:
                return declared
            return rest.rstrip("]") if bracket and name.endswith("]") else ""
        return units.get(name, "")

    def __post_init__(self) -> None:
        self.t_s = np.asarray(self.t_s, dtype=float)
        n_rows = len(self.t_s)
        fields = field_values(self)
        for name in ("state", "measurement", "action", "estimate", "setpoint"):
            value = fields[name]
            if value is not None:  # (T, k) float; a 1-D series becomes one column
                value = np.asarray(value, dtype=float)
                setattr(self, name, value[:, None] if value.ndim == 1 else value)
        for name in ("state", "measurement", "action", "estimate", "covariance", "setpoint",
                     "body_pos", "body_quat_wxyz"):
            value = field_values(self)[name]
            if value is not None and len(value) != n_rows:
                raise ValueError(
                    f"Trajectory.{name} has {len(value)} rows, expected {n_rows} (len(t_s))"
                )
        for label, names, arr in (("state_names", self.state_names, self.state),
                                  ("measurement_names", self.measurement_names,
                                   self.measurement),
                                  ("action_names", self.action_names, self.action)):
            if len(names) != arr.shape[1]:
                raise ValueError(f"Trajectory.{label} has {len(names)} names for "
                                 f"{arr.shape[1]} columns")
        n = self.state.shape[1]
        if self.estimate is not None and self.estimate.shape != (n_rows, n):
            raise ValueError(f"Trajectory.estimate has shape {self.estimate.shape}, "
                             f"expected {(n_rows, n)}")
        if self.covariance is not None and np.shape(self.covariance) != (n_rows, n, n):
            raise ValueError(f"Trajectory.covariance has shape {np.shape(self.covariance)}, "
                             f"expected {(n_rows, n, n)}")

    def setpoint_names(self) -> list[str]:
        """Names of the setpoint components.

        ``meta["setpoint_names"]`` when given with the right length, else the leading state
        names (a setpoint tracks the first ``n_ref`` states, e.g. pitch and yaw), else the
        component indices; empty without a setpoint.
        """
        if self.setpoint is None:
            return []
        n_ref = self.setpoint.shape[1]
        names = self.meta.get("setpoint_names")
        if names is not None and len(names) == n_ref:
            return [str(n) for n in names]
        if n_ref <= len(self.state_names):
            return list(self.state_names[:n_ref])
        return [str(i) for i in range(n_ref)]

    @property
    def n_steps(self) -> int:
        """Number of control steps (rows minus the initial one)."""
        return len(self.t_s) - 1

    def std(self) -> np.ndarray | None:
        """Standard deviation of each state's estimate, shape (T, n), or None."""
        if self.covariance is None:
            return None
        return np.sqrt(np.clip(np.diagonal(self.covariance, axis1=1, axis2=2), 0.0, None))
