"""The step of a one-member simulator on Python floats: the batch step's operations in the
same order (bitwise the same values), without numpy's per-call overhead on arrays of one row.

A second implementation of the step, kept for its speed (docs/architecture.md gives the
measured cost of the batch step at N = 1): a change to
:meth:`testbed.sim.step.BatchStep.step` must be made in :meth:`OneMemberStep._step_single`
too; ``tests/sim/test_batch_physics.py::test_one_member_step_equals_a_member_of_a_batch`` and
``tests/sensors/test_state_row_plan.py`` fail when they drift.
"""

from __future__ import annotations

import operator

import numpy as np

from testbed.sensors import Sample
from testbed.sensors.fused import state_row_plan
from testbed.sim.physics import _ALL

_le, _ne = operator.le, operator.ne  # (the one-member step's comparisons, read once)


class OneMemberStep:
    """:meth:`step_row` and the one-member :meth:`~testbed.sim.step.BatchStep.step` (a part
    of :class:`~testbed.sim.simulator.Simulator`)."""

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
        return self.views.obs.copy(), self.reward.item(0), self.terminated.item(0)

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
        limits, inputs = self.limits, self.inputs
        has_signal, dist_active = inputs.has_signal, inputs.active
        no_manoeuvre = self.schedules.none
        index, sel = self.rows.all, _ALL
        t = None
        if has_signal or not no_manoeuvre:  # the times as the batch step has them
            t = np.array((self.steps.item(0) * self.dt_s,))
        applied, clipped, profile = self._single_applied(ul, t)
        # (1, nu): a view of the new (nu,) array (one numpy call less than ((applied,)))
        applied_rows = np.array(applied)[None]
        xi = self._noise_all.normal(self.draws.step) if self.draws.step else None
        step_noise = qfrc = None
        if not inputs.plain:  # step noise, disturbance forces or a signal
            n_step = rig.step_noise_dim
            if n_step:
                step_noise = xi[:, :n_step]
                info["step_noise"][sel] = step_noise
            if dist_active:
                w, accel, qfrc = self._forces(t, index, sel, True, xi, self.rows.zero_accel)
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
        if warned or not all(map(_le, map(abs, xl), limits.envelope_list)):
            inside = np.less_equal(np.abs(x), limits.envelope)
            self._diverged(index, physics.unstable[sel], ~inside.all(axis=1), x,
                           np.array((t_now,)))
        ref = self._single_score(x, xl, t_now)
        y = self._single_measure(x, xl, xi, t_now, applied_rows)
        row_views = self.views
        if type(y) is list:  # (the plan's row of floats, into the 1-D view of the row)
            row_views.obs[...] = y
        else:
            self.obs[...] = y
        xl.append(t_now)  # (state and t: adjacent columns, as setpoint and action_applied)
        views = row_views.step
        if len(views) == 1:  # no disturbance columns between: one write
            xl += ref
            xl += applied
            views[0][...] = xl
        else:
            views[0][...] = xl
            views[1][...] = ref + applied
        row_views.clipped[...] = clipped
        if has_signal:
            info["disturbance"][sel] = w
        if profile is not None:
            info["manoeuvre"][sel] = profile
        if dist_active:
            info["process_accel"][sel] = accel

    def _single_applied(self, ul: list[float], t: np.ndarray | None
                        ) -> tuple[list[float], list[bool], np.ndarray | None]:
        """The applied input (nu,) as Python floats, the clipped flags, and the input
        profile (1, nu) (None when it is zero)."""
        limits = self.limits
        # min(max(v, lo), hi) as the builtins compare: max(v, lo) is lo only if lo > v,
        # min(m, hi) is hi only if hi < m (the same objects, without two calls per entry)
        if self.schedules.none:  # the profile is zero: clipped + 0 (which makes -0.0 +0.0),
            # in the clip's pass; the flags compare it with the action: c + 0.0 != v is
            # c != v (only a zero's sign changes, and -0.0 == 0.0)
            applied = [(hi if hi < (m := (lo if lo > v else v)) else m) + 0.0
                       for v, lo, hi in zip(ul, limits.low_list, limits.high_list, strict=True)]
            return applied, list(map(_ne, applied, ul)), None
        clipped_u = [hi if hi < (m := (lo if lo > v else v)) else m
                     for v, lo, hi in zip(ul, limits.low_list, limits.high_list, strict=True)]
        profile = self._manoeuvre(t, _ALL, True)
        total = list(map(operator.add, clipped_u, profile.tolist()[0]))
        applied = list(map(min, map(max, total, limits.low_list), limits.high_list))
        clipped = [c != v or a != s for c, v, a, s in zip(clipped_u, ul, applied, total,
                                                           strict=True)]
        return applied, clipped, profile

    def _single_score(self, x: np.ndarray, xl: list[float], t_now: float) -> list[float]:
        """The member's reward and termination into their arrays; its reference returned
        (a list of floats, read only)."""
        schedules, scoring = self.schedules, self.scoring
        lo, hi, table_row = schedules.row_cache
        if lo <= t_now < hi and len(schedules.tables) == 1:  # the default table's row as before
            ref = schedules.table_lists[table_row]  # (read only: the info list is built anew)
        else:
            ref = self._single_reference(t_now)
        r = scoring.count
        if r == 2:  # (the batch step's e * e summed, in the same order)
            c0, c1 = scoring.columns
            e0, e1 = xl[c0] - ref[0], xl[c1] - ref[1]
            total = e0 * e0 + e1 * e1
        elif r == 1:
            e0 = xl[scoring.columns[0]] - ref[0]
            total = e0 * e0
        else:  # (numpy's sum of the squares, as the batch step)
            e = x[:, scoring.cols] - np.array((ref,)).reshape(1, r)
            total = np.add.reduce(e * e, axis=1).item(0)
        self.reward[0] = -total
        if scoring.terminates:
            self.terminated[0] = (self.rig.terminated_row(xl) if scoring.terminated_row
                                  else self.rig.terminated(x)[0])
        return ref

    def _single_measure(self, x: np.ndarray, xl: list[float], xi: np.ndarray | None,
                        t_now: float, applied_rows: np.ndarray) -> list[float] | np.ndarray:
        """The member's measurement: a row of floats from a state-only plan, else the
        sensors' (1, m) from a :class:`~testbed.sensors.Sample`."""
        has_signal, sel = self.inputs.has_signal, _ALL
        row_plan = self._row_plan
        y = None
        if row_plan is not None and not has_signal:  # sensors that read the state only: the
            # plan's steps on the state list, without the sample (times, signal) made for them
            drawn = None if xi is None else xi.tolist()[0][self.draws.sensor_offset:]
            y = row_plan.measure_state_row(self.sensors, xl, drawn, sel)
        if y is None:
            t = np.array((t_now,))
            w_now = self._signal(t, self.rows.all, True) if has_signal else self.rows.zero_w
            act = self.physics.actuator_states(sel) if self._reads_act else None
            y = self._measure(Sample(x, t, applied_rows, w_now, sel, act), self._noise_all, xi,
                              one=True)
            if row_plan is not None and not has_signal:  # (the suite was fused again)
                plan = state_row_plan(self.sensors)
                self._row_plan = (plan if plan is not None and plan.draws == self.draws.sensors
                                  else None)
        return y

    def _single_reference(self, t: float) -> list[float]:
        """The reference of the one member at ``t``, a list of floats (r,) (read only: the
        default table's may be returned)."""
        if len(self.schedules.tables) == 1:
            return self.schedules.table_lists[self._table_row(t)]
        return self._reference(np.array((t,)), self.rows.all).tolist()[0]
