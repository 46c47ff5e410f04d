"""The design model: what a filter designer knows about a rig, its sensors and its period.

An estimator factory (:mod:`testbed.estimators`) receives a :class:`DesignModel` and nothing
else: the rig's nominal linear model (never the simulated, possibly mismatched truth), the
configured sensors' linear model, noise covariances, the prior, names and units.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from filters import DiscreteLinearSystem, LinearSystem
from testbed.design.held_noise import rig_held_noise
from testbed.design.mismatch import MatchedMismatch
from testbed.sensors import Sensor, SensorModel


@dataclass
class DesignModel:
    """Linear models, noise, prior and names of one rig + sensors + control period.

    Attributes
    ----------
    dt_s : float
        Control (sampling) period, s.
    continuous : filters.LinearSystem
        ``dx = (A x + B u) dt + dW``, ``cov = Q dt``; ``y dt = C x dt + D u dt + dV`` with
        intensity ``R`` (= per-sample covariance times ``dt_s``). Only the stochastic
        channels (``measurement_index``).
    discrete : filters.DiscreteLinearSystem
        Exact zero-order-hold discretization at ``dt_s``: ``F, B, H, Q, R`` with ``Q``, ``R``
        per-sample covariances.
    x0 : ndarray, shape (n,)
        Prior mean.
    P0 : ndarray, shape (n, n)
        Prior covariance.
    state_names, state_units, input_names, input_units : tuple of str
    measurement_names, measurement_units : tuple of str
        All sensor channels (the ``y`` an estimator's ``step`` receives).
    measurement_index : ndarray of int
        Channels of ``y`` that ``continuous``/``discrete`` model (the stochastic ones; not
        the channels an input is computed from, ``sensors.inputs``).
    sensors : SensorModel
        Linear model of every channel (``C``, ``D``, ``R``, ``Hw``, ``stochastic``).
    output_matrix : ndarray, shape (q, n)
        ``L`` of the estimated output ``z = L x`` (the tracked states).
    disturbance_matrix : ndarray, shape (n, s) or None
        ``G`` of the deterministic disturbance ``G w(t)`` in the state equation.
    input_transform : callable ``(u (k, nu), x_hat (k, n)) -> (k, nu)``
        Applied by the loop before ``u`` reaches the estimator (e.g. minus the voltage that
        compensates gravity at the estimate): ``u`` of ``step`` is in the model's coordinates.
    extras : dict
        Rig-specific design data (paper models, LMI design systems); ``cubic_model`` is the
        rig's :meth:`~testbed.rigs.base.Rig.cubic_model` and ``parameter_mismatch`` its
        :meth:`~testbed.rigs.base.Rig.parameter_mismatch` (both set by :func:`build_design`).
        A matched design (:func:`build_matched_design`) has no ``parameter_mismatch`` (its
        states are not the linearization's) but ``matched_mismatch``
        (:class:`~testbed.design.mismatch.MatchedMismatch`: derivatives of its own discrete
        model, the design rebuilt at scaled parameters). It keeps the rig's paper design in
        ``extras["paper_design"]`` (the fallback of estimator families that cannot use an
        augmented model, and the controller's model).
    physical_index : ndarray of int, shape (n_rig,), or None
        Where the rig's physical states (``x = [positions, velocities]``, the rig's order)
        sit in the design state. None: the design state *is* the rig's state. An augmented
        design (actuator, sensor-bias and delay states) sets it; the loop and the metrics
        compare ``x[..., physical_index]`` with the truth and use the marginal covariance
        ``P[..., physical_index, physical_index]``.
    """

    dt_s: float
    continuous: LinearSystem
    discrete: DiscreteLinearSystem
    x0: np.ndarray
    P0: np.ndarray
    state_names: tuple[str, ...]
    state_units: tuple[str, ...]
    input_names: tuple[str, ...]
    input_units: tuple[str, ...]
    measurement_names: tuple[str, ...]
    measurement_units: tuple[str, ...]
    measurement_index: np.ndarray
    sensors: SensorModel
    output_matrix: np.ndarray
    disturbance_matrix: np.ndarray | None = None
    input_transform: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    extras: dict[str, Any] = field(default_factory=dict)
    physical_index: np.ndarray | None = None

    @property
    def n(self) -> int:
        """State dimension."""
        return len(self.state_names)

    @property
    def physical(self) -> np.ndarray:
        """:attr:`physical_index`, or every state when the design is not augmented."""
        if self.physical_index is None:
            return np.arange(self.n)
        return np.asarray(self.physical_index, dtype=int)

    @property
    def augmented(self) -> bool:
        """Whether the design state has more than the rig's physical states."""
        return self.physical_index is not None and len(self.physical_index) != self.n

    @property
    def deterministic_index(self) -> np.ndarray:
        """Channels that are noise-free functions of ``x`` and ``w`` (``y2 = C2 x + H w``)."""
        return np.flatnonzero(~self.sensors.stochastic & ~self.sensors.inputs)


@dataclass(frozen=True, eq=False)
class InputStates:
    """How a matched design's extra states reach the rig's physical input (for the
    nonlinear filters; :class:`testbed.estimators.nonlinear.PhysicalInput`).

    The rig's input over a control period is ``w = o(x) + from_input (u - [o(x), 0]) +
    from_states e`` with ``o`` the rig's operating input (zero for a design without an input
    transform) and ``e`` the extra states (after the rig's in the design state). Extra states
    that are inputs relative to the operating input (a motor's lagged voltage above the
    gravity-compensating one) have ``relative = I`` on those rows: ``e + relative o(x)`` is
    absolute.

    Attributes
    ----------
    from_input : ndarray, shape (k_rig, k)
    from_states : ndarray, shape (k_rig, n_e)
    relative : ndarray, shape (n_e, k_rig)
    """

    from_input: np.ndarray
    from_states: np.ndarray
    relative: np.ndarray

    def check(self, k_rig: int, k: int, n_e: int) -> None:
        """Raise ``ValueError`` unless the shapes are ``(k_rig, k)``, ``(k_rig, n_e)`` and
        ``(n_e, k_rig)`` and the entries finite."""
        for name, shape in (("from_input", (k_rig, k)), ("from_states", (k_rig, n_e)),
                            ("relative", (n_e, k_rig))):
            value = np.asarray(getattr(self, name), float)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise ValueError(f"InputStates.{name} must be finite with shape {shape}, got "
                                 f"shape {value.shape}")


def build_design(rig, sensors: Sensor, dt_s: float, A: np.ndarray, B: np.ndarray,
                 Q: np.ndarray, x0: np.ndarray, P0: np.ndarray, *,
                 disturbance_matrix: np.ndarray | None = None,
                 input_transform: Callable | None = None,
                 output_matrix: np.ndarray | None = None,
                 extras: dict[str, Any] | None = None,
                 input_noise_cov: np.ndarray | None = None,
                 held_noise: bool = False) -> DesignModel:
    """A :class:`DesignModel` from continuous ``A, B, Q`` and the sensors' linear model.

    Parameters
    ----------
    rig : testbed.rigs.base.Rig
        Names and units.
    sensors : Sensor
    dt_s : float
    A, B, Q : ndarray, shapes (n, n), (n, nu), (n, n)
        Continuous model and process-noise intensity.
    x0, P0 : ndarray
        Prior.
    disturbance_matrix, input_transform, output_matrix, extras
        See :class:`DesignModel`; ``output_matrix`` defaults to the tracked states' rows.
    input_noise_cov : ndarray, shape (nu, nu), optional
        Per-sample covariance of the error of a measured input (the input transform's
        output): adds ``D S D^T`` to ``R`` of the channels the input enters.
    """
    model = sensors.linear_model()
    index = np.flatnonzero(model.stochastic & ~model.inputs)
    C, D, R = model.C[index], model.D[index], model.R[np.ix_(index, index)]
    if input_noise_cov is not None:
        R = R + D @ np.asarray(input_noise_cov, float) @ D.T
    has_d = bool(np.any(D))
    plant = LinearSystem(A=A, B=B, C=C, Q=Q, R=R * dt_s, D=D if has_d else None)
    if output_matrix is None:
        output_matrix = np.eye(rig.n_states)[rig.tracked_index]
    discrete = plant.discretize(dt_s)
    held = rig_held_noise(rig, dt_s, np.asarray(A, float), np.asarray(Q, float)) \
        if held_noise else None
    if held is not None:
        discrete = DiscreteLinearSystem(F=discrete.F, B=discrete.B, H=discrete.H, Q=held,
                                        R=discrete.R, dt_s=dt_s, D=discrete.D)
    return DesignModel(
        dt_s=float(dt_s), continuous=plant, discrete=discrete,
        x0=np.asarray(x0, float), P0=np.asarray(P0, float),
        state_names=tuple(rig.state_names), state_units=tuple(rig.state_units),
        input_names=tuple(rig.action_names), input_units=tuple(rig.action_units),
        measurement_names=tuple(sensors.names), measurement_units=tuple(sensors.units),
        measurement_index=index, sensors=model, output_matrix=np.asarray(output_matrix, float),
        disturbance_matrix=disturbance_matrix, input_transform=input_transform,
        extras={"cubic_model": getattr(type(rig), "cubic_model", None),
                "parameter_mismatch": _mismatch(rig), **_designer(rig), **(extras or {})})


def _designer(rig) -> dict[str, Any]:
    """The designer's rig as the nonlinear filters rebuild it: its class, physics step,
    nominal parameters and options (``extras["rig_type"]``, ``["physics_dt_s"]``,
    ``["rig_params"]``, ``["rig_options"]``)."""
    model = getattr(rig, "model", None)
    return {"rig_type": type(rig),
            "physics_dt_s": None if model is None else float(model.opt.timestep),
            "rig_params": getattr(rig, "params", None),
            "rig_options": dict(getattr(rig, "options", None) or {})}


def _mismatch(rig) -> Any:
    """The rig's :class:`~testbed.rigs.base.ParameterMismatch` (None without one)."""
    declared = getattr(rig, "parameter_mismatch", None)
    return None if declared is None else declared()


def rate_noise(n_states: int, n_joints: int, intensity: float,
               disturbance: Any = None) -> tuple[np.ndarray, np.ndarray | None]:
    """A design's process noise: ``intensity`` on each velocity row (unmodelled
    accelerations), plus the disturbance's white-noise intensity; and its ``G``.

    Parameters
    ----------
    n_states, n_joints : int
        The state ``[positions (n_joints), velocities]``.
    intensity : float
        Per velocity row, (unit/s)^2 / s.
    disturbance : testbed.rigs.disturbances.Disturbance, optional

    Returns
    -------
    Q : ndarray, shape (n, n)
    G : ndarray, shape (n, s), or None
    """
    Q = np.zeros((n_states, n_states))
    Q[n_joints:, n_joints:] += intensity * np.eye(n_states - n_joints)
    G = None
    if disturbance is not None:
        if disturbance.intensity is not None:
            Q = Q + disturbance.intensity
        G = disturbance.G
    return Q, G


def design_from_linearization(rig, sensors: Sensor, dt_s: float, disturbance=None, *,
                              process_noise: float = 0.01, prior_std: float = 0.1
                              ) -> DesignModel:
    """The default design model: MuJoCo's linearization with nominal parameters.

    ``A, B`` from :meth:`Rig.linearize` at the rig's linearization point; ``Q`` is the
    disturbance's white-noise intensity plus ``process_noise`` on each velocity row; the
    prior is the rig's default initial state with ``P0 = prior_std^2 I``; the input is
    taken relative to :meth:`Rig.operating_input` at the estimate.
    """
    for name, value in (("process_noise", process_noise), ("prior_std", prior_std)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be finite and >= 0, got {value}")
    nominal = rig.params  # the designer's rig: nominal, or a twin's values
    A, B = rig.linearize()
    Q, G = rate_noise(rig.n_states, len(rig.joints), process_noise, disturbance)

    def relative_input(u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
        return u - rig.operating_input(nominal, x_hat)

    return build_design(rig, sensors, dt_s, A, B, Q, rig.default_x0(),
                        prior_std**2 * np.eye(rig.n_states), disturbance_matrix=G,
                        input_transform=relative_input)


#: Design profiles: ``matched`` (the model of the rig as its profile declares it) and
#: ``paper`` (the papers' model whatever the profile: a deliberate model-mismatch study).
DESIGN_PROFILES = ("matched", "paper")


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
                         input_scales: dict[int, float] | None = None) -> DesignModel:
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
    """
    from scipy.linalg import block_diag

    model = sensors.linear_model()
    nr = rig.n_states
    A, B, Q = (np.asarray(a, float) for a in (A, B, Q))
    n0, nu = B.shape
    nu_rig = len(rig.action_names)
    index = (np.flatnonzero(model.stochastic & ~model.inputs) if channels is None
             else np.asarray(channels, int))
    effects = channel_effects(sensors) if effects is None else effects
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
    names = list(rig.state_names) + [n for n, _ in extra_states]
    units = list(rig.state_units) + [u for _, u in extra_states]
    # bias states (random walks)
    biased = [(pos, int(ch)) for pos, ch in enumerate(index)
              if effects[ch].bias_walk > 0 or effects[ch].bias0_std > 0]
    nb = len(biased)
    Qb = np.diag([effects[ch].bias_walk ** 2 for _, ch in biased]) if nb else np.zeros((0, 0))
    Pb = np.diag([effects[ch].bias0_std ** 2 for _, ch in biased]) if nb else np.zeros((0, 0))
    for _, ch in biased:
        names.append(f"bias_{sensors.names[ch]}")
        units.append(sensors.units[ch])
    n1 = n0 + nb
    A1 = block_diag(A, np.zeros((nb, nb)))
    B1 = np.vstack([B, np.zeros((nb, nu))])
    Q1 = block_diag(Q, Qb)
    H1 = np.hstack([C0, np.zeros((len(index), nb))])
    for j, (pos, _) in enumerate(biased):
        H1[pos, n0 + j] = 1.0
    # delay states
    delayed = [(pos, int(ch), effects[ch].delay) for pos, ch in enumerate(index)
               if effects[ch].delay > 0]
    nd = sum(d for *_, d in delayed)
    nm = nu if input_memory_std is not None and any(np.any(D0[pos]) for pos, *_ in delayed) \
        else 0
    km = n1 + nd  # the input-memory states
    n = km + nm
    Ac, Bc = np.zeros((n, n)), np.zeros((n, nu))
    Ac[:n1, :n1], Bc[:n1] = A1, B1
    F, Bd = np.zeros((n, n)), np.zeros((n, nu))
    # the continuous noise covariance here: on the hardware profile the unmodelled
    # accelerations (Coulomb friction, stops, deadband) are not white noise held over the
    # period, and the held covariance's near-singular position-rate blocks would make the
    # filter trust what they break (the helicopter's NEES 30 of 4 against 2.85)
    disc = LinearSystem(A=A1, B=B1, C=np.zeros((1, n1)), Q=Q1, R=np.eye(1)).discretize(dt_s)
    Qd1 = np.array(disc.Q)
    F[:n1, :n1], Bd[:n1] = disc.F, disc.B
    H = np.hstack([H1, np.zeros((len(index), nd + nm))])
    D = D0.copy()
    T0 = [np.eye(n1)]  # prior of the delay states: the first sample repeats (s_j = h x0)
    k = n1
    for pos, ch, d in delayed:
        src_x, src_u = C0[pos], D0[pos]
        for j in range(d):
            names.append(f"{sensors.names[ch]}_delay{j + 1}")
            units.append(sensors.units[ch])
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
    input_names = tuple(rig.action_names) + tuple(nm_ for nm_, _ in extra_inputs)
    input_units = tuple(rig.action_units) + tuple(un for _, un in extra_inputs)
    if nm:
        F[km:, km:], Bd[km:] = 0.0, np.eye(nu)
        Ac[km:, km:], Bc[km:] = -np.eye(nu) / dt_s, np.eye(nu) / dt_s
        names.extend(f"{name}_prev" for name in input_names)
        units.extend(input_units)
    T = np.vstack(T0)
    x0_full = np.concatenate([T @ np.concatenate([np.asarray(x0, float), np.zeros(nb)]),
                              np.zeros(nm)])
    P0_full = block_diag(T @ block_diag(np.asarray(P0, float), Pb) @ T.T,
                         np.diag(np.asarray(input_memory_std, float) ** 2) if nm
                         else np.zeros((0, 0)))
    Qc = block_diag(Q1, np.zeros((nd + nm, nd + nm)))
    has_d = bool(np.any(D))
    plant = LinearSystem(A=Ac, B=Bc, C=H, Q=Qc, R=R * dt_s, D=D if has_d else None)
    discrete = DiscreteLinearSystem(F=F, B=Bd, H=H, Q=block_diag(Qd1,
                                                                 np.zeros((nd + nm, nd + nm))),
                                    R=R, dt_s=dt_s, D=D if has_d else None)
    if output_matrix is None:
        output_matrix = np.eye(nr)[rig.tracked_index]
    L = np.zeros((len(output_matrix), n))
    L[:, :nr] = output_matrix
    G = None
    if disturbance_matrix is not None:
        G = np.zeros((n, np.shape(disturbance_matrix)[1]))
        G[:nr] = np.asarray(disturbance_matrix, float)[:nr]
    bias_columns = {pos: n0 + j for j, (pos, _) in enumerate(biased)}
    consider = consider_parameters(
        [(pos, sensors.names[ch], effects[ch].scale_std) for pos, ch in enumerate(index)],
        H, D, Bd, bias_columns, [(j, input_names[j], std)
                                 for j, std in sorted((input_scales or {}).items())])
    declared = _mismatch(rig)
    all_extras = {"cubic_model": None, "parameter_mismatch": None, **_designer(rig),
                  # the mismatch of this model: derivatives of the rebuilt designs' F
                  "matched_mismatch": None if declared is None
                  else MatchedMismatch(declared, sensors, float(dt_s)),
                  "consider": None if not consider else {"parameters": consider,
                                                         "R": R_constants},
                  "paper_design": paper_design, "design_profile": "matched",
                  "augmentation": {"extra": [nm for nm, _ in extra_states],
                                   "biases": [sensors.names[ch] for _, ch in biased],
                                   "delays": {sensors.names[ch]: d for _, ch, d in delayed}},
                  **(extras or {})}
    return DesignModel(
        dt_s=float(dt_s), continuous=plant, discrete=discrete, x0=x0_full, P0=P0_full,
        state_names=tuple(names), state_units=tuple(units),
        input_names=input_names, input_units=input_units,
        measurement_names=tuple(sensors.names), measurement_units=tuple(sensors.units),
        measurement_index=index, sensors=model, output_matrix=L,
        disturbance_matrix=G, input_transform=input_transform, extras=all_extras,
        physical_index=np.arange(nr))
