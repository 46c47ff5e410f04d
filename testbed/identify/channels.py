"""The recorded channels as the identification sees them: noise-free measurement functions,
their linear rows, and the initial state a recording gives.

A rig's sensor suite is a tree of channels (:class:`~testbed.sensors.StateChannel`, a rig's
own IMU...) under decorators (quantization, noise, bias, scale factor, delay, hold). The
identification predicts a channel by the *core* channel's noise-free measurement of the
simulated state (nonlinear where the channel is: the helicopter's ``gyro_yaw`` is
``yaw_rate cos(pitch)``), then the fitted per-channel sensor model ``bias + (1 + scale)
y(t - delay)``. The decorators only tell which of bias and delay a channel may have
(:func:`channel_plan`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from testbed.sensors import (
    Bias,
    BiasRandomWalk,
    Decorator,
    Delay,
    Sample,
    SampleAndHold,
    ScaleFactor,
    Sensor,
    StateChannel,
    Suite,
)
from testbed.sensors.streams import OwnStream


class IdentificationError(ValueError):
    """Input the identification cannot use: one line naming the argument and what was
    expected."""


class _NoNoise:
    """A noise source for the core channels, which draw none (decorators do)."""

    def normal(self, d: int) -> np.ndarray:
        raise RuntimeError("a core sensor channel drew noise; only decorators may")


@dataclasses.dataclass(frozen=True)
class ChannelInfo:
    """What the identification knows of one recorded channel.

    Attributes
    ----------
    name : str
    unit : str
    core : Sensor
        The undecorated channel that measures it.
    column : int
        Its column in ``core``'s output.
    C : ndarray, shape (n,)
        Its row of the linear model (``y ~ C x + D u``).
    D : ndarray, shape (nu,)
    direct_state : int or None
        The state it returns unchanged (an encoder), else None.
    bias : bool
        Whether a bias is fitted by default: every channel but a direct state without a
        declared bias (an encoder's zero is the rig's zero; a gyro has a bias).
    scale : bool
        Whether a scale factor is fitted by default: a declared sensitivity error
        (:class:`~testbed.sensors.ScaleFactor`).
    delay : int
        The declared delay in whole samples (a hold counts half its length): where the fit
        starts.
    max_delay : int
        Largest whole-sample delay searched by default: twice the declared delay plus the
        declared hold, 0 for a channel with neither.
    is_input : bool
        An input channel (e.g. the vehicle's speed): not predicted from the state.
    reads_act : bool
        It reads MuJoCo's actuator states (the Aero's rotor speeds and motor currents): an
        input channel that can be predicted from a rollout's actuator states, fitted when
        named (``channels``), never by default.
    """

    name: str
    unit: str
    core: Sensor
    column: int
    C: np.ndarray
    D: np.ndarray
    direct_state: int | None
    bias: bool
    scale: bool
    delay: int
    max_delay: int
    is_input: bool
    reads_act: bool = False


def _walk(sensor: Sensor, delay: int, hold: int, biased: bool, out: dict[str, ChannelInfo],
          scaled: bool = False) -> None:
    """Collect the core channels of ``sensor`` with the delay, hold, bias and scale factor
    above them."""
    if isinstance(sensor, Suite):
        for part in sensor.sensors:
            _walk(part, delay, hold, biased, out, scaled)
        return
    if isinstance(sensor, OwnStream):  # noise from its own streams: the decorators inside
        _walk(sensor.inner, delay, hold, biased, out, scaled)
        return
    if isinstance(sensor, Decorator):
        if isinstance(sensor, Delay):
            delay += sensor.samples
        elif isinstance(sensor, SampleAndHold):
            hold += sensor.every - 1
        elif isinstance(sensor, Bias | BiasRandomWalk):
            biased = True
        elif isinstance(sensor, ScaleFactor):
            scaled = bool(np.any(sensor.initial_std > 0) or np.any(sensor.error != 0))
        _walk(sensor.inner, delay, hold, biased, out, scaled)
        return
    model = sensor.linear_model()
    inputs = model.inputs if model.inputs is not None else np.zeros(sensor.dim, bool)
    direct = sensor.direct_state() if isinstance(sensor, StateChannel) else None
    for j, name in enumerate(sensor.names):
        out[name] = ChannelInfo(
            name=name, unit=sensor.units[j], core=sensor, column=j, C=model.C[j].copy(),
            D=model.D[j].copy(), direct_state=direct, bias=direct is None or biased,
            scale=scaled,
            delay=delay + hold // 2, max_delay=2 * delay + hold, is_input=bool(inputs[j]),
            reads_act=bool(sensor.reads_act))


def channel_plan(sensors: Sensor) -> dict[str, ChannelInfo]:
    """Every channel of a sensor suite by name (:class:`ChannelInfo`), in suite order."""
    out: dict[str, ChannelInfo] = {}
    _walk(sensors, 0, 0, False, out)
    return out


def measure_noise_free(infos: list[ChannelInfo], x: np.ndarray, u_prev: np.ndarray,
                       t_s: np.ndarray, act: np.ndarray | None = None) -> np.ndarray:
    """The core channels' measurements of states ``x`` without any decorator.

    Parameters
    ----------
    infos : list of ChannelInfo
        The channels, in output order.
    x : ndarray, shape (M, n)
        States (any number of samples and members, flattened).
    u_prev : ndarray, shape (M, nu)
        The input applied over the step that ended at each sample (zero at a reset).
    t_s : ndarray, shape (M,)
    act : ndarray, shape (M, na), optional
        MuJoCo's actuator states (for channels reading them; without them such a channel
        reads the steady state of ``u_prev``).

    Returns
    -------
    ndarray, shape (M, len(infos))
    """
    sample = Sample(x, t_s, u_prev, np.zeros((len(x), 0)), slice(None), act)
    cache: dict[int, np.ndarray] = {}
    out = np.empty((len(x), len(infos)))
    for i, info in enumerate(infos):
        key = id(info.core)
        if key not in cache:
            cache[key] = np.asarray(info.core.measure(sample, _NoNoise()), float)
        out[:, i] = cache[key][:, info.column]
    return out


def smoothed(y: np.ndarray, start: int, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Value and slope per sample at ``start`` of a local quadratic fit over
    ``y[start:start + window]`` (Savitzky and Golay 1964, one-sided at the start).

    Parameters
    ----------
    y : ndarray, shape (N, m)
    start : int
    window : int
        Samples in the fit (at least 3, cut at the end of ``y``).

    Returns
    -------
    value : ndarray, shape (m,)
    slope : ndarray, shape (m,)
        Per sample (divide by the sample period for a rate).
    """
    seg = y[start:start + max(window, 3)]
    k = np.arange(len(seg), dtype=float)
    degree = min(2, len(seg) - 1)
    if degree < 1:
        return seg[0].copy(), np.zeros(y.shape[1])
    V = np.vander(k, degree + 1, increasing=True)
    coef, *_ = np.linalg.lstsq(V, seg, rcond=None)
    return coef[0], coef[1]


