"""Sensor suites: turn the true state into what a rig's electronics would report.

MuJoCo adds no sensor noise; every random number here comes from the generator the
environment passes in (its seeded ``np_random``), so a seed fixes the measurements.

Noise conventions:

- ``noise_std_*`` parameters are standard deviations of each discrete sample.
- ``intensity`` parameters are continuous-time white-noise intensities (power spectral
  densities, e.g. ``h h^T`` of ``dy = C x dt + h dW``); a sample taken every ``dt_s`` seconds
  (the average of ``dy/dt`` over the interval) has covariance ``intensity / dt_s``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _as_pair(value: float | tuple[float, float] | np.ndarray, name: str) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=float), (2,)).copy()
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name} must be finite and non-negative (one value or two), got {value}")
    return arr


@dataclass
class EncoderSuite:
    """Optical encoders on pitch and yaw, optionally with rate gyros.

    ``y = [round(pitch / q_p) q_p, round(yaw / q_y) q_y] + n`` where ``q = 2 pi / counts`` and
    ``n`` is optional Gaussian noise; with ``gyros=True`` two rate channels
    ``[pitch_rate, yaw_rate] + n_g`` follow.

    Parameters
    ----------
    counts_per_rev : (int, int)
        Encoder resolution (pitch, yaw), counts per revolution. Quanser's are 4096 and 8192.
    noise_std_rad : float or (float, float)
        Extra additive Gaussian noise on the angle channels (std per sample, rad).
    gyros : bool
        Append rate-gyro channels.
    gyro_noise_std_rad_s : float or (float, float)
        Gyro noise std per sample, rad/s.
    """

    counts_per_rev: tuple[int, int] = (4096, 8192)
    noise_std_rad: float | tuple[float, float] = 0.0
    gyros: bool = False
    gyro_noise_std_rad_s: float | tuple[float, float] = 0.005
    name: str = field(default="encoders", init=False)

    def __post_init__(self) -> None:
        counts = np.asarray(self.counts_per_rev)
        if counts.shape != (2,) or np.any(counts < 1) or np.any(counts != np.round(counts)):
            raise ValueError("counts_per_rev must be two positive integers (pitch, yaw), "
                             f"got {self.counts_per_rev}")
        self._quantum = 2 * np.pi / counts.astype(float)
        self._angle_std = _as_pair(self.noise_std_rad, "noise_std_rad")
        self._angle_noise = bool(np.any(self._angle_std > 0))
        self._gyro_std = _as_pair(self.gyro_noise_std_rad_s, "gyro_noise_std_rad_s")

    @property
    def names(self) -> list[str]:
        """Measurement channel names, length ``dim``."""
        return ["pitch", "yaw"] + (["pitch_rate", "yaw_rate"] if self.gyros else [])

    @property
    def dim(self) -> int:
        """Number of measurement channels."""
        return 4 if self.gyros else 2

    @property
    def measured_state_index(self) -> list[int | None]:
        """Index of the state each channel measures."""
        return [0, 1, 2, 3][: self.dim]

    @property
    def noise_draws(self) -> int:
        """Standard normal variates one sample consumes (angle noise, then gyro noise)."""
        return 2 * int(self._angle_noise) + 2 * int(self.gyros)

    def measure(self, x: np.ndarray, t_s: float, rng: np.random.Generator,
                w: np.ndarray | None = None) -> np.ndarray:
        """One sample of the sensors.

        Parameters
        ----------
        x : ndarray, shape (4,)
            True state.
        t_s : float
            Time (unused: encoders are time-invariant).
        rng : numpy.random.Generator
            Source of all noise (``noise_draws`` standard normal variates).
        w : ndarray, optional
            Deterministic disturbance (unused by this suite).

        Returns
        -------
        ndarray, shape (dim,)
        """
        xi = rng.standard_normal((1, self.noise_draws))
        return self.measure_batch(x[None], xi, None)[0]

    def measure_batch(self, x: np.ndarray, xi: np.ndarray,
                      w: np.ndarray | None = None) -> np.ndarray:
        """Samples of ``k`` states with given noise variates (what :meth:`measure` draws).

        Parameters
        ----------
        x : ndarray, shape (k, 4)
        xi : ndarray, shape (k, noise_draws)
            Standard normal variates, in the order :meth:`measure` draws them.
        w : ndarray, optional
            Unused.

        Returns
        -------
        ndarray, shape (k, dim)
        """
        angles = np.round(x[:, :2] / self._quantum) * self._quantum
        col = 0
        if self._angle_noise:
            angles = angles + self._angle_std * xi[:, :2]
            col = 2
        if not self.gyros:
            return angles
        rates = x[:, 2:4] + self._gyro_std * xi[:, col:col + 2]
        return np.concatenate([angles, rates], axis=1)

    def linear_model(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Observation matrix and per-sample noise covariance for filter design.

        Quantization is modelled as uniform white noise of variance ``q^2 / 12``.

        Returns
        -------
        C : ndarray, shape (dim, 4)
        R : ndarray, shape (dim, dim)
        """
        C = np.eye(4)[: self.dim]
        variances = self._quantum**2 / 12.0 + self._angle_std**2
        if self.gyros:
            variances = np.concatenate([variances, self._gyro_std**2])
        return C, np.diag(variances)


