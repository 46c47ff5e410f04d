"""``testbed/VehicleRoll-v0``: the roll of a vehicle's sprung mass as a Gymnasium environment."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from testbed.envs.common import reset_options
from testbed.manoeuvres import MANOEUVRES, Manoeuvre, make_manoeuvre
from testbed.rigs.vehicle_roll import (
    A_Y_LIMIT_M_S2,
    ACTION_NAMES,
    STATE_NAMES,
    VehicleRollParams,
    VehicleRollRig,
)
from testbed.vehicle_sensors import ImuSuite, PaperRollSuite, make_vehicle_sensor_suite

RESET_OPTION_KEYS = ("x0", "params", "manoeuvre", "manoeuvre_params")
#: Roll angle beyond which the vehicle has rolled over (episode terminates), rad.
ROLLOVER_RAD = float(np.pi / 2)


def _resolve_manoeuvre(manoeuvre: str | Manoeuvre | None,
                       params: dict[str, Any] | None) -> Manoeuvre | None:
    """A manoeuvre object from a name (+ params), an object, or None (no manoeuvre)."""
    if manoeuvre is None or manoeuvre == "none":
        if params:
            raise ValueError("manoeuvre_params given without a manoeuvre")
        return None
    if isinstance(manoeuvre, str):
        return make_manoeuvre(manoeuvre, **(params or {}))
    if params:
        raise ValueError("manoeuvre_params is only used with a manoeuvre name")
    if not callable(manoeuvre) or not hasattr(manoeuvre, "name"):
        raise ValueError(f"manoeuvre must be one of {sorted(MANOEUVRES)}, 'none', None or a "
                         f"callable t_s -> a_y with a name, got {manoeuvre!r}")
    return manoeuvre


class VehicleRollEnv(gym.Env):
    """Roll dynamics of a light commercial vehicle's sprung mass, simulated in MuJoCo.

    seed-002 Example 5.2, eq. (51), Table 1: the sprung mass (1700 kg, centre of mass
    0.25 m above the roll axis, 1700 kg m^2 about it) rolls against a torsional spring
    (55314 N m/rad) and damper (53071 N m s/rad); gravity and the lateral acceleration
    ``a_y`` roll it; the damping carries the multiplicative noise ``D_n w_k`` (``D_n = 20``,
    ``w_k ~ N(0, 1)`` drawn once per control step from the env's generator). See
    :mod:`testbed.rigs.vehicle_roll` for the physics and the paper-vs-physics comparison.

    ## Action space

    ``Box(-8, 8, (1,), float64)``

    | Num | Action                                                  | Min | Max | Unit  |
    |-----|---------------------------------------------------------|-----|-----|-------|
    | 0   | lateral acceleration ``a_y`` (+ left), or its perturbation | -8  | 8   | m/s^2 |

    Without a manoeuvre the action is the lateral acceleration. With a manoeuvre (constructor
    ``manoeuvre=`` or ``reset(options={"manoeuvre": ...})``) the action is an additive
    perturbation: over the step ``[t_k, t_k + dt)`` the rig feels (zero-order hold)::

        a_y = clip(manoeuvre(t_k) + clip(action, -8, 8), -8, 8)

    Either clipping sets ``info["action_clipped"]``. NaN, inf or a wrong shape raise
    ``ValueError`` and leave the simulation (and the random generator) unchanged.

    ## Observation space

    The sensor vector of the chosen suite, ``Box(-inf, inf, (m,), float64)``:

    | suite   | Num | Observation                                                | Unit  |
    |---------|-----|------------------------------------------------------------|-------|
    | `imu`   | 0   | roll-rate gyro: ``roll_rate + bias + noise``               | rad/s |
    |         | 1   | lateral accelerometer: ``a_y cos(roll) + g sin(roll) + n`` | m/s^2 |
    |         | 2   | roll-angle sensor (``roll_sensor=True``)                   | rad   |
    | `paper` | 0-1 | ``y = H x + L v_k`` of seed-002 (52)                       | -     |

    See :mod:`testbed.vehicle_sensors` for the noise models and defaults.

    ## Info

    | key              | content                                                | unit       |
    |------------------|--------------------------------------------------------|------------|
    | `state`          | true ``[roll, roll_rate]`` after the step, shape (2,)  | rad, rad/s |
    | `t`              | time after the step                                    | s          |
    | `a_y`            | lateral acceleration applied over the step (float)     | m/s^2      |
    | `a_y_manoeuvre`  | the manoeuvre's part of it (0 without a manoeuvre)     | m/s^2      |
    | `damping_noise`  | ``w_k`` of the step (damping was ``C_R + D_n w_k``)    | -          |
    | `disturbance`    | ``[v_k]`` in the `paper` suite's output, else (0,)     | -          |
    | `setpoint`       | no reference: shape (0,)                               |            |
    | `action_applied` | ``[a_y]``, the applied lateral acceleration, (1,)      | m/s^2      |
    | `action_clipped` | bool, shape (1,)                                       |            |

    ``action_applied`` is the physical input (manoeuvre + perturbation), not the raw action:
    it is what :class:`~testbed.wrappers.FilterInLoop` hands to an estimator as ``u``.
    After ``reset`` ``a_y``, ``action_applied`` are 0 and ``damping_noise`` is 0.

    ## Reward

    ``-roll^2`` (rad^2) after each step; estimator studies can ignore it.

    ## Episode end

    Terminates if ``|roll| > 90 deg`` (rolled over; impossible with the nominal parameters
    inside the +-8 m/s^2 limit). Truncated after ``max_episode_steps`` (registration default
    1000 control steps = 10 s).

    ## Arguments

    ``physics_dt_s`` (default 0.001 s) and ``frame_skip`` (default 10: 10 ms control period,
    the paper's ``T``); ``sensors`` (``"imu"``, ``"paper"`` or a suite object) with
    ``sensor_kwargs``; ``manoeuvre`` (a name of :data:`testbed.manoeuvres.MANOEUVRES`, a
    manoeuvre object or None) with ``manoeuvre_params``; ``params``: default parameter scale
    factors of :class:`~testbed.rigs.vehicle_roll.VehicleRollParams`.

    ``reset(seed=..., options={"x0": (2,), "params": {name: scale}, "manoeuvre": name or
    None, "manoeuvre_params": {...}})``: ``x0`` defaults to upright at rest; ``params``
    multiplies the constructor's parameters (model mismatch); ``manoeuvre`` replaces the
    constructor's for this episode (``None``/``"none"``: the action drives ``a_y``);
    ``manoeuvre_params`` alone re-parameterizes the constructor's manoeuvre (by name). Unknown
    keys raise ``ValueError``.
    """

    metadata = {"render_modes": [], "render_fps": 100}

    def __init__(
        self,
        physics_dt_s: float = 0.001,
        frame_skip: int = 10,
        sensors: str | ImuSuite | PaperRollSuite = "imu",
        sensor_kwargs: dict[str, Any] | None = None,
        manoeuvre: str | Manoeuvre | None = None,
        manoeuvre_params: dict[str, Any] | None = None,
        params: dict[str, float] | None = None,
        render_mode: str | None = None,
    ):
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (headless rig), got {render_mode!r}")
        if int(frame_skip) != frame_skip or frame_skip < 1:
            raise ValueError(f"frame_skip must be a positive integer, got {frame_skip}")
        self.frame_skip = int(frame_skip)
        self.nominal_params = VehicleRollParams().scaled(params or {})
        self.rig = VehicleRollRig(self.nominal_params, physics_dt_s=physics_dt_s)
        self.dt_s = physics_dt_s * self.frame_skip
        if isinstance(sensors, str):
            sensors = make_vehicle_sensor_suite(sensors, self.dt_s, **(sensor_kwargs or {}))
        elif sensor_kwargs:
            raise ValueError("sensor_kwargs is only used with a sensor suite name")
        suite_dt = getattr(sensors, "dt_s", self.dt_s)
        if not np.isclose(suite_dt, self.dt_s, rtol=1e-9, atol=0.0):
            raise ValueError(f"the sensor suite samples every {suite_dt} s but the control "
                             f"period is {self.dt_s} s; they must match")
        self.sensors = sensors
        self._default_manoeuvre = _resolve_manoeuvre(manoeuvre, manoeuvre_params)
        self.manoeuvre = self._default_manoeuvre

        self.action_space = spaces.Box(-A_Y_LIMIT_M_S2, A_Y_LIMIT_M_S2, (1,), np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.sensors.dim,), np.float64)
        self.state_names = list(STATE_NAMES)
        self.action_names = [f"{n} [m/s^2]" for n in ACTION_NAMES]
        self._model_data = self.rig.model, self.rig.data
        self._steps = 0
        self._x0 = np.zeros(2)
        self._a_y = 0.0

    # ------------------------------------------------------------------ helpers
    @property
    def t_s(self) -> float:
        """Simulation time in s (control steps times the control period, no drift)."""
        return self._steps * self.dt_s

    @property
    def x0(self) -> np.ndarray:
        """True initial state of the current episode, shape (2,)."""
        return self._x0.copy()

    @property
    def a_y(self) -> float:
        """Lateral acceleration applied over the last step, m/s^2 (0 after reset)."""
        return self._a_y

    def _disturbance(self, t_s: float) -> np.ndarray:
        signal = getattr(self.sensors, "disturbance", None)
        return np.zeros(0) if signal is None else np.asarray(signal(t_s), dtype=float)

    def _measure(self, x: np.ndarray, t_s: float, w: np.ndarray, a_y: float) -> np.ndarray:
        if isinstance(self.sensors, (ImuSuite, PaperRollSuite)):
            return self.sensors.measure(x, t_s, self.np_random, w, a_y=a_y)
        return self.sensors.measure(x, t_s, self.np_random, w if len(w) else None)

    def _validate_action(self, action: Any) -> np.ndarray:
        try:
            u = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"action must be numeric with shape (1,) (a_y in m/s^2), got "
                             f"{action!r}") from None
        if u.shape != (1,):
            raise ValueError(f"action must have shape (1,) (a_y in m/s^2), got shape {u.shape}")
        if not np.isfinite(u).all():
            raise ValueError(f"action must be finite (no NaN/inf), got {u}")
        return u

    def _info(self, x: np.ndarray, a_y: float, a_man: float, w_k: float, v: np.ndarray,
              clipped: bool) -> dict[str, Any]:
        return {
            "state": x,
            "t": self.t_s,
            "a_y": a_y,
            "a_y_manoeuvre": a_man,
            "damping_noise": w_k,
            "disturbance": v,
            "setpoint": np.zeros(0),
            "action_applied": np.array([a_y]),
            "action_clipped": np.array([clipped]),
        }

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the rig; see the class docstring for ``options``."""
        options = reset_options(options, RESET_OPTION_KEYS)
        params = self.nominal_params.scaled(options.get("params") or {})
        x0 = np.zeros(2)
        if options.get("x0") is not None:
            x0 = np.asarray(options["x0"], dtype=float)
            if x0.shape != (2,) or not np.all(np.isfinite(x0)):
                raise ValueError("options['x0'] must be a finite array of shape (2,) "
                                 f"[roll, roll_rate], got {options['x0']!r}")
            if abs(x0[0]) >= ROLLOVER_RAD:
                raise ValueError(f"options['x0'] roll {x0[0]:.4f} rad is beyond rollover "
                                 f"(+-{ROLLOVER_RAD:.4f} rad)")
        manoeuvre = self._default_manoeuvre
        if "manoeuvre" in options:
            manoeuvre = _resolve_manoeuvre(options["manoeuvre"], options.get("manoeuvre_params"))
        elif options.get("manoeuvre_params"):  # new parameters for the default manoeuvre
            if manoeuvre is None:
                raise ValueError("options['manoeuvre_params'] given without a manoeuvre")
            manoeuvre = _resolve_manoeuvre(manoeuvre.name, options["manoeuvre_params"])
        super().reset(seed=seed)

        self.rig.set_params(params)
        model, data = self._model_data
        mujoco.mj_resetData(model, data)
        self.manoeuvre = manoeuvre
        self._steps = 0
        self._x0 = x0.copy()
        self._a_y = 0.0
        self.rig.set_state(x0)
        reset_sensors = getattr(self.sensors, "reset", None)
        if reset_sensors is not None:
            reset_sensors(self.np_random)
        v = self._disturbance(0.0)
        obs = self._measure(x0, 0.0, v, 0.0)
        return obs, self._info(self.rig.get_state(), 0.0, 0.0, 0.0, v, False)

    def step(self, action):
        """Apply a lateral acceleration for one control period; see the class docstring."""
        u = self._validate_action(action)
        perturbation = float(np.clip(u[0], -A_Y_LIMIT_M_S2, A_Y_LIMIT_M_S2))
        a_man = 0.0 if self.manoeuvre is None else float(self.manoeuvre(self.t_s))
        if not np.isfinite(a_man):
            raise ValueError(f"manoeuvre {self.manoeuvre.name!r} returned a_y = {a_man} at "
                             f"t = {self.t_s} s")
        total = a_man + perturbation
        a_y = float(np.clip(total, -A_Y_LIMIT_M_S2, A_Y_LIMIT_M_S2))
        clipped = perturbation != u[0] or a_y != total
        model, data = self._model_data

        w_k = float(self.np_random.standard_normal())
        self.rig.set_damping_noise(w_k)
        self.rig.set_lateral_acceleration(a_y)
        mujoco.mj_step(model, data, nstep=self.frame_skip)
        self._steps += 1
        self._a_y = a_y

        x = self.rig.get_state()
        reward = -float(x[0] * x[0])
        terminated = bool(abs(x[0]) > ROLLOVER_RAD)
        v = self._disturbance(self.t_s)
        obs = self._measure(x, self.t_s, v, a_y)
        return obs, reward, terminated, False, self._info(x, a_y, a_man, w_k, v, clipped)

    # ------------------------------------------------------------------ for viz
    def body_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """World positions (nbody, 3) and orientations (nbody, 4, wxyz) of all bodies."""
        _, data = self._model_data
        return data.xpos.copy(), data.xquat.copy()
