"""Decorators that make any sensor behave like hardware; each works on every rig.

``WhiteNoise(Quantize(channel, step), std=...)`` etc. A decorator wraps a :class:`Sensor`
and is one: it measures the inner sensor first (so the inner draws come first), then
changes the values, and updates the linear model where the change is modelled.

=======================  ==============================================  ==================
decorator                output                                          linear model
=======================  ==============================================  ==================
:class:`Quantize`        ``round(y / q) q``                              ``R += q^2 / 12``
:class:`WhiteNoise`      ``y + v``, std, covariance, intensity, density  ``R += cov(v)``
:class:`Bias`            ``y + b`` (constant)                            unmodelled
:class:`BiasRandomWalk`  ``y + b_k``, ``b_{k+1} = b_k + q sqrt(dt) xi``  unmodelled
:class:`ScaleFactor`     ``(1 + s) y``, ``s`` fixed plus drawn at reset     unmodelled
:class:`Delay`           ``y`` of ``d`` samples ago                      unmodelled
:class:`SampleAndHold`   ``y`` updated every ``every`` samples           unmodelled
:class:`Tap`             ``y``, kept per member in ``last``                unchanged
=======================  ==============================================  ==================
"""

from __future__ import annotations

import numpy as np

from testbed.sensors.base import Noise, Sample, Sensor, SensorModel, as_array


class _Rows:
    """A per-channel parameter (m,) repeated for the k rows of a sample, remade when the
    parameter is replaced or k changes: numpy's ufuncs between arrays of one shape skip the
    broadcasting machinery, which costs more than the arithmetic on a few channels (the same
    values, bitwise)."""

    __slots__ = ("rows", "source")

    def __init__(self) -> None:
        self.source: np.ndarray | None = None
        self.rows = np.zeros((0, 0))

    def of(self, values: np.ndarray, k: int) -> np.ndarray:
        """``values`` as a read-only (k, m) array."""
        rows = self.rows
        if values is not self.source or len(rows) != k:
            rows = np.tile(values, (k, 1))
            rows.flags.writeable = False
            self.source, self.rows = values, rows
        return rows


class Decorator(Sensor):
    """A sensor wrapping another; by default passes everything through.

    Parameters
    ----------
    inner : Sensor
    """

    #: The sampling period the decorator was built for, s (None: it has none).
    dt_s: float | None = None

    def __init__(self, inner: Sensor):
        if not isinstance(inner, Sensor):
            raise ValueError(f"inner must be a Sensor, got {inner!r}")
        self.inner = inner
        self.names, self.units = inner.names, inner.units
        self.measured_state = inner.measured_state

    def allocate(self, num: int) -> None:
        """Allocate the inner sensor (subclasses add their own state)."""
        self.inner.allocate(num)

    def reset(self, sample: Sample, noise: Noise) -> None:
        """Reset the inner sensor."""
        self.inner.reset(sample, noise)

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """The inner sensor's measurement, changed by :meth:`apply`."""
        return self.apply(self.inner.measure(sample, noise), sample, noise)

    def apply(self, y: np.ndarray, sample: Sample, noise: Noise) -> np.ndarray:
        """Change the inner measurement ``y`` (k, m)."""
        return y

    def linear_model(self) -> SensorModel:
        """The inner sensor's model (the change is not modelled)."""
        return self.inner.linear_model()

    #: Normals this decorator draws per sample, after its inner sensor's (None: not
    #: declared). A subclass that keeps :meth:`measure` and :meth:`apply` draws none.
    own_draws: int | None = None

    def draws_per_sample(self) -> int | None:
        """The inner sensor's draws plus :attr:`own_draws` (None when either is unknown)."""
        own = self.own_draws
        if own is None and type(self).measure is Decorator.measure \
                and type(self).apply is Decorator.apply:
            own = 0  # passes the inner measurement through
        inner = self.inner.draws_per_sample()
        return None if own is None or inner is None else inner + own

    def sample_periods_s(self) -> set[float]:
        """The inner sensor's periods plus this decorator's ``dt_s`` (if it has one)."""
        own = self.dt_s
        return self.inner.sample_periods_s() | (set() if own is None else {float(own)})

    def describe(self) -> str:
        """``name(inner)``."""
        return f"{type(self).__name__.lower()}({self.inner.describe()})"


