"""The batch-first simulator: one implementation of reset/step for N members of any rig.

The Gymnasium ``Env`` (:class:`testbed.envs.RigEnv`) is its N = 1 view, the ``VectorEnv``
(:class:`testbed.envs.RigVectorEnv`) its N view, and the runner's closed loop drives it
directly, so a member's trajectory does not depend on how many members run with it.

Step semantics (per member, one control period ``dt_s = physics_dt_s * frame_skip``):

1. the action is checked (shape, finite) for every member before anything changes, clipped
   to the rig's limits; with a manoeuvre (open-loop input profile) the clipped action is
   added to the profile at the step's start and the sum clipped again (zero-order hold);
2. the rig's step noise perturbs its model (e.g. the vehicle's damping noise), then the
   disturbance ``G w(t) + b dW`` becomes joint accelerations and, through the mass matrix
   ``M(q)``, generalized forces (Euler-Maruyama: ``b xi / sqrt(dt)`` held over the step);
3. MuJoCo steps ``frame_skip`` times (``mujoco.batch`` on C threads, without the GIL; a
   rig's per-physics-step input limit runs in C, :mod:`testbed.sim.native`);
4. divergence check: a MuJoCo instability warning, a non-finite state or a state past the
   rig's ``state_envelope`` raises :class:`SimulationDiverged` (time, members, state);
5. the sensors sample the new state.

Randomness: member ``i`` owns one stream (:class:`testbed.sensors.NoiseStreams`, seeded like
a Gymnasium env's ``np_random``); per step it gives, in order, the rig's step noise, the
disturbance noise, then the sensors' noise.

Physics: the members are the simulations of one :class:`mujoco.batch.Batch`: each member's
complete MuJoCo integration state (``mjSTATE_INTEGRATION``: time, qpos, qvel, warm start,
ctrl, applied forces, userdata) is a row of one array, which the batch's C threads load into
an ``MjData``, step and store back: bitwise identical to stepping a dedicated ``MjData``,
without one ``MjData`` per member and without Python per member. A member's parameters and
the rig's step noise are per-simulation model fields (``Batch.expand``), written for all
members with one numpy assignment per field.

The parts, one module each: :mod:`testbed.sim.physics` (:class:`Physics`, the members'
MuJoCo states and their batch), this module (:class:`Simulator`: construction, declarations,
reset options, reset), :mod:`testbed.sim.step` (the batch step), :mod:`testbed.sim.step_one`
(the one-member step on Python floats), :mod:`testbed.sim.signals` (setpoints, input
profiles, disturbance signals by time), :mod:`testbed.sim.outputs` (``obs`` and ``info``'s
layout) and :mod:`testbed.sim.errors` (:class:`SimulationDiverged`).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np

from filters import real_array
from testbed.rigs.base import Rig
from testbed.rigs.disturbances import Disturbance
from testbed.sensors import Drawn, NoiseStreams, Sample, Sensor, reads_actuators
from testbed.sensors.fused import as_slice, state_row_plan
from testbed.sim.errors import SimulationDiverged
from testbed.sim.layout import (
    DisturbanceInputs,
    Draws,
    InfoLayout,
    Limits,
    Scoring,
    Sizes,
    WholeBatch,
)
from testbed.sim.outputs import _INFO_KEYS, Outputs, _joined
from testbed.sim.physics import _ALL, Physics, default_num_threads, positive_int
from testbed.sim.signals import Schedules, Signals
from testbed.sim.step import BatchStep
from testbed.sim.step_one import OneMemberStep

__all__ = ["RESET_OPTION_KEYS", "Physics", "SimulationDiverged", "Simulator",
           "default_num_threads", "positive_int"]

#: The keys of a member's reset options (:meth:`Simulator.reset`).
RESET_OPTION_KEYS = ("x0", "params", "setpoints", "manoeuvre", "manoeuvre_params")


def _defines_with(cls: type, method: str, companion: str) -> bool:
    """Whether the class in ``cls``'s MRO that defines ``method`` defines ``companion``."""
    for klass in cls.__mro__:
        if method in klass.__dict__:
            return companion in klass.__dict__
    return False


