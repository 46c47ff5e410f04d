"""A matched design: the rig's continuous model augmented with what the rig and its sensors
declare (actuator states, bias random walks, whole-sample delays, input memory), the
channels' declared imperfections (:func:`channel_effects`) and the consider constants of
their sensitivity errors (:func:`consider_parameters`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from filters import DiscreteLinearSystem, LinearSystem
from testbed.design.mismatch import MatchedMismatch
from testbed.design.model import DesignModel, designer_extras
from testbed.sensors import Sensor


@dataclass(frozen=True)
class ChannelEffects:
    """What the sensor objects of one channel declare about its imperfections.

    Read from the decorators (:func:`channel_effects`): declared parameters only, never
    the values an episode draws.

    Attributes
    ----------
    delay : int
        Whole samples of delay (:class:`~testbed.sensors.Delay`).
    bias_walk : float
        Bias random-walk intensity, unit/sqrt(s) (:class:`~testbed.sensors.BiasRandomWalk`).
    bias0_std : float
        Standard deviation of the bias drawn at reset.
    scale_std : float
        Standard deviation of the sensitivity error drawn at reset
        (:class:`~testbed.sensors.ScaleFactor`).
    hold : int
        Samples a value is held (:class:`~testbed.sensors.SampleAndHold`).
    """

    delay: int = 0
    bias_walk: float = 0.0
    bias0_std: float = 0.0
    scale_std: float = 0.0
    hold: int = 1


def channel_effects(sensor: Sensor) -> list[ChannelEffects]:
    """The declared imperfections of every channel of a sensor (suite), in channel order."""
    from testbed.sensors import BiasRandomWalk, Decorator, Delay, SampleAndHold, ScaleFactor
    from testbed.sensors.base import Suite

    out = [dict(delay=0, bias_walk=0.0, bias0_std=0.0, scale_std=0.0, hold=1)
           for _ in range(sensor.dim)]

    def walk(s: Sensor, offset: int) -> None:
        if isinstance(s, Suite):
            for part in s.sensors:
                walk(part, offset)
                offset += part.dim
            return
        if not isinstance(s, Decorator):
            return
        for j in range(s.dim):
            e = out[offset + j]
            if isinstance(s, Delay):
                e["delay"] += s.samples
            elif isinstance(s, BiasRandomWalk):
                e["bias_walk"] = float(np.hypot(e["bias_walk"], s.walk[j]))
                e["bias0_std"] = float(np.hypot(e["bias0_std"], s.initial_std[j]))
            elif isinstance(s, ScaleFactor):
                e["scale_std"] = float(np.hypot(e["scale_std"], s.initial_std[j]))
            elif isinstance(s, SampleAndHold):
                e["hold"] *= s.every
        walk(s.inner, offset)

    walk(sensor, 0)
    return [ChannelEffects(**e) for e in out]


def consider_parameters(channels: list[tuple[int, str, float]], H: np.ndarray, D: np.ndarray,
                        B: np.ndarray, bias_columns: dict[int, int],
                        inputs: list[tuple[int, str, float]] = ()) -> list:
    """The consider constants of a design's sensitivity and input-scale errors.

    A channel ``y_i = (1 + s) signal_i + bias_i + noise`` has ``G = e_i H_i`` with the
    channel's own bias column removed and ``J = e_i D_i``; a measured input ``u_j`` with a
    scale error (``u_j = (1 + s) u_true``) has ``N = -B e_j e_j^T`` and ``J = -D e_j e_j^T``
    (to first order in ``s``).

    Parameters
    ----------
    channels : list of (row, name, std)
        Rows of ``H`` with their sensitivity error's standard deviation (0: none).
    H, D, B : ndarray, shapes (m, n), (m, k), (n, k)
        The discrete model.
    bias_columns : dict
        ``{row: column}`` of each row's own bias state.
    inputs : list of (input, name, std)

    Returns
    -------
    list of filters.schmidt.ConsiderParameter
    """
    from filters.schmidt import ConsiderParameter

    out = []
    k = D.shape[1]
    for row, name, std in channels:
        if not std:
            continue
        G, J = np.zeros_like(H), np.zeros_like(D)
        G[row] = H[row]
        if row in bias_columns:
            G[row, bias_columns[row]] = 0.0
        J[row] = D[row]
        out.append(ConsiderParameter(float(std), f"scale_{name}", measurement_state=G,
                                     measurement_input=J))
    for j, name, std in inputs:
        if not std:
            continue
        select = np.zeros((k, k))
        select[j, j] = 1.0
        out.append(ConsiderParameter(float(std), f"scale_{name}",
                                     transition_input=-B @ select,
                                     measurement_input=-D @ select))
    return out


def build_matched_design(rig, sensors: Sensor, dt_s: float, A: np.ndarray, B: np.ndarray,
                         Q: np.ndarray, x0: np.ndarray, P0: np.ndarray, *,
                         extra_states: tuple[tuple[str, str], ...] = (),
                         channels: np.ndarray | None = None,
                         rows: dict[int, np.ndarray] | None = None,
                         extra_R: dict[int, float] | None = None,
                         effects: list[ChannelEffects] | None = None,
                         paper_design: DesignModel | None = None,
                         input_transform: Callable | None = None,
                         output_matrix: np.ndarray | None = None,
                         disturbance_matrix: np.ndarray | None = None,
                         extras: dict[str, Any] | None = None,
                         input_noise_cov: np.ndarray | None = None,
                         extra_inputs: tuple[tuple[str, str], ...] = (),
                         input_memory_std: np.ndarray | None = None,
                         scale_R: dict[int, float] | None = None,
                         input_scales: dict[int, float] | None = None,
                         held_intensity: np.ndarray | None = None) -> DesignModel:
    """A design model augmented with what the rig and its sensors declare.

    State ``[physical (rig.n_states), extra (actuators...), biases, delays]``:

    - ``A, B, Q, x0, P0`` (continuous, the physical states first, then ``extra_states``);
    - one **bias state** per used channel with a declared bias (random walk of the declared
      intensity, prior variance the declared reset spread): ``y_i += b_i``;
    - one **delay state** per sample of a used channel's declared whole-sample delay: the
      discrete model shifts ``s_1 <- h_i x + d_i u``, ``s_j <- s_{j-1}`` exactly and the
      channel reads ``s_d``. Continuous time cannot hold a pure delay: ``design.continuous``
      has each shift as a first-order lag of time constant ``dt_s`` (Pade (0, 1)), so
      ``design.discrete`` is the ZOH of ``design.continuous`` except on the delay rows.

    Parameters
    ----------
    rig, sensors, dt_s
        As in :func:`build_design`.
    A, B, Q : ndarray, shapes (n0, n0), (n0, nu), (n0, n0)
        Continuous model of the physical and extra states (intensity ``Q``).
    x0, P0 : ndarray, shapes (n0,), (n0, n0)
    extra_states : tuple of (name, unit)
        The states after the physical ones in ``A``.
    channels : ndarray of int, optional
        Channels the design uses (default: the stochastic, non-input ones).
    rows : dict, optional
        ``{channel: row (n_rig,) or (n0,)}``: the channel's linearization instead of the
        sensor's (with ``n0`` entries it also reads the extra states).
    extra_R : dict, optional
        ``{channel: variance}`` added to the channel's per-sample noise variance.
    effects : list of ChannelEffects, optional
        Per channel of ``sensors`` (default :func:`channel_effects`).
    paper_design : DesignModel, optional
        Kept in ``extras["paper_design"]``.
    extra_inputs : tuple of (name, unit)
        Inputs after the rig's actions in ``B`` (computed by ``input_transform``).
    input_memory_std : ndarray, shape (nu,), optional
        The input the estimator receives is on time while the delayed channels' feedthrough
        ``d_i u`` is as late as the channel: add **input-memory states** ``p <- u`` (prior std
        this, mean 0) and feed the first delay stage ``d_i p`` (None: the input is as late
        as the delayed channels, e.g. computed from channels of the same delay).
    input_transform, output_matrix, disturbance_matrix, extras, input_noise_cov
        As in :func:`build_design` (``output_matrix`` in the rig's states: padded here).
    scale_R : dict, optional
        ``{channel: variance}``: the white-noise stand-in of the channel's declared
        sensitivity error (its variance at a design value of the signal), added to ``R`` for
        the families that cannot carry constants. The error itself, a constant per run, is
        a consider constant in ``extras["consider"]`` (:func:`consider_parameters`).
    input_scales : dict, optional
        ``{input: std}``: a measured input's scale error, a constant per run (the vehicle's
        speed): a consider constant too.
    held_intensity : ndarray, shape (n_rig, n_rig), optional
        The part of ``Q`` on the physical states that the simulator applies as white noise
        held over each physics step (the rig's own process noise): its per-sample
        covariance is the held one (:func:`testbed.design.held_noise.rig_held_noise`), the
        rest of ``Q`` (floors standing for unmodelled accelerations, actuator and bias
        noise) Van Loan's integral of the intensity. None: all of ``Q`` continuous.
    """
    model = sensors.linear_model()
    A, B, Q = (np.asarray(a, float) for a in (A, B, Q))
    index = (np.flatnonzero(model.stochastic & ~model.inputs) if channels is None
             else np.asarray(channels, int))
    effects = channel_effects(sensors) if effects is None else effects
    ch = _channels(rig, model, index, B.shape, rows, extra_R, scale_R, input_noise_cov)
    aug = _Augmented(names=list(rig.state_names) + [n for n, _ in extra_states],
                     units=list(rig.state_units) + [u for _, u in extra_states])
    biased, Pb, A1, B1, Q1, H1 = _bias_states(sensors, effects, index, ch.C0, A, B, Q, aug)
    delayed = [(pos, int(c), effects[c].delay) for pos, c in enumerate(index)
               if effects[c].delay > 0]
    n0, nu = B.shape
    nd = sum(d for *_, d in delayed)
    nm = nu if input_memory_std is not None and any(np.any(ch.D0[pos]) for pos, *_ in delayed) \
        else 0
    input_names = tuple(rig.action_names) + tuple(nm_ for nm_, _ in extra_inputs)
    input_units = tuple(rig.action_units) + tuple(un for _, un in extra_inputs)
    held = _held_part(rig, dt_s, A1, Q1, held_intensity)
    plant, discrete, T, (H, D, Bd) = _delay_states(sensors, delayed, ch, A1, B1, Q1, H1, n0,
                                                   nd, nm, dt_s, aug, input_names, input_units,
                                                   held)
    x0_full, P0_full = _prior(T, x0, P0, Pb, nm, input_memory_std)
    L, G = _padded_outputs(rig, plant.A.shape[0], output_matrix, disturbance_matrix)
    bias_columns = {pos: n0 + j for j, (pos, _) in enumerate(biased)}
    consider = consider_parameters(
        [(pos, sensors.names[c], effects[c].scale_std) for pos, c in enumerate(index)],
        H, D, Bd, bias_columns, [(j, input_names[j], std)
                                 for j, std in sorted((input_scales or {}).items())])
    declared = rig.parameter_mismatch()
    all_extras = {"cubic_model": None, "parameter_mismatch": None, **designer_extras(rig),
                  # the mismatch of this model: derivatives of the rebuilt designs' F
                  "matched_mismatch": None if declared is None
                  else MatchedMismatch(declared, sensors, float(dt_s)),
                  "consider": None if not consider else {"parameters": consider,
                                                         "R": ch.R_constants},
                  "paper_design": paper_design, "design_profile": "matched",
                  "augmentation": {"extra": [nm for nm, _ in extra_states],
                                   "biases": [sensors.names[c] for _, c in biased],
                                   "delays": {sensors.names[c]: d for _, c, d in delayed}},
                  **(extras or {})}
    return DesignModel(
        dt_s=float(dt_s), continuous=plant, discrete=discrete, x0=x0_full, P0=P0_full,
        state_names=tuple(aug.names), state_units=tuple(aug.units),
        input_names=input_names, input_units=input_units,
        measurement_names=tuple(sensors.names), measurement_units=tuple(sensors.units),
        measurement_index=index, sensors=model, output_matrix=L,
        disturbance_matrix=G, input_transform=input_transform, extras=all_extras,
        physical_index=np.arange(rig.n_states))


@dataclass
class _Channels:
    """The used channels' rows of a matched design before its augmentation: ``C0`` (k, n0),
    ``D0`` (k, nu), ``R`` (k, k) per sample with the sensitivity errors' white stand-ins,
    ``R_constants`` without them."""

    C0: np.ndarray
    D0: np.ndarray
    R: np.ndarray
    R_constants: np.ndarray


@dataclass
class _Augmented:
    """The names and units of a matched design's states, in order, as they are added."""

    names: list[str]
    units: list[str]


def _channels(rig, model: Any, index: np.ndarray, shape: tuple[int, int],
              rows: dict[int, np.ndarray] | None, extra_R: dict[int, float] | None,
              scale_R: dict[int, float] | None, input_noise_cov: np.ndarray | None
              ) -> _Channels:
    """The used channels' linear model on the physical and extra states (``shape`` is
    ``B``'s: ``(n0, nu)``), the rig's linearizations in ``rows`` in place of the sensors'."""
    nr, nu_rig = rig.n_states, len(rig.action_names)
    n0, nu = shape
    C0 = np.zeros((len(index), n0))
    C0[:, :nr] = model.C[index]
    for pos, ch in enumerate(index):
        if rows is not None and int(ch) in rows:
            row = np.asarray(rows[int(ch)], float)
            C0[pos, :len(row)] = row
    D0 = np.zeros((len(index), nu))
    D0[:, :nu_rig] = model.D[index]
    R = model.R[np.ix_(index, index)].astype(float)
    if input_noise_cov is not None:
        R = R + D0[:, :nu_rig] @ np.asarray(input_noise_cov, float) @ D0[:, :nu_rig].T
    for pos, ch in enumerate(index):
        R[pos, pos] += (extra_R or {}).get(int(ch), 0.0)
    R_constants = R.copy()  # without the white-noise stand-ins of the constants
    for pos, ch in enumerate(index):
        R[pos, pos] += (scale_R or {}).get(int(ch), 0.0)
    return _Channels(C0=C0, D0=D0, R=R, R_constants=R_constants)


def _bias_states(sensors: Sensor, effects: list[ChannelEffects], index: np.ndarray,
                 C0: np.ndarray, A: np.ndarray, B: np.ndarray, Q: np.ndarray,
                 aug: _Augmented) -> tuple[list[tuple[int, int]], np.ndarray, np.ndarray,
                                           np.ndarray, np.ndarray, np.ndarray]:
    """One random-walk bias state per used channel with a declared bias: the biased
    ``(row, channel)`` pairs, their prior ``Pb``, and ``A1, B1, Q1, H1`` with them."""
    from scipy.linalg import block_diag

    n0, nu = B.shape
    biased = [(pos, int(ch)) for pos, ch in enumerate(index)
              if effects[ch].bias_walk > 0 or effects[ch].bias0_std > 0]
    nb = len(biased)
    Qb = np.diag([effects[ch].bias_walk ** 2 for _, ch in biased]) if nb else np.zeros((0, 0))
    Pb = np.diag([effects[ch].bias0_std ** 2 for _, ch in biased]) if nb else np.zeros((0, 0))
    for _, ch in biased:
        aug.names.append(f"bias_{sensors.names[ch]}")
        aug.units.append(sensors.units[ch])
    A1 = block_diag(A, np.zeros((nb, nb)))
    B1 = np.vstack([B, np.zeros((nb, nu))])
    Q1 = block_diag(Q, Qb)
    H1 = np.hstack([C0, np.zeros((len(index), nb))])
    for j, (pos, _) in enumerate(biased):
        H1[pos, n0 + j] = 1.0
    return biased, Pb, A1, B1, Q1, H1


def _held_part(rig, dt_s: float, A1: np.ndarray, Q1: np.ndarray,
               held_intensity: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
    """``(intensity, per-sample covariance)`` of the rig's held process noise, both padded to
    ``Q1``'s shape (None: no held part, or one the simulator's integrator does not hold)."""
    from testbed.design.held_noise import rig_held_noise

    if held_intensity is None:
        return None
    n = rig.n_states
    intensity = np.zeros_like(Q1)
    intensity[:n, :n] = np.asarray(held_intensity, float)
    covariance = rig_held_noise(rig, dt_s, A1, intensity)
    if covariance is None:
        return None
    padded = np.zeros_like(Q1)
    padded[:n, :n] = covariance
    return intensity, padded


def _delay_states(sensors: Sensor, delayed: list[tuple[int, int, int]], ch: _Channels,
                  A1: np.ndarray, B1: np.ndarray, Q1: np.ndarray, H1: np.ndarray, n0: int,
                  nd: int, nm: int, dt_s: float, aug: _Augmented,
                  input_names: tuple[str, ...], input_units: tuple[str, ...],
                  held: tuple[np.ndarray, np.ndarray] | None = None
                  ) -> tuple[LinearSystem, DiscreteLinearSystem, np.ndarray,
                             tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The delay states (a shift register per delayed channel) and the input-memory states
    after the bias-augmented model: the continuous and discrete models, the map ``T`` of the
    bias-augmented prior to the delays' (the first sample repeats), and the discrete ``H``,
    ``D`` (zeros included) and ``B``."""
    from scipy.linalg import block_diag

    n1, nu = B1.shape
    C0, D0 = ch.C0, ch.D0
    km = n1 + nd  # the input-memory states
    n = km + nm
    Ac, Bc = np.zeros((n, n)), np.zeros((n, nu))
    Ac[:n1, :n1], Bc[:n1] = A1, B1
    F, Bd = np.zeros((n, n)), np.zeros((n, nu))
    # the continuous noise covariance for all but the rig's held noise: on the hardware
    # profile the unmodelled accelerations (Coulomb friction, stops, deadband) are not white
    # noise held over the period, and a held covariance for them (near-singular
    # position-rate blocks) would make the filter trust what they break (the helicopter's
    # NEES 30 of 4); the rig's own noise is held (NEES 2.83 -> 4.02 with it)
    Qc = Q1 if held is None else Q1 - held[0]
    disc = LinearSystem(A=A1, B=B1, C=np.zeros((1, n1)), Q=Qc, R=np.eye(1)).discretize(dt_s)
    Qd1 = np.array(disc.Q) if held is None else np.array(disc.Q) + held[1]
    F[:n1, :n1], Bd[:n1] = disc.F, disc.B
    H = np.hstack([H1, np.zeros((len(C0), nd + nm))])
    D = D0.copy()
    T0 = [np.eye(n1)]  # prior of the delay states: the first sample repeats (s_j = h x0)
    k = n1
    for pos, c, d in delayed:
        src_x, src_u = C0[pos], D0[pos]
        for j in range(d):
            aug.names.append(f"{sensors.names[c]}_delay{j + 1}")
            aug.units.append(sensors.units[c])
            if j == 0 and nm:
                F[k, :n0], F[k, km:] = src_x, src_u
                Ac[k, :n0], Ac[k, km:] = src_x / dt_s, src_u / dt_s
            elif j == 0:
                F[k, :n0], Bd[k] = src_x, src_u
                Ac[k, :n0], Bc[k] = src_x / dt_s, src_u / dt_s
            else:
                F[k, k - 1] = 1.0
                Ac[k, k - 1] = 1.0 / dt_s
            Ac[k, k] = -1.0 / dt_s
            row = np.zeros(n1)
            row[:n0] = src_x
            T0.append(row[None])
            k += 1
        H[pos, :n0] = 0.0
        H[pos, k - 1] = 1.0
        D[pos] = 0.0
    if nm:
        F[km:, km:], Bd[km:] = 0.0, np.eye(nu)
        Ac[km:, km:], Bc[km:] = -np.eye(nu) / dt_s, np.eye(nu) / dt_s
        aug.names.extend(f"{name}_prev" for name in input_names)
        aug.units.extend(input_units)
    Qc = block_diag(Q1, np.zeros((nd + nm, nd + nm)))
    has_d = bool(np.any(D))
    plant = LinearSystem(A=Ac, B=Bc, C=H, Q=Qc, R=ch.R * dt_s, D=D if has_d else None)
    discrete = DiscreteLinearSystem(F=F, B=Bd, H=H, Q=block_diag(Qd1,
                                                                 np.zeros((nd + nm, nd + nm))),
                                    R=ch.R, dt_s=dt_s, D=D if has_d else None)
    return plant, discrete, np.vstack(T0), (H, D, Bd)


def _prior(T: np.ndarray, x0: np.ndarray, P0: np.ndarray, Pb: np.ndarray, nm: int,
           input_memory_std: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The augmented prior: mean and covariance of ``[x, biases, delays, input memory]``."""
    from scipy.linalg import block_diag

    nb = Pb.shape[0]
    x0_full = np.concatenate([T @ np.concatenate([np.asarray(x0, float), np.zeros(nb)]),
                              np.zeros(nm)])
    P0_full = block_diag(T @ block_diag(np.asarray(P0, float), Pb) @ T.T,
                         np.diag(np.asarray(input_memory_std, float) ** 2) if nm
                         else np.zeros((0, 0)))
    return x0_full, P0_full


def _padded_outputs(rig, n: int, output_matrix: np.ndarray | None,
                    disturbance_matrix: np.ndarray | None
                    ) -> tuple[np.ndarray, np.ndarray | None]:
    """The output matrix ``L`` (p, n) and disturbance matrix ``G`` (n, s) or None, given in
    the rig's states, padded with zeros to the ``n`` design states."""
    nr = rig.n_states
    if output_matrix is None:
        output_matrix = np.eye(nr)[rig.tracked_index]
    L = np.zeros((len(output_matrix), n))
    L[:, :nr] = output_matrix
    G = None
    if disturbance_matrix is not None:
        G = np.zeros((n, np.shape(disturbance_matrix)[1]))
        G[:nr] = np.asarray(disturbance_matrix, float)[:nr]
    return L, G