class Quantize(Decorator):
    """Round to a resolution ``step`` (an encoder: ``step = 2 pi / counts``).

    Parameters
    ----------
    inner : Sensor
    step : float or sequence of float
        Resolution per channel, in the channel's unit (positive).
    """

    own_draws = 0

    def __init__(self, inner: Sensor, step: float | np.ndarray):
        super().__init__(inner)
        self.step = as_array(step, inner.dim, "step")
        if np.any(self.step <= 0):
            raise ValueError(f"step must be positive, got {step!r}")
        self._step_rows = _Rows()

    def apply(self, y: np.ndarray, sample: Sample, noise: Noise) -> np.ndarray:
        """``round(y / step) step``."""
        step = self._step_rows.of(self.step, len(y))
        return np.rint(y / step) * step  # np.round with 0 decimals, less overhead

    def linear_model(self) -> SensorModel:
        """Quantization as uniform white noise: ``R += diag(step^2 / 12)``."""
        model = self.inner.linear_model()
        model.R = model.R + np.diag(self.step**2 / 12.0)
        model.stochastic = np.ones(self.dim, bool)
        return model


class WhiteNoise(Decorator):
    """Additive Gaussian white noise, given exactly one way.

    Parameters
    ----------
    inner : Sensor
    std : float or sequence, optional
        Standard deviation per sample and channel.
    cov : ndarray, shape (m, m), optional
        Per-sample covariance (correlated channels).
    intensity : ndarray, shape (m, m) or (m,), optional
        Continuous-time intensity (PSD) ``S``; per-sample covariance ``S / dt_s``.
    density : float or sequence, optional
        Noise density ``N`` (unit/sqrt(Hz)); per-sample std ``N sqrt(1 / dt_s)``.
    dt_s : float, optional
        Sampling period, required with ``intensity`` or ``density``.

    Notes
    -----
    Draws ``m`` standard normals per sample (none when the noise is zero).
    """

    def __init__(self, inner: Sensor, *, std=None, cov=None, intensity=None, density=None,
                 dt_s: float | None = None):
        super().__init__(inner)
        given = [k for k, v in (("std", std), ("cov", cov), ("intensity", intensity),
                                ("density", density)) if v is not None]
        if len(given) != 1:
            raise ValueError(f"WhiteNoise takes exactly one of std, cov, intensity, density; "
                             f"got {given or 'none'}")
        m = inner.dim
        if intensity is not None or density is not None:
            if dt_s is None or not (np.isfinite(dt_s) and dt_s > 0):
                raise ValueError(f"dt_s must be a positive sampling period in s with "
                                 f"{given[0]}, got {dt_s}")
        #: The sampling period the intensity or density was converted with (None: std/cov).
        self.dt_s = None if intensity is None and density is None else float(dt_s)
        self._chol: np.ndarray | None = None
        self._std: np.ndarray | None = None
        if std is not None:
            self._std = as_array(std, m, "std")
        elif density is not None:
            self._std = as_array(density, m, "density") * np.sqrt(1.0 / dt_s)
        else:
            S = np.asarray(cov if cov is not None else intensity, dtype=float)
            S = np.diag(S) if S.ndim == 1 else S
            if S.shape != (m, m) or not np.all(np.isfinite(S)) or not np.allclose(S, S.T):
                raise ValueError(f"{given[0]} must be a finite symmetric ({m}, {m}) matrix, "
                                 f"got shape {S.shape}")
            S = S / dt_s if intensity is not None else S
            try:
                self._chol = np.linalg.cholesky(S)
            except np.linalg.LinAlgError:
                raise ValueError(f"{given[0]} must be positive definite") from None
        self.cov = (np.diag(self._std**2) if self._std is not None
                    else self._chol @ self._chol.T)
        self._draws = m if (self._std is None or np.any(self._std > 0)) else 0
        self._std_rows = _Rows()

    @property
    def own_draws(self) -> int:
        """``m`` normals per sample (none when the noise is zero)."""
        return self._draws

    def apply(self, y: np.ndarray, sample: Sample, noise: Noise) -> np.ndarray:
        """``y + std xi`` or ``y + chol(cov) xi``."""
        if not self._draws:
            return y
        xi = noise.normal(self._draws)
        if self._std is not None:
            return y + self._std_rows.of(self._std, len(y)) * xi
        return y + np.matvec(self._chol, xi)

    def linear_model(self) -> SensorModel:
        """``R += cov``."""
        model = self.inner.linear_model()
        model.R = model.R + self.cov
        model.stochastic = np.ones(self.dim, bool)
        return model


