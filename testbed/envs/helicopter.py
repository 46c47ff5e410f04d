"""``testbed/Helicopter2DOF-v0``: the MuJoCo 2-DOF helicopter as a Gymnasium environment."""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from testbed.disturbances import Disturbance, seed000_disturbance
from testbed.envs.common import reset_options
from testbed.rigs.helicopter import (
    ACTION_NAMES,
    PITCH_LIMIT_RAD,
    STATE_NAMES,
    VOLTAGE_LIMIT_V,
    HelicopterParams,
    HelicopterRig,
)
from testbed.sensors import EncoderSuite, PaperSuite, make_sensor_suite

#: Default setpoint schedule: (start time s, pitch rad, yaw rad).
DEFAULT_SETPOINTS: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.0, 0.0),
    (5.0, np.deg2rad(10.0), np.deg2rad(30.0)),
    (10.0, np.deg2rad(-5.0), np.deg2rad(-20.0)),
    (15.0, np.deg2rad(5.0), 0.0),
)
RESET_OPTION_KEYS = ("x0", "params", "setpoints")


def _validate_setpoints(setpoints: Sequence[Sequence[float]]) -> np.ndarray:
    table = np.asarray(setpoints, dtype=float)
    if table.ndim != 2 or table.shape[1] != 3 or len(table) == 0:
        raise ValueError("setpoints must be a sequence of (t_s, pitch_rad, yaw_rad) rows, got "
                         f"shape {table.shape}")
    if not np.all(np.isfinite(table)) or np.any(np.diff(table[:, 0]) < 0) or table[0, 0] > 0:
        raise ValueError("setpoints must be finite, start at t <= 0 and be sorted by time")
    if np.any(np.abs(table[:, 1]) > PITCH_LIMIT_RAD):
        raise ValueError(f"setpoint pitch must lie within +-{np.rad2deg(PITCH_LIMIT_RAD)} deg")
    return table


