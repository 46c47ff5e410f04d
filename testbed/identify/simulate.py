"""The rig simulated with a recording's inputs: K parameter sets (and segments) at once.

Every rollout goes through the project's simulator (:class:`testbed.sim.simulator.Simulator`:
one :mod:`mujoco.batch` of members, per-member parameters through ``reset(options={"params":
...})``, open-loop inputs per control step), so the hardware profile's actuator model (rotor
lag, deadband, the per-physics-step current limit) is the same code as in every run.

Control period: the recording's sample period ``dt_rec``. The physics step is the largest
``dt_rec / frame_skip`` not above ``physics_dt_max_s`` (1 ms): ``frame_skip = ceil(dt_rec /
physics_dt_max_s)``, so a period that is no multiple of 1 ms (e.g. 2.5 ms, 400 Hz) gets a
shorter physics step (0.833 ms, three per sample) rather than a drifting clock.

Input convention: ``inputs[k]`` is held over ``[t_k, t_{k+1})`` (what a logger records when
it writes the command computed at ``t_k``); ``channels[k]`` is measured at ``t_k`` and sees the
input held over the step before it (zero at the first sample), as the simulator's sensors do.

The prediction is the mean model: the rig's step noise (e.g. the vehicle's damping noise)
is held at zero, no disturbance, no sensor noise.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from testbed.identify.channels import (
    ChannelInfo,
    IdentificationError,
    channel_plan,
    check_channels,
    initial_state,
    measure_noise_free,
)
from testbed.identify.sensor_model import quantization_step, still_start
from testbed.io.recording import Recording
from testbed.records import field_values
from testbed.rigs.base import Params, Rig
from testbed.rigs.base import build_rig as base_build_rig
from testbed.sensors import NoiseStreams, StateChannel, Suite
from testbed.sim.simulator import SimulationDiverged, Simulator

_INTEGRATION = int(mujoco.mjtState.mjSTATE_INTEGRATION)
_ACT = int(mujoco.mjtState.mjSTATE_ACT)
_QPOS = int(mujoco.mjtState.mjSTATE_QPOS)
_QVEL = int(mujoco.mjtState.mjSTATE_QVEL)
#: Largest physics step, s (the rigs' default).
PHYSICS_DT_MAX_S = 0.001
#: Window of the local fits giving a segment's initial state, s (at least 9 samples).
INIT_WINDOW_S = 0.03


class _ZeroStreams(NoiseStreams):
    """Noise streams that give zeros: the rig's step noise at its mean."""

    def draw(self, d: int, members: Any = slice(None)) -> np.ndarray:
        return np.zeros((len(np.arange(len(self.generators))[members]), d))

    def draw_all(self, d: int) -> np.ndarray:
        return np.zeros((len(self.generators), d))


def build_rig(rig_cls: type[Rig], physics_dt_s: float, profile: str,
              options: dict[str, Any] | None) -> Rig:
    """``rig_cls`` at nominal parameters with its options checked
    (:func:`testbed.rigs.base.build_rig`)."""
    return base_build_rig(rig_cls, physics_dt_s=physics_dt_s, profile=profile,
                          options=rig_cls.resolve_options(options))


def check_recording(recording: Any, rig_cls: type[Rig]) -> None:
    """One-line ``IdentificationError`` for a recording the rig cannot be simulated with."""
    if not isinstance(recording, Recording):
        raise IdentificationError(f"recording must be a testbed.io.Recording, got "
                                  f"{type(recording).__name__}")
    t = np.asarray(recording.time_s, float)
    if t.ndim != 1 or len(t) < 10 or not np.all(np.isfinite(t)):
        raise IdentificationError(f"recording {recording.source}: time_s must be a finite 1-D "
                                  f"array of at least 10 samples, got shape {t.shape}")
    steps = np.diff(t)
    dt = float(np.median(steps))
    if not dt > 0 or np.max(np.abs(steps - dt)) > 0.01 * dt:
        raise IdentificationError(f"recording {recording.source}: time_s must be uniformly "
                                  f"sampled (steps within 1 % of {dt:g} s)")
    missing = [a for a in rig_cls.action_names if a not in recording.inputs]
    if missing:
        raise IdentificationError(f"recording {recording.source} has no input {missing[0]!r} of "
                                  f"rig {rig_cls.name!r} (inputs {list(rig_cls.action_names)})")
    for kind, table in (("input", recording.inputs), ("channel", recording.channels)):
        for name, values in table.items():
            v = np.asarray(values, float)
            if v.shape != t.shape or not np.all(np.isfinite(v)):
                raise IdentificationError(f"recording {recording.source}: {kind} {name!r} must "
                                          f"be finite with {len(t)} samples")


