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
"""

from __future__ import annotations

import bisect
import copy
import math
import operator
import os
from collections.abc import Callable, Sequence
from typing import Any

import mujoco
import mujoco.batch
import numpy as np

from filters import real_array
from testbed.rigs.base import Params, Rig
from testbed.rigs.disturbances import Disturbance
from testbed.sensors import Drawn, NoiseStreams, Sample, Sensor
from testbed.sensors.fused import as_slice, measure_one, state_row_plan
from testbed.sim import native

_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
_CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
_QFRC = int(mujoco.mjtState.mjSTATE_QFRC_APPLIED)
_XFRC = int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)
_USERDATA = int(mujoco.mjtState.mjSTATE_USERDATA)
_QPOS = int(mujoco.mjtState.mjSTATE_QPOS)
_QVEL = int(mujoco.mjtState.mjSTATE_QVEL)
RESET_OPTION_KEYS = ("x0", "params", "setpoints", "manoeuvre", "manoeuvre_params")


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
_le, _ne = operator.le, operator.ne  # (the one-member step's comparisons, read once)


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


def _per_time(fn: Callable[[float], np.ndarray], t: np.ndarray, dim: int,
              common: bool = False) -> np.ndarray:
    """``fn(t_i)`` for every entry of ``t`` (k,), evaluated once per distinct time: (k, dim).

    ``common``: the caller knows that every entry of ``t`` is the same time (not looked at).
    """
    if len(t) and (common or t.min() == t.max()):
        return _filled(fn(float(t[0])), len(t), dim)
    values, inverse = np.unique(t, return_inverse=True)
    table = np.array([fn(float(v)) for v in values], dtype=float).reshape(len(values), dim)
    return table[inverse]


def _finite_profile(out: np.ndarray, checked: np.ndarray, t: Any) -> np.ndarray:
    """``out``, the input profiles, when ``checked`` (its rows to check) is finite; else
    ``ValueError`` naming the time(s) ``t``."""
    if np.count_nonzero(np.isfinite(checked)) != checked.size:
        times = t.tolist() if isinstance(t, np.ndarray) else [t]
        raise ValueError(f"the manoeuvre returned a non-finite input at t = {times} s")
    return out


def _filled(value: Any, k: int, dim: int) -> np.ndarray:
    """A new (k, dim) array of one time's ``value`` (a float, or what broadcasts to (dim,))
    in every row (broadcast, as np.broadcast_to)."""
    out = np.empty((k, dim))
    if type(value) is float:
        out.fill(value)
    else:
        out[...] = np.asarray(value, dtype=float)
    return out


def _defines_with(cls: type, method: str, companion: str) -> bool:
    """Whether the class in ``cls``'s MRO that defines ``method`` defines ``companion``."""
    for klass in cls.__mro__:
        if method in klass.__dict__:
            return companion in klass.__dict__
    return False


#: The float entries of :attr:`Simulator.info`, in its order (``action_clipped`` follows).
_INFO_KEYS = ("state", "t", "disturbance", "setpoint", "action_applied", "manoeuvre",
              "process_accel", "step_noise")