class Bias(Decorator):
    """A constant offset ``b`` (per channel), left out of the linear model."""

    own_draws = 0

    def __init__(self, inner: Sensor, bias: float | np.ndarray):
        super().__init__(inner)
        self.bias = as_array(bias, inner.dim, "bias", non_negative=False)
        self._bias_rows = _Rows()

    def apply(self, y: np.ndarray, sample: Sample, noise: Noise) -> np.ndarray:
        """``y + b``."""
        return y + self._bias_rows.of(self.bias, len(y))


class BiasRandomWalk(Decorator):
    """A drifting bias: ``y_k + b_k``, then ``b_{k+1} = b_k + walk sqrt(dt_s) xi_k``.

    Parameters
    ----------
    inner : Sensor
    walk : float or sequence
        Random-walk intensity ``q`` (unit/sqrt(s)) per channel.
    dt_s : float
        Sampling period, s.
    initial_std : float or sequence
        Standard deviation of ``b_0``, drawn at reset (0: calibrated, no draw).

    Notes
    -----
    Draws: ``m`` normals at reset when ``initial_std > 0``; ``m`` per sample, after the
    inner sensor's, when ``walk > 0``.
    """

    def __init__(self, inner: Sensor, walk: float | np.ndarray, dt_s: float,
                 initial_std: float | np.ndarray = 0.0):
        super().__init__(inner)
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be a positive sampling period in s, got {dt_s}")
        self.walk = as_array(walk, inner.dim, "walk")
        self.initial_std = as_array(initial_std, inner.dim, "initial_std")
        self.dt_s = float(dt_s)
        self.bias = np.zeros((0, inner.dim))
        self._walk_of: np.ndarray | None = None  # the walk _walk_step was computed from
        self._walk_step: np.ndarray | None = None
        self._step_rows = _Rows()

    def allocate(self, num: int) -> None:
        """One bias per member and channel."""
        super().allocate(num)
        self.bias = np.zeros((num, self.dim))

    def reset(self, sample: Sample, noise: Noise) -> None:
        """Inner reset, then ``b_0 = initial_std xi``."""
        super().reset(sample, noise)
        if np.any(self.initial_std > 0):
            self.bias[sample.members] = self.initial_std * noise.normal(self.dim)
        else:
            self.bias[sample.members] = 0.0

    def draws_per_sample(self) -> int | None:
        """The inner sensor's draws, plus ``m`` when the bias walks (``walk > 0``)."""
        inner = self.inner.draws_per_sample()
        return None if inner is None else inner + (self.dim if np.any(self.walk > 0) else 0)

    def apply(self, y: np.ndarray, sample: Sample, noise: Noise) -> np.ndarray:
        """``y + b_k``; then the walk advances."""
        bias = self.bias[sample.members]
        out = y + bias
        walk = self.walk
        if walk is not self._walk_of:  # (walk * sqrt(dt)) xi, as written before
            self._walk_of, self._walk_step = walk, (walk * np.sqrt(self.dt_s)
                                                    if np.any(walk > 0) else None)
        if self._walk_step is not None:
            self.bias[sample.members] = bias + (self._step_rows.of(self._walk_step, len(y))
                                                * noise.normal(self.dim))
        return out


class ScaleFactor(Decorator):
    """A gain error: ``(1 + s) y`` per channel, ``s = error + initial_std xi`` per episode.

    Parameters
    ----------
    inner : Sensor
    error : float or sequence
        Known part of the scale-factor error per channel (e.g. ``0.01`` = +1 %).
    initial_std : float or sequence
        Standard deviation of the random part, drawn at every reset (a datasheet's
        sensitivity tolerance); 0: none, no draw.

    Notes
    -----
    Draws ``m`` normals at reset when ``initial_std > 0``, none per sample.
    """

    own_draws = 0

    def __init__(self, inner: Sensor, error: float | np.ndarray = 0.0,
                 initial_std: float | np.ndarray = 0.0):
        super().__init__(inner)
        self.error = as_array(error, inner.dim, "error", non_negative=False)
        self.initial_std = as_array(initial_std, inner.dim, "initial_std")
        if np.any(self.error <= -1):
            raise ValueError(f"error must be > -1 (a gain of 1 + error > 0), got {error!r}")
        self.scale = np.zeros((0, inner.dim))

    def allocate(self, num: int) -> None:
        """One scale factor per member and channel."""
        super().allocate(num)
        self.scale = np.zeros((num, self.dim))

    def reset(self, sample: Sample, noise: Noise) -> None:
        """Inner reset, then ``s = error + initial_std xi``."""
        super().reset(sample, noise)
        if np.any(self.initial_std > 0):
            self.scale[sample.members] = self.error + self.initial_std * noise.normal(self.dim)
        else:
            self.scale[sample.members] = self.error

    def apply(self, y: np.ndarray, sample: Sample, noise: Noise) -> np.ndarray:
        """``(1 + s) y``."""
        return y * (1.0 + self.scale[sample.members])


