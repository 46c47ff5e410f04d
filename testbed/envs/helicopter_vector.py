"""Batched 2-DOF helicopter: N copies of ``Helicopter2DOFEnv`` stepped together.

:class:`HelicopterBatch` is the engine (no Gymnasium API): it reproduces N
:class:`~testbed.envs.helicopter.Helicopter2DOFEnv` instances exactly (same MuJoCo calls on
the same states, the same random numbers in the same order), vectorized everywhere except
inside MuJoCo. :class:`Helicopter2DOFVectorEnv` wraps it as a Gymnasium ``VectorEnv``
(``gymnasium.make_vec("testbed/Helicopter2DOF-v0", num_envs=N,
vectorization_mode="vector_entry_point")``).

Physics (:class:`BatchPhysics`): each trajectory's complete MuJoCo integration state
(``mjSTATE_INTEGRATION``: time, qpos, qvel, constraint warm start, ctrl, applied forces) is a
row of one array; a small pool of threads, each with its own ``MjData``, loads a row, calls
``mj_step`` and stores the row back. ``mj_step`` releases the GIL (two threads run 2.0x
faster than one on this model), and loading the full integration state makes a step
bitwise identical to stepping a dedicated ``MjData``, without one ``MjData`` per trajectory
(each reserves a 13.6 MB arena, ~0.44 MB of it resident: 1000 of them would cost 440 MB).
``mujoco.rollout`` was measured as the alternative: 1.00-1.05x the speed of this pool when
called once per control step, but its state output has no warm start and no mass matrix, so
it cannot reproduce the single environment exactly.

Random numbers (:class:`NoiseStreams`): member ``i`` owns
``gymnasium.utils.seeding.np_random(seed_i)``, exactly like a single environment's
``np_random``; its standard normals are drawn ahead in blocks (numpy's ``Generator`` fills
an array from one stream without caching, so a block equals the same number of single
draws) and consumed in the single environment's order: disturbance white noise, then sensor
noise, every step; sensor noise only at reset.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import mujoco
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from testbed.disturbances import Disturbance
from testbed.envs.common import reset_options
from testbed.envs.helicopter import (
    DEFAULT_SETPOINTS,
    RESET_OPTION_KEYS,
    Helicopter2DOFEnv,
    _validate_setpoints,
)
from testbed.rigs.helicopter import (
    PITCH_LIMIT_RAD,
    VOLTAGE_LIMIT_V,
    HelicopterParams,
    HelicopterRig,
)

_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
_CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
_QFRC = int(mujoco.mjtState.mjSTATE_QFRC_APPLIED)
_QPOS = int(mujoco.mjtState.mjSTATE_QPOS)
_QVEL = int(mujoco.mjtState.mjSTATE_QVEL)
Members = np.ndarray | None  # sorted member indices (k,), or None for all


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


class BatchPhysics:
    """MuJoCo integration states of N trajectories, stepped by a pool of threads.

    Parameters
    ----------
    rig : HelicopterRig
        Model factory: :meth:`model_for` writes parameters into its model and copies it (the
        rig's own model is modified; pass a dedicated rig).
    num : int
        Number of trajectories.
    frame_skip : int
        ``mj_step`` calls per control step.
    num_threads : int, optional
        Worker threads (default :func:`default_num_threads`, at most ``num``); the calling
        thread is one of them.

    Attributes
    ----------
    state : ndarray, shape (num, nstate)
        ``mjSTATE_INTEGRATION`` vector of every trajectory.
    mass : ndarray, shape (num, nv, nv)
        Joint-space mass matrix left in each trajectory's ``MjData`` by its last
        ``mj_forward``/``mj_step`` (what ``HelicopterRig.joint_accel_to_force`` reads).
    """

    def __init__(self, rig: HelicopterRig, num: int, frame_skip: int,
                 num_threads: int | None = None):
        self.rig = rig
        self.num = int(num)
        self.frame_skip = int(frame_skip)
        model = rig.model
        self.nu, self.nv = model.nu, model.nv
        self._cache: dict[HelicopterParams, mujoco.MjModel] = {}
        self._models = [self.model_for(rig.params)] * self.num
        nstate = mujoco.mj_stateSize(model, _INTEGRATION)
        self.state = np.zeros((self.num, nstate))
        self.mass = np.zeros((self.num, self.nv, self.nv))
        self._ctrl = slice(c := _state_offset(model, _INTEGRATION, _CTRL), c + self.nu)
        self._qfrc = slice(f := _state_offset(model, _INTEGRATION, _QFRC), f + self.nv)
        joints = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
                  for name in ("pitch", "yaw")]
        self._qpos_adr = model.jnt_qposadr[joints]
        self._dof_adr = model.jnt_dofadr[joints]
        qpos, qvel = (_state_offset(model, _INTEGRATION, b) for b in (_QPOS, _QVEL))
        self._gather = np.concatenate([qpos + self._qpos_adr, qvel + self._dof_adr])
        self._check_layout()
        threads = default_num_threads() if num_threads is None else int(num_threads)
        if threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        self.num_threads = min(threads, max(self.num, 1))
        self._datas = [mujoco.MjData(model) for _ in range(self.num_threads)]
        bounds = np.linspace(0, self.num, self.num_threads + 1).round().astype(int)
        self._all = [range(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
        self._pool = (ThreadPoolExecutor(self.num_threads - 1, "testbed-physics")
                      if self.num_threads > 1 else None)

    def _check_layout(self) -> None:
        """Verify the computed state offsets against MuJoCo (fails loudly if it changes)."""
        model = self.rig.model
        data = mujoco.MjData(model)
        data.ctrl[:] = np.arange(1, self.nu + 1)
        data.qfrc_applied[:] = -np.arange(1, self.nv + 1)
        data.qpos[:] = 10 + np.arange(model.nq)
        data.qvel[:] = 20 + np.arange(self.nv)
        row = np.zeros(self.state.shape[1])
        mujoco.mj_getState(model, data, row, _INTEGRATION)
        expected = np.concatenate([data.qpos[self._qpos_adr], data.qvel[self._dof_adr]])
        if not (np.array_equal(row[self._ctrl], data.ctrl)
                and np.array_equal(row[self._qfrc], data.qfrc_applied)
                and np.array_equal(row[self._gather], expected)):
            raise RuntimeError("unexpected mjSTATE_INTEGRATION layout in this MuJoCo version")

    def model_for(self, params: HelicopterParams) -> mujoco.MjModel:
        """A model with these parameters (cached; identical to ``rig.set_params(params)``)."""
        model = self._cache.get(params)
        if model is None:
            self.rig.set_params(params)
            model = self._cache[params] = copy.copy(self.rig.model)  # mj_copyModel
        return model

    def reset(self, members: Sequence[int], params: Sequence[HelicopterParams],
              x0: np.ndarray) -> None:
        """Reset trajectories like ``Helicopter2DOFEnv.reset``.

        ``mj_resetData``, then ``x0`` written into qpos/qvel and ``mj_forward``.

        Parameters
        ----------
        members : sequence of int, length k
        params : sequence of HelicopterParams, length k
        x0 : ndarray, shape (k, 4)
            ``[pitch, yaw, pitch_rate, yaw_rate]``.
        """
        data = self._datas[0]
        for j, i in enumerate(members):
            model = self._models[i] = self.model_for(params[j])
            mujoco.mj_resetData(model, data)
            data.qpos[self._qpos_adr] = x0[j, :2]
            data.qvel[self._dof_adr] = x0[j, 2:]
            mujoco.mj_forward(model, data)
            mujoco.mj_getState(model, data, self.state[i], _INTEGRATION)
            mujoco.mj_fullM(model, data, self.mass[i])
        in_use = {id(m) for m in self._models}
        self._cache = {p: m for p, m in self._cache.items() if id(m) in in_use}

    def states(self, members: Members = None) -> np.ndarray:
        """True states ``[pitch, yaw, pitch_rate, yaw_rate]``, shape (k, 4)."""
        rows = self.state if members is None else self.state[members]
        return rows[:, self._gather]

    def step(self, ctrl: np.ndarray, qfrc: np.ndarray | None, members: Members = None,
             need_mass: bool = False) -> None:
        """Set ``ctrl`` (and ``qfrc_applied``), then ``mj_step`` ``frame_skip`` times.

        Parameters
        ----------
        ctrl : ndarray, shape (k, nu)
        qfrc : ndarray, shape (k, nv), or None
            Applied joint forces; None keeps each trajectory's current ones.
        members : ndarray of int, shape (k,), optional
            Trajectories to step (default all).
        need_mass : bool
            Refresh :attr:`mass` after the step.
        """
        sel = slice(None) if members is None else members
        self.state[sel, self._ctrl] = ctrl
        if qfrc is not None:
            self.state[sel, self._qfrc] = qfrc
        if members is None:
            chunks: list[Any] = self._all
        else:
            chunks = [c.tolist() for c in np.array_split(members, self.num_threads) if len(c)]
        futures = [self._pool.submit(self._work, self._datas[w], chunk, need_mass)
                   for w, chunk in enumerate(chunks[1:], 1)] if self._pool else []
        try:
            if chunks:
                self._work(self._datas[0], chunks[0], need_mass)
        finally:
            for future in futures:
                future.result()

    def _work(self, data: mujoco.MjData, rows: Sequence[int], need_mass: bool) -> None:
        models, state, mass, nstep = self._models, self.state, self.mass, self.frame_skip
        set_state, get_state, step, full_m = (mujoco.mj_setState, mujoco.mj_getState,
                                              mujoco.mj_step, mujoco.mj_fullM)
        for i in rows:
            model, row = models[i], state[i]
            set_state(model, data, row, _INTEGRATION)
            step(model, data, nstep)
            get_state(model, data, row, _INTEGRATION)
            if need_mass:
                full_m(model, data, mass[i])

    def close(self) -> None:
        """Stop the worker threads."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None


class NoiseStreams:
    """Per-trajectory standard-normal streams, drawn ahead in blocks.

    Parameters
    ----------
    num : int
        Number of trajectories.
    block : int
        Values drawn per refill and trajectory (at least the largest single request).
    """

    def __init__(self, num: int, block: int):
        self.block = max(int(block), 1)
        self.generators: list[np.random.Generator | None] = [None] * num
        self._buf = np.empty((num, self.block))
        self._pos = np.full(num, self.block)

    def seed(self, i: int, seed: int | None) -> None:
        """Restart trajectory ``i``'s stream like ``gym.Env.reset(seed=seed)``.

        A None seed keeps an existing generator (and creates a random one otherwise).
        """
        if seed is not None or self.generators[i] is None:
            self.generators[i] = seeding.np_random(seed)[0]
            self._pos[i] = self.block

    def _refill(self, i: int) -> None:
        pos, buf = self._pos[i], self._buf[i]
        left = self.block - pos
        buf[:left] = buf[pos:]
        self.generators[i].standard_normal(out=buf[left:])
        self._pos[i] = 0

    def draw(self, k: int, members: Members = None) -> np.ndarray:
        """The next ``k`` values of each selected stream, shape (len(members) or num, k)."""
        index = np.arange(len(self._pos)) if members is None else members
        if k == 0:
            return np.zeros((len(index), 0))
        if k > self.block:
            raise ValueError(f"cannot draw {k} values at once (block {self.block})")
        pos = self._pos[index]
        for i in index[pos + k > self.block]:
            self._refill(i)
        pos = self._pos[index]
        if members is None and pos[0] == pos.min() == pos.max():
            start = int(pos[0])
            out = self._buf[:, start:start + k].copy()
        else:
            out = self._buf[index[:, None], pos[:, None] + np.arange(k)]
        self._pos[index] = pos + k
        return out


def _per_time(fn: Callable[[float], np.ndarray], t: np.ndarray, dim: int) -> np.ndarray:
    """``fn(t_i)`` for every entry of ``t`` (k,), evaluated once per distinct time: (k, dim)."""
    if len(t) and t.min() == t.max():
        return np.broadcast_to(np.asarray(fn(float(t[0])), dtype=float), (len(t), dim))
    values, inverse = np.unique(t, return_inverse=True)
    table = np.array([fn(float(v)) for v in values], dtype=float).reshape(len(values), dim)
    return table[inverse]


class HelicopterBatch:
    """N independent :class:`Helicopter2DOFEnv` episodes stepped together.

    Parameters
    ----------
    template : Helicopter2DOFEnv
        Supplies the configuration (physics and control periods, sensor suite, disturbance,
        nominal parameters, spaces); it is neither stepped nor modified.
    num_envs : int
        Batch size N.
    setpoints : sequence of (t_s, pitch_rad, yaw_rad)
        Default setpoint schedule (the template's ``setpoints`` argument).
    num_threads : int, optional
        Physics threads (see :class:`BatchPhysics`).

    Attributes
    ----------
    obs : ndarray, shape (N, m)
        Last measurements.
    info : dict of ndarray
        Last ``info`` of every member, batched: ``state`` (N, 4), ``t`` (N,),
        ``disturbance`` (N, s), ``setpoint`` (N, 2), ``action_applied`` (N, 2),
        ``action_clipped`` (N, 2) bool, ``process_accel`` (N, 2).
    reward : ndarray, shape (N,)
        Last rewards (0 after a reset).
    steps : ndarray of int, shape (N,)
        Control steps since each member's reset.

    Notes
    -----
    ``reset``/``step`` act on all members or on a sorted index array ``members``; the
    arrays above are updated in those rows only.
    """

    def __init__(self, template: Helicopter2DOFEnv, num_envs: int,
                 setpoints: Sequence[Sequence[float]] = DEFAULT_SETPOINTS,
                 num_threads: int | None = None):
        if int(num_envs) != num_envs or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs}")
        n = self.num_envs = int(num_envs)
        self.template = template
        self.dt_s = template.dt_s
        self.nominal_params = template.nominal_params
        self.state_names = list(template.state_names)
        if not (hasattr(template.sensors, "measure_batch")
                and hasattr(template.sensors, "noise_draws")):
            raise TypeError("the batched helicopter needs sensor suites with noise_draws and "
                            "measure_batch(x, xi, w) (as testbed.sensors' suites have), got "
                            f"{type(template.sensors).__name__}")
        self.sensors = template.sensors
        self.disturbance = dist = template.disturbance
        if type(dist).acceleration is not Disturbance.acceleration:
            raise TypeError("the batched helicopter vectorizes Disturbance.acceleration; a "
                            f"{type(dist).__name__} that overrides it is not supported")
        self._dist_draws = 0 if dist.b is None else dist.b.shape[1]
        self._np = dist.n_positions
        self._w_dim = len(dist.signal(0.0))
        rig = HelicopterRig(self.nominal_params, physics_dt_s=template.rig.model.opt.timestep)
        self._dof = rig.dof_index
        self.physics = BatchPhysics(rig, n, template.frame_skip, num_threads)
        draws = self._dist_draws + self.sensors.noise_draws
        self.noise = NoiseStreams(n, 64 * max(draws, 1))
        self._tables = [_validate_setpoints(setpoints)]
        self._table_of = np.zeros(n, dtype=int)
        self.steps = np.zeros(n, dtype=np.int64)
        self._ready = np.zeros(n, dtype=bool)
        self.x0 = np.zeros((n, 4))
        self.obs = np.zeros((n, self.sensors.dim))
        self.reward = np.zeros(n)
        self.info: dict[str, np.ndarray] = {
            "state": np.zeros((n, 4)),
            "t": np.zeros(n),
            "disturbance": np.zeros((n, self._w_dim)),
            "setpoint": np.zeros((n, 2)),
            "action_applied": np.zeros((n, 2)),
            "action_clipped": np.zeros((n, 2), dtype=bool),
            "process_accel": np.zeros((n, 2)),
        }

    # ------------------------------------------------------------------ helpers
    def member_options(self, options: dict | Sequence[dict | None] | None,
                       k: int) -> list[dict[str, Any]]:
        """Normalize reset options to one dict per reset member (see :meth:`reset`)."""
        if options is None or isinstance(options, dict):
            shared = reset_options(options, RESET_OPTION_KEYS)
            per = [{} for _ in range(k)]
            for key, value in shared.items():
                if value is None:
                    continue
                if key == "params" and not isinstance(value, dict):
                    values = list(value)
                elif key == "x0" and np.ndim(value) == 2:
                    values = list(np.asarray(value, dtype=float))
                else:
                    values = [value] * k
                if len(values) != k:
                    raise ValueError(f"options[{key!r}] has {len(values)} entries for {k} "
                                     "members being reset")
                for d, v in zip(per, values, strict=True):
                    d[key] = v
            return per
        per = [dict(o or {}) for o in options]
        if len(per) != k:
            raise ValueError(f"got {len(per)} option dicts for {k} members being reset")
        for d in per:
            reset_options(d, RESET_OPTION_KEYS)
        return per

    def _x0(self, value: Any) -> np.ndarray:
        x0 = np.array([-PITCH_LIMIT_RAD, 0.0, 0.0, 0.0])
        if value is not None:
            x0 = np.asarray(value, dtype=float)
            if x0.shape != (4,) or not np.all(np.isfinite(x0)):
                raise ValueError("options['x0'] must be a finite array of shape (4,) "
                                 f"[pitch, yaw, pitch_rate, yaw_rate], got {value!r}")
            if abs(x0[0]) > PITCH_LIMIT_RAD + 1e-9:
                raise ValueError(f"options['x0'] pitch {x0[0]:.4f} rad is outside the stops "
                                 f"+-{PITCH_LIMIT_RAD:.4f} rad")
        return x0

    def _table_index(self, setpoints: Any) -> int:
        if setpoints is None:
            return 0
        table = _validate_setpoints(setpoints)
        for j, known in enumerate(self._tables):
            if known.shape == table.shape and np.array_equal(known, table):
                return j
        self._tables.append(table)
        return len(self._tables) - 1

    def _setpoints(self, t: np.ndarray, sel: Any) -> np.ndarray:
        """References ``[pitch, yaw]`` at times ``t`` (k,) of members ``sel``: (k, 2)."""
        groups = self._table_of[sel]
        if not groups.any():  # everyone on the default schedule
            table = self._tables[0]
            rows = np.searchsorted(table[:, 0], t, side="right") - 1
            return table[np.maximum(rows, 0), 1:]
        out = np.empty((len(t), 2))
        for g in np.unique(groups):
            table = self._tables[g]
            mask = groups == g
            rows = np.searchsorted(table[:, 0], t[mask], side="right") - 1
            out[mask] = table[np.maximum(rows, 0), 1:]
        return out

    def setpoints_at(self, t_s: float) -> np.ndarray:
        """Every member's reference ``[pitch, yaw]`` (rad) at time ``t_s``, shape (N, 2)."""
        return self._setpoints(np.full(self.num_envs, float(t_s)), slice(None))

    def _signal(self, t: np.ndarray) -> np.ndarray:
        return _per_time(self.disturbance.signal, t, self._w_dim)

    # ------------------------------------------------------------------ API
    def reset(self, members: Members = None, seeds: Sequence[int | None] | None = None,
              options: dict | Sequence[dict | None] | None = None) -> None:
        """Reset members like ``Helicopter2DOFEnv.reset(seed=..., options=...)``.

        Parameters
        ----------
        members : ndarray of int, shape (k,), optional
            Members to reset (default all).
        seeds : sequence of (int or None), length k, optional
            Per-member seeds; None keeps a member's generator (a new random one if it has
            none), as a single environment does.
        options : dict or sequence of k dicts, optional
            Keys ``x0``, ``params``, ``setpoints`` as for the single environment. In one
            shared dict, ``x0`` may be (k, 4) and ``params`` a sequence of k dicts.
        """
        index = np.arange(self.num_envs) if members is None else np.asarray(members, int)
        k = len(index)
        seeds = [None] * k if seeds is None else list(seeds)
        if len(seeds) != k:
            raise ValueError(f"got {len(seeds)} seeds for {k} members being reset")
        per = self.member_options(options, k)
        params = [self.nominal_params.scaled(o.get("params") or {}) for o in per]
        for p in params:
            p.validate()
        x0 = np.array([self._x0(o.get("x0")) for o in per]).reshape(k, 4)
        tables = [self._table_index(o.get("setpoints")) for o in per]
        for i, seed in zip(index.tolist(), seeds, strict=True):
            self.noise.seed(i, None if seed is None else int(seed))
        sel = slice(None) if members is None else index
        self.physics.reset(index.tolist(), params, x0)
        self._table_of[sel] = tables
        self._ready[sel] = True
        self.steps[sel] = 0
        self.x0[sel] = x0
        w = self._signal(np.zeros(k))
        xi = self.noise.draw(self.sensors.noise_draws, None if members is None else index)
        self.obs[sel] = self.sensors.measure_batch(x0, xi, w)
        self.reward[sel] = 0.0
        info = self.info
        info["state"][sel] = self.physics.states(None if members is None else index)
        info["t"][sel] = 0.0
        info["disturbance"][sel] = w
        info["setpoint"][sel] = self._setpoints(np.zeros(k), sel)
        info["action_applied"][sel] = 0.0
        info["action_clipped"][sel] = False
        info["process_accel"][sel] = 0.0

    def step(self, actions: np.ndarray, members: Members = None) -> None:
        """Apply motor voltages (k, 2) for one control period to members (default all).

        Raises
        ------
        ValueError
            Wrong shape or non-finite actions (nothing is stepped).
        RuntimeError
            A member was never reset.
        """
        sel = slice(None) if members is None else members
        k = self.num_envs if members is None else len(members)
        if not self._ready[sel].all():
            raise RuntimeError("reset() every member before stepping it")
        try:
            u = np.asarray(actions, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"actions must be numeric with shape ({k}, 2) in volts") from None
        if u.shape != (k, 2):
            raise ValueError(f"actions must have shape ({k}, 2) (V_pitch, V_yaw per member), "
                             f"got shape {u.shape}")
        if not np.isfinite(u).all():
            raise ValueError("actions must be finite (no NaN/inf)")
        clipped_u = u.clip(-VOLTAGE_LIMIT_V, VOLTAGE_LIMIT_V)
        t = self.steps[sel] * self.dt_s
        dist = self.disturbance
        qfrc = None
        if dist.active:
            w = self._signal(t)
            accel: Any = 0.0
            if dist.G is not None:
                accel = np.matvec(dist.G[self._np:], w)
            if dist.b is not None:
                xi = self.noise.draw(self._dist_draws, members)
                accel = accel + np.matvec(dist.b[self._np:], xi) / np.sqrt(self.dt_s)
            a = np.zeros((k, self.physics.nv))
            a[:, self._dof] = accel
            qfrc = np.matvec(self.physics.mass[sel], a)
        else:
            w, accel = self.info["disturbance"][sel], 0.0
        self.physics.step(clipped_u, qfrc, members, need_mass=dist.active)
        self.steps[sel] += 1
        t = self.steps[sel] * self.dt_s
        x = self.physics.states(members)
        ref = self._setpoints(t, sel)
        e = x[:, :2] - ref
        self.reward[sel] = -(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1])
        w_now = self._signal(t) if dist.has_deterministic else None
        xi = self.noise.draw(self.sensors.noise_draws, members)
        self.obs[sel] = self.sensors.measure_batch(x, xi, w_now)
        info = self.info
        info["state"][sel] = x
        info["t"][sel] = t
        info["disturbance"][sel] = w
        info["setpoint"][sel] = ref
        info["action_applied"][sel] = clipped_u
        info["action_clipped"][sel] = clipped_u != u
        info["process_accel"][sel] = accel

    def close(self) -> None:
        """Stop the physics threads."""
        self.physics.close()