def _joined(columns: dict[str, slice], first: str, second: str) -> slice:
    """The columns of two adjacent blocks of ``columns`` as one slice."""
    a, b = columns[first], columns[second]
    assert a.stop == b.start
    return slice(a.start, b.stop)


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
        self._r = len(self._tracked)  # tracked states (reward terms)
        lo, hi = (int(self._tracked[0]), int(self._tracked[-1]) + 1) if len(self._tracked) \
            else (0, 0)
        #: The tracked columns as a slice when contiguous (a view instead of a gather).
        self._tracked_cols = (slice(lo, hi) if np.array_equal(self._tracked, np.arange(lo, hi))
                              else self._tracked)
        self._envelope = rig.envelope
        #: A one-member simulator steps on Python floats (:meth:`_step_single`): its limits,
        #: envelope and tracked columns as lists.
        self._single = n == 1
        self._low_list, self._high_list = self._low.tolist(), self._high.tolist()
        self._envelope_list = self._envelope.tolist()
        self._tracked_list = self._tracked.tolist()
        table = setpoints if setpoints is not None else (rig.default_setpoints or None)
        r = len(self._tracked)
        self._tables = [rig.validate_setpoints(table) if table is not None
                        else np.zeros((1, 1 + r))]
        self._table_times = self._tables[0][:, 0].tolist()
        self._table_rows = [row[None, 1:] for row in self._tables[0]]  # (1, r) views
        self._table_lists = [row[1:].tolist() for row in self._tables[0]]
        #: The default table's row found last and the times it holds for, ``lo <= t < hi``
        #: (:meth:`_table_row`).
        self._row_cache = (math.inf, -math.inf, 0)
        self._table_of = np.zeros(n, dtype=int)
        self._schedules: list[Any] = [self._resolve_manoeuvre(manoeuvre, manoeuvre_params)]
        self._schedule_of = np.zeros(n, dtype=int)
        #: No member has an input profile (updated when a reset registers one).
        self._no_manoeuvre = self._schedules[0] is None
        self._w_dim = len(self.disturbance.signal(0.0))
        self._dist_draws = 0 if self.disturbance.b is None else self.disturbance.b.shape[1]
        self.physics = Physics(rig, n, self.frame_skip, num_threads)
        self.physics.reset(range(n), [self.nominal_params] * n,
                           np.tile(rig.default_x0(), (n, 1)))
        #: The sensors' normals per sample when they declare a fixed number (drawn with the
        #: step's own in one call, :class:`~testbed.sensors.Drawn`), else None.
        self._sensor_draws = self.sensors.draws_per_sample()
        #: Normals a step draws in one call: the rig's step noise, the disturbance's, then
        #: (when declared) the sensors'.
        self._step_draws = (rig.step_noise_dim + self._dist_draws
                            + (self._sensor_draws or 0))
        #: A one-member simulator's sensors measured from the state list alone (a fused
        #: plan's steps on a row, :func:`~testbed.sensors.fused.state_row_plan`), with the
        #: offset of the plan's normals in the step's draw; else None.
        plan = state_row_plan(self.sensors) if n == 1 else None
        self._row_plan = plan if plan is not None and plan.draws == self._sensor_draws else None
        self._sensor_offset = rig.step_noise_dim + self._dist_draws
        self.noise = NoiseStreams(n, max(64 * max(self._dist_draws + rig.step_noise_dim
                                                  + self.sensors.dim + rig.x0_draws, 4),
                                         self._step_draws))
        self._noise_all = self.noise.view(slice(None))
        self._no_draws = Drawn(np.zeros((n, 0)))  # for sensors that draw nothing
        # fixed for the simulator's life: read once, not per step
        self._has_signal, self._dist_active = self.disturbance.has_signal, self.disturbance.active
        #: No signal, disturbance forces or step noise: a one-member step skips their inputs
        #: (:meth:`_step_single`).
        self._plain_inputs = not (self._has_signal or self._dist_active or rig.step_noise_dim)
        dist = self.disturbance
        #: The disturbance's velocity rows of G and b (None without), sqrt(dt) and the rig's
        #: dof addresses: what a step turns into joint accelerations.
        self._dist_rows = (None if dist.G is None else dist.G[self._j:],
                           None if dist.b is None else dist.b[self._j:], np.sqrt(self.dt_s),
                           rig.dof_adr)
        self.steps = np.zeros(n, dtype=np.int64)
        #: Whether every member has the same step count (the common case of a batch reset and
        #: stepped together): the references, input profiles and disturbance signals are then
        #: looked up once per step, not per member.
        self._same_steps = False
        self._ready = np.zeros(n, dtype=bool)
        self._all_ready = False
        self._terminates = type(rig).terminated is not Rig.terminated
        #: Whether the rig's class that defines ``terminated`` defines ``terminated_row``
        #: too (else a one-member step calls ``terminated``).
        self._terminated_row = _defines_with(type(rig), "terminated", "terminated_row")
        self.x0 = np.zeros((n, self._nx))
        self.obs = np.zeros((n, self.sensors.dim))
        self.reward = np.zeros(n)
        self.terminated = np.zeros(n, dtype=bool)
        self.record_poses = False
        self._all = np.arange(n)  # read-only constants of the step
        self._zero_input, self._zero_accel = np.zeros((n, self._nu)), np.zeros((n, self._j))
        self._zero_w = np.zeros((n, 0))
        # the step's constants with one row per member: numpy's ufuncs between arrays of one
        # shape skip the broadcasting machinery, which costs more than the arithmetic on a few
        # columns (the same values, bitwise)
        self._low_rows, self._high_rows = np.tile(self._low, (n, 1)), np.tile(self._high, (n, 1))
        self._envelope_rows = np.tile(self._envelope, (n, 1))
        self._dt_rows, self._one_rows = np.full(n, self.dt_s), np.ones(n, dtype=np.int64)
        for a in (self._all, self._zero_input, self._zero_accel, self._zero_w, self._low_rows,
                  self._high_rows, self._envelope_rows, self._dt_rows, self._one_rows):
            a.flags.writeable = False
        #: The whole batch's joint accelerations in generalized coordinates (num, nv): zero
        #: but in the rig's dof columns, which :meth:`_forces` overwrites every step.
        self._accel_rows = np.zeros((n, self.physics.nv))
        #: The rig's dof columns: a slice when they are consecutive (a basic-index write).
        self._dof_cols = as_slice(rig.dof_adr)
        #: What a step of the whole batch reads for its members: their indices, selection,
        #: number, action limits, envelope and zero input, acceleration and signal rows.
        self._whole = (self._all, _ALL, n, self._low_rows, self._high_rows,
                       self._envelope_rows, self._zero_input, self._zero_accel, self._zero_w)
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
        #: The column blocks in the order of :meth:`member_info`'s dict display (``t`` its
        #: column index: the entry is a float, no block is sliced for it).
        assert tuple(widths) == _INFO_KEYS
        self._info_slices = tuple(cols.start if key == "t" else cols
                                  for key, cols in self._info_columns.items())
        #: Adjacent column blocks a one-member step writes at once: state and t, setpoint
        #: and action_applied.
        self._state_t_cols = _joined(self._info_columns, "state", "t")
        self._setpoint_action_cols = _joined(self._info_columns, "setpoint", "action_applied")
        #: Both blocks as one when the disturbance's columns between them are none.
        self._step_cols = (slice(self._state_t_cols.start, self._setpoint_action_cols.stop)
                           if self._w_dim == 0 else None)
        self.info: dict[str, np.ndarray] = {}
        self._info_views(np.zeros((n, self._nu), dtype=bool))

    def _info_views(self, action_clipped: np.ndarray) -> None:
        """``info``: views of the column blocks of ``_info_rows``; and the views of member 0's
        rows the one-member step writes through (rebuilt in copies)."""
        self.info.clear()
        self.info.update({key: self._info_rows[:, cols]
                          for key, cols in self._info_columns.items()})
        self.info["t"] = self._info_rows[:, self._info_columns["t"].start]
        self.info["action_clipped"] = action_clipped
        row = self._info_row = self._info_rows[0]
        # 1-D views of member 0's columns: a list of floats assigned to a whole 1-D view
        # (``view[...] = values``) costs less than to a slice or a row of a 2-D array
        self._clipped_row = action_clipped[0]
        self._obs_row = self.obs[0]
        #: State and t, setpoint and action_applied (adjacent blocks) as one view when the
        #: disturbance's columns between them are none (:meth:`_step_single`), else two.
        self._step_views = ((row[self._step_cols],) if self._step_cols is not None
                            else (row[self._state_t_cols], row[self._setpoint_action_cols]))

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
        row = (self._info_row if i == 0 else self._info_rows[i]).copy()
        # a dict display with the keys of _INFO_KEYS (fixed): no loop over the blocks. The
        # entries are new views of the copy, zero-width ones too (one shared empty array
        # would be visible: a user may set its shape, flags or dtype)
        state, t, w, setpoint, applied, manoeuvre, accel, step_noise = self._info_slices
        return {"state": row[state], "t": row.item(t), "disturbance": row[w],
                "setpoint": row[setpoint], "action_applied": row[applied],
                "manoeuvre": row[manoeuvre], "process_accel": row[accel],
                "step_noise": row[step_noise],
                "action_clipped": (self._clipped_row if i == 0
                                   else self.info["action_clipped"][i]).copy()}

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
    def _reference(self, t: np.ndarray, sel: Any, common: bool = False) -> np.ndarray:
        """References (k, r) of the members ``sel`` at their times ``t`` (k,); ``common``:
        every entry of ``t`` is the same time."""
        if len(self._tables) == 1:  # one schedule for every member
            table = self._tables[0]
            if len(t) == 1 or (common and len(t)):  # one time: the row searchsorted finds
                # below for each member, looked up once without numpy's per-call overhead
                ref = self._table_rows[self._table_row(float(t[0]))]
                return ref if len(t) == 1 else ref.repeat(len(t), axis=0)
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

    def _table_row(self, t: float) -> int:
        """The row of the default setpoint table in force at ``t``: what ``searchsorted(times,
        t, side="right") - 1`` (at least 0) finds, looked up again only when ``t`` leaves the
        times the last row holds for (a step is then a compare, not a search)."""
        lo, hi, row = self._row_cache
        if lo <= t < hi:
            return row
        times = self._table_times
        row = max(bisect.bisect_right(times, t) - 1, 0)
        self._row_cache = (times[row] if row else -math.inf,
                           times[row + 1] if row + 1 < len(times) else math.inf, row)
        return row

    def setpoints_at(self, t_s: float | np.ndarray, members: Any = slice(None)) -> np.ndarray:
        """References of the members at time(s) ``t_s``, shape (k, r)."""
        groups = self._table_of[members]
        t = np.asarray(t_s, float)
        if t.ndim == 0:  # one time for every member
            return self._reference(np.full(groups.shape, t), members, common=True)
        return self._reference(np.broadcast_to(t, groups.shape), members)

    def _manoeuvre(self, t: np.ndarray, sel: Any, common: bool = False) -> np.ndarray:
        """The input profiles (k, nu) of the members ``sel`` at their times ``t`` (k,);
        ``common``: every entry of ``t`` is the same time."""
        if self._no_manoeuvre:  # no profile anywhere
            return np.zeros((len(t), self._nu))
        if len(self._schedules) == 1:  # every member's profile (one, not None)
            fn = self._schedules[0]
            if common and len(t):  # one time: one call, every row the first one
                return self._common_profile(float(t[0]), len(t))
            out = _per_time(lambda s: np.atleast_1d(fn(s)), t, self._nu)
        else:
            groups = self._schedule_of[sel]
            out = np.zeros((len(t), self._nu))
            for g in np.unique(groups):
                fn = self._schedules[g]
                if fn is None:
                    continue
                mask = groups == g
                out[mask] = _per_time(lambda s, fn=fn: np.atleast_1d(fn(s)), t[mask], self._nu)
        return _finite_profile(out, out, t)

    def _common_profile(self, t: float, k: int) -> np.ndarray:
        """The input profiles (k, nu) of ``k`` members at one time ``t`` when every member
        has the one default profile: one call, every row its value."""
        value = self._schedules[0](t)
        out = _filled(value, k, self._nu)
        if type(value) is float and math.isfinite(value):
            return out
        return _finite_profile(out, out[:1], t)

    def _signal(self, t: np.ndarray, index: np.ndarray, common: bool = False) -> np.ndarray:
        """The disturbance signal (k, s) of the members ``index`` at their times ``t`` (k,);
        ``common``: every entry of ``t`` is the same time."""
        member_signal = getattr(self.disturbance, "member_signal", None)
        if member_signal is not None:  # one sequence per member (SampledDisturbance)
            return member_signal(t, index)
        return _per_time(self.disturbance.signal, t, self._w_dim, common)

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
        self._no_manoeuvre = len(self._schedules) == 1 and self._schedules[0] is None
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
        if (type(actions) is np.ndarray and actions.dtype == np.float64
                and actions.shape == (k, self._nu)
                and np.count_nonzero(np.isfinite(actions)) == actions.size):
            return actions  # used as it is: a step keeps none of it
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
        # the simulator's and the sensors' arrays: a basic slice for the whole batch (no
        # gather/scatter copies); noise streams and physics keep the member indices
        if members is None:
            if not self._all_ready:
                raise RuntimeError("reset() every member before stepping it")
            if self._single:  # one member: its few numbers on Python floats
                self._step_single((actions if checked
                                   else self.check_actions(actions, 1)).tolist()[0])
                return
            index, sel, k, low, high, envelope, zero_u, zero_accel, zero_w = self._whole
            common = self._same_steps
        else:
            index = sel = np.asarray(members, int)
            k = len(index)
            if np.count_nonzero(self._ready[index]) != k:
                raise RuntimeError("reset() every member before stepping it")
            low, high, envelope = self._low, self._high, self._envelope
            zero_u, zero_accel = self._zero_input[:k], self._zero_accel[:k]
            zero_w = self._zero_w[:k]
            common = False
        u = actions if checked else self.check_actions(actions, k)
        rig, physics, info = self.rig, self.physics, self.info
        has_signal, dist_active, no_manoeuvre = (self._has_signal, self._dist_active,
                                                 self._no_manoeuvre)
        # every member at one time with the one default profile: the profile from a float
        one_profile = common and not no_manoeuvre and len(self._schedules) == 1
        t = None
        if has_signal or not (no_manoeuvre or one_profile):
            t = self.steps[sel] * self.dt_s
        # clip(u, low, high) is min(max(u, low), high), bitwise (u is finite)
        clipped_u = np.minimum(np.maximum(u, low), high)
        # the whole batch's flags go straight into info (no one else reads them)
        clipped_out = info["action_clipped"] if members is None else None
        if no_manoeuvre:  # the profile is zero: clipped + 0 needs no second clip
            profile = zero_u
            applied = clipped_u + profile
            clipped = np.not_equal(clipped_u, u, out=clipped_out)
        else:
            # one time for every member: steps * dt_s of the first, a Python float (int64
            # to double and the product, as numpy's)
            profile = (self._common_profile(self.steps.item(0) * self.dt_s, k)
                       if t is None else self._manoeuvre(t, sel, common))
            total = clipped_u + profile
            applied = np.minimum(np.maximum(total, low), high)
            clipped = np.bitwise_or(clipped_u != u, applied != total, out=clipped_out)
        # the step's normals in one draw, in stream order: step noise, disturbance, sensors
        if members is None:  # (every stream: drawn without the view's selection test)
            noise = self._noise_all
            xi = self.noise.draw_all(self._step_draws) if self._step_draws else None
        else:
            noise = self.noise.view(index)
            xi = noise.normal(self._step_draws) if self._step_draws else None
        n_step = rig.step_noise_dim
        step_noise = None
        if n_step:  # applied by the physics threads, before each member's step
            step_noise = xi[:, :n_step]
            info["step_noise"][sel] = step_noise
        qfrc = None
        if dist_active:
            w, accel, qfrc = self._forces(t, index, sel, common, xi, zero_accel)
        elif has_signal:
            w = self._signal(t, index, common)
        physics.set_inputs(sel, rig.physics_inputs(applied, physics.constants[sel]), qfrc)
        warned = physics.step(index, need_mass=dist_active, need_poses=self.record_poses,
                              step_noise=step_noise)
        if members is None:
            steps = self.steps + self._one_rows  # (faster than an in-place np.add(out=))
            self.steps[...] = steps
            t = steps * self._dt_rows
        else:
            steps = self.steps[sel] + 1
            self.steps[sel] = steps
            t = steps * self.dt_s
            self._same_steps = False
        x = physics.states(sel)
        inside = np.less_equal(np.abs(x), envelope)  # NaN compares False
        if warned or np.count_nonzero(inside) != inside.size:
            self._diverged(index, physics.unstable[sel], ~inside.all(axis=1), x, t)
        r = self._r
        one_row = common and len(self._tables) == 1
        if one_row:  # one row (1, r), broadcast, not repeated
            row = self._table_row(t.item(0))
            ref = self._table_rows[row]
        else:
            ref = self._reference(t, sel, common)
        if one_row and r == 1:  # the tracked column (1-D: numpy's one loop) minus the row's
            # float: the same differences and squares
            e = x[:, self._tracked_list[0]] - self._table_lists[row][0]
            total = e * e
        else:
            e = x[:, self._tracked_cols] - ref
            sq = e * e
            if r == 2:  # the two squares' sum is add.reduce's, bitwise (squares are >= +0)
                total = sq[:, 0] + sq[:, 1]
            else:
                total = sq[:, 0] if r == 1 else np.add.reduce(sq, axis=1)
        if members is None:
            np.negative(total, self.reward)
        else:
            self.reward[sel] = -total
        if self._terminates:  # the base Rig.terminated never ends an episode
            self.terminated[sel] = rig.terminated(x)
        w_now = self._signal(t, index, common) if has_signal else zero_w
        self.obs[sel] = self._measure(Sample(x, t, applied, w_now, sel), noise, xi)
        info["state"][sel] = x
        info["t"][sel] = t
        info["setpoint"][sel] = ref
        info["action_applied"][sel] = applied
        if clipped_out is None:
            info["action_clipped"][sel] = clipped
        # the entries below keep what reset wrote without a signal, profile or disturbance
        if has_signal:
            info["disturbance"][sel] = w
        if not no_manoeuvre:
            info["manoeuvre"][sel] = profile
        if dist_active:
            info["process_accel"][sel] = accel

    def step_row(self, action: list[float]) -> tuple[np.ndarray, float, bool]:
        """:meth:`step` of a one-member simulator with its action as Python floats (nu,),
        the caller's checked finite values (the Gymnasium env's check).

        Returns
        -------
        obs : ndarray, shape (m,)
            A copy of the member's observation.
        reward : float
        terminated : bool
            The member's entries of :attr:`reward` and :attr:`terminated` (Python scalars,
            without numpy scalars between).
        """
        if not self._all_ready:
            raise RuntimeError("reset() every member before stepping it")
        if not self._single:
            raise RuntimeError("step_row steps a one-member simulator")
        self._step_single(action)
        return self._obs_row.copy(), self.reward.item(0), self.terminated.item(0)

    def _step_single(self, ul: list[float]) -> None:
        """:meth:`step` of a one-member simulator (``ul`` its checked action, Python floats
        of shape (nu,)).

        The same operations in the same order as the batch step, but the few numbers of the
        bookkeeping (clipping, time, envelope check, reference, reward, info) are Python
        floats: IEEE-754 doubles like numpy's, so bitwise the same values
        (``min(max(v, lo), hi)`` is numpy's ``minimum(maximum(v, lo), hi)`` on finite
        values, ``abs(v) <= bound`` is False for NaN like ``less_equal``), without numpy's
        per-call overhead on arrays of one row. The rig, disturbance, physics and sensors
        get the same arrays as in a batch step (new ones each step: a rig or sensor may
        keep them); sensors whose fused plan reads the state only
        (:func:`~testbed.sensors.fused.state_row_plan`) run the plan's steps on the state
        list, the operations the sample's measurement runs, without the sample.
        """
        rig, physics, info = self.rig, self.physics, self.info
        has_signal, dist_active, no_manoeuvre = (self._has_signal, self._dist_active,
                                                 self._no_manoeuvre)
        index, sel = self._all, _ALL
        # min(max(v, lo), hi) as the builtins compare: max(v, lo) is lo only if lo > v,
        # min(m, hi) is hi only if hi < m (the same objects, without two calls per entry)
        t = None
        if has_signal or not no_manoeuvre:  # the times as the batch step has them
            t = np.array((self.steps.item(0) * self.dt_s,))
        if no_manoeuvre:  # the profile is zero: clipped + 0 (which makes -0.0 +0.0), in the
            # clip's pass; the flags compare it with the action: c + 0.0 != v is c != v
            # (only a zero's sign changes, and -0.0 == 0.0)
            profile = None
            applied = [(hi if hi < (m := (lo if lo > v else v)) else m) + 0.0
                       for v, lo, hi in zip(ul, self._low_list, self._high_list, strict=True)]
            clipped = list(map(_ne, applied, ul))
        else:
            clipped_u = [hi if hi < (m := (lo if lo > v else v)) else m
                         for v, lo, hi in zip(ul, self._low_list, self._high_list, strict=True)]
            profile = self._manoeuvre(t, sel, True)
            total = list(map(operator.add, clipped_u, profile.tolist()[0]))
            applied = list(map(min, map(max, total, self._low_list), self._high_list))
            clipped = [c != v or a != s for c, v, a, s in zip(clipped_u, ul, applied, total,
                                                               strict=True)]
        # (1, nu): a view of the new (nu,) array (one numpy call less than ((applied,)))
        applied_rows = np.array(applied)[None]
        xi = self._noise_all.normal(self._step_draws) if self._step_draws else None
        step_noise = qfrc = None
        if not self._plain_inputs:  # step noise, disturbance forces or a signal
            n_step = rig.step_noise_dim
            if n_step:
                step_noise = xi[:, :n_step]
                info["step_noise"][sel] = step_noise
            if dist_active:
                w, accel, qfrc = self._forces(t, index, sel, True, xi, self._zero_accel)
            elif has_signal:
                w = self._signal(t, index, True)
        physics.set_inputs(sel, rig.physics_inputs(applied_rows, physics.constants), qfrc)
        if step_noise is None and not (dist_active or self.record_poses or physics.substeps):
            warned = physics.step_plain()
        else:
            warned = physics.step(index, need_mass=dist_active, need_poses=self.record_poses,
                                  step_noise=step_noise)
        steps = self.steps.item(0) + 1
        self.steps[0] = steps
        t_now = steps * self.dt_s
        x = physics.states(sel)
        xl = x.tolist()[0]
        if warned or not all(map(_le, map(abs, xl), self._envelope_list)):
            inside = np.less_equal(np.abs(x), self._envelope)
            self._diverged(index, physics.unstable[sel], ~inside.all(axis=1), x,
                           np.array((t_now,)))
        lo, hi, table_row = self._row_cache
        if lo <= t_now < hi and len(self._tables) == 1:  # the default table's row as before
            ref = self._table_lists[table_row]  # (read only: the info list is built anew)
        else:
            ref = self._single_reference(t_now)
        r = self._r
        if r == 2:  # (the batch step's e * e summed, in the same order)
            c0, c1 = self._tracked_list
            e0, e1 = xl[c0] - ref[0], xl[c1] - ref[1]
            total = e0 * e0 + e1 * e1
        elif r == 1:
            e0 = xl[self._tracked_list[0]] - ref[0]
            total = e0 * e0
        else:  # (numpy's sum of the squares, as the batch step)
            e = x[:, self._tracked_cols] - np.array((ref,)).reshape(1, r)
            total = np.add.reduce(e * e, axis=1).item(0)
        self.reward[0] = -total
        if self._terminates:
            self.terminated[0] = (rig.terminated_row(xl) if self._terminated_row
                                  else rig.terminated(x)[0])
        row_plan = self._row_plan
        y = None
        if row_plan is not None and not has_signal:  # sensors that read the state only: the
            # plan's steps on the state list, without the sample (times, signal) made for them
            y = row_plan.measure_state_row(
                self.sensors, xl, None if xi is None else xi.tolist()[0][self._sensor_offset:],
                sel)
        if y is None:
            t = np.array((t_now,))
            w_now = self._signal(t, index, True) if has_signal else self._zero_w
            y = self._measure(Sample(x, t, applied_rows, w_now, sel), self._noise_all, xi,
                              one=True)
            if row_plan is not None and not has_signal:  # (the suite was fused again)
                plan = state_row_plan(self.sensors)
                self._row_plan = (plan if plan is not None and plan.draws == self._sensor_draws
                                  else None)
        if type(y) is list:  # (the plan's row of floats, into the 1-D view of the row)
            self._obs_row[...] = y
        else:
            self.obs[...] = y
        xl.append(t_now)  # (state and t: adjacent columns, as setpoint and action_applied)
        views = self._step_views
        if len(views) == 1:  # no disturbance columns between: one write
            xl += ref
            xl += applied
            views[0][...] = xl
        else:
            views[0][...] = xl
            views[1][...] = ref + applied
        self._clipped_row[...] = clipped
        if has_signal:
            info["disturbance"][sel] = w
        if profile is not None:
            info["manoeuvre"][sel] = profile
        if dist_active:
            info["process_accel"][sel] = accel

    def _single_reference(self, t: float) -> list[float]:
        """The reference of the one member at ``t``, a list of floats (r,) (read only: the
        default table's may be returned)."""
        if len(self._tables) == 1:
            return self._table_lists[self._table_row(t)]
        return self._reference(np.array((t,)), self._all).tolist()[0]

    def _forces(self, t: np.ndarray | None, index: np.ndarray, sel: Any, common: bool,
                xi: np.ndarray | None, zero_accel: np.ndarray
                ) -> tuple[np.ndarray | None, Any, np.ndarray]:
        """The disturbance of a step: the signal ``w`` (k, s) (the one reset wrote when
        there is none; None when there is neither a signal nor ``G``: no one reads it), the
        joint accelerations ``G w + b xi / sqrt(dt)`` (k, j) and the generalized forces
        ``M(q) a`` (k, nv) of the members."""
        G_rows, b_rows, sqrt_dt, dof_adr = self._dist_rows
        w = None
        if self._has_signal:
            w = self._signal(t, index, common)
        elif G_rows is not None:
            w = self.info["disturbance"][sel]
        accel: Any = zero_accel
        if G_rows is not None:
            accel = accel + np.matvec(G_rows, w)
        if b_rows is not None:
            n_step = self.rig.step_noise_dim
            drawn = xi[:, n_step:n_step + self._dist_draws]
            # accel + (b xi) / sqrt(dt): the division and the sum into the new product
            noise = np.matvec(b_rows, drawn)
            np.divide(noise, sqrt_dt, out=noise)
            accel = np.add(accel, noise, out=noise)
        if isinstance(sel, slice):  # the whole batch: its rows, zero outside the dof columns
            a = self._accel_rows
            a[:, self._dof_cols] = accel
            mass = self.physics.mass  # (every row: the array itself, as its view would be)
        else:
            a = np.zeros((len(index), self.physics.nv))
            a[:, dof_adr] = accel
            mass = self.physics.mass[sel]
        return w, accel, np.matvec(mass, a)

    def _measure(self, sample: Sample, noise: Any, xi: np.ndarray | None,
                 one: bool = False) -> Any:
        """The sensors' sample (k, m): with the normals drawn ahead ``xi`` when they declare
        how many they draw (checked), else from the streams ``noise``. ``one``: of one
        member, the row as :func:`~testbed.sensors.fused.measure_one` gives it (a list of
        floats (m,) or a (1, m) array: the same values)."""
        sensors = self.sensors
        if self._sensor_draws is None:  # the sensors draw from the streams themselves
            return measure_one(sensors, sample, noise) if one else sensors.measure(sample, noise)
        drawn_ahead = (Drawn(xi[:, self._sensor_offset:])
                       if self._sensor_draws else self._no_draws)
        y = (measure_one(sensors, sample, drawn_ahead) if one
             else sensors.measure(sample, drawn_ahead))
        if drawn_ahead.position != self._sensor_draws:
            self._no_draws.position = 0
            raise RuntimeError(f"the sensors ({self.sensors.describe()}) drew "
                               f"{drawn_ahead.position} normals per sample but declare "
                               f"{self._sensor_draws} (draws_per_sample)")
        return y

    def _diverged(self, index: np.ndarray, unstable: np.ndarray, outside: np.ndarray,
                  x: np.ndarray, t: np.ndarray) -> None:
        """Mark the diverged members unready and raise :class:`SimulationDiverged`."""
        bad = unstable | outside
        self._ready[index[bad]] = False
        self._all_ready = False
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
