"""The sensor contract: batched, stateful, seeded, with a linear model for designers.

A :class:`Sensor` turns the true state of N simulated members into measurements. Every
sensor (a channel a rig declares, a decorator around another sensor, a suite of sensors)
has the same four parts:

- declarations: ``names``, ``units`` and ``measured_state`` (the state a channel measures
  directly, or None), one entry per output channel;
- ``allocate(num)``: size the per-member state (biases, delay lines) for N members;
- ``reset(sample, noise)`` and ``measure(sample, noise) -> (k, m)``: the members in
  ``sample.members`` start an episode / take one sample. All randomness comes from
  ``noise.normal(d)``, each member's own seeded stream, so a member's measurements do not
  depend on which other members are simulated with it;
- ``linear_model()``: ``y = C x + D u + Hw w + v``, ``cov(v) = R`` per sample, for designers;
- ``draws_per_sample()`` (optional): how many normals ``measure`` draws per member, when that
  is fixed; the simulator then draws them together with the step's own and hands them out
  in order (:class:`Drawn`): the same values, one draw per step instead of one per request.

MuJoCo adds no sensor noise; noise given as a continuous-time intensity ``S`` (a power
spectral density) becomes the per-sample covariance ``S / dt_s`` (the average of ``dy/dt``
over one sample), a density ``N`` (unit/sqrt(Hz)) the standard deviation ``N sqrt(1/dt_s)``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from gymnasium.utils import seeding

Members = np.ndarray | slice


@dataclass(slots=True)
class Sample:
    """What a sensor may read at one sample instant, for ``k`` members.

    Attributes
    ----------
    x : ndarray, shape (k, n)
        True states.
    t_s : ndarray, shape (k,)
        Sample times, s.
    u : ndarray, shape (k, nu)
        Actions applied over the step that ended at this sample (zeros at reset), rig units.
    w : ndarray, shape (k, s)
        Deterministic disturbance at the sample time (``s = 0`` without one).
    members : ndarray of int (k,) or slice
        Which of the ``num`` allocated members these rows are.
    act : ndarray, shape (k, na), or None
        MuJoCo's actuator states (``act``: a rotor lag's state) at the sample time, given
        only to a suite with a sensor that reads them (:func:`reads_actuators`); else None.
    """

    x: np.ndarray
    t_s: np.ndarray
    u: np.ndarray
    w: np.ndarray
    members: Members = field(default_factory=lambda: slice(None))
    act: np.ndarray | None = None

    @property
    def k(self) -> int:
        """Number of members in this sample."""
        return len(self.x)


class NoiseStreams:
    """Per-member standard-normal streams, drawn ahead in blocks.

    Member ``i`` owns ``gymnasium.utils.seeding.np_random(seed_i)``, exactly like a single
    Gymnasium environment's ``np_random``. numpy's ``Generator`` fills an array from one
    stream without caching, so a block equals the same number of single draws: a member's
    values do not depend on the batch it runs in.

    Parameters
    ----------
    num : int
        Number of members.
    block : int
        Values drawn per refill and member (at least the largest single request).
    """

    def __init__(self, num: int, block: int = 256):
        self.block = max(int(block), 1)
        self.generators: list[np.random.Generator | None] = [None] * num
        self._buf = np.empty((num, self.block))
        self._positions = np.full(num, self.block)
        #: The position of every stream when they are all at the same one (the common case
        #: of a batch drawing together): kept as an int instead of in ``_positions``.
        self._common: int | None = None

    @property
    def _pos(self) -> np.ndarray:
        """Each stream's position in its block, shape (num,)."""
        self._sync()
        return self._positions

    def _sync(self) -> None:
        if self._common is not None:
            self._positions[:] = self._common
            self._common = None

    def seed(self, i: int, seed: int | None) -> None:
        """Restart member ``i``'s stream like ``gym.Env.reset(seed=seed)``.

        A None seed keeps an existing generator (and creates a random one otherwise).
        """
        if seed is not None or self.generators[i] is None:
            self._sync()
            self.generators[i] = seeding.np_random(seed)[0]
            self._positions[i] = self.block

    def _refill(self, i: int) -> None:
        pos, buf = self._positions[i], self._buf[i]
        left = self.block - pos
        buf[:left] = buf[pos:]
        self.generators[i].standard_normal(out=buf[left:])
        self._positions[i] = 0

    def _refill_all(self, pos: int) -> None:
        """:meth:`_refill` of every stream, all at position ``pos`` (the values left move
        to the front in one copy, then each generator fills the rest of its row: the same
        draws as stream by stream, without the per-stream position bookkeeping). The
        positions are then 0: the caller sets ``_common``."""
        left = self.block - pos
        buf = self._buf
        if left:
            buf[:, :left] = buf[:, pos:]
        for generator, row in zip(self.generators, buf[:, left:] if left else buf,
                                  strict=True):
            generator.standard_normal(out=row)

    def draw(self, d: int, members: Members = slice(None)) -> np.ndarray:
        """The next ``d`` values of each selected stream, shape (k, d)."""
        if isinstance(members, slice) and members == slice(None):
            return self.draw_all(d)
        self._sync()
        index = np.arange(len(self._positions))[members]
        if d == 0:
            return np.zeros((len(index), 0))
        if d > self.block:
            raise ValueError(f"cannot draw {d} values at once (block {self.block})")
        pos = self._positions[index]
        for i in index[pos + d > self.block]:
            self._refill(i)
        pos = self._positions[index]
        if len(pos) and pos.min() == pos.max():
            start = int(pos[0])
            out = self._buf[index, start:start + d]
        else:
            out = self._buf[index[:, None], pos[:, None] + np.arange(d)]
        self._positions[index] = pos + d
        return out

    def draw_all(self, d: int) -> np.ndarray:
        """:meth:`draw` for every stream, shape (num, d) (the same values, without
        per-call gathers when the streams are at one position)."""
        c = self._common
        if c is None:
            pos = self._positions
            if not len(pos) or pos.min() != pos.max():
                return self.draw(d, np.arange(len(pos)))
            c = int(pos[0])
        if d == 0:
            return np.zeros((len(self._positions), 0))
        if d > self.block:
            raise ValueError(f"cannot draw {d} values at once (block {self.block})")
        if c + d > self.block:
            self._refill_all(c)
            c = 0
        self._common = c + d
        return self._buf[:, c:c + d].copy()

    def view(self, members: Members) -> Noise:
        """The streams of ``members`` as a :class:`Noise` source."""
        return Noise(self, members)


