"""Gymnasium views of the simulator: ``RigEnv`` (N = 1) and ``RigVectorEnv`` (N members).

Both are thin: every reset/step semantic lives in :class:`testbed.sim.simulator.Simulator`, so
``gymnasium.make("testbed/VehicleRoll-v0")`` and member ``i`` of
``gymnasium.make_vec("testbed/VehicleRoll-v0", num_envs=N,
vectorization_mode="vector_entry_point")`` follow the same code (bitwise equal with the same
seeds).

## Spaces
Action: ``Box(action_low, action_high)`` of the rig (actions outside are clipped, like an
amplifier, and flagged in ``info["action_clipped"]``; NaN, inf or a wrong shape raise
``ValueError`` with the state unchanged). Observation: the sensor vector
``Box(-inf, inf, (m,))``; names and units in ``env.unwrapped.sensors``.

## Info
``state`` (truth), ``t`` (s), ``disturbance`` (``w``), ``setpoint`` (reference of the
tracked states), ``action_applied``, ``action_clipped``, ``manoeuvre`` (the open-loop
profile's part of the applied input), ``process_accel`` (disturbance accelerations, rad/s^2),
``step_noise`` (the rig's model noise of the step).

## Reward
``-|x_tracked - reference|^2`` after each step (estimator studies can ignore it).

## Arguments
``rig`` (registered name or :class:`~testbed.rigs.base.Rig` subclass), ``profile``
(``"paper"``: the papers' idealizations, or ``"hardware"``: the real rig's actuator and
sensor effects, see the rig's docs), ``physics_dt_s``,
``frame_skip``, ``sensors`` (a preset name of the rig or a :class:`~testbed.sensors.Sensor`)
with ``sensor_kwargs``, ``disturbance`` (name of the rig's disturbances, a
:class:`~testbed.rigs.disturbances.Disturbance` or None), ``process_noise`` (scale of the rig's
white process noise), ``ambient_noise`` (scale of the rig's small documented ambient
disturbance: air turbulence, gusts; default 1, 0 for none), ``reset_noise_scale`` (scale of
the rig's documented initial-state distribution; default 1, 0 for the fixed default state),
``setpoints``, ``manoeuvre`` with ``manoeuvre_params``, ``params`` (default parameter scale
factors). ``reset(seed=, options={"x0", "params", "setpoints",
"manoeuvre", "manoeuvre_params"})``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from filters import real_array
from testbed.envs.common import check_seed, with_twin
from testbed.sim import build_simulator
from testbed.sim.simulator import positive_int

#: (a dtype compares with a dtype faster than with the type ``np.float64``)
_FLOAT64 = np.dtype(np.float64)


class RigEnv(gym.Env):
    """Any registered rig as a Gymnasium environment (the simulator with N = 1).

    See the module docstring for spaces, info, reward and arguments. ``render_mode=
    "rgb_array"``: :meth:`render` returns the rig's current pose seen from its documented
    camera (:mod:`testbed.outputs.render`; headless: ``MUJOCO_GL=egl`` or ``osmesa``), so
    Gymnasium's ``RecordVideo`` works.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}

    def __init__(self, rig: Any = "helicopter", render_mode: str | None = None, **kwargs: Any):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if render_mode == "rgb_array":  # no OpenGL here: one line now, not a deep traceback
            from testbed.outputs.render import check_rendering

            try:
                check_rendering()
            except ValueError as exc:
                raise ValueError(f"render_mode='rgb_array': {exc}") from None
        self.render_mode = render_mode
        self._renderer = None
        rig, kwargs = with_twin(rig, kwargs)
        self.sim = build_simulator(rig, 1, num_threads=1, **kwargs)
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.sim.dt_s}
        self.rig = self.sim.rig
        self.sensors = self.sim.sensors
        self.dt_s = self.sim.dt_s
        self.frame_skip = self.sim.frame_skip
        self.nominal_params = self.sim.nominal_params
        self.disturbance = self.sim.disturbance
        rig_obj = self.rig
        self.action_space = spaces.Box(np.asarray(rig_obj.action_low, np.float64),
                                       np.asarray(rig_obj.action_high, np.float64),
                                       (rig_obj.n_actions,), np.float64)
        self.observation_space = spaces.Box(-np.inf, np.inf, (self.sensors.dim,), np.float64)
        self.state_names = list(rig_obj.state_names)
        self.action_names = list(rig_obj.action_names)
        self._shape = (rig_obj.n_actions,)
        self._action_label = (f"action ({', '.join(rig_obj.action_names)} in "
                              f"{', '.join(rig_obj.action_units)})")

    @property
    def t_s(self) -> float:
        """Simulation time, s (steps times the control period)."""
        return float(self.sim.steps[0] * self.dt_s)

    @property
    def x0(self) -> np.ndarray:
        """True initial state of the current episode, shape (n,)."""
        return self.sim.x0[0].copy()

    def units(self) -> dict[str, str]:
        """Units of states, actions and measurements."""
        return self.sim.units()

    def setpoint(self, t_s: float) -> np.ndarray:
        """Reference of the tracked states at ``t_s``, shape (r,)."""
        return self.sim.setpoints_at(t_s, np.array([0]))[0]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset the rig (see the module docstring for ``options``); everything is checked
        before anything changes."""
        check_seed(seed)
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be a dict or None, got {type(options).__name__}")
        self.sim.reset(None, [seed], options)
        super().reset(seed=seed)
        return self.sim.obs[0].copy(), self.sim.member_info(0)

    def step(self, action):
        """Apply one action for one control period."""
        u = action
        # a finite float64 array of the action's shape is read as Python floats (the
        # simulator's one-member step works on them); anything else is converted and
        # checked by real_array. Finite: the sum of the entries is (a NaN or an infinity
        # makes it NaN or infinite); a sum that overflows takes real_array's full check
        if not (type(u) is np.ndarray and u.dtype == _FLOAT64 and u.shape == self._shape
                and math.isfinite(sum(values := u.tolist()))):
            values = real_array(action, self._action_label, shape=self._shape).tolist()
        sim = self.sim
        obs, reward, terminated = sim.step_row(values)
        return obs, reward, terminated, False, sim.member_info(0)

    def body_poses(self) -> tuple[np.ndarray, np.ndarray]:
        """World positions (nbody, 3) and orientations (nbody, 4, wxyz) of all bodies."""
        physics = self.sim.physics
        if not self.sim.record_poses:
            physics.forward_poses(np.array([0]))
        return physics.poses[0][0].copy(), physics.poses[1][0].copy()

    def render(self) -> np.ndarray | None:
        """With ``render_mode="rgb_array"``: the current pose, (height, width, 3) uint8."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode (use render_mode="
                            "'rgb_array')")
            return None
        if self._renderer is None:
            from testbed.outputs.render import RigRenderer

            self._renderer = RigRenderer(self.rig)
        return self._renderer.render(self.sim.info["state"][0])

    def close(self) -> None:
        """Stop the physics threads and free the renderer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.sim.close()


class RigVectorEnv(VectorEnv):
    """Any registered rig as a Gymnasium ``VectorEnv`` of ``num_envs`` members.

    Equal, member by member, to ``num_envs`` :class:`RigEnv` with the same seeds (what
    ``gymnasium.make_vec(..., vectorization_mode="sync")`` builds), stepped as one batch.

    Parameters
    ----------
    num_envs : int
    max_episode_steps : int, optional
        Truncate a member after this many steps (``make_vec`` passes the registration's).
    autoreset_mode : gymnasium.vector.AutoresetMode or str
        ``NEXT_STEP`` (default), ``SAME_STEP`` (``info["final_obs"]``/``["final_info"]``) or
        ``DISABLED`` (reset with ``reset(options={"reset_mask": m})``).
    num_threads : int, optional
        Physics threads (default: the CPUs available).
    **kwargs
        Arguments of :class:`RigEnv` (``rig``, ``sensors``, ``params``...).

    Notes
    -----
    ``reset(seed=...)``: None, an int ``s`` (member ``i`` gets ``s + i``, as
    ``SyncVectorEnv``) or a list of ``num_envs`` ints/None. ``options`` go to every member
    (plus ``reset_mask``); ``options["x0"]`` may be ``(num_envs, n)`` and
    ``options["params"]`` a list of dicts. Infos are batched like ``SyncVectorEnv``'s, with
    ``_key`` masks.
    """

    metadata = {"render_modes": [], "render_fps": 100, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, rig: Any = "helicopter",
                 max_episode_steps: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 num_threads: int | None = None, render_mode: str | None = None, **kwargs):
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (headless rig), got {render_mode!r}")
        if max_episode_steps is not None:
            positive_int(max_episode_steps, "max_episode_steps")
        positive_int(num_envs, "num_envs")
        rig, kwargs = with_twin(rig, kwargs)
        self.sim = build_simulator(rig, int(num_envs), num_threads=num_threads, **kwargs)
        self.num_envs = self.sim.num
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode = None
        r = self.sim.rig
        self.single_action_space = spaces.Box(np.asarray(r.action_low, np.float64),
                                              np.asarray(r.action_high, np.float64),
                                              (r.n_actions,), np.float64)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (self.sim.sensors.dim,),
                                                   np.float64)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.state_names = list(r.state_names)
        self.action_names = list(r.action_names)
        self._done = np.zeros(self.num_envs, dtype=bool)

    def _infos(self, members: np.ndarray | None = None) -> dict[str, Any]:
        mask = np.ones(self.num_envs, dtype=bool)
        if members is not None:
            mask[:] = False
            mask[members] = True
        infos: dict[str, Any] = {}
        for key, value in self.sim.info.items():
            array = value.copy()
            if members is not None:
                array[~mask] = 0
            infos[key] = array
            infos[f"_{key}"] = mask.copy()
        return infos

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset all members (or those in ``options["reset_mask"]``)."""
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(n)]
        elif isinstance(seed, list | tuple | np.ndarray):
            seeds = list(seed)
        else:
            raise ValueError(f"seed must be None, a non-negative integer or a list of "
                             f"{n} of them, got {seed!r}")
        if len(seeds) != n:
            raise ValueError(f"If seeds are passed as a list the length must match "
                             f"num_envs={n} but got length={len(seeds)}.")
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be a dict or None, got {type(options).__name__}")
        for s in seeds:
            check_seed(s)
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        members = None
        if mask is not None:
            mask = np.asarray(mask)
            if mask.shape != (n,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(f"options['reset_mask'] must be a bool array of shape ({n},) "
                                 "with at least one True value")
            members = np.flatnonzero(mask)
            seeds = [seeds[i] for i in members]
        self.sim.reset(members, seeds, options or None)
        self._done[slice(None) if members is None else members] = False
        return self.sim.obs.copy(), self._infos(members)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                  np.ndarray, dict[str, Any]]:
        """Step every member with ``actions`` of shape (num_envs, nu)."""
        n = self.num_envs
        sim = self.sim
        u = sim.check_actions(actions, n)
        resetting = np.flatnonzero(self._done)
        if len(resetting) and self.autoreset_mode == AutoresetMode.DISABLED:
            raise RuntimeError(f"members {resetting.tolist()} finished their episode; reset "
                               "them with reset(options={'reset_mask': ...}) first")
        if len(resetting) and self.autoreset_mode == AutoresetMode.NEXT_STEP:
            stepping = np.flatnonzero(~self._done)
            if len(stepping):
                sim.step(u[stepping], stepping)
            sim.reset(resetting)
            stepped = ~self._done
        else:
            sim.step(u)
            stepped = np.ones(n, dtype=bool)
        terminated = sim.terminated & stepped
        truncated = np.zeros(n, dtype=bool)
        if self.max_episode_steps is not None:
            truncated = stepped & (sim.steps >= self.max_episode_steps)
        reward = sim.reward.copy()
        obs = sim.obs.copy()
        infos = self._infos()
        done = terminated | truncated
        if self.autoreset_mode == AutoresetMode.SAME_STEP and done.any():
            finished = np.flatnonzero(done)
            final_obs = np.full(n, None, dtype=object)
            final_info: dict[str, Any] = {}
            for i in finished:
                final_obs[i] = obs[i].copy()
                final_info = self._add_info(final_info, {k: v[i] for k, v in infos.items()
                                                         if not k.startswith("_")}, int(i))
            sim.reset(finished)
            obs = sim.obs.copy()
            infos = self._infos()
            infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
            infos["final_info"], infos["_final_info"] = final_info, done.copy()
            self._done[:] = False
        else:
            self._done = done
        return obs, reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the physics threads."""
        self.sim.close()