class RecordingModel:
    """A rig, its sensors and a recording: rollouts of parameter sets over segments.

    Parameters
    ----------
    rig_cls : type
        A :class:`~testbed.rigs.base.Rig` subclass.
    recording : Recording
    profile : str
    options : dict, optional
        The rig's construction options (:attr:`Rig.rig_options`).
    sensors : Sensor or str, optional
        The sensor suite (or preset name) that made the recording (default: the profile's
        default preset at the recording's period).
    channels : list of str, optional
        The channels used (default: every recorded channel the sensors measure).
    """

    def __init__(self, rig_cls: type[Rig], recording: Recording, *, profile: str,
                 options: dict[str, Any] | None = None, sensors: Any = None,
                 channels: Any = None, physics_dt_max_s: float = PHYSICS_DT_MAX_S):
        if not (isinstance(rig_cls, type) and issubclass(rig_cls, Rig)):
            raise IdentificationError(f"rig must be a testbed Rig subclass, got {rig_cls!r}")
        if profile not in rig_cls.profiles:
            raise IdentificationError(f"unknown profile {profile!r} for rig {rig_cls.name!r}; "
                                      f"expected one of {rig_cls.profiles}")
        check_recording(recording, rig_cls)
        self.rig_cls, self.recording, self.profile = rig_cls, recording, profile
        self.options = rig_cls.resolve_options(options)
        self.dt_s = recording.dt_s
        self.frame_skip = max(1, math.ceil(self.dt_s / physics_dt_max_s - 1e-9))
        self.physics_dt_s = self.dt_s / self.frame_skip
        self.rig = build_rig(rig_cls, self.physics_dt_s, profile, self.options)
        if sensors is None or isinstance(sensors, str):
            sensors = self.rig.sensors(sensors, dt_s=self.dt_s)
        self.sensors = sensors
        self.plan = channel_plan(sensors)
        self.infos: list[ChannelInfo] = check_channels(recording, self.plan, channels,
                                                       rig_cls.name)
        self.names = tuple(i.name for i in self.infos)
        self.y = recording.channel_matrix(self.names).astype(float)
        self.u = recording.input_matrix(tuple(rig_cls.action_names)).astype(float)
        low, high = np.asarray(self.rig.action_low, float), np.asarray(self.rig.action_high)
        clipped = np.clip(self.u, low, high)
        #: The input over the step before each sample (zero at the first), clipped.
        self.u_prev = np.vstack([np.zeros((1, self.u.shape[1])), clipped[:-1]])
        self.n = self.rig.n_states
        self.j = len(self.rig.joints)
        self.nominal: Params = self.rig.params
        self._sims: dict[int, Simulator] = {}
        steps = np.array([quantization_step(self.y[:, c]) for c in range(len(self.infos))])
        #: The quantization step of each channel (0: none).
        self.steps = steps
        #: ``(0, stop)`` when the recording starts at rest (:func:`still_start`): a rollout
        #: from its first sample starts from the channels' means there, rates zero.
        self.rest = still_start(self.u, self.y, steps)
        #: Channels whose bias the initial states are read with: those with a declared bias
        #: (a gyro's); a quantized position's fitted offset is not one.
        self.x0_bias_mask = np.array([i.bias for i in self.infos], bool)
        #: MuJoCo actuator states (the hardware profile's rotor lag) in the integration state
        #: rows: not measured; multiple shooting starts them from :meth:`actuator_track`.
        self.na = int(self.rig.model.na)
        offset = sum(mujoco.mj_stateSize(self.rig.model, 1 << b) for b in range(16)
                     if (_INTEGRATION & (1 << b)) and (1 << b) < _ACT)
        self._act_cols = slice(offset, offset + self.na)
        qpos = sum(mujoco.mj_stateSize(self.rig.model, 1 << b) for b in range(16)
                   if (_INTEGRATION & (1 << b)) and (1 << b) < _QPOS)
        qvel = sum(mujoco.mj_stateSize(self.rig.model, 1 << b) for b in range(16)
                   if (_INTEGRATION & (1 << b)) and (1 << b) < _QVEL)
        self._qpos_cols = qpos + self.rig.qpos_adr
        self._qvel_cols = qvel + self.rig.dof_adr
        self._act_track: np.ndarray | None = None
        #: Whether a fitted channel reads the actuator states (rollouts then keep them).
        self.reads_act = any(i.reads_act for i in self.infos)
        self.rollouts = 0  # member-steps simulated (for timings)
        # joint ranges of limited joints (a measured position just past a stop is clipped)
        model = self.rig.model
        self._ranges = []
        for i, name in enumerate(self.rig.joints):
            jid = self.rig.joint_id(name)
            if model.jnt_limited[jid]:
                self._ranges.append((i, *map(float, model.jnt_range[jid])))

    @property
    def n_samples(self) -> int:
        """Samples ``N`` of the recording."""
        return len(self.y)

    def _simulator(self, k: int) -> Simulator:
        sim = self._sims.get(k)
        if sim is None:
            bare = Suite(*[StateChannel(i, self.n, self.rig.n_actions, f"x{i}", "")
                           for i in range(self.n)])
            rig = build_rig(self.rig_cls, self.physics_dt_s, self.profile, self.options)
            threads = 1 if k < 48 else None
            sim = Simulator(rig, bare, k, self.frame_skip, num_threads=threads)
            sim.noise = _ZeroStreams(k, sim.noise.block)
            sim._noise_all = sim.noise.view(slice(None))
            self._sims[k] = sim
        return sim

    def clip_state(self, x: np.ndarray) -> np.ndarray:
        """States (S, n) the rig accepts: one past a joint's range (a quantized encoder just
        beyond a stop) has that position moved onto the range."""
        out = np.array(x, float).reshape(-1, self.n)
        envelope = self.rig.envelope
        for row in out:
            np.clip(row, -envelope, envelope, out=row)
            try:
                self.rig.validate_x0(row)
            except ValueError:
                for i, lo, hi in self._ranges:
                    row[i] = np.clip(row[i], lo, hi)
                self.rig.validate_x0(row)
        return out.reshape(np.shape(x))

    def initial_states(self, starts: np.ndarray, bias: np.ndarray, delay: np.ndarray,
                       window_s: float = INIT_WINDOW_S) -> np.ndarray:
        """Measured states at the sample indices ``starts`` (S,): shape (S, n)."""
        window = max(9, int(round(window_s / self.dt_s)))
        fallback = self.rig.default_x0()
        x = np.array([initial_state(self.infos, self.y, self.u_prev, int(s), self.dt_s, self.j,
                                    bias, delay, window, fallback, self.rest)
                      for s in starts])
        return np.clip(x, -self.rig.envelope, self.rig.envelope)

    def actuator_track(self) -> np.ndarray:
        """The actuator states (N, na) of a free run at nominal parameters over the whole
        recording: what the recorded inputs make of the rig's actuator dynamics (the
        helicopter's rotor speeds follow the voltages, whatever the body does)."""
        if self._act_track is None:
            x0 = self.initial_states(np.array([0]), np.zeros(len(self.infos)),
                                     np.zeros(len(self.infos), int))
            _, _, act = self.rollout([self.nominal], x0, np.array([0]), self.n_samples,
                                     with_act=True)
            self._act_track = act[0, 0]
        return self._act_track

    def rollout(self, params: list[Params], x0: np.ndarray, starts: np.ndarray,
                length: int, act0: np.ndarray | None = None, with_act: bool = False
                ) -> tuple[np.ndarray, ...]:
        """Simulate every parameter set from every segment's start.

        Parameters
        ----------
        params : list of Params, length P
        x0 : ndarray, shape (S, n)
            Each segment's initial state.
        starts : ndarray of int, shape (S,)
            Each segment's first sample.
        length : int
            Samples per segment ``L`` (the state at the start, then ``L - 1`` steps).
        act0 : ndarray, shape (S, na), optional
            Each segment's initial actuator states (default: MuJoCo's reset, zero).
        with_act : bool
            Also return the actuator states (P, S, L, na).

        Returns
        -------
        states : ndarray, shape (P, S, L, n)
            NaN after a member diverged (:class:`SimulationDiverged`).
        u_prev : ndarray, shape (P, S, L, nu)
            The input the simulator applied over the step before each sample.
        """
        P, S = len(params), len(starts)
        k = P * S
        sim = self._simulator(k)
        index = np.minimum(np.asarray(starts)[:, None] + np.arange(length)[None, :],
                           self.n_samples - 1)
        seg_u = self.u[index]  # (S, L, nu), the last input held past the end
        u_all = np.tile(seg_u, (P, 1, 1))  # member p * S + s
        x0 = np.tile(np.asarray(x0, float), (P, 1))
        sim.reset(options={"x0": self.clip_state(x0),
                           "params": [_as_scales(self.nominal, p) for p in params
                                      for _ in range(S)]})
        rows = sim.physics.state
        # the measured state itself, where the reset took it clipped onto a stop (a rig
        # resting on its stop sinks into the soft contact, past what validate_x0 accepts)
        rows[:, self._qpos_cols] = x0[:, :self.j]
        rows[:, self._qvel_cols] = x0[:, self.j:]
        if act0 is not None and self.na:
            rows[:, self._act_cols] = np.tile(np.asarray(act0, float).reshape(S, self.na),
                                              (P, 1))
        states = np.full((k, length, self.n), np.nan)
        applied = np.zeros((k, length, self.rig.n_actions))
        acts = np.zeros((k, length, self.na)) if with_act else None
        states[:, 0] = x0
        if with_act:
            acts[:, 0] = rows[:, self._act_cols]
        alive = np.arange(k)
        info_state, info_applied = sim.info["state"], sim.info["action_applied"]
        u_steps = np.ascontiguousarray(u_all.transpose(1, 0, 2))  # (L, k, nu)
        step_fn, act_cols = sim.step, self._act_cols
        whole = True
        for step in range(length - 1):
            try:
                if whole:  # every member (the common case: basic slices, no gathers)
                    step_fn(u_steps[step], checked=True)
                    states[:, step + 1] = info_state
                    applied[:, step + 1] = info_applied
                    if with_act:
                        acts[:, step + 1] = rows[:, act_cols]
                    continue
                sim.step(u_steps[step, alive], members=alive)
            except SimulationDiverged as err:
                alive = np.setdiff1d(alive, err.members)
                whole = False
                if not len(alive):
                    break
                states[alive, step + 1] = sim.physics.states(alive)
                applied[alive, step + 1] = np.clip(u_all[alive, step], sim.limits.low,
                                                   sim.limits.high)
                continue
            states[alive, step + 1] = info_state[alive]
            applied[alive, step + 1] = info_applied[alive]
            if with_act:
                acts[alive, step + 1] = rows[alive, act_cols]
        self.rollouts += k * (length - 1)
        shape = (P, S, length)
        out = (states.reshape(*shape, self.n), applied.reshape(*shape, -1))
        return out + (acts.reshape(*shape, self.na),) if with_act else out

    def measure(self, states: np.ndarray, u_prev: np.ndarray, delay: np.ndarray,
                act: np.ndarray | None = None) -> np.ndarray:
        """Noise-free measurement of rollouts, each channel ``delay`` samples late within its
        segment (its first value repeated, as :class:`~testbed.sensors.Delay`):
        (..., L, m). ``act`` (..., L, na): the rollouts' actuator states, for channels
        reading them."""
        lead = states.shape[:-1]
        h = measure_noise_free(self.infos, states.reshape(-1, self.n),
                               u_prev.reshape(-1, u_prev.shape[-1]),
                               np.zeros(int(np.prod(lead))),
                               None if act is None else act.reshape(-1, act.shape[-1])
                               ).reshape(*lead, len(self.infos))
        length = h.shape[-2]
        out = np.empty_like(h)
        for c, d in enumerate(np.asarray(delay, int)):
            index = np.clip(np.arange(length) - d, 0, None)
            out[..., c] = h[..., index, c]
        return out