@dataclass(slots=True)
class Noise:
    """Standard normals for the members of one sample (a view of :class:`NoiseStreams`)."""

    streams: NoiseStreams
    members: Members

    def normal(self, d: int) -> np.ndarray:
        """``d`` standard normals per member, shape (k, d), from each member's own stream."""
        return self.streams.draw(d, self.members)


class Drawn:
    """Standard normals drawn ahead for one sample, handed out in order (a :class:`Noise`).

    A stream's values do not depend on how its draws are split (:class:`NoiseStreams`), so
    drawing everything a step needs at once, then handing out ``xi[:, p:p + d]`` to each
    request in turn, gives every request the values it would have drawn itself.

    Parameters
    ----------
    xi : ndarray, shape (k, D)
        The sample's normals, in the order they are requested.
    """

    __slots__ = ("xi", "position")

    def __init__(self, xi: np.ndarray):
        self.xi, self.position = xi, 0

    def normal(self, d: int) -> np.ndarray:
        """The next ``d`` normals of each member, shape (k, d) (read-only use)."""
        p = self.position
        e = p + d
        if e > self.xi.shape[1]:
            raise RuntimeError(f"the sensors drew more than the {self.xi.shape[1]} normals per "
                               "sample they declare (draws_per_sample)")
        self.position = e
        return self.xi[:, p:e]


#: A channel in its nonlinear form: ``value(x (M, n_rig), w (M, k_rig), g) -> (M,)`` and its
#: gradients ``d/dx -> (M, n_rig)`` and ``d/dw -> (M, k_rig)`` (``w``: the rig's physical
#: input, absolute; ``g``: the model's gravity, m/s^2). Module-level functions (they pickle).
ChannelFunctions = tuple[Callable[..., np.ndarray], Callable[..., np.ndarray],
                         Callable[..., np.ndarray]]