def _scoring(rig: Rig) -> Scoring:
    """The rig's tracked states and termination hooks as a step reads them."""
    tracked = rig.tracked_index
    lo, hi = (int(tracked[0]), int(tracked[-1]) + 1) if len(tracked) else (0, 0)
    cols = slice(lo, hi) if np.array_equal(tracked, np.arange(lo, hi)) else tracked
    return Scoring(tracked, len(tracked), cols, tracked.tolist(),
                   type(rig).terminated is not Rig.terminated,
                   _defines_with(type(rig), "terminated", "terminated_row"))


def _whole_batch(limits: Limits, sizes: Sizes, n: int, dt_s: float, nv: int) -> WholeBatch:
    """The batch step's read-only rows (one per member: numpy's ufuncs between arrays of one
    shape skip the broadcasting machinery, which costs more than the arithmetic on a few
    columns; the same values, bitwise) and its acceleration rows (n, nv)."""
    every = np.arange(n)
    zero_u, zero_accel, zero_w = (np.zeros((n, sizes.actions)), np.zeros((n, sizes.joints)),
                                  np.zeros((n, 0)))
    low, high = np.tile(limits.low, (n, 1)), np.tile(limits.high, (n, 1))
    envelope = np.tile(limits.envelope, (n, 1))
    dt, one = np.full(n, dt_s), np.ones(n, dtype=np.int64)
    for a in (every, zero_u, zero_accel, zero_w, low, high, envelope, dt, one):
        a.flags.writeable = False
    return WholeBatch(every, zero_u, zero_accel, zero_w, low, high, envelope, dt, one,
                      np.zeros((n, nv)),
                      (every, _ALL, n, low, high, envelope, zero_u, zero_accel, zero_w))


def _info_layout(sizes: Sizes, tracked: int, step_noise_dim: int, n: int) -> InfoLayout:
    """``info``'s float entries as column blocks of one (n, width) array, in
    :data:`~testbed.sim.outputs._INFO_KEYS` order."""
    widths = {"state": sizes.states, "t": 1, "disturbance": sizes.signal, "setpoint": tracked,
              "action_applied": sizes.actions, "manoeuvre": sizes.actions,
              "process_accel": sizes.joints, "step_noise": step_noise_dim}
    assert tuple(widths) == _INFO_KEYS
    columns: dict[str, slice] = {}
    start = 0
    for key, width in widths.items():
        columns[key] = slice(start, start + width)
        start += width
    # (t: its column index, the entry is a float, no block is sliced for it)
    slices = tuple(cols.start if key == "t" else cols for key, cols in columns.items())
    state_t = _joined(columns, "state", "t")
    setpoint_action = _joined(columns, "setpoint", "action_applied")
    step = slice(state_t.start, setpoint_action.stop) if sizes.signal == 0 else None
    return InfoLayout(np.zeros((n, start)), columns, slices, state_t, setpoint_action, step)