class Delay(Decorator):
    """The inner measurement ``samples`` sample periods late (the first one repeats).

    Parameters
    ----------
    inner : Sensor
    samples : int
        Delay in samples (>= 1).
    """

    own_draws = 0

    def __init__(self, inner: Sensor, samples: int):
        super().__init__(inner)
        if int(samples) != samples or samples < 1:
            raise ValueError(f"samples must be a positive integer, got {samples!r}")
        self.samples = int(samples)
        self._line = np.zeros((0, self.samples, inner.dim))
        self._fresh = np.zeros(0, bool)

    def allocate(self, num: int) -> None:
        """A delay line per member."""
        super().allocate(num)
        self._line = np.zeros((num, self.samples, self.dim))
        self._fresh = np.ones(num, bool)

    def reset(self, sample: Sample, noise: Noise) -> None:
        """Inner reset; the line fills with the first measurement."""
        super().reset(sample, noise)
        self._fresh[sample.members] = True

    def apply(self, y: np.ndarray, sample: Sample, noise: Noise) -> np.ndarray:
        """The oldest value of the line; ``y`` enters it."""
        m = sample.members
        fresh = self._fresh[m]
        line = self._line[m]
        line[fresh] = y[fresh][:, None, :]
        out = line[:, 0].copy()
        self._line[m] = np.concatenate([line[:, 1:], y[:, None, :]], axis=1)
        self._fresh[m] = False
        return out


class SampleAndHold(Decorator):
    """Measure every ``every`` samples and hold the value in between (a slower sensor).

    The inner sensor is measured (and draws its noise) only at its own sample instants.
    """

    def __init__(self, inner: Sensor, every: int):
        super().__init__(inner)
        if int(every) != every or every < 1:
            raise ValueError(f"every must be a positive integer, got {every!r}")
        self.every = int(every)
        self._held = np.zeros((0, inner.dim))
        self._count = np.zeros(0, int)

    def allocate(self, num: int) -> None:
        """A held value and a counter per member."""
        super().allocate(num)
        self._held = np.zeros((num, self.dim))
        self._count = np.zeros(num, int)

    def sample_periods_s(self) -> set[float]:
        """The inner sensor samples every ``every`` control periods: its periods / every."""
        return {p / self.every for p in self.inner.sample_periods_s()}

    def reset(self, sample: Sample, noise: Noise) -> None:
        """Inner reset; the next sample is taken."""
        super().reset(sample, noise)
        self._count[sample.members] = 0

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """New values for members at a sample instant, the held ones otherwise."""
        m = sample.members
        count = self._count[m]
        due = count % self.every == 0
        held = self._held[m]
        if due.any():
            index = np.arange(len(self._count))[m][due]
            sub = Sample(sample.x[due], sample.t_s[due], sample.u[due], sample.w[due], index)
            held[due] = self.inner.measure(sub, Noise(noise.streams, index))
        self._held[m] = held
        self._count[m] = count + 1
        return held.copy()


class Tap(Decorator):
    """Pass the inner measurement through and keep it per member in :attr:`last` (num, m).

    For inputs computed from measurements: a design's ``input_transform`` reads the latest
    sample of the channels it taps (e.g. the vehicle's ``a_y`` = speed times yaw rate), so
    every estimator in the loop gets the measured input.
    """

    own_draws = 0

    def __init__(self, inner: Sensor):
        super().__init__(inner)
        self.last = np.zeros((0, inner.dim))

    def allocate(self, num: int) -> None:
        """A row of the latest values per member."""
        super().allocate(num)
        self.last = np.zeros((num, self.dim))

    def apply(self, y: np.ndarray, sample: Sample, noise: Noise) -> np.ndarray:
        """``y``, also stored in ``last``."""
        self.last[sample.members] = y
        return y