class Helicopter2DOFEnv(gym.Env):
    """Quanser-style 2-DOF helicopter simulated in MuJoCo, with sensors and disturbances.

    The rig is nonlinear (gravity ``m g l cos(pitch)``, pitch-dependent yaw inertia, Coriolis
    and thrust-direction coupling); seed-000's ``A``, ``B`` are its linearization about level
    pitch. It rests on the lower pitch stop at -40.5 deg.

    ## Action space

    ``Box(-24, 24, (2,), float64)``

    | Num | Action                         | Min | Max | Unit |
    |-----|--------------------------------|-----|-----|------|
    | 0   | front (pitch) motor voltage    | -24 | 24  | V    |
    | 1   | back (yaw) motor voltage       | -24 | 24  | V    |

    Voltages outside the range are clipped, like the real amplifier, and flagged in
    ``info["action_clipped"]``. NaN, inf or a wrong shape raise ``ValueError`` and leave the
    simulation unchanged.

    ## Observation space

    The sensor vector of the chosen suite, ``Box(-inf, inf, (m,), float64)``:

    | suite            | Num | Observation                                 | Unit  |
    |------------------|-----|---------------------------------------------|-------|
    | `encoders`       | 0   | pitch encoder (4096 counts/rev, quantized)  | rad   |
    |                  | 1   | yaw encoder (8192 counts/rev, quantized)    | rad   |
    | `encoders+gyros` | 2   | pitch-rate gyro                             | rad/s |
    |                  | 3   | yaw-rate gyro                               | rad/s |
    | `paper`          | 0-1 | ``y1 = C1 x + e``, ``cov(e) = h h^T / dt``  | rad   |
    |                  | 2-3 | ``y2 = C2 x + H w`` (when configured)       | rad   |

    ## Info

    ``state``: true ``[pitch, yaw, pitch_rate, yaw_rate]`` (rad, rad/s); ``t``: time after the
    step (s); ``disturbance``: ``w(t)`` applied over the step (paper units, empty if none);
    ``setpoint``: ``[pitch, yaw]`` reference (rad); ``action_applied`` (V) and
    ``action_clipped`` (bool per channel); ``process_accel``: joint accelerations applied as
    disturbance forces (rad/s^2).

    ## Reward

    ``-((pitch - pitch_ref)^2 + (yaw - yaw_ref)^2)`` in rad^2 after each step; estimator
    studies can ignore it.

    ## Episode end

    Never terminates; truncated after ``max_episode_steps`` (registration default 2000
    control steps = 20 s).

    ## Arguments

    ``physics_dt_s`` (default 0.001 s) and ``frame_skip`` (default 10: 10 ms control period);
    ``sensors`` (suite name or object) with ``sensor_kwargs``; ``disturbance``
    (:class:`~testbed.disturbances.Disturbance`, ``"seed000"`` or None); ``setpoints``
    ``[(t_s, pitch_rad, yaw_rad), ...]``; ``params``: default parameter scales.

    ``reset(seed=..., options={"x0": (4,), "params": {name: scale}, "setpoints": [...]})``:
    ``x0`` defaults to resting on the stop ``[-40.5 deg, 0, 0, 0]``; ``params`` multiplies
    :class:`~testbed.rigs.helicopter.HelicopterParams` fields (model mismatch). Unknown keys
    raise ``ValueError``.
    """

    metadata = {"render_modes": [], "render_fps": 100}

    def __init__(
        self,
        physics_dt_s: float = 0.001,
        frame_skip: int = 10,
        sensors: str | EncoderSuite | PaperSuite = "encoders",
        sensor_kwargs: dict[str, Any] | None = None,
        disturbance: Disturbance | str | None = None,
        setpoints: Sequence[Sequence[float]] = DEFAULT_SETPOINTS,
        params: dict[str, float] | None = None,
        render_mode: str | None = None,
    ):
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (headless rig), got {render_mode!r}")
        if int(frame_skip) != frame_skip or frame_skip < 1:
            raise ValueError(f"frame_skip must be a positive integer, got {frame_skip}")
        self.frame_skip = int(frame_skip)
        self.nominal_params = HelicopterParams().scaled(params or {})
        self.rig = HelicopterRig(self.nominal_params, physics_dt_s=physics_dt_s)
        self.dt_s = physics_dt_s * self.frame_skip
        if isinstance(sensors, str):
            sensors = make_sensor_suite(sensors, self.dt_s, **(sensor_kwargs or {}))
        elif sensor_kwargs:
            raise ValueError("sensor_kwargs is only used with a sensor suite name")
        self.sensors = sensors
        if disturbance == "seed000":
            disturbance = seed000_disturbance()
        elif isinstance(disturbance, str):
            raise ValueError(f"unknown disturbance {disturbance!r}; expected 'seed000', a "
                             "Disturbance or None")
        self.disturbance = disturbance or Disturbance()
        self._default_setpoints = _validate_setpoints(setpoints)
        self._setpoints = self._default_setpoints
        self._setpoint_times = self._setpoints[:, 0].tolist()

        self.action_space = spaces.Box(-VOLTAGE_LIMIT_V, VOLTAGE_LIMIT_V, (2,), np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.sensors.dim,), np.float64)
        self.state_names = list(STATE_NAMES)
        self.action_names = [f"{n} [V]" for n in ACTION_NAMES]
        self._model_data = self.rig.model, self.rig.data
        self._dof = self.rig.dof_index
        self._steps = 0
        self._w = np.zeros(0)
        self._x0 = np.zeros(4)

    # ------------------------------------------------------------------ helpers
    @property
    def _t_s(self) -> float:
        return self._steps * self.dt_s

    @property
    def t_s(self) -> float:
        """Simulation time in s (control steps times the control period, no drift)."""
        return self._t_s

    @property
    def x0(self) -> np.ndarray:
        """True initial state of the current episode, shape (4,)."""
        return self._x0.copy()

    def setpoint(self, t_s: float) -> np.ndarray:
        """Reference ``[pitch, yaw]`` (rad) active at time ``t_s``, shape (2,)."""
        row = bisect.bisect_right(self._setpoint_times, t_s) - 1
        return self._setpoints[max(row, 0), 1:].copy()

    def _validate_action(self, action: Any) -> np.ndarray:
        try:
            u = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"action must be numeric with shape (2,) in volts, got {action!r}"
                             ) from None
        if u.shape != (2,):
            raise ValueError(f"action must have shape (2,) (V_pitch, V_yaw in volts), got "
                             f"shape {u.shape}")
        if not np.isfinite(u).all():
            raise ValueError(f"action must be finite (no NaN/inf), got {u}")
        return u

    def _info(self, x: np.ndarray, ref: np.ndarray, u: np.ndarray, clipped: np.ndarray,
              accel: np.ndarray) -> dict[str, Any]:
        return {
            "state": x,
            "t": self._t_s,
            "disturbance": self._w,
            "setpoint": ref,
            "action_applied": u,
            "action_clipped": clipped,
            "process_accel": accel,
        }

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the rig; see the class docstring for ``options``."""
        options = reset_options(options, RESET_OPTION_KEYS)
        params = self.nominal_params.scaled(options.get("params") or {})
        x0 = np.array([-PITCH_LIMIT_RAD, 0.0, 0.0, 0.0])
        if options.get("x0") is not None:
            x0 = np.asarray(options["x0"], dtype=float)
            if x0.shape != (4,) or not np.all(np.isfinite(x0)):
                raise ValueError("options['x0'] must be a finite array of shape (4,) "
                                 f"[pitch, yaw, pitch_rate, yaw_rate], got {options['x0']!r}")
            if abs(x0[0]) > PITCH_LIMIT_RAD + 1e-9:
                raise ValueError(f"options['x0'] pitch {x0[0]:.4f} rad is outside the stops "
                                 f"+-{PITCH_LIMIT_RAD:.4f} rad")
        setpoints = self._default_setpoints
        if options.get("setpoints") is not None:
            setpoints = _validate_setpoints(options["setpoints"])
        super().reset(seed=seed)

        self.rig.set_params(params)
        model, data = self._model_data
        mujoco.mj_resetData(model, data)
        self._setpoints = setpoints
        self._setpoint_times = setpoints[:, 0].tolist()
        self._steps = 0
        self._x0 = x0.copy()
        self.rig.set_state(x0)
        self._w = self.disturbance.signal(0.0)
        obs = self.sensors.measure(x0, 0.0, self.np_random, self._w)
        return obs, self._info(self.rig.get_state(), self.setpoint(0.0), np.zeros(2),
                               np.zeros(2, bool), np.zeros(2))

    def step(self, action):
        """Apply motor voltages for one control period; see the class docstring."""
        u = self._validate_action(action)
        clipped_u = u.clip(-VOLTAGE_LIMIT_V, VOLTAGE_LIMIT_V)
        clipped = clipped_u != u
        model, data = self._model_data

        disturbance = self.disturbance
        if disturbance.active:
            w = disturbance.signal(self._t_s)
            accel = disturbance.acceleration(self._t_s, self.dt_s, self.np_random, w)
            data.qfrc_applied[:] = self.rig.joint_accel_to_force(accel)
        else:
            w, accel = self._w, np.zeros(2)
        data.ctrl[:] = clipped_u
        mujoco.mj_step(model, data, nstep=self.frame_skip)
        self._steps += 1
        self._w = w

        x = self.rig.get_state()
        ref = self.setpoint(self._t_s)
        e0, e1 = x[0] - ref[0], x[1] - ref[1]
        reward = -(e0 * e0 + e1 * e1)
        w_now = disturbance.signal(self._t_s) if disturbance.has_deterministic else None
        obs = self.sensors.measure(x, self._t_s, self.np_random, w_now)
        return obs, reward, False, False, self._info(x, ref, clipped_u, clipped, accel)

    # ------------------------------------------------------------------ for viz
    def body_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """World positions (nbody, 3) and orientations (nbody, 4, wxyz) of all bodies."""
        _, data = self._model_data
        return data.xpos.copy(), data.xquat.copy()