def _as_scales(nominal: Params, params: Params) -> dict[str, float]:
    """``params`` as scale factors of ``nominal`` (the simulator's reset option)."""
    out = {}
    values = field_values(params)
    for name, b in field_values(nominal).items():
        a = values[name]
        if a != b:
            if b == 0:
                raise IdentificationError(f"parameter {name!r} has a nominal value of 0: it "
                                          "cannot be given as a scale factor")
            out[name] = a / b
    return out


def params_from_scales(rig_cls: type[Rig], nominal: Params, scales: Any,
                       names: tuple[str, ...] | None = None) -> list[Params]:
    """Parameter sets from scale factors: an array (K, p) over ``names`` (default the rig's
    :attr:`~testbed.rigs.base.Rig.identifiable` fields, in declaration order) or a list of
    ``{field: factor}`` dicts."""
    if isinstance(scales, dict):
        scales = [scales]
    if isinstance(scales, list | tuple) and all(isinstance(s, dict) for s in scales):
        out = []
        for s in scales:
            try:
                out.append(nominal.scaled(s))
            except ValueError as err:
                raise IdentificationError(f"params_scales: {err}") from None
        return out
    names = tuple(rig_cls.identifiable) if names is None else tuple(names)
    arr = np.asarray(scales, float)
    if arr.ndim != 2 or arr.shape[1] != len(names) or not np.all(np.isfinite(arr)):
        raise IdentificationError(f"params_scales must be a finite array (K, {len(names)}) over "
                                  f"{list(names)} or a list of dicts, got shape {arr.shape}")
    return params_from_scales(rig_cls, nominal, [dict(zip(names, row, strict=True))
                                                 for row in arr.tolist()])