class Helicopter2DOFVectorEnv(VectorEnv):
    """``testbed/Helicopter2DOF-v0`` as a Gymnasium ``VectorEnv`` of ``num_envs`` members.

    Equal, member by member, to ``num_envs`` single environments with the same seeds (what
    ``gymnasium.make_vec(..., vectorization_mode="sync")`` builds), but stepped as one batch
    (:class:`HelicopterBatch`).

    Parameters
    ----------
    num_envs : int
    max_episode_steps : int, optional
        Truncate a member after this many steps (``make_vec`` passes the registration's 2000).
    autoreset_mode : gymnasium.vector.AutoresetMode or str
        ``NEXT_STEP`` (default, Gymnasium 1.x): the step after a member's episode ended resets
        it instead of stepping it, ignores its action and returns its reset observation with
        reward 0 and ``terminated = truncated = False``. ``SAME_STEP``: a finished member is
        reset in the same step; ``info["final_obs"]`` / ``info["final_info"]`` hold its last
        step. ``DISABLED``: reset finished members with ``reset(options={"reset_mask": m})``.
    num_threads : int, optional
        Physics threads (default: the CPUs available).
    **kwargs
        Arguments of :class:`~testbed.envs.helicopter.Helicopter2DOFEnv` (``sensors``,
        ``disturbance``, ``params``, ``setpoints``...).

    Notes
    -----
    ``reset(seed=...)``: None, an int ``s`` (member ``i`` gets ``s + i``, as
    ``SyncVectorEnv``) or a list of ``num_envs`` ints/None. ``options`` go to every member
    (keys of the single environment, plus ``reset_mask``); ``options["x0"]`` may also be
    ``(num_envs, 4)`` and ``options["params"]`` a list of ``num_envs`` dicts. Infos are
    batched like ``SyncVectorEnv``'s: ``info[key]`` of shape ``(num_envs, ...)`` with the mask
    ``info["_" + key]``. The environment never terminates; only ``max_episode_steps``
    truncates. Stepping before the first ``reset`` raises ``RuntimeError``.

    Speed: the physics threads need the cores; OpenBLAS threads busy-waiting after the
    caller's own numpy calls slow them down, so on small machines run the loop inside
    :func:`testbed.batch.limit_blas_threads` (or with ``OPENBLAS_NUM_THREADS=1``).
    """

    metadata = {"render_modes": [], "render_fps": 100, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 num_threads: int | None = None, render_mode: str | None = None, **kwargs):
        template = Helicopter2DOFEnv(render_mode=render_mode, **kwargs)
        if max_episode_steps is not None and (int(max_episode_steps) != max_episode_steps
                                              or max_episode_steps < 1):
            raise ValueError(f"max_episode_steps must be a positive integer or None, "
                             f"got {max_episode_steps}")
        self.batch = HelicopterBatch(template, num_envs,
                                     setpoints=kwargs.get("setpoints", DEFAULT_SETPOINTS),
                                     num_threads=num_threads)
        self.num_envs = self.batch.num_envs
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        self.metadata = {**type(self).metadata, "autoreset_mode": self.autoreset_mode}
        self.render_mode = None
        self.single_observation_space = template.observation_space
        self.single_action_space = template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.state_names = list(template.state_names)
        self.action_names = list(template.action_names)
        self._done = np.zeros(self.num_envs, dtype=bool)

    def _infos(self, members: np.ndarray | None = None) -> dict[str, Any]:
        """Batched infos (copies) with ``_key`` masks for ``members`` (default all)."""
        mask = np.ones(self.num_envs, dtype=bool)
        if members is not None:
            mask[:] = False
            mask[members] = True
        infos: dict[str, Any] = {}
        for key, value in self.batch.info.items():
            array = value.copy()
            if members is not None:
                array[~mask] = 0
            infos[key] = array
            infos[f"_{key}"] = mask.copy()
        return infos

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset all members (or those in ``options["reset_mask"]``); see the class notes."""
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, int | np.integer):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
        if len(seeds) != n:
            raise ValueError(f"If seeds are passed as a list the length must match "
                             f"num_envs={n} but got length={len(seeds)}.")
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
        self.batch.reset(members, seeds, options or None)
        self._done[slice(None) if members is None else members] = False
        return self.batch.obs.copy(), self._infos(members)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                  np.ndarray, dict[str, Any]]:
        """Step every member with ``actions`` of shape (num_envs, 2) in volts."""
        n = self.num_envs
        u = np.asarray(actions, dtype=np.float64)
        if u.shape != (n, 2):
            raise ValueError(f"actions must have shape ({n}, 2), got shape {u.shape}")
        batch = self.batch
        resetting = np.flatnonzero(self._done)
        if len(resetting) and self.autoreset_mode == AutoresetMode.DISABLED:
            raise RuntimeError(f"members {resetting.tolist()} finished their episode; reset "
                               "them with reset(options={'reset_mask': ...}) first")
        if len(resetting) and self.autoreset_mode == AutoresetMode.NEXT_STEP:
            stepping = np.flatnonzero(~self._done)
            if len(stepping):
                batch.step(u[stepping], stepping)
            batch.reset(resetting)
            stepped = ~self._done
        else:
            batch.step(u)
            stepped = np.ones(n, dtype=bool)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        if self.max_episode_steps is not None:
            truncated = stepped & (batch.steps >= self.max_episode_steps)
        reward = batch.reward.copy()
        obs = batch.obs.copy()
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
            batch.reset(finished)
            obs = batch.obs.copy()
            infos = self._infos()
            infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
            infos["final_info"], infos["_final_info"] = final_info, done.copy()
            self._done[:] = False
        else:
            self._done = done
        return obs, reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the physics threads."""
        self.batch.close()