def no_input_gradient(x: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
    """``d value / dw`` of a channel that does not see the input: zeros (M, k_rig)."""
    return np.zeros((len(x), w.shape[1]))


@dataclass
class SensorModel:
    """Linear model ``y = C x + D u + Hw w + v``, ``cov(v) = R`` per sample.

    Attributes
    ----------
    C : ndarray, shape (m, n)
    D : ndarray, shape (m, nu)
    R : ndarray, shape (m, m)
        Per-sample covariance of the modelled noise (quantization as ``q^2 / 12``).
    Hw : ndarray, shape (m, s)
        Deterministic disturbance input (``s = 0`` when the channels do not see ``w``).
    stochastic : ndarray of bool, shape (m,)
        Channels a stochastic (Kalman-type) design uses; a noise-free channel driven by
        ``w`` (an H-infinity filter's ``y2 = C2 x + H w``) is not.
    inputs : ndarray of bool, shape (m,), optional
        Channels an estimator's *input* is computed from (e.g. the vehicle's speed and yaw
        rate giving ``a_y``), not measurements of the state: designs leave them out.
        Default: none.
    nonlinear : dict of str to ChannelFunctions
        Channels whose exact noise-free value is nonlinear in the state, by name: the
        function and its gradients (:data:`ChannelFunctions`), declared by the sensor beside
        its linear model (the EKF/UKF measure with them). Default: none.
    """

    C: np.ndarray
    D: np.ndarray
    R: np.ndarray
    Hw: np.ndarray
    stochastic: np.ndarray
    inputs: np.ndarray | None = None
    nonlinear: dict[str, ChannelFunctions] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.inputs is None:
            self.inputs = np.zeros(len(self.C), bool)

    @staticmethod
    def stack(models: list[SensorModel]) -> SensorModel:
        """The model of sensors measured one after the other (block-diagonal ``R``)."""
        from scipy.linalg import block_diag

        s = max(mod.Hw.shape[1] for mod in models)
        Hw = np.vstack([np.pad(mod.Hw, ((0, 0), (0, s - mod.Hw.shape[1]))) for mod in models])
        return SensorModel(C=np.vstack([mod.C for mod in models]),
                           D=np.vstack([mod.D for mod in models]),
                           R=block_diag(*[mod.R for mod in models]), Hw=Hw,
                           stochastic=np.concatenate([mod.stochastic for mod in models]),
                           inputs=np.concatenate([mod.inputs for mod in models]),
                           nonlinear={k: v for mod in models for k, v in mod.nonlinear.items()})


class Sensor:
    """Base of every sensor: declarations, per-member state, batched measurement.

    Subclasses implement :meth:`measure` and :meth:`linear_model`, and set ``names``,
    ``units`` and ``measured_state`` (tuples of equal length). Stateful ones override
    :meth:`allocate` and :meth:`reset`.
    """

    names: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    measured_state: tuple[int | None, ...] = ()
    #: The channel reads MuJoCo's actuator states (``Sample.act``: :func:`reads_actuators`).
    reads_act: bool = False
    #: The sensor a decorator wraps (None: not a decorator).
    inner: Sensor | None = None

    @property
    def dim(self) -> int:
        """Number of output channels ``m``."""
        return len(self.names)

    def allocate(self, num: int) -> None:
        """Size the per-member state for ``num`` members (default: stateless)."""

    def reset(self, sample: Sample, noise: Noise) -> None:
        """Start an episode for ``sample.members`` (default: nothing to reset, no draws)."""

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """One sample of every member in ``sample``, shape (k, m)."""
        raise NotImplementedError

    def measure_row(self, sample: Sample, noise: Noise) -> list[float]:
        """:meth:`measure` of a one-member sample (k = 1) as a list of ``m`` Python floats:
        what a fused suite's one-row path reads (:mod:`testbed.sensors.fused`). Default: the
        row of :meth:`measure`; a channel may compute it without numpy, with the same
        values, bitwise."""
        return self.measure(sample, noise).tolist()[0]

    def measure_into(self, sample: Sample, noise: Noise, out: np.ndarray) -> None:
        """:meth:`measure` written into ``out`` (k, m), the columns of a fused suite's array
        (:mod:`testbed.sensors.fused`). Default: the values of :meth:`measure`; a channel
        may compute them into ``out`` directly, with the same operations (bitwise the same
        values, without the array between)."""
        out[...] = self.measure(sample, noise)

    def linear_model(self) -> SensorModel:
        """The model a designer uses (see :class:`SensorModel`)."""
        raise NotImplementedError

    def draws_per_sample(self) -> int | None:
        """Standard normals :meth:`measure` draws per member and sample, when that number is
        fixed (the simulator then draws them with the step's own, in one call); None
        (default): not declared, the sensor draws from the streams itself."""
        return None

    def sample_periods_s(self) -> set[float]:
        """Sampling periods (s) this sensor's parameters were computed for, in units of the
        simulator's control period (default: none; the simulator checks that every one equals
        its ``dt_s``)."""
        return set()

    def direct_state(self) -> int | None:
        """The state index this sensor returns unchanged, if it is exactly one state
        component (lets a :class:`Suite` of such channels read them in one gather)."""
        return None

    def __add__(self, other: Sensor) -> Suite:
        return Suite(self, other)

    def describe(self) -> str:
        """Short description for outputs, e.g. ``quantize(pitch)``."""
        return "+".join(self.names)


class Suite(Sensor):
    """Sensors measured one after the other; the output is their concatenation.

    Parameters
    ----------
    *sensors : Sensor
    """

    def __init__(self, *sensors: Sensor):
        flat: list[Sensor] = []
        for s in sensors:
            if not isinstance(s, Sensor):
                raise ValueError(f"Suite members must be Sensor objects, got {s!r}")
            flat.extend(s.sensors if isinstance(s, Suite) else [s])
        if not flat:
            raise ValueError("a Suite needs at least one sensor")
        self.sensors = tuple(flat)
        self.names = tuple(n for s in flat for n in s.names)
        self.units = tuple(u for s in flat for u in s.units)
        self.measured_state = tuple(i for s in flat for i in s.measured_state)
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"sensor channel names must be unique, got {list(self.names)}")
        direct = [s.direct_state() for s in flat]
        #: States read directly when every member is a bare state channel (one gather; a
        #: slice when they are consecutive).
        self._state_index: Any = None
        if None not in direct:
            lo = direct[0]
            self._state_index = (slice(lo, lo + len(direct))
                                 if direct == list(range(lo, lo + len(direct)))
                                 else np.array(direct))
        #: The decorators applied across channels (:mod:`testbed.sensors.fused`), made at
        #: :meth:`allocate`; None: measured sensor by sensor.
        self._plan: Any = None

    #: What fuses an allocated suite's decorators across its channels: ``suite -> plan or
    #: None``. :mod:`testbed.sensors.fused` sets it to its ``build_plan`` where it defines it
    #: (imported with :mod:`testbed.sensors`), so that this contract imports nothing above
    #: it; None: every suite is measured sensor by sensor (the same values).
    fuse: ClassVar[Callable[[Suite], Any] | None] = None

    def allocate(self, num: int) -> None:
        """Allocate every member sensor; then fuse their decorators across channels where
        they allow it (:attr:`fuse`: :func:`testbed.sensors.fused.build_plan`)."""
        for s in self.sensors:
            s.allocate(num)
        fuse = self.fuse
        self._plan = None if self._state_index is not None or fuse is None else fuse(self)

    def reset(self, sample: Sample, noise: Noise) -> None:
        """Reset every member sensor, in order."""
        for s in self.sensors:
            s.reset(sample, noise)

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """Every sensor in order (their draws in that order), concatenated: (k, m)."""
        index = self._state_index
        if index is not None:  # what the channels return, in one gather
            return (sample.x[:, index].copy() if isinstance(index, slice)
                    else sample.x.take(index, axis=1))
        plan = self._plan
        if plan is not None:  # the decorators across channels, bitwise the same values
            if not plan.current():  # a decorator's state was replaced: fuse it again
                plan = self._plan = self.fuse(self)
            if plan is not None:
                return plan.measure(sample, noise)
        if len(self.sensors) == 1:
            return self.sensors[0].measure(sample, noise)
        parts = [s.measure(sample, noise) for s in self.sensors]
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)

    def draws_per_sample(self) -> int | None:
        """The member sensors' draws summed (None when one of them does not declare its)."""
        draws = [s.draws_per_sample() for s in self.sensors]
        return None if None in draws else sum(draws)

    def sample_periods_s(self) -> set[float]:
        """The union of the member sensors' periods."""
        return set().union(*(s.sample_periods_s() for s in self.sensors))

    def linear_model(self) -> SensorModel:
        """The stacked models of the member sensors."""
        return SensorModel.stack([s.linear_model() for s in self.sensors])

    def describe(self) -> str:
        """The members' descriptions joined by ``+``."""
        return " + ".join(s.describe() for s in self.sensors)


def reads_actuators(sensor: Sensor) -> bool:
    """Whether ``sensor`` (a suite, a decorator or a channel) has a channel reading MuJoCo's
    actuator states (``Sample.act``): a channel declaring ``reads_act = True``, found
    through suites (``sensors``) and wrappers (``inner``)."""
    if sensor.reads_act:
        return True
    if isinstance(sensor, Suite):
        return any(reads_actuators(s) for s in sensor.sensors)
    return isinstance(sensor.inner, Sensor) and reads_actuators(sensor.inner)


def as_array(value: Any, size: int, name: str, *, non_negative: bool = True) -> np.ndarray:
    """A finite float array of shape (size,) from a scalar or a sequence; else ValueError."""
    try:
        arr = np.broadcast_to(np.asarray(value, dtype=float), (size,)).copy()
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be one number or {size} numbers, got {value!r}") from None
    if not np.all(np.isfinite(arr)) or (non_negative and np.any(arr < 0)):
        kind = "finite and non-negative" if non_negative else "finite"
        raise ValueError(f"{name} must be {kind}, got {value!r}")
    return arr