def simulate_recording(rig_cls: type[Rig], recording: Recording, *, profile: str = "paper",
                       options: dict[str, Any] | None = None, params_scales: Any = None,
                       x0: np.ndarray | None = None, sensors: Any = None,
                       channels: Any = None, bias: dict[str, float] | None = None,
                       scale: dict[str, float] | None = None,
                       delay: dict[str, int] | None = None) -> np.ndarray:
    """Predicted channels of a recording for K parameter sets, from one batched simulation.

    Parameters
    ----------
    rig_cls : type
        A :class:`~testbed.rigs.base.Rig` subclass.
    recording : Recording
        Its inputs drive the simulation; its channels give the initial state.
    profile : str
        The rig's simulation profile (its actuator model).
    options : dict, optional
        The rig's construction options.
    params_scales : array (K, p) or list of K dicts, optional
        Scale factors of the nominal parameters: columns over the rig's ``identifiable``
        fields, or ``{field: factor}`` dicts. Default: one set, nominal.
    x0 : ndarray, shape (n,), optional
        Initial state (default: from the recorded channels, :func:`initial_state`).
    sensors : Sensor or str, optional
        The sensor suite (default: the profile's default preset).
    channels : list of str, optional
        Channels to predict (default: every recorded state channel the sensors have).
    bias, scale, delay : dict, optional
        The sensor model per channel: ``y = bias + (1 + scale) h(x(t - delay))``, delay
        in whole samples (default 0).

    Returns
    -------
    ndarray, shape (K, N, m)
        The predicted channels (in the order of ``channels``), channel units.
    """
    model = RecordingModel(rig_cls, recording, profile=profile, options=options,
                           sensors=sensors, channels=channels)
    sets = ([model.nominal] if params_scales is None
            else params_from_scales(rig_cls, model.nominal, params_scales))
    b, s, d = sensor_vectors(model.names, bias, scale, delay)
    if x0 is None:
        start = model.initial_states(np.array([0]), b, d)
    else:
        start = np.asarray(model.rig.validate_x0(x0), float)[None]
    if model.reads_act:
        states, u_prev, act = model.rollout(sets, start, np.array([0]), model.n_samples,
                                            with_act=True)
        h = model.measure(states[:, 0], u_prev[:, 0], d, act[:, 0])
    else:
        states, u_prev = model.rollout(sets, start, np.array([0]), model.n_samples)
        h = model.measure(states[:, 0], u_prev[:, 0], d)
    return b + (1.0 + s) * h


def sensor_vectors(names: tuple[str, ...], bias: dict | None, scale: dict | None,
                   delay: dict | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-channel bias, scale and delay vectors (m,) from dicts by channel name."""
    out = []
    for label, table, kind in (("bias", bias, float), ("scale", scale, float),
                               ("delay", delay, int)):
        table = dict(table or {})
        unknown = set(table) - set(names)
        if unknown:
            raise IdentificationError(f"{label} names channel {sorted(unknown)[0]!r}, not one of "
                                      f"{list(names)}")
        vec = np.array([kind(table.get(n, 0)) for n in names], dtype=kind)
        if kind is int and np.any(vec < 0):
            raise IdentificationError(f"{label} must be whole samples >= 0, got {table}")
        out.append(vec)
    return out[0], out[1], out[2]
