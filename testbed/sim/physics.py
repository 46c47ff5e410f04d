"""The members' MuJoCo physics: N integration states stepped by one ``mujoco.batch.Batch``.

Each member's complete MuJoCo integration state (``mjSTATE_INTEGRATION``: time, qpos, qvel,
warm start, ctrl, applied forces, userdata) is a row of one array, which the batch's C
threads load into an ``MjData``, step and store back: bitwise identical to stepping a
dedicated ``MjData``, without one ``MjData`` per member and without Python per member. A
member's parameters and the rig's step noise are per-simulation model fields
(``Batch.expand``), written for all members with one numpy assignment per field.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import mujoco
import mujoco.batch
import numpy as np

from testbed.rigs.base import Params, Rig
from testbed.sensors.fused import as_slice
from testbed.sim import native

_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
_CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
_QFRC = int(mujoco.mjtState.mjSTATE_QFRC_APPLIED)
_XFRC = int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)
_USERDATA = int(mujoco.mjtState.mjSTATE_USERDATA)
_QPOS = int(mujoco.mjtState.mjSTATE_QPOS)
_QVEL = int(mujoco.mjtState.mjSTATE_QVEL)
_ACT = int(mujoco.mjtState.mjSTATE_ACT)


#: MuJoCo's instability warnings: NaN, inf or huge qpos, qvel or qacc (MuJoCo then resets
#: the state, which stays finite; the counters in ``MjData.warning`` tell).
_BAD_WARNINGS = tuple(int(w) for w in (mujoco.mjtWarning.mjWARN_BADQPOS,
                                       mujoco.mjtWarning.mjWARN_BADQVEL,
                                       mujoco.mjtWarning.mjWARN_BADQACC))


#: The whole batch as a selection, and the types of an integer index (module constants: not
#: rebuilt per step).
_ALL = slice(None)
_STAGE_NONE = int(mujoco.mjtStage.mjSTAGE_NONE)
_INTEGERS = (int, np.integer)


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


class _MemberModels(Sequence):
    """``physics.models[i]``: a copy of the model member ``i`` runs on now (its parameters
    and its last step noise included), made on access (``Batch.get_model``)."""

    def __init__(self, physics: Physics):
        self._physics = physics

    def __len__(self) -> int:
        return self._physics.num

    def __getitem__(self, i: Any) -> Any:
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        i = int(i)
        if not -len(self) <= i < len(self):
            raise IndexError(f"member {i} out of range for {len(self)} members")
        return self._physics.batch.get_model(i % len(self))


class Physics:
    """MuJoCo integration states of N members, stepped by ``mujoco.batch`` on C threads.

    Each member is one simulation of a :class:`mujoco.batch.Batch` of the rig's model (its
    ``mjSTATE_INTEGRATION`` row is a row of :attr:`state`); per-member parameters and the
    rig's step noise are per-simulation model fields (``Batch.expand``), written for all
    members at once. The batch loads a row into an ``MjData``, steps and stores it back, on
    its threads without the GIL: bitwise identical to stepping a dedicated ``MjData``.

    Parameters
    ----------
    rig : Rig
        Model factory (its own model is not changed).
    num : int
    frame_skip : int
    num_threads : int, optional
        Batch threads (default :func:`default_num_threads`, at most ``num``).
    """

    def __init__(self, rig: Rig, num: int, frame_skip: int, num_threads: int | None = None):
        self.rig, self.num, self.frame_skip = rig, int(num), int(frame_skip)
        model = rig.model
        self.nu, self.nv, self.nbody = model.nu, model.nv, model.nbody
        self._scratch = mujoco.MjData(model)
        threads = (default_num_threads() if num_threads is None
                   else positive_int(num_threads, "num_threads"))
        self.num_threads = min(threads, max(self.num, 1))
        self._base = rig.model_with(rig.params, self._scratch)
        self._attach()
        self.params: list[Params] = [rig.params] * self.num
        #: Model fields that differ from the nominal model for some parameters, by params.
        self._diffs: dict[Params, dict[str, np.ndarray]] = {rig.params: {}}
        self.constants = np.tile(rig.member_constants(rig.params), (self.num, 1))
        self.mass = np.zeros((self.num, self.nv, self.nv))
        #: ``mass`` as (num, nv * nv), a view (one index per entry, not two): made again
        #: when it is no view of ``mass`` (a copy or an unpickled physics).
        self._mass_flat = self.mass.reshape(self.num, -1)
        c = _state_offset(model, _INTEGRATION, _CTRL)
        f = _state_offset(model, _INTEGRATION, _QFRC)
        x = _state_offset(model, _INTEGRATION, _XFRC)
        self._ctrl, self._qfrc = slice(c, c + self.nu), slice(f, f + self.nv)
        self._xfrc = slice(x, x + 6 * self.nbody)
        a = _state_offset(model, _INTEGRATION, _ACT)
        #: The actuator states' columns of the state rows (MuJoCo ``act``).
        self._act_cols = slice(a, a + model.na)
        qpos, qvel = (_state_offset(model, _INTEGRATION, b) for b in (_QPOS, _QVEL))
        self._qpos_cols, self._qvel_cols = qpos + rig.qpos_adr, qvel + rig.dof_adr
        self._gather = np.concatenate([self._qpos_cols, self._qvel_cols])
        self._check_layout()
        # the dense mass matrix from MuJoCo's sparse lower triangle (rows, columns)
        rows = np.repeat(np.arange(self.nv), model.M_rownnz)
        self._m_rows, self._m_cols = rows, np.asarray(model.M_colind)
        #: Their flat positions in a member's (nv, nv) matrix, below and above the diagonal.
        self._m_flat = (rows * self.nv + self._m_cols, self._m_cols * self.nv + rows)
        lower, upper = self._m_flat
        #: The same positions for the whole batch's write: slices where consecutive, and no
        #: upper write when it is the lower one (a diagonal M).
        self._m_flat_whole = (as_slice(lower),
                              None if np.array_equal(lower, upper) else as_slice(upper))
        #: The rig's per-physics-step ctrl runs in C (testbed.sim.native): the userdata
        #: columns of the state rows holding [flag, command, c, r].
        self._native: tuple[int, slice, slice] | None = None
        window = rig.act_window(self.constants[:1]) if rig.needs_substep else None
        if window is not None and model.nuserdata == 1 + 3 * self.nu and native.install():
            u = _state_offset(model, _INTEGRATION, _USERDATA)
            self._native = (u, slice(u + 1, u + 1 + self.nu), slice(u + 1 + self.nu,
                                                                  u + 1 + 3 * self.nu))
        self.poses: tuple[np.ndarray, np.ndarray] | None = None
        #: Members whose MuJoCo data reported an instability warning in their last step.
        self.unstable = np.zeros(self.num, dtype=bool)
        self._any_unstable = False  # whether some entry of unstable is True
        self._all_ids = np.arange(self.num)

    def _attach(self) -> None:
        """A new batch of the members (all at the nominal model's defaults) and its views."""
        self.batch = mujoco.batch.Batch(self._base, self.num, nthread=self.num_threads)
        #: The members' integration states, one row each (the batch's own rows: live).
        self.state = self.batch.state
        self._fields: dict[str, np.ndarray] = {}  # expanded fields: their (N, ...) values
        self._mass_bound: np.ndarray | None = None
        self._poses_bound: tuple[np.ndarray, np.ndarray] | None = None
        self._warning = self.batch.warning  # (N, mjNWARNING, (lastinfo, number))
        lo, hi = min(_BAD_WARNINGS), max(_BAD_WARNINGS) + 1
        assert hi - lo == len(_BAD_WARNINGS)  # contiguous: a view, one count per step
        #: The counters of MuJoCo's instability warnings, (N, 3), a view.
        self._bad = self._warning[:, lo:hi, 1]
        self._act = self.batch.bind("act") if self.rig.needs_substep else None
        #: Whether a step sets ``ctrl`` before each physics step (the rig's substep_ctrl).
        self.substeps = self._act is not None
        self.models = _MemberModels(self)
        #: ``Batch.step(None, frame_skip)``'s C call (the same call without the wrapper's
        #: id check, which ``None`` skips): its number of failed simulations, or None when
        #: this MuJoCo's batch has no such call (then :meth:`step_plain` is ``Batch.step``).
        core = getattr(self.batch, "_b", None)
        self._c_step = getattr(core, "step", None)

    _UNPICKLED = ("batch", "state", "_fields", "_mass_bound", "_poses_bound", "_warning", "_bad",
                  "_act", "models", "_c_step")

    def __getstate__(self) -> dict[str, Any]:
        """Picklable (and deep-copyable): the batch's rows, warning counters and
        per-simulation fields, without the batch."""
        out = {k: v for k, v in self.__dict__.items() if k not in self._UNPICKLED}
        out["_saved"] = (self.state.copy(), self._warning.copy(),
                         {name: values.copy() for name, values in self._fields.items()})
        return out

    def __setstate__(self, state: dict[str, Any]) -> None:
        rows, warnings, fields = state.pop("_saved")
        self.__dict__.update(state)
        self._attach()
        for name, values in fields.items():
            self._fields[name] = self.batch.expand(name)
            self._fields[name][...] = values
        self.state[...] = rows
        self._warning[...] = warnings
        if self._native is not None and not native.install():
            self._native = None  # no C callback here: the rig's Python hook (same numbers)

    def _check_layout(self) -> None:
        """Verify the computed state offsets against MuJoCo and the batch's rows (fails
        loudly if either changes)."""
        model = self._base
        data = mujoco.MjData(model)
        data.ctrl[:] = np.arange(1, self.nu + 1)
        data.qfrc_applied[:] = -np.arange(1, self.nv + 1)
        data.xfrc_applied[:] = np.arange(6 * self.nbody).reshape(self.nbody, 6) + 0.5
        data.qpos[:] = 10 + np.arange(model.nq)
        data.qvel[:] = 20 + np.arange(self.nv)
        row = np.zeros(self.state.shape[1])
        mujoco.mj_getState(model, data, row, _INTEGRATION)
        expected = np.concatenate([data.qpos[self.rig.qpos_adr], data.qvel[self.rig.dof_adr]])
        ok = (self.state.shape[1] == mujoco.mj_stateSize(model, _INTEGRATION)
              and np.array_equal(row[self._ctrl], data.ctrl)
              and np.array_equal(row[self._qfrc], data.qfrc_applied)
              and np.array_equal(row[self._xfrc], data.xfrc_applied.ravel())
              and np.array_equal(row[self._gather], expected))
        if ok:
            saved = self.state[0].copy()
            self.state[0] = row
            back = self.batch.get_data(0)
            self.state[0] = saved
            ok = (np.array_equal(back.qpos, data.qpos) and np.array_equal(back.qvel, data.qvel)
                  and np.array_equal(back.ctrl, data.ctrl)
                  and np.array_equal(back.xfrc_applied, data.xfrc_applied))
        if not ok:
            raise RuntimeError("unexpected mjSTATE_INTEGRATION layout in this MuJoCo version")

    # ------------------------------------------------------------------ parameters
    def _diff(self, params: Params) -> dict[str, np.ndarray]:
        """The model fields in which the rig's model with ``params`` differs from the
        nominal one (bitwise), with their values: what makes a member's model exactly
        ``rig.model_with(params)``."""
        diff = self._diffs.get(params)
        if diff is None:
            model, base = self.rig.model_with(params, self._scratch), self._base
            diff = {}
            for name in _model_fields():
                mine, nominal = _model_field(model, name), _model_field(base, name)
                if mine.tobytes() != nominal.tobytes():
                    diff[name] = mine.copy()
            self._diffs[params] = diff
        return diff

    def _write_params(self, members: np.ndarray, params: Sequence[Params]) -> None:
        """Per-simulation model fields of the members from their parameters."""
        groups: dict[Params, list[int]] = {}
        for i, p in zip(members.tolist(), params, strict=True):
            groups.setdefault(p, []).append(i)
        diffs = {p: self._diff(p) for p in groups}
        for diff in diffs.values():
            for name in diff:
                if name not in self._fields:
                    self._fields[name] = self.batch.expand(name)
        if not self._fields:
            return
        for p, ids in groups.items():
            diff = diffs[p]
            rows = np.asarray(ids)
            for name, values in self._fields.items():
                values[rows] = diff.get(name, _model_field(self._base, name))
        in_use = set(self.params)
        self._diffs = {p: d for p, d in self._diffs.items() if p in in_use
                       or p == self.rig.params}

    def reset(self, members: Sequence[int], params: Sequence[Params], x0: np.ndarray) -> None:
        """``mj_resetData``, ``x0`` into qpos/qvel, ``mj_forward`` for each member (k,)."""
        index = np.asarray(members, dtype=int).reshape(-1)
        if not len(index):
            return
        order = np.argsort(index, kind="stable")
        index, x0 = index[order], np.asarray(x0, float)[order]
        params = [params[j] for j in order.tolist()]
        for i, p in zip(index.tolist(), params, strict=True):
            self.params[i] = p
            self.constants[i] = self.rig.member_constants(p)
        self._write_params(index, params)
        batch = self.batch
        batch.reset(index, stage=int(mujoco.mjtStage.mjSTAGE_NONE))
        j = len(self.rig.joints)
        self.state[index[:, None], self._qpos_cols] = x0[:, :j]
        self.state[index[:, None], self._qvel_cols] = x0[:, j:]
        if self._mass_bound is None:
            self._mass_bound = batch.bind("M")
        batch.forward(index)
        self._store_mass(index)
        if self._native is not None:  # the C current limit's flag and constants
            flag, _, consts = self._native
            self.state[index, flag] = native.MAGIC
            self.state[index, consts] = np.concatenate(
                self.rig.act_window(self.constants[index]), axis=1)
        self._warning[index] = 0
        self.unstable[index] = False
        self._any_unstable = bool(np.count_nonzero(self.unstable))

    def _store_mass(self, sel: Any) -> None:
        """Dense mass matrices of the members from MuJoCo's sparse ``M`` (a copy of the
        values, as ``mj_fullM``)."""
        flat = self._mass_flat
        if flat.base is not self.mass:
            flat = self._mass_flat = self.mass.reshape(self.num, -1)
        lower, upper = self._m_flat
        if sel is _ALL:
            m = self._mass_bound  # (every row: the array, without a view of it)
            lower_cols, upper_cols = self._m_flat_whole
            flat[:, lower_cols] = m
            if upper_cols is not None:
                flat[:, upper_cols] = m
        elif isinstance(sel, slice):
            m = self._mass_bound[sel]
            flat[sel, lower] = m
            flat[sel, upper] = m
        else:
            m = self._mass_bound[sel]
            flat[sel[:, None], lower] = m
            flat[sel[:, None], upper] = m

    def states(self, members: Any = slice(None)) -> np.ndarray:
        """Rig states of the members (a slice or int indices), shape (k, n)."""
        if members is _ALL:  # (the common case, without the comparison)
            return self.state.take(self._gather, axis=1)
        if isinstance(members, slice):
            state = self.state if members == _ALL else self.state[members]
            return state.take(self._gather, axis=1)
        return self.state[np.asarray(members)[:, None], self._gather]

    def actuator_states(self, members: Any = slice(None)) -> np.ndarray:
        """MuJoCo actuator states (``act``) of the members, shape (k, na) (a copy)."""
        return self.state[members, self._act_cols].copy()

    def set_inputs(self, members: Any, inputs: dict[str, np.ndarray],
                   qfrc: np.ndarray | None) -> None:
        """Write ctrl / xfrc_applied / qfrc_applied of the members' state rows and their
        ``opt.gravity`` (:meth:`~testbed.rigs.base.Rig.physics_inputs`)."""
        if "gravity" in inputs:
            field = self._fields.get("opt.gravity")
            if field is None:  # (a member's reset writes its model's back: _write_params)
                field = self._fields["opt.gravity"] = self.batch.expand("opt.gravity")
            field[members] = inputs["gravity"]
        if "ctrl" in inputs:
            self.state[members, self._ctrl] = inputs["ctrl"]
        if "xfrc" in inputs:
            self.state[members, self._xfrc] = inputs["xfrc"].reshape(len(inputs["xfrc"]), -1)
        if qfrc is not None:
            self.state[members, self._qfrc] = qfrc

    def _apply_step_noise(self, sel: Any, step_noise: np.ndarray) -> None:
        """The rig's step noise into the members' per-simulation model fields."""
        for name, (where, values) in self.rig.step_noise_model(self.constants[sel],
                                                               step_noise).items():
            field = self._fields.get(name)
            if field is None:
                field = self._fields[name] = self.batch.expand(name)
            field[(sel, where) if isinstance(where, _INTEGERS)
                  else (sel, *np.atleast_1d(where).tolist())] = values

    def step(self, members: np.ndarray, need_mass: bool = False,
             need_poses: bool = False, step_noise: np.ndarray | None = None) -> bool:
        """``mj_step`` ``frame_skip`` times for the members (sorted int array); whether any
        of them reported an instability warning (:attr:`unstable`).

        ``step_noise`` (k, d), one row per member, perturbs each member's model (the rig's
        :meth:`~testbed.rigs.base.Rig.step_noise_model`) before its step. With
        ``rig.needs_substep`` the rig's ``substep_ctrl`` sets every member's ``ctrl`` before
        each physics step (vectorized over the members), else MuJoCo takes the
        ``frame_skip`` steps in one call.
        """
        k = len(members)
        if not k:
            return False
        whole = k == self.num
        sel: Any = _ALL if whole else members
        ids = None if whole else members
        batch = self.batch
        if need_poses and self._poses_bound is None:
            self._poses_bound = (batch.bind("xpos"), batch.bind("xquat"))
        if need_mass and self._mass_bound is None:
            self._mass_bound = batch.bind("M")
        if step_noise is not None:
            self._apply_step_noise(sel, step_noise)
        if self._act is None:
            if ids is None and self._c_step is not None:  # (step_plain's C call)
                failed = self._c_step(None, self.frame_skip, _STAGE_NONE)
                if failed:
                    batch._check(None, failed)
            else:
                batch.step(ids, self.frame_skip)
        elif self._native is not None and native.installed():  # ctrl set in C, from the
            # command held in userdata
            state, cols, held = self.state, self._ctrl, self._native[1]
            command = state[sel, cols]
            state[sel, held] = command
            batch.step(ids, self.frame_skip)
            state[sel, cols] = state[sel, held]
        else:  # ctrl from the held command and the actuator state, every physics step
            state, cols = self.state, self._ctrl
            command = state[sel, cols].copy()
            constants, substep = self.constants[sel], self.rig.substep_ctrl
            act = self._act
            for _ in range(self.frame_skip):
                state[sel, cols] = substep(command, act[sel], constants)
                batch.step(ids, 1)
            state[sel, cols] = command
        warned = self._mark_unstable(sel, k)
        if need_mass:
            self._store_mass(sel)
        if need_poses:
            self._store_poses(sel)
        return warned

    def step_plain(self) -> bool:
        """:meth:`step` of every member of a one-member physics without step noise, mass,
        poses or per-substep ctrl (no ``needs_substep``): the batch's step and the warning
        check, without the general path's branches (the same calls, the same values).

        The step is the batch's C call (``Batch.step``'s ``_b.step``, the wrapper's id
        conversion and status check skipped: about 0.6 us of a one-member step) where this
        MuJoCo has it (4.0), else the public ``Batch.step``; tests run both.
        """
        c_step = self._c_step
        if c_step is None:
            self.batch.step(None, self.frame_skip)
        else:
            failed = c_step(None, self.frame_skip, _STAGE_NONE)
            if failed:  # the wrapper's error (SimulationError)
                self.batch._check(None, failed)
        return self._mark_unstable(_ALL, 1)

    def _mark_unstable(self, sel: Any, k: int) -> bool:
        """Whether any of the ``k`` stepped members ``sel`` (a slice or int indices) reported
        one of MuJoCo's instability warnings in its step: marks them in :attr:`unstable` and
        clears their counters (and the marks of an earlier step when none did)."""
        bad = self._bad if sel is _ALL else self._bad[sel]
        # (one member: its three counters as Python ints, without numpy's call overhead)
        warned = any(bad.tolist()[0]) if k == 1 else bool(np.count_nonzero(bad))
        if warned:  # rare: mark the members and clear their counters
            unstable = np.any(bad, axis=1)
            self.unstable[sel] = unstable
            self._warning[self._all_ids[sel][unstable]] = 0
            self._any_unstable = True
        elif self._any_unstable:  # clear the marks of an earlier step
            self.unstable[sel] = False
            self._any_unstable = bool(np.count_nonzero(self.unstable))
        return warned

    def _store_poses(self, sel: Any) -> None:
        if self.poses is None or len(self.poses[0]) != self.num:
            self.poses = (np.zeros((self.num, self.nbody, 3)), np.zeros((self.num, self.nbody, 4)))
        self.poses[0][sel] = self._poses_bound[0][sel]
        self.poses[1][sel] = self._poses_bound[1][sel]

    def forward_poses(self, members: np.ndarray) -> None:
        """Body poses of the members from their current states (``mj_kinematics``)."""
        if self._poses_bound is None:
            self._poses_bound = (self.batch.bind("xpos"), self.batch.bind("xquat"))
        index = np.unique(np.asarray(members, dtype=int))
        self.batch.forward(index, stage=int(mujoco.mjtStage.mjSTAGE_POS))
        self._store_poses(index)

    def close(self) -> None:
        """Nothing to stop (the batch's threads end with it)."""


_MODEL_FIELDS: tuple[str, ...] | None = None


def _model_fields() -> tuple[str, ...]:
    """The model fields a batch can hold per simulation, but for structure (addresses,
    counts, ids, types) and names."""
    global _MODEL_FIELDS
    if _MODEL_FIELDS is None:
        _MODEL_FIELDS = tuple(sorted(
            n for n in mujoco.batch.MODEL_FIELDS
            if not n.startswith(("name_", "names_")) and n not in ("bvh_aabb",)))
    return _MODEL_FIELDS


def _model_field(model: mujoco.MjModel, name: str) -> np.ndarray:
    if name.startswith("opt."):
        return np.asarray(getattr(model.opt, name[4:]))
    return np.asarray(getattr(model, name))