def initial_state(infos: list[ChannelInfo], y: np.ndarray, u_prev: np.ndarray, start: int,
                  dt_s: float, n_positions: int, bias: np.ndarray, delay: np.ndarray,
                  window: int, fallback: np.ndarray,
                  still: tuple[int, int] | None = None) -> np.ndarray:
    """The state at sample ``start`` from the recorded channels.

    Positions from the channels measuring them directly (encoders); rates from the
    smoothed slope of such a channel (unbiased), else from a channel measuring the rate
    (a gyro, less its bias); any state left from the channels' linear model (``y - b -
    D u = C x``, least squares: the vehicle's roll from its lateral accelerometer).
    Everything from a local quadratic fit over ``window`` samples (:func:`smoothed`), each
    channel read ``delay`` samples later (it shows the state that late). A state no
    channel determines keeps ``fallback``.

    Parameters
    ----------
    infos : list of ChannelInfo
        The channels of ``y``'s columns.
    y : ndarray, shape (N, m)
    u_prev : ndarray, shape (N, nu)
    start : int
    dt_s : float
    n_positions : int
        Positions in the state (then as many rates).
    bias, delay : ndarray, shape (m,)
        The sensor model's bias (channel units) and delay (samples) per channel.
    window : int
    fallback : ndarray, shape (n,)
    still : (int, int), optional
        Samples where the rig is at rest (inputs constant, channels still): a start among
        them takes the channels' means there and zero rates.

    Returns
    -------
    ndarray, shape (n,)
    """
    n = 2 * n_positions
    m = len(infos)
    values, slopes = np.zeros(m), np.zeros(m)
    at_rest = still is not None and still[0] <= start < still[1]
    for i in range(m):
        if at_rest:
            values[i] = float(np.mean(y[still[0]:still[1], i])) - bias[i]
            continue
        at = min(start + int(delay[i]), len(y) - 1)
        # the input's feedthrough (the accelerometer's a_y) steps within the window: it is
        # taken out before the fit and put back at the start
        feed = u_prev[at:at + max(window, 3)] @ infos[i].D
        seg = y[at:at + len(feed), i] - feed
        v, s = smoothed(seg[:, None], 0, window)
        values[i], slopes[i] = v[0] + feed[0] - bias[i], s[0] / dt_s
    x = np.array(fallback, float)
    known = np.zeros(n, bool)
    if at_rest:
        x[n_positions:], known[n_positions:] = 0.0, True
    for i, info in enumerate(infos):
        if info.direct_state is not None and not info.is_input:
            j = info.direct_state
            x[j], known[j] = values[i], True
            if j < n_positions and not known[j + n_positions]:
                x[j + n_positions], known[j + n_positions] = slopes[i], True
    for i, info in enumerate(infos):  # single-state rows (gyros): x_j = (y - D u) / c
        if info.is_input:
            continue
        nz = np.flatnonzero(np.abs(info.C) > 1e-12)
        if len(nz) == 1 and not known[nz[0]]:
            j = nz[0]
            x[j] = (values[i] - info.D @ u_prev[start]) / info.C[j]
            known[j] = True
    rows = [i for i, info in enumerate(infos) if not info.is_input
            and np.any(np.abs(info.C[~known]) > 1e-12)]
    if rows and not known.all():
        C = np.array([infos[i].C for i in rows])
        rhs = (np.array([values[i] - infos[i].D @ u_prev[start] for i in rows])
               - C[:, known] @ x[known])
        sol, *_ = np.linalg.lstsq(C[:, ~known], rhs, rcond=None)
        determined = np.abs(C[:, ~known]).sum(axis=0) > 1e-12
        free = np.flatnonzero(~known)
        x[free[determined]] = sol[determined]
        x = _refine(infos, rows, values, u_prev[start], x, free[determined])
    return x