@dataclass
class PaperSuite:
    """seed-000's observation channels: ``dy1 = C1 x dt + h dW2`` and ``y2 = C2 x + H w``.

    The stochastic channel is sampled every ``dt_s``: ``y1 = C1 x + e`` with
    ``cov(e) = h h^T / dt_s`` (``intensity`` is ``h h^T``). The deterministic channel ``y2``
    is appended when ``C2`` and ``H`` are given and needs the disturbance ``w``.

    Parameters
    ----------
    C1 : ndarray, shape (m1, 4)
    intensity : ndarray, shape (m1, m1)
        ``h h^T``, continuous-time intensity (rad^2 s for angle channels).
    dt_s : float
        Sampling period in s.
    C2 : ndarray, shape (m2, 4), optional
    H : ndarray, shape (m2, s), optional
    """

    C1: np.ndarray = field(default_factory=lambda: np.eye(4)[:2])
    intensity: np.ndarray = field(default_factory=lambda: np.eye(2))
    dt_s: float = 0.01
    C2: np.ndarray | None = None
    H: np.ndarray | None = None
    name: str = field(default="paper", init=False)

    def __post_init__(self) -> None:
        self.C1 = np.atleast_2d(np.asarray(self.C1, dtype=float))
        if self.C1.ndim != 2 or self.C1.shape[1] != 4:
            raise ValueError(f"C1 must have shape (m1, 4), got {self.C1.shape}")
        m1 = self.C1.shape[0]
        self.intensity = np.atleast_2d(np.asarray(self.intensity, dtype=float))
        if self.intensity.shape != (m1, m1) or not np.allclose(self.intensity,
                                                                self.intensity.T):
            raise ValueError(f"intensity must be a symmetric ({m1}, {m1}) matrix, "
                             f"got shape {self.intensity.shape}")
        if not (np.isfinite(self.dt_s) and self.dt_s > 0):
            raise ValueError(f"dt_s must be a positive sampling period in s, got {self.dt_s}")
        try:
            self._chol = np.linalg.cholesky(self.intensity / self.dt_s)
        except np.linalg.LinAlgError:
            raise ValueError("intensity must be positive definite (h h^T > 0)") from None
        if (self.C2 is None) != (self.H is None):
            raise ValueError("C2 and H must be given together (y2 = C2 x + H w)")
        if self.C2 is not None:
            self.C2 = np.atleast_2d(np.asarray(self.C2, dtype=float))
            self.H = np.atleast_2d(np.asarray(self.H, dtype=float))
            if self.C2.shape[1] != 4 or self.H.shape[0] != self.C2.shape[0]:
                raise ValueError(f"C2 must be (m2, 4) and H (m2, s); got {self.C2.shape}, "
                                 f"{self.H.shape}")

    @property
    def dim(self) -> int:
        """Number of measurement channels (``m1 + m2``)."""
        return self.C1.shape[0] + (0 if self.C2 is None else self.C2.shape[0])

    @property
    def names(self) -> list[str]:
        """Channel names ``y1_0...`` then ``y2_0...``; angle channels named by their state."""
        state = ["pitch", "yaw", "pitch_rate", "yaw_rate"]
        out = []
        for prefix, C in (("", self.C1), ("y2_", self.C2)):
            if C is None:
                continue
            for i, row in enumerate(C):
                nz = np.flatnonzero(row)
                label = state[nz[0]] if len(nz) == 1 and row[nz[0]] == 1 else f"ch{i}"
                out.append(prefix + label)
        return out

    @property
    def measured_state_index(self) -> list[int | None]:
        """Index of the state each ``y1`` channel measures (``None`` for ``y2`` and mixtures)."""
        out: list[int | None] = []
        for row in self.C1:
            nz = np.flatnonzero(row)
            out.append(int(nz[0]) if len(nz) == 1 and row[nz[0]] == 1 else None)
        if self.C2 is not None:
            out += [None] * self.C2.shape[0]
        return out

    @property
    def noise_draws(self) -> int:
        """Standard normal variates one sample consumes (``m1``)."""
        return self.C1.shape[0]

    def measure(self, x: np.ndarray, t_s: float, rng: np.random.Generator,
                w: np.ndarray | None = None) -> np.ndarray:
        """One sample ``[y1, y2]``, shape (dim,).

        Raises
        ------
        ValueError
            If the suite has a ``y2`` channel and ``w`` is missing or of the wrong size.
        """
        xi = rng.standard_normal((1, self.noise_draws))
        return self.measure_batch(x[None], xi, None if w is None else np.asarray(w)[None])[0]

    def measure_batch(self, x: np.ndarray, xi: np.ndarray,
                      w: np.ndarray | None = None) -> np.ndarray:
        """Samples of ``k`` states with given noise variates.

        Parameters
        ----------
        x : ndarray, shape (k, 4)
        xi : ndarray, shape (k, m1)
        w : ndarray, shape (k, s), optional
            Required with a ``y2`` channel.

        Returns
        -------
        ndarray, shape (k, dim)
        """
        y1 = np.matvec(self.C1, x) + np.matvec(self._chol, xi)
        if self.C2 is None:
            return y1
        if w is None or w.shape[1:] != (self.H.shape[1],):
            raise ValueError(f"w must have shape ({self.H.shape[1]},) for the y2 channel")
        return np.concatenate([y1, np.matvec(self.C2, x) + np.matvec(self.H, w)], axis=1)

    def linear_model(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``C1`` and the sampled covariance ``intensity / dt_s`` of the stochastic channel.

        Returns
        -------
        C : ndarray, shape (m1, 4)
        R : ndarray, shape (m1, m1)
        """
        return self.C1.copy(), self.intensity / dt_s


@dataclass
class DisturbanceChannel:
    """A sensor suite plus seed-000's deterministic channel ``y2 = C2 x + H w``.

    The channel carries no noise: ``w`` is the environment's deterministic disturbance at the
    sample time (zeros when it has none).

    Parameters
    ----------
    base : EncoderSuite or PaperSuite
        The stochastic channels ``y1`` (first ``base.dim`` entries).
    C2 : ndarray, shape (m2, 4)
    H : ndarray, shape (m2, s)
    """

    base: EncoderSuite | PaperSuite
    C2: np.ndarray
    H: np.ndarray
    name: str = field(default="", init=False)

    def __post_init__(self) -> None:
        self.C2 = np.atleast_2d(np.asarray(self.C2, dtype=float))
        self.H = np.atleast_2d(np.asarray(self.H, dtype=float))
        if self.C2.shape[1] != 4 or self.H.shape[0] != self.C2.shape[0]:
            raise ValueError(f"C2 must be (m2, 4) and H (m2, s); got {self.C2.shape}, "
                             f"{self.H.shape}")
        self.name = f"{self.base.name}+y2"

    @property
    def dim(self) -> int:
        """``base.dim + m2``."""
        return self.base.dim + self.C2.shape[0]

    @property
    def names(self) -> list[str]:
        """Base channel names, then ``y2_0, y2_1, ...``."""
        return self.base.names + [f"y2_{i}" for i in range(self.C2.shape[0])]

    @property
    def measured_state_index(self) -> list[int | None]:
        """The base suite's, then ``None`` for the ``y2`` channels."""
        return self.base.measured_state_index + [None] * self.C2.shape[0]

    @property
    def noise_draws(self) -> int:
        """The base suite's (the ``y2`` channel is noise-free)."""
        return self.base.noise_draws

    def measure(self, x: np.ndarray, t_s: float, rng: np.random.Generator,
                w: np.ndarray | None = None) -> np.ndarray:
        """``[y1, C2 x + H w]``, shape (dim,); ``w = 0`` when None."""
        xi = rng.standard_normal((1, self.noise_draws))
        return self.measure_batch(x[None], xi, None if w is None else np.asarray(w)[None])[0]

    def measure_batch(self, x: np.ndarray, xi: np.ndarray,
                      w: np.ndarray | None = None) -> np.ndarray:
        """``[y1, C2 x + H w]`` for ``k`` states, shape (k, dim); ``w`` (k, s) or None."""
        w = np.zeros((len(x), self.H.shape[1])) if w is None else w
        return np.concatenate([self.base.measure_batch(x, xi, None),
                               np.matvec(self.C2, x) + np.matvec(self.H, w)], axis=1)

    def linear_model(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The stochastic channels' ``(C, R)`` (see the base suite)."""
        return self.base.linear_model(dt_s)


SENSOR_SUITES = ("encoders", "encoders+gyros", "paper")


def make_sensor_suite(name: str, dt_s: float, **kwargs) -> EncoderSuite | PaperSuite:
    """Build a sensor suite by name.

    Parameters
    ----------
    name : {"encoders", "encoders+gyros", "paper"}
    dt_s : float
        Control (sampling) period, used by the ``paper`` suite's intensity.
    **kwargs
        Passed to the suite's constructor.

    Raises
    ------
    ValueError
        Unknown name (the valid ones are listed).
    """
    if name == "encoders":
        return EncoderSuite(**kwargs)
    if name == "encoders+gyros":
        return EncoderSuite(gyros=True, **kwargs)
    if name == "paper":
        return PaperSuite(dt_s=dt_s, **kwargs)
    raise ValueError(f"unknown sensor suite {name!r}; expected one of {SENSOR_SUITES}")