class Simulator(BatchStep, OneMemberStep, Signals, Outputs):
    """N members of one rig with sensors and a disturbance, stepped together.

    Parameters
    ----------
    rig : Rig
        The rig (nominal parameters; dedicated to this simulator: its model is modified).
    sensors : Sensor
        Copied; the copy holds the members' sensor states.
    num : int
        Number of members N.
    frame_skip : int
        Physics steps per control step.
    disturbance : Disturbance, optional
    params : dict, optional
        Default parameter scale factors of the simulated members (model mismatch).
    setpoints : sequence of rows, optional
        Default reference ``(t_s, *tracked)`` (default: the rig's, else zero).
    manoeuvre : str or callable, optional
        Default open-loop input profile (a name of ``rig.manoeuvres`` or ``t_s -> (nu,)``).
    manoeuvre_params : dict, optional
    num_threads : int, optional
    reset_noise_scale : float
        Scale of the rig's initial-state distribution (:meth:`Rig.random_x0`) for members
        reset without ``options["x0"]``; 0 (default here): the rig's fixed ``default_x0``.
        The draws come first in the member's stream, at reset.

    Attributes
    ----------
    obs : ndarray, shape (N, m)
    info : dict of ndarray
        ``state`` (N, n), ``t`` (N,), ``disturbance`` (N, s), ``setpoint`` (N, r),
        ``action_applied`` (N, nu), ``action_clipped`` (N, nu) bool, ``manoeuvre`` (N, nu)
        (the profile's part), ``process_accel`` (N, nv_rig), ``step_noise`` (N, d).
    reward : ndarray, shape (N,)
        ``-|x_tracked - reference|^2`` after the step.
    terminated : ndarray of bool, shape (N,)
    steps : ndarray of int, shape (N,)
    """

    def __init__(self, rig: Rig, sensors: Sensor, num: int = 1, frame_skip: int = 10, *,
                 disturbance: Disturbance | None = None, params: dict | None = None,
                 setpoints: Sequence[Sequence[float]] | None = None,
                 manoeuvre: Any = None, manoeuvre_params: dict | None = None,
                 num_threads: int | None = None, reset_noise_scale: float = 0.0):
        if not (isinstance(reset_noise_scale, int | float) and np.isfinite(reset_noise_scale)
                and reset_noise_scale >= 0):
            raise ValueError(f"reset_noise_scale must be finite and >= 0, got "
                             f"{reset_noise_scale!r}")
        self.reset_noise_scale = float(reset_noise_scale)
        positive_int(num, "num")
        positive_int(frame_skip, "frame_skip")
        if not isinstance(sensors, Sensor):
            raise ValueError(f"sensors must be a testbed.sensors.Sensor, got {sensors!r}")
        self.rig = rig
        self.num = n = int(num)
        self.frame_skip = int(frame_skip)
        self.dt_s = float(rig.model.opt.timestep) * self.frame_skip
        self.nominal_params = rig.params.scaled(params or {})
        self.disturbance = dist = disturbance or Disturbance(n_positions=len(rig.joints))
        mismatched = sorted(p for p in sensors.sample_periods_s()
                            if not np.isclose(p, self.dt_s, rtol=1e-9, atol=0.0))
        if mismatched:
            raise ValueError(f"sensors were built for a sampling period of {mismatched[0]} s "
                             f"but the control period is {self.dt_s} s (frame_skip "
                             f"{self.frame_skip} x timestep {rig.model.opt.timestep} s)")
        self.sensors = copy.deepcopy(sensors)
        self.sensors.allocate(n)
        j = len(rig.joints)
        self.sizes = Sizes(rig.n_states, rig.n_actions, j, len(dist.signal(0.0)))
        low, high = np.asarray(rig.action_low, float), np.asarray(rig.action_high, float)
        self.limits = Limits(low, high, rig.envelope, low.tolist(), high.tolist(),
                             rig.envelope.tolist())
        self.scoring = _scoring(rig)
        #: A one-member simulator steps on Python floats (:mod:`testbed.sim.step_one`).
        self._single = n == 1
        table = setpoints if setpoints is not None else (rig.default_setpoints or None)
        table = (rig.validate_setpoints(table) if table is not None
                 else np.zeros((1, 1 + self.scoring.count)))
        self.schedules = Schedules.default(table, self._resolve_manoeuvre(manoeuvre,
                                                                          manoeuvre_params), n)
        self.physics = Physics(rig, n, self.frame_skip, num_threads)
        self.physics.reset(range(n), [self.nominal_params] * n,
                           np.tile(rig.default_x0(), (n, 1)))
        d_draws = 0 if dist.b is None else dist.b.shape[1]
        s_draws = self.sensors.draws_per_sample()
        self.draws = Draws(d_draws, s_draws, rig.step_noise_dim + d_draws + (s_draws or 0),
                           rig.step_noise_dim + d_draws)
        #: A one-member simulator's sensors measured from the state list alone (a fused
        #: plan's steps on a row, :func:`~testbed.sensors.fused.state_row_plan`); else None.
        plan = state_row_plan(self.sensors) if n == 1 else None
        self._row_plan = plan if plan is not None and plan.draws == s_draws else None
        #: Whether a sensor reads the actuator states (``Sample.act``; they are then read
        #: for it at every sample, and the state-only row plan is not used).
        self._reads_act = reads_actuators(self.sensors)
        if self._reads_act:
            self._row_plan = None
        self.noise = NoiseStreams(n, max(64 * max(d_draws + rig.step_noise_dim
                                                  + self.sensors.dim + rig.x0_draws, 4),
                                         self.draws.step))
        self._noise_all = self.noise.view(slice(None))
        self._no_draws = Drawn(np.zeros((n, 0)))  # for sensors that draw nothing
        self.inputs = DisturbanceInputs(
            dist.has_signal, dist.active,
            not (dist.has_signal or dist.active or rig.step_noise_dim),
            None if dist.G is None else dist.G[j:], None if dist.b is None else dist.b[j:],
            np.sqrt(self.dt_s), rig.dof_adr, as_slice(rig.dof_adr))
        self.steps = np.zeros(n, dtype=np.int64)
        #: Whether every member has the same step count (the common case of a batch reset and
        #: stepped together): the references, input profiles and disturbance signals are then
        #: looked up once per step, not per member.
        self._same_steps = False
        self._ready = np.zeros(n, dtype=bool)
        self._all_ready = False
        self.x0 = np.zeros((n, self.sizes.states))
        self.obs = np.zeros((n, self.sensors.dim))
        self.reward = np.zeros(n)
        self.terminated = np.zeros(n, dtype=bool)
        self.record_poses = False
        self.rows = _whole_batch(self.limits, self.sizes, n, self.dt_s, self.physics.nv)
        self.layout = _info_layout(self.sizes, self.scoring.count, rig.step_noise_dim, n)
        self.info: dict[str, np.ndarray] = {}
        self._info_views(np.zeros((n, self.sizes.actions), dtype=bool))

    # ------------------------------------------------------------------ declarations
    @property
    def state_names(self) -> list[str]:
        """The rig's state names."""
        return list(self.rig.state_names)

    @property
    def action_names(self) -> list[str]:
        """The rig's action names."""
        return list(self.rig.action_names)

    @property
    def known_disturbance(self) -> Disturbance | None:
        """The disturbance a designer is told about (None when it has neither a signal nor
        an intensity)."""
        d = self.disturbance
        return d if (d.active or d.has_signal) else None


    def units(self) -> dict[str, str]:
        """Units of states, actions and measurement channels."""
        units = self.rig.units()
        for name, unit in zip(self.sensors.names, self.sensors.units, strict=True):
            units.setdefault(name, unit)
            units[f"measurement:{name}"] = unit
        return units

    # ------------------------------------------------------------------ options

    def member_options(self, options: dict | Sequence[dict | None] | None,
                       k: int) -> list[dict[str, Any]]:
        """One validated options dict per reset member.

        One shared dict applies to every member; in it ``x0`` may be (k, n) and ``params`` a
        sequence of k dicts. A sequence gives one dict (or None) per member.
        """
        def check(d: dict) -> dict:
            if not isinstance(d, dict):
                raise ValueError(f"reset options must be a dict, got {type(d).__name__}")
            unknown = set(d) - set(RESET_OPTION_KEYS)
            if unknown:
                raise ValueError(f"unknown reset options {sorted(unknown)}; expected keys among "
                                 f"{RESET_OPTION_KEYS}")
            return d

        if options is None or isinstance(options, dict):
            shared = check(dict(options or {}))
            per: list[dict[str, Any]] = [{} for _ in range(k)]
            for key, value in shared.items():
                if value is None:
                    continue
                if key == "params" and not isinstance(value, dict):
                    if not isinstance(value, list | tuple) or not all(
                            v is None or isinstance(v, dict) for v in value):
                        raise ValueError("options['params'] must be a dict {field: scale} or a "
                                         f"list of {k} such dicts, got {value!r}")
                    values = list(value)
                elif key == "x0" and np.ndim(real_array(value, "options['x0']",
                                                        finite=False)) == 2:
                    values = list(real_array(value, "options['x0']", finite=False))
                else:
                    values = [value] * k
                if len(values) != k:
                    raise ValueError(f"options[{key!r}] has {len(values)} entries for {k} "
                                     "members being reset")
                for d, v in zip(per, values, strict=True):
                    d[key] = v
            return per
        per = [check(dict(o or {})) for o in options]
        if len(per) != k:
            raise ValueError(f"got {len(per)} option dicts for {k} members being reset")
        return per


    # ------------------------------------------------------------------ signals


    # ------------------------------------------------------------------ API
    def reset(self, members: np.ndarray | None = None,
              seeds: Sequence[int | None] | None = None,
              options: dict | Sequence[dict | None] | None = None) -> None:
        """Reset members (default all) like ``gym.Env.reset(seed=..., options=...)``.

        Parameters
        ----------
        members : ndarray of int, shape (k,), optional
        seeds : sequence of (int or None), length k, optional
            None keeps a member's generator (a new random one if it has none).
        options : dict or sequence of k dicts, optional
            Keys ``x0`` (n,), ``params`` ({name: scale}), ``setpoints`` (rows
            ``(t_s, *tracked)``), ``manoeuvre`` (name, callable or None),
            ``manoeuvre_params``. Everything is validated before any member changes.
        """
        index = np.arange(self.num) if members is None else np.asarray(members, int)
        k = len(index)
        seeds = [None] * k if seeds is None else list(seeds)
        if len(seeds) != k:
            raise ValueError(f"got {len(seeds)} seeds for {k} members being reset")
        for seed in seeds:
            if seed is not None and (not isinstance(seed, int | np.integer) or seed < 0):
                raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
        per = self.member_options(options, k)
        nominal = self.nominal_params  # (validated when built; frozen: shared, not copied)
        params = [nominal.scaled(o["params"]) if o.get("params") else nominal for o in per]
        x0 = np.array([self.rig.validate_x0(o["x0"]) if o.get("x0") is not None
                       else self.rig.default_x0() for o in per]).reshape(k, self.sizes.states)
        tables = [0 if o.get("setpoints") is None else
                  self._index(self.schedules.tables, self.rig.validate_setpoints(o["setpoints"]))
                  for o in per]
        schedules = []
        for o in per:
            if "manoeuvre" in o:
                fn = self._resolve_manoeuvre(o["manoeuvre"], o.get("manoeuvre_params"))
            elif o.get("manoeuvre_params"):
                default = self.schedules.profiles[0]
                if default is None:
                    raise ValueError("options['manoeuvre_params'] given without a manoeuvre")
                fn = self._resolve_manoeuvre(default.name, o["manoeuvre_params"])
            else:
                fn = self.schedules.profiles[0]
            schedules.append(self._index(self.schedules.profiles, fn))
        # validated: now change state
        for i, seed in zip(index.tolist(), seeds, strict=True):
            self.noise.seed(i, None if seed is None else int(seed))
        drawn = [j for j, o in enumerate(per) if o.get("x0") is None]
        if drawn and self.reset_noise_scale > 0 and self.rig.x0_draws:
            xi = self.noise.view(index[drawn]).normal(self.rig.x0_draws)
            x0[drawn] = self.rig.random_x0(xi * self.reset_noise_scale)
        self.physics.reset(index.tolist(), params, x0)
        self.schedules.table_of[index] = tables
        self.schedules.profile_of[index] = schedules
        self.schedules.none = (len(self.schedules.profiles) == 1
                               and self.schedules.profiles[0] is None)
        self._ready[index] = True
        self._all_ready = bool(self._ready.all())
        self.steps[index] = 0
        self._same_steps = not np.count_nonzero(self.steps)
        self.x0[index] = x0
        t = np.zeros(k)
        info = self.info
        w = self._signal(t, index, common=True)
        x = self.physics.states(index)
        info["state"][index] = x
        info["t"][index] = 0.0
        info["disturbance"][index] = w
        info["setpoint"][index] = self._reference(t, index, common=True)
        for key in ("action_applied", "action_clipped", "manoeuvre", "process_accel",
                    "step_noise"):
            info[key][index] = 0
        sample = Sample(x, t, np.zeros((k, self.sizes.actions)), np.asarray(w), index,
                        self.physics.actuator_states(index) if self._reads_act else None)
        noise = self.noise.view(index)
        self.sensors.reset(sample, noise)
        self.obs[index] = self.sensors.measure(sample, noise)
        self.reward[index] = 0.0
        self.terminated[index] = False
        if self.record_poses:
            self.physics.forward_poses(index)


    def close(self) -> None:
        """Stop the physics threads."""
        self.physics.close()
