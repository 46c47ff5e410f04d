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
3. MuJoCo steps ``frame_skip`` times (a pool of threads; ``mj_step`` releases the GIL);
4. divergence check: a MuJoCo instability warning, a non-finite state or a state past the
   rig's ``state_envelope`` raises :class:`SimulationDiverged` (time, members, state);
5. the sensors sample the new state.

Randomness: member ``i`` owns one stream (:class:`testbed.sensors.NoiseStreams`, seeded like
a Gymnasium env's ``np_random``); per step it gives, in order, the rig's step noise, the
disturbance noise, then the sensors' noise.

Physics: each member's complete MuJoCo integration state (``mjSTATE_INTEGRATION``: time,
qpos, qvel, warm start, ctrl, applied forces) is a row of one array; a worker thread loads a
row into its own ``MjData``, steps and stores it back, which is bitwise identical to stepping
a dedicated ``MjData`` without one ``MjData`` (13.6 MB arena) per member.
"""

from __future__ import annotations

import bisect
import copy
import os
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import mujoco
import numpy as np

from filters import real_array
from testbed.rigs.base import Params, Rig
from testbed.rigs.disturbances import Disturbance
from testbed.sensors import NoiseStreams, Sample, Sensor

_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
_CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
_QFRC = int(mujoco.mjtState.mjSTATE_QFRC_APPLIED)
_XFRC = int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)
_QPOS = int(mujoco.mjtState.mjSTATE_QPOS)
_QVEL = int(mujoco.mjtState.mjSTATE_QVEL)
#: Chunks per physics thread a step is split into (the threads take them from a queue).
_CHUNKS_PER_THREAD = 8
RESET_OPTION_KEYS = ("x0", "params", "setpoints", "manoeuvre", "manoeuvre_params")


#: MuJoCo's instability warnings: NaN, inf or huge qpos, qvel or qacc (MuJoCo then resets
#: the state, which stays finite; the counters in ``MjData.warning`` tell).
_BAD_WARNINGS = tuple(int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS,
                                       mujoco.mjtWarning.mjWARN_BADQVEL,
                                       mujoco.mjtWarning.mjWARN_BADQACC))


class SimulationDiverged(RuntimeError):
    """The simulation left what the rig can physically do; its results would be meaningless.

    Raised by :meth:`Simulator.step` when, after a control step, a member's MuJoCo data
    reported an instability warning (NaN, inf or huge ``qpos``/``qvel``/``qacc``, after which
    MuJoCo silently resets the state), its state is not finite, or a state component is past
    the rig's :attr:`~testbed.rigs.base.Rig.state_envelope`. The diverged members must be
    reset before they step again.

    Parameters
    ----------
    message : str
        Human-readable description (time, member, reason, state).
    time_s : float
        Simulation time at the end of the failing step, s.
    state : ndarray, shape (k, n)
        States of the diverged members after the step.
    members : list of int
        Indices of the diverged members.
    reason : str
        ``"mujoco warning"``, ``"non-finite state"`` or ``"outside envelope"`` (of the first).
    """

    def __init__(self, message: str, *, time_s: float, state: np.ndarray, members: list[int],
                 reason: str):
        super().__init__(message)
        self.message, self.time_s, self.reason = message, float(time_s), reason
        self.state, self.members = np.asarray(state), list(members)

    def __reduce__(self) -> tuple[Any, ...]:
        # keyword-only constructor: picklable for process pools and Ray
        return (_rebuild_diverged, (self.message, self.time_s, self.state, self.members,
                                    self.reason))


def _rebuild_diverged(message: str, time_s: float, state: np.ndarray, members: list[int],
                      reason: str) -> SimulationDiverged:
    return SimulationDiverged(message, time_s=time_s, state=state, members=members,
                              reason=reason)


def positive_int(value: Any, name: str) -> int:
    """``value`` as an ``int >= 1`` (a bool, float or other type is a ``ValueError``)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def default_num_threads() -> int:
    """CPUs this process may run on (the default size of the physics thread pool)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _state_offset(model: mujoco.MjModel, spec: int, component: int) -> int:
    """Offset of one component in a ``spec`` state vector (stored in increasing bit order)."""
    return sum(mujoco.mj_stateSize(model, 1 << k) for k in range(component.bit_length() - 1)
               if spec & (1 << k))


class Physics:
    """MuJoCo integration states of N members, stepped by a pool of threads.

    Parameters
    ----------
    rig : Rig
        Model factory (its own model is modified to make per-parameter copies).
    num : int
    frame_skip : int
    num_threads : int, optional
        Worker threads (default :func:`default_num_threads`, at most ``num``).
    """

    def __init__(self, rig: Rig, num: int, frame_skip: int, num_threads: int | None = None):
        self.rig, self.num, self.frame_skip = rig, int(num), int(frame_skip)
        model = rig.model
        self.nu, self.nv, self.nbody = model.nu, model.nv, model.nbody
        self._own_models = rig.step_noise_dim > 0  # each member perturbs its model per step
        self._cache: dict[Params, mujoco.MjModel] = {}
        self._scratch = mujoco.MjData(model)
        self.models = [self.model_for(rig.params)] * self.num
        #: Members still on their parameters' shared model that perturb it in their next
        #: step: they get their own copy first (:meth:`_own_copies`); ``_any_shared``: any.
        self._shared = np.full(self.num, self._own_models)
        self._any_shared = self._own_models
        self.constants = np.tile(rig.member_constants(rig.params), (self.num, 1))
        nstate = mujoco.mj_stateSize(model, _INTEGRATION)
        self.state = np.zeros((self.num, nstate))
        self.mass = np.zeros((self.num, self.nv, self.nv))
        c = _state_offset(model, _INTEGRATION, _CTRL)
        f = _state_offset(model, _INTEGRATION, _QFRC)
        x = _state_offset(model, _INTEGRATION, _XFRC)
        self._ctrl, self._qfrc = slice(c, c + self.nu), slice(f, f + self.nv)
        self._xfrc = slice(x, x + 6 * self.nbody)
        qpos, qvel = (_state_offset(model, _INTEGRATION, b) for b in (_QPOS, _QVEL))
        self._gather = np.concatenate([qpos + rig.qpos_adr, qvel + rig.dof_adr])
        self._check_layout()
        threads = (default_num_threads() if num_threads is None
                   else positive_int(num_threads, "num_threads"))
        self.num_threads = min(threads, max(self.num, 1))
        self._datas = [mujoco.MjData(model) for _ in range(self.num_threads)]
        self.poses: tuple[np.ndarray, np.ndarray] | None = None
        #: Members whose MuJoCo data reported an instability warning in their last step.
        self.unstable = np.zeros(self.num, dtype=bool)
        self._pool = (ThreadPoolExecutor(self.num_threads - 1, "testbed-physics")
                      if self.num_threads > 1 else None)

    def __getstate__(self) -> dict[str, Any]:
        """Copies (``copy.deepcopy``, pickle) are independent: without the thread pool."""
        state = dict(self.__dict__)
        state["_pool"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if self.num_threads > 1:
            self._pool = ThreadPoolExecutor(self.num_threads - 1, "testbed-physics")

    def _check_layout(self) -> None:
        """Verify the computed state offsets against MuJoCo (fails loudly if it changes)."""
        model = self.rig.model
        data = mujoco.MjData(model)
        data.ctrl[:] = np.arange(1, self.nu + 1)
        data.qfrc_applied[:] = -np.arange(1, self.nv + 1)
        data.xfrc_applied[:] = np.arange(6 * self.nbody).reshape(self.nbody, 6) + 0.5
        data.qpos[:] = 10 + np.arange(model.nq)
        data.qvel[:] = 20 + np.arange(self.nv)
        row = np.zeros(self.state.shape[1])
        mujoco.mj_getState(model, data, row, _INTEGRATION)
        expected = np.concatenate([data.qpos[self.rig.qpos_adr], data.qvel[self.rig.dof_adr]])
        if not (np.array_equal(row[self._ctrl], data.ctrl)
                and np.array_equal(row[self._qfrc], data.qfrc_applied)
                and np.array_equal(row[self._xfrc], data.xfrc_applied.ravel())
                and np.array_equal(row[self._gather], expected)):
            raise RuntimeError("unexpected mjSTATE_INTEGRATION layout in this MuJoCo version")

    def model_for(self, params: Params) -> mujoco.MjModel:
        """A copy of the rig's model with these parameters (cached: shared by the members
        with these parameters, never perturbed); the rig is not changed."""
        model = self._cache.get(params)
        if model is None:
            model = self._cache[params] = self.rig.model_with(params, self._scratch)
        return model

    def _own_copies(self, members: np.ndarray) -> None:
        """Give the members still on a shared model their own copy of it (their step noise
        perturbs it). Copy on the first step, not at the reset: a reset only reads the
        model, and a second reset before a step (the runner's) copies nothing."""
        for i in members[self._shared[members]].tolist():
            self.models[i] = copy.copy(self.models[i])  # mj_copyModel: bitwise equal
        self._shared[members] = False
        self._any_shared = bool(self._shared.any())

    def reset(self, members: Sequence[int], params: Sequence[Params], x0: np.ndarray) -> None:
        """``mj_resetData``, ``x0`` into qpos/qvel, ``mj_forward`` for each member (k,)."""
        data = self._datas[0]
        for j, i in enumerate(members):
            model = self.models[i] = self.model_for(params[j])
            self.constants[i] = self.rig.member_constants(params[j])
            mujoco.mj_resetData(model, data)
            self.rig.set_state(x0[j], data, model)
            mujoco.mj_getState(model, data, self.state[i], _INTEGRATION)
            mujoco.mj_fullM(model, data, self.mass[i])
        self.unstable[list(members)] = False
        self._shared[list(members)] = self._own_models
        self._any_shared = bool(self._shared.any())
        in_use = {id(m) for m in self.models}
        self._cache = {p: m for p, m in self._cache.items() if id(m) in in_use}

    def states(self, members: Any = slice(None)) -> np.ndarray:
        """Rig states of the members, shape (k, n)."""
        return self.state[members][:, self._gather]

    def set_inputs(self, members: Any, inputs: dict[str, np.ndarray],
                   qfrc: np.ndarray | None) -> None:
        """Write ctrl / xfrc_applied / qfrc_applied of the members' state rows."""
        if "ctrl" in inputs:
            self.state[members, self._ctrl] = inputs["ctrl"]
        if "xfrc" in inputs:
            self.state[members, self._xfrc] = inputs["xfrc"].reshape(len(inputs["xfrc"]), -1)
        if qfrc is not None:
            self.state[members, self._qfrc] = qfrc

    def step(self, members: np.ndarray, need_mass: bool = False,
             need_poses: bool = False, step_noise: np.ndarray | None = None) -> None:
        """``mj_step`` ``frame_skip`` times for the members (sorted int array).

        ``step_noise`` (k, d), one row per member, is applied to each member's model
        (``rig.apply_step_noise``) right before its step, by the thread that steps it (so
        this Python work overlaps the other threads' physics).

        The threads (the calling one included) take chunks of about ``k / (8 threads)``
        members from a shared queue until none is left, so a thread slowed down by another
        process (a shared machine) or a late start does fewer. Which thread steps a member
        does not change its result (each loads its whole state into the thread's data).
        """
        if need_poses and (self.poses is None or len(self.poses[0]) != self.num):
            self.poses = (np.zeros((self.num, self.nbody, 3)), np.zeros((self.num, self.nbody, 4)))
        k = len(members)
        if not k:
            return
        if step_noise is not None and self._any_shared:
            self._own_copies(members)
        rows = members.tolist()
        if self._pool is None or k < 2:
            self._work(self._datas[0], ((0, k),), rows, need_mass, need_poses, step_noise)
            return
        size = -(-k // (_CHUNKS_PER_THREAD * self.num_threads))
        queue = iter([(s, min(s + size, k)) for s in range(0, k, size)])
        lock = threading.Lock()

        def chunks() -> Iterator[tuple[int, int]]:  # one per thread, all from the queue
            while True:
                with lock:
                    chunk = next(queue, None)
                if chunk is None:
                    return
                yield chunk

        args = (rows, need_mass, need_poses, step_noise)
        futures = [self._pool.submit(self._work, data, chunks(), *args)
                   for data in self._datas[1:min(self.num_threads, k)]]
        try:
            self._work(self._datas[0], chunks(), *args)
        finally:
            for future in futures:
                future.result()

    def _work(self, data: mujoco.MjData, chunks: Iterable[tuple[int, int]], rows: list[int],
              need_mass: bool, need_poses: bool, step_noise: np.ndarray | None) -> None:
        """Step the members ``rows[start:stop]`` of each chunk ``(start, stop)`` in ``data``
        (``step_noise`` rows are indexed like ``rows``)."""
        models, state, mass, nstep = self.models, self.state, self.mass, self.frame_skip
        set_state, get_state, step = mujoco.mj_setState, mujoco.mj_getState, mujoco.mj_step
        substep = self.rig.substep_ctrl if self.rig.needs_substep else None
        perturb, constants = self.rig.apply_step_noise, self.constants
        warnings = data.warning.number  # a view of MuJoCo's counters (zero unless it warned)
        w1, w2, w3 = _BAD_WARNINGS
        unstable = self.unstable
        for start, stop in chunks:
            for j in range(start, stop):
                i = rows[j]
                model, row = models[i], state[i]
                if step_noise is not None:
                    perturb(model, constants[i], step_noise[j])
                set_state(model, data, row, _INTEGRATION)
                if substep is None:
                    step(model, data, nstep)
                else:  # ctrl from the held command and the actuator state, every physics step
                    command = data.ctrl.copy()
                    for _ in range(nstep):
                        data.ctrl[:] = substep(command, data.act, constants[i])
                        step(model, data)
                    data.ctrl[:] = command
                get_state(model, data, row, _INTEGRATION)
                unstable[i] = bool(warnings[w1] or warnings[w2] or warnings[w3])
                if unstable[i]:
                    warnings[:] = 0
                if need_mass:
                    mujoco.mj_fullM(model, data, mass[i])
                if need_poses:
                    self.poses[0][i] = data.xpos
                    self.poses[1][i] = data.xquat

    def forward_poses(self, members: np.ndarray) -> None:
        """Body poses of the members from their current states (``mj_kinematics``)."""
        if self.poses is None or len(self.poses[0]) != self.num:
            self.poses = (np.zeros((self.num, self.nbody, 3)), np.zeros((self.num, self.nbody, 4)))
        data = self._datas[0]
        for i in members:
            mujoco.mj_setState(self.models[i], data, self.state[i], _INTEGRATION)
            mujoco.mj_kinematics(self.models[i], data)
            self.poses[0][i] = data.xpos
            self.poses[1][i] = data.xquat

    def close(self) -> None:
        """Stop the worker threads."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


def _per_time(fn: Callable[[float], np.ndarray], t: np.ndarray, dim: int) -> np.ndarray:
    """``fn(t_i)`` for every entry of ``t`` (k,), evaluated once per distinct time: (k, dim)."""
    if len(t) and t.min() == t.max():
        return np.broadcast_to(np.asarray(fn(float(t[0])), dtype=float), (len(t), dim))
    values, inverse = np.unique(t, return_inverse=True)
    table = np.array([fn(float(v)) for v in values], dtype=float).reshape(len(values), dim)
    return table[inverse]


class Simulator:
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
        self.disturbance = disturbance or Disturbance(n_positions=len(rig.joints))
        mismatched = sorted(p for p in sensors.sample_periods_s()
                            if not np.isclose(p, self.dt_s, rtol=1e-9, atol=0.0))
        if mismatched:
            raise ValueError(f"sensors were built for a sampling period of {mismatched[0]} s "
                             f"but the control period is {self.dt_s} s (frame_skip "
                             f"{self.frame_skip} x timestep {rig.model.opt.timestep} s)")
        self.sensors = copy.deepcopy(sensors)
        self.sensors.allocate(n)
        self._low = np.asarray(rig.action_low, float)
        self._high = np.asarray(rig.action_high, float)
        self._nu, self._nx = rig.n_actions, rig.n_states
        self._j = len(rig.joints)
        self._tracked = rig.tracked_index
        lo, hi = (int(self._tracked[0]), int(self._tracked[-1]) + 1) if len(self._tracked) \
            else (0, 0)
        #: The tracked columns as a slice when contiguous (a view instead of a gather).
        self._tracked_cols = (slice(lo, hi) if np.array_equal(self._tracked, np.arange(lo, hi))
                              else self._tracked)
        self._envelope = rig.envelope
        table = setpoints if setpoints is not None else (rig.default_setpoints or None)
        r = len(self._tracked)
        self._tables = [rig.validate_setpoints(table) if table is not None
                        else np.zeros((1, 1 + r))]
        self._table_times = self._tables[0][:, 0].tolist()
        self._table_of = np.zeros(n, dtype=int)
        self._schedules: list[Any] = [self._resolve_manoeuvre(manoeuvre, manoeuvre_params)]
        self._schedule_of = np.zeros(n, dtype=int)
        self._w_dim = len(self.disturbance.signal(0.0))
        self._dist_draws = 0 if self.disturbance.b is None else self.disturbance.b.shape[1]
        self.physics = Physics(rig, n, self.frame_skip, num_threads)
        self.physics.reset(range(n), [self.nominal_params] * n,
                           np.tile(rig.default_x0(), (n, 1)))
        self.noise = NoiseStreams(n, 64 * max(self._dist_draws + rig.step_noise_dim
                                              + self.sensors.dim + rig.x0_draws, 4))
        self._noise_all = self.noise.view(slice(None))
        self.steps = np.zeros(n, dtype=np.int64)
        self._ready = np.zeros(n, dtype=bool)
        self.x0 = np.zeros((n, self._nx))
        self.obs = np.zeros((n, self.sensors.dim))
        self.reward = np.zeros(n)
        self.terminated = np.zeros(n, dtype=bool)
        self.record_poses = False
        self._all = np.arange(n)  # read-only constants of the step
        self._zero_input, self._zero_accel = np.zeros((n, self._nu)), np.zeros((n, self._j))
        self._zero_w = np.zeros((n, 0))
        for a in (self._all, self._zero_input, self._zero_accel, self._zero_w):
            a.flags.writeable = False
        widths = {"state": self._nx, "t": 1, "disturbance": self._w_dim, "setpoint": r,
                  "action_applied": self._nu, "manoeuvre": self._nu, "process_accel": self._j,
                  "step_noise": rig.step_noise_dim}
        # the float entries of info are column blocks of one array, so one member's info is
        # one row copy (:meth:`member_info`)
        self._info_rows = np.zeros((n, sum(widths.values())))
        self._info_columns: dict[str, slice] = {}
        start = 0
        for key, width in widths.items():
            self._info_columns[key] = slice(start, start + width)
            start += width
        self.info: dict[str, np.ndarray] = {}
        self._info_views(np.zeros((n, self._nu), dtype=bool))

    def _info_views(self, action_clipped: np.ndarray) -> None:
        """``info``: views of the column blocks of ``_info_rows`` (rebuilt in copies)."""
        self.info.clear()
        self.info.update({key: self._info_rows[:, cols]
                          for key, cols in self._info_columns.items()})
        self.info["t"] = self._info_rows[:, self._info_columns["t"].start]
        self.info["action_clipped"] = action_clipped

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Copies (``copy.deepcopy``, pickle) step on their own arrays: ``info`` is views of
        the copy's ``_info_rows`` again (a copied view would be a detached array)."""
        self.__dict__.update(state)
        self.info = {}
        self._info_views(np.array(state["info"]["action_clipped"], copy=True))

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

    def member_info(self, i: int) -> dict[str, Any]:
        """A copy of member ``i``'s entries of :attr:`info` (arrays without the member axis,
        ``t`` a float): the Gymnasium ``info`` of a step."""
        row = self._info_rows[i].copy()
        out: dict[str, Any] = {key: row[cols] for key, cols in self._info_columns.items()}
        out["t"] = float(row[self._info_columns["t"].start])
        out["action_clipped"] = self.info["action_clipped"][i].copy()
        return out

    def units(self) -> dict[str, str]:
        """Units of states, actions and measurement channels."""
        units = self.rig.units()
        for name, unit in zip(self.sensors.names, self.sensors.units, strict=True):
            units.setdefault(name, unit)
            units[f"measurement:{name}"] = unit
        return units

    # ------------------------------------------------------------------ options
    def _resolve_manoeuvre(self, manoeuvre: Any, params: dict | None) -> Any:
        if manoeuvre is None or manoeuvre == "none":
            if params:
                raise ValueError("manoeuvre_params given without a manoeuvre")
            return None
        if isinstance(manoeuvre, str):
            if manoeuvre not in self.rig.manoeuvres:
                raise ValueError(f"unknown manoeuvre {manoeuvre!r} for rig {self.rig.name!r}; "
                                 f"expected one of {sorted(self.rig.manoeuvres) or 'none'}")
            try:
                return self.rig.manoeuvres[manoeuvre](**(params or {}))
            except TypeError as err:
                raise ValueError(f"bad manoeuvre_params for {manoeuvre!r}: {err}") from None
        if params:
            raise ValueError("manoeuvre_params is only used with a manoeuvre name")
        if not callable(manoeuvre):
            raise ValueError(f"manoeuvre must be a name, None or a callable t_s -> input, got "
                             f"{manoeuvre!r}")
        return manoeuvre

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

    def _index(self, registry: list, value: Any) -> int:
        for j, known in enumerate(registry):
            if known is value or (isinstance(known, np.ndarray) and isinstance(value, np.ndarray)
                                  and known.shape == value.shape and np.array_equal(known, value)):
                return j
        registry.append(value)
        return len(registry) - 1

    # ------------------------------------------------------------------ signals
    def _reference(self, t: np.ndarray, sel: Any) -> np.ndarray:
        if len(self._tables) == 1:  # one schedule for every member
            table = self._tables[0]
            if len(t) == 1:  # the same row as below, without numpy's per-call overhead
                row = bisect.bisect_right(self._table_times, float(t[0])) - 1
                return table[max(row, 0), 1:][None]
            rows = np.searchsorted(table[:, 0], t, side="right") - 1
            return table[np.maximum(rows, 0), 1:]
        groups = self._table_of[sel]
        out = np.empty((len(t), len(self._tracked)))
        for g in np.unique(groups):
            table = self._tables[g]
            mask = groups == g
            rows = np.searchsorted(table[:, 0], t[mask], side="right") - 1
            out[mask] = table[np.maximum(rows, 0), 1:]
        return out

    def setpoints_at(self, t_s: float | np.ndarray, members: Any = slice(None)) -> np.ndarray:
        """References of the members at time(s) ``t_s``, shape (k, r)."""
        groups = self._table_of[members]
        return self._reference(np.broadcast_to(np.asarray(t_s, float), groups.shape), members)

    @property
    def _no_manoeuvre(self) -> bool:
        """No member has an input profile."""
        return len(self._schedules) == 1 and self._schedules[0] is None

    def _manoeuvre(self, t: np.ndarray, sel: Any) -> np.ndarray:
        if self._no_manoeuvre:  # no profile anywhere
            return np.zeros((len(t), self._nu))
        groups = self._schedule_of[sel]
        out = np.zeros((len(t), self._nu))
        for g in (0,) if len(self._schedules) == 1 else np.unique(groups):
            fn = self._schedules[g]
            if fn is None:
                continue
            mask = groups == g
            out[mask] = _per_time(lambda s, fn=fn: np.atleast_1d(fn(s)), t[mask], self._nu)
        if not np.all(np.isfinite(out)):
            raise ValueError(f"the manoeuvre returned a non-finite input at t = {t.tolist()} s")
        return out

    def _signal(self, t: np.ndarray, index: np.ndarray) -> np.ndarray:
        member_signal = getattr(self.disturbance, "member_signal", None)
        if member_signal is not None:  # one sequence per member (SampledDisturbance)
            return member_signal(t, index)
        return _per_time(self.disturbance.signal, t, self._w_dim)

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
        params = [self.nominal_params.scaled(o.get("params") or {}) for o in per]
        x0 = np.array([self.rig.validate_x0(o["x0"]) if o.get("x0") is not None
                       else self.rig.default_x0() for o in per]).reshape(k, self._nx)
        tables = [0 if o.get("setpoints") is None else
                  self._index(self._tables, self.rig.validate_setpoints(o["setpoints"]))
                  for o in per]
        schedules = []
        for o in per:
            if "manoeuvre" in o:
                fn = self._resolve_manoeuvre(o["manoeuvre"], o.get("manoeuvre_params"))
            elif o.get("manoeuvre_params"):
                default = self._schedules[0]
                if default is None:
                    raise ValueError("options['manoeuvre_params'] given without a manoeuvre")
                fn = self._resolve_manoeuvre(default.name, o["manoeuvre_params"])
            else:
                fn = self._schedules[0]
            schedules.append(self._index(self._schedules, fn))
        # validated: now change state
        for i, seed in zip(index.tolist(), seeds, strict=True):
            self.noise.seed(i, None if seed is None else int(seed))
        drawn = [j for j, o in enumerate(per) if o.get("x0") is None]
        if drawn and self.reset_noise_scale > 0 and self.rig.x0_draws:
            xi = self.noise.view(index[drawn]).normal(self.rig.x0_draws)
            x0[drawn] = self.rig.random_x0(xi * self.reset_noise_scale)
        self.physics.reset(index.tolist(), params, x0)
        self._table_of[index] = tables
        self._schedule_of[index] = schedules
        self._ready[index] = True
        self.steps[index] = 0
        self.x0[index] = x0
        t = np.zeros(k)
        info = self.info
        w = self._signal(t, index)
        x = self.physics.states(index)
        info["state"][index] = x
        info["t"][index] = 0.0
        info["disturbance"][index] = w
        info["setpoint"][index] = self._reference(t, index)
        for key in ("action_applied", "action_clipped", "manoeuvre", "process_accel",
                    "step_noise"):
            info[key][index] = 0
        sample = Sample(x, t, np.zeros((k, self._nu)), np.asarray(w), index)
        noise = self.noise.view(index)
        self.sensors.reset(sample, noise)
        self.obs[index] = self.sensors.measure(sample, noise)
        self.reward[index] = 0.0
        self.terminated[index] = False
        if self.record_poses:
            self.physics.forward_poses(index)

    def check_actions(self, actions: Any, k: int) -> np.ndarray:
        """``actions`` as a finite float array of shape (k, nu), else ``ValueError``."""
        u = real_array(actions, "actions", finite=False)
        if u.shape != (k, self._nu):
            raise ValueError(f"actions must have shape ({k}, {self._nu}) "
                             f"({', '.join(self.rig.action_names)} per member), got shape "
                             f"{u.shape}")
        if not np.isfinite(u).all():
            raise ValueError("actions must be finite (no NaN/inf)")
        return u

    def step(self, actions: Any, members: np.ndarray | None = None, *,
             checked: bool = False) -> None:
        """Apply actions (k, nu) for one control period to members (default all).

        ``checked=True``: the caller has already made ``actions`` a finite ``float64`` array
        of shape (k, nu) (the Gymnasium env's own check), so it is not checked twice.
        """
        index = self._all if members is None else np.asarray(members, int)
        # the simulator's own arrays: a basic slice for the whole batch (no gather/scatter
        # copies); sensors, noise streams and physics keep the member indices
        sel: Any = slice(None) if members is None else index
        k = len(index)
        if np.count_nonzero(self._ready[sel]) != k:
            raise RuntimeError("reset() every member before stepping it")
        u = actions if checked else self.check_actions(actions, k)
        low, high = self._low, self._high
        rig, physics, dist = self.rig, self.physics, self.disturbance
        no_manoeuvre = self._no_manoeuvre
        t = self.steps[sel] * self.dt_s if dist.has_signal or not no_manoeuvre else None
        clipped_u = u.clip(low, high)
        if no_manoeuvre:  # the profile is zero: clipped + 0 needs no second clip
            profile = self._zero_input[:k]
            applied = clipped_u + profile
            clipped = clipped_u != u
        else:
            profile = self._manoeuvre(t, sel)
            total = clipped_u + profile
            applied = total.clip(low, high)
            clipped = (clipped_u != u) | (applied != total)
        noise = self._noise_all if members is None else self.noise.view(index)
        info = self.info
        step_noise = None
        if rig.step_noise_dim:  # applied by the physics threads, before each member's step
            step_noise = noise.normal(rig.step_noise_dim)
            info["step_noise"][sel] = step_noise
        qfrc = None
        w = self._signal(t, index) if dist.has_signal else info["disturbance"][sel]
        accel: Any = self._zero_accel[:k]
        if dist.active:
            if dist.G is not None:
                accel = accel + np.matvec(dist.G[self._j:], w)
            if dist.b is not None:
                xi = noise.normal(self._dist_draws)
                accel = accel + np.matvec(dist.b[self._j:], xi) / np.sqrt(self.dt_s)
            a = np.zeros((k, physics.nv))
            a[:, rig.dof_adr] = accel
            qfrc = np.matvec(physics.mass[sel], a)
        physics.set_inputs(sel, rig.actuation(applied, physics.constants[sel]), qfrc)
        physics.step(index, need_mass=dist.active, need_poses=self.record_poses,
                     step_noise=step_noise)
        steps = self.steps[sel] + 1
        self.steps[sel] = steps
        t = steps * self.dt_s
        x = physics.states(sel)
        inside = np.less_equal(np.abs(x), self._envelope)  # NaN compares False
        unstable = physics.unstable[sel]
        if np.count_nonzero(inside) != inside.size or np.count_nonzero(unstable):
            self._diverged(index, unstable, ~inside.all(axis=1), x, t)
        ref = self._reference(t, sel)
        e = x[:, self._tracked_cols] - ref
        self.reward[sel] = -np.add.reduce(e * e, axis=1)
        self.terminated[sel] = rig.terminated(x)
        w_now = self._signal(t, index) if dist.has_signal else self._zero_w[:k]
        sample = Sample(x, t, applied, w_now, index)
        self.obs[sel] = self.sensors.measure(sample, noise)
        info["state"][sel] = x
        info["t"][sel] = t
        info["setpoint"][sel] = ref
        info["action_applied"][sel] = applied
        info["action_clipped"][sel] = clipped
        # the entries below keep what reset wrote without a signal, profile or disturbance
        if dist.has_signal:
            info["disturbance"][sel] = w
        if not no_manoeuvre:
            info["manoeuvre"][sel] = profile
        if dist.active:
            info["process_accel"][sel] = accel

    def _diverged(self, index: np.ndarray, unstable: np.ndarray, outside: np.ndarray,
                  x: np.ndarray, t: np.ndarray) -> None:
        """Mark the diverged members unready and raise :class:`SimulationDiverged`."""
        bad = unstable | outside
        self._ready[index[bad]] = False
        j = int(np.flatnonzero(bad)[0])
        names, units = self.rig.state_names, self.rig.state_units
        if unstable[j]:
            reason, why = "mujoco warning", ("MuJoCo reported NaN, inf or a huge value in qpos, "
                                             "qvel or qacc (and reset the state)")
        elif not np.all(np.isfinite(x[j])):
            reason, why = "non-finite state", "the state is not finite"
        else:
            c = int(np.flatnonzero(np.abs(x[j]) > self._envelope)[0])
            reason = "outside envelope"
            why = (f"{names[c]} = {x[j, c]:.6g} {units[c]} is outside the rig's envelope "
                   f"|{names[c]}| <= {self._envelope[c]:g} {units[c]}")
        state = ", ".join(f"{n} {v:.6g}" for n, v in zip(names, x[j], strict=True))
        raise SimulationDiverged(
            f"simulation diverged at t = {t[j]:.6g} s (member {int(index[j])}"
            f"{f' and {int(bad.sum()) - 1} more' if bad.sum() > 1 else ''}): {why}; state "
            f"[{state}]", time_s=float(t[j]), state=x[bad].copy(),
            members=index[bad].tolist(), reason=reason)

    def close(self) -> None:
        """Stop the physics threads."""
        self.physics.close()