def _refine(infos: list[ChannelInfo], rows: list[int], values: np.ndarray, u: np.ndarray,
            x: np.ndarray, unknown: np.ndarray, iterations: int = 3) -> np.ndarray:
    """Gauss-Newton steps on the ``unknown`` states with the channels' nonlinear
    measurement (the linear model's solution is the start): the vehicle's accelerometer
    reads ``a_y cos(roll) + g sin(roll)``, not ``a_y + g roll``."""
    if not len(unknown):
        return x
    sel = [infos[i] for i in rows]
    target = values[rows]
    eps = 1e-7
    for _ in range(iterations):
        probes = np.tile(x, (1 + len(unknown), 1))
        for k, j in enumerate(unknown):
            probes[1 + k, j] += eps
        h = measure_noise_free(sel, probes, np.tile(u, (len(probes), 1)),
                               np.zeros(len(probes)))
        J = ((h[1:] - h[0]) / eps).T
        step, *_ = np.linalg.lstsq(J, target - h[0], rcond=None)
        x = x.copy()
        x[unknown] += step
        if np.max(np.abs(step)) < 1e-12:
            break
    return x


def check_channels(recording: Any, plan: dict[str, ChannelInfo], channels: Any,
                   rig_name: str) -> list[ChannelInfo]:
    """The channels to fit: ``channels`` (names) or every recorded channel the rig's sensors
    measure from the state; one-line errors for a name the recording or the rig lacks."""
    if channels is None:
        names = [n for n in plan if n in recording.channels and not plan[n].is_input]
        if not names:
            raise IdentificationError(
                f"recording {recording.source}: none of its channels "
                f"{sorted(recording.channels)} is a state channel of rig {rig_name!r} "
                f"({sorted(n for n in plan if not plan[n].is_input)})")
        return [plan[n] for n in names]
    if isinstance(channels, str) or not all(isinstance(c, str) for c in channels):
        raise IdentificationError(f"channels must be a list of channel names, got {channels!r}")
    out = []
    for name in channels:
        if name not in plan:
            raise IdentificationError(f"channel {name!r} is not a channel of rig {rig_name!r}; "
                                      f"expected one of {list(plan)}")
        if plan[name].is_input and not plan[name].reads_act:
            raise IdentificationError(f"channel {name!r} of rig {rig_name!r} is an input "
                                      "channel, not a measurement of the state")
        if name not in recording.channels:
            raise IdentificationError(f"recording {recording.source} has no channel {name!r}; "
                                      f"it has {sorted(recording.channels)}")
        out.append(plan[name])
    if not out:
        raise IdentificationError("channels must name at least one channel")
    return out
