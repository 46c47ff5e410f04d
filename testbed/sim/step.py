"""The step of N members, batch-first (the simulator's module docstring gives its semantics):
action checks and clipping, input profiles, step noise, disturbance forces, the physics,
the divergence check, reference and reward, the sensors, ``info``.

:class:`BatchStep` is the part of :class:`~testbed.sim.simulator.Simulator` that steps;
a one-member simulator's step is :mod:`testbed.sim.step_one`'s.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from filters import real_array
from testbed.sensors import Drawn, Sample
from testbed.sensors.fused import measure_one
from testbed.sim.errors import SimulationDiverged


class BatchStep:
    """:meth:`step` of any members (a part of :class:`~testbed.sim.simulator.Simulator`)."""

    def check_actions(self, actions: Any, k: int) -> np.ndarray:
        """``actions`` as a finite float array of shape (k, nu), else ``ValueError``."""
        if (type(actions) is np.ndarray and actions.dtype == np.float64
                and actions.shape == (k, self.sizes.actions)
                and np.count_nonzero(np.isfinite(actions)) == actions.size):
            return actions  # used as it is: a step keeps none of it
        u = real_array(actions, "actions", finite=False)
        if u.shape != (k, self.sizes.actions):
            raise ValueError(f"actions must have shape ({k}, {self.sizes.actions}) "
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
            index, sel, k, low, high, envelope, zero_u, zero_accel, zero_w = self.rows.whole
            common = self._same_steps
        else:
            index = sel = np.asarray(members, int)
            k = len(index)
            if np.count_nonzero(self._ready[index]) != k:
                raise RuntimeError("reset() every member before stepping it")
            low, high, envelope = self.limits.low, self.limits.high, self.limits.envelope
            zero_u, zero_accel = self.rows.zero_input[:k], self.rows.zero_accel[:k]
            zero_w = self.rows.zero_w[:k]
            common = False
        u = actions if checked else self.check_actions(actions, k)
        rig, physics, info = self.rig, self.physics, self.info
        has_signal, dist_active = self.inputs.has_signal, self.inputs.active
        # every member at one time with the one default profile: the profile from a float
        no_manoeuvre = self.schedules.none
        one_profile = common and not no_manoeuvre and len(self.schedules.profiles) == 1
        t = None
        if has_signal or not (no_manoeuvre or one_profile):
            t = self.steps[sel] * self.dt_s
        applied, clipped, clipped_out, profile = self._applied(u, t, sel, k, low, high, zero_u,
                                                               common, members is None)
        # the step's normals in one draw, in stream order: step noise, disturbance, sensors
        if members is None:  # (every stream: drawn without the view's selection test)
            noise = self._noise_all
            xi = self.noise.draw_all(self.draws.step) if self.draws.step else None
        else:
            noise = self.noise.view(index)
            xi = noise.normal(self.draws.step) if self.draws.step else None
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
            steps = self.steps + self.rows.one  # (faster than an in-place np.add(out=))
            self.steps[...] = steps
            t = steps * self.rows.dt
        else:
            steps = self.steps[sel] + 1
            self.steps[sel] = steps
            t = steps * self.dt_s
            self._same_steps = False
        x = physics.states(sel)
        inside = np.less_equal(np.abs(x), envelope)  # NaN compares False
        if warned or np.count_nonzero(inside) != inside.size:
            self._diverged(index, physics.unstable[sel], ~inside.all(axis=1), x, t)
        ref = self._score(x, t, sel, common, members is None)
        w_now = self._signal(t, index, common) if has_signal else zero_w
        self.obs[sel] = self._measure(
            Sample(x, t, applied, w_now, sel,
                   physics.actuator_states(sel) if self._reads_act else None), noise, xi)
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

    def _applied(self, u: np.ndarray, t: np.ndarray | None, sel: Any, k: int,
                 low: np.ndarray, high: np.ndarray, zero_u: np.ndarray, common: bool,
                 whole: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
        """The applied input (k, nu): the action clipped, plus the input profile, clipped
        again; the clipped flags, the info array they were written into (the whole batch's)
        or None, and the profile."""
        # clip(u, low, high) is min(max(u, low), high), bitwise (u is finite)
        clipped_u = np.minimum(np.maximum(u, low), high)
        # the whole batch's flags go straight into info (no one else reads them)
        clipped_out = self.info["action_clipped"] if whole else None
        if self.schedules.none:  # the profile is zero: clipped + 0 needs no second clip
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
        return applied, clipped, clipped_out, profile

    def _score(self, x: np.ndarray, t: np.ndarray, sel: Any, common: bool,
               whole: bool) -> np.ndarray:
        """The reward (minus the tracked states' squared error) and termination of the
        members into their arrays; the reference (the setpoint rows) returned."""
        r = self.scoring.count
        one_row = common and len(self.schedules.tables) == 1
        if one_row:  # one row (1, r), broadcast, not repeated
            row = self._table_row(t.item(0))
            ref = self.schedules.table_rows[row]
        else:
            ref = self._reference(t, sel, common)
        if one_row and r == 1:  # the tracked column (1-D: numpy's one loop) minus the row's
            # float: the same differences and squares
            e = x[:, self.scoring.columns[0]] - self.schedules.table_lists[row][0]
            total = e * e
        else:
            e = x[:, self.scoring.cols] - ref
            sq = e * e
            if r == 2:  # the two squares' sum is add.reduce's, bitwise (squares are >= +0)
                total = sq[:, 0] + sq[:, 1]
            else:
                total = sq[:, 0] if r == 1 else np.add.reduce(sq, axis=1)
        if whole:
            np.negative(total, self.reward)
        else:
            self.reward[sel] = -total
        if self.scoring.terminates:  # the base Rig.terminated never ends an episode
            self.terminated[sel] = self.rig.terminated(x)
        return ref

    def _forces(self, t: np.ndarray | None, index: np.ndarray, sel: Any, common: bool,
                xi: np.ndarray | None, zero_accel: np.ndarray
                ) -> tuple[np.ndarray | None, Any, np.ndarray]:
        """The disturbance of a step: the signal ``w`` (k, s) (the one reset wrote when
        there is none; None when there is neither a signal nor ``G``: no one reads it), the
        joint accelerations ``G w + b xi / sqrt(dt)`` (k, j) and the generalized forces
        ``M(q) a`` (k, nv) of the members."""
        inputs = self.inputs
        G_rows, b_rows, sqrt_dt = inputs.G_rows, inputs.b_rows, inputs.sqrt_dt
        w = None
        if inputs.has_signal:
            w = self._signal(t, index, common)
        elif G_rows is not None:
            w = self.info["disturbance"][sel]
        accel: Any = zero_accel
        if G_rows is not None:
            accel = accel + np.matvec(G_rows, w)
        if b_rows is not None:
            n_step = self.rig.step_noise_dim
            drawn = xi[:, n_step:n_step + self.draws.disturbance]
            # accel + (b xi) / sqrt(dt): the division and the sum into the new product
            noise = np.matvec(b_rows, drawn)
            np.divide(noise, sqrt_dt, out=noise)
            accel = np.add(accel, noise, out=noise)
        if isinstance(sel, slice):  # the whole batch: its rows, zero outside the dof columns
            a = self.rows.accel
            a[:, inputs.dof_cols] = accel
            mass = self.physics.mass  # (every row: the array itself, as its view would be)
        else:
            a = np.zeros((len(index), self.physics.nv))
            a[:, inputs.dof_adr] = accel
            mass = self.physics.mass[sel]
        return w, accel, np.matvec(mass, a)

    def _measure(self, sample: Sample, noise: Any, xi: np.ndarray | None,
                 one: bool = False) -> Any:
        """The sensors' sample (k, m): with the normals drawn ahead ``xi`` when they declare
        how many they draw (checked), else from the streams ``noise``. ``one``: of one
        member, the row as :func:`~testbed.sensors.fused.measure_one` gives it (a list of
        floats (m,) or a (1, m) array: the same values)."""
        sensors = self.sensors
        if self.draws.sensors is None:  # the sensors draw from the streams themselves
            return measure_one(sensors, sample, noise) if one else sensors.measure(sample, noise)
        drawn_ahead = (Drawn(xi[:, self.draws.sensor_offset:])
                       if self.draws.sensors else self._no_draws)
        y = (measure_one(sensors, sample, drawn_ahead) if one
             else sensors.measure(sample, drawn_ahead))
        if drawn_ahead.position != self.draws.sensors:
            self._no_draws.position = 0
            raise RuntimeError(f"the sensors ({self.sensors.describe()}) drew "
                               f"{drawn_ahead.position} normals per sample but declare "
                               f"{self.draws.sensors} (draws_per_sample)")
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
            c = int(np.flatnonzero(np.abs(x[j]) > self.limits.envelope)[0])
            reason = "outside envelope"
            why = (f"{names[c]} = {x[j, c]:.6g} {units[c]} is outside the rig's envelope "
                   f"|{names[c]}| <= {self.limits.envelope[c]:g} {units[c]}")
        state = ", ".join(f"{n} {v:.6g}" for n, v in zip(names, x[j], strict=True))
        raise SimulationDiverged(
            f"simulation diverged at t = {t[j]:.6g} s (member {int(index[j])}"
            f"{f' and {int(bad.sum()) - 1} more' if bad.sum() > 1 else ''}): {why}; state "
            f"[{state}]", time_s=float(t[j]), state=x[bad].copy(),
            members=index[bad].tolist(), reason=reason)
