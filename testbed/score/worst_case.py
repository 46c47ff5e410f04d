"""Adversarial search for the worst energy-bounded disturbance of an estimator in the loop.

The gain of a disturbance ``w`` (held over each control period ``dt``) on the scenario's
disturbance channel is::

    gain(w) = ||dz||_2 / ||w||_2,    ||f||_2^2 = sum_k |f_k|^2 dt,
    dz = L (x_hat - x) with w  -  L (x_hat - x) without w

the output estimation error the disturbance causes: the error of the closed-loop run with
``w`` minus the error of the run with the same seed without it (common random numbers:
measurement noise, process noise and the initial estimation error cancel; for a linear loop
``dz`` is exactly the deterministic error system's response). Every reported gain is such a
measured ratio of two runs of the nonlinear rig; a larger one found later only raises it, so
the result is a lower bound of the worst case, never a certificate.

Every closed-loop run of the search measures **probe sensors**: the scenario's sensors with
the rounding of every :class:`~testbed.sensors.Quantize` decorator removed
(:func:`without_quantization`; noise, bias, delays, holds and the linear model kept, the
estimator unchanged). With quantized sensors a disturbance also moves the truth across
quantization steps, and ``dz`` then contains the change of the quantization error, a term of
the order of the step whatever the disturbance: on the helicopter's encoders it floored every
filter's gain at about 1e-3 rad per unit of ``w`` (Kalman 0.00111, Kalman-Bucy 0.00136,
poly-hinf 0.00146 over the quick suite's 3 s) and ranked nothing. Without quantization
``dz`` is the error system's response to ``w`` (plus the rig's and the estimator's own
nonlinearity).

The search (Tierno, Murray, Doyle & Gregory 1997 style):

1. **The loop's error system, measured.** Impulses ``eps e_j`` on each channel of ``w`` at
   step ``k0 = K / 4`` (past the gains' transient), one batched closed-loop run of ``k0 + K``
   steps on the probe sensors (:meth:`LoopEvaluator.impulse_response`), give the impulse
   response ``t_l`` of ``w -> dz``, so that ``dz_k = sum_i t_(k-i) w_i`` (the linearization
   about run 0 at ``k0``, taken as time-invariant). It contains everything in the loop: the
   controller's reaction to the disturbed truth, the estimator's response to measurements and
   inputs (input transform included), the sensors' delays and holds. (The model-based
   alternative, ``t_l = L (g^x_l - sum_(a+b=l) h_a g^y_b)`` from the rig's open-loop
   linearization and the estimator's Markov parameters, :func:`plant_markov`,
   :func:`estimator_markov`, :func:`error_response`, misses the controller: on the
   helicopter the open-loop yaw integrates ``w`` while the LQR holds it, and its predictions
   were 3 to 4 times the gains the loop has.)
2. **Power iteration with the adjoint.** Subspace iteration on ``T^T T`` (forward: the
   convolution; adjoint: the correlation with ``t^T``, both by FFT) gives the top right
   singular vectors ``v_1..v_p`` over the horizon.
3. **Refinement on the nonlinear rig.** ``+-v_1`` scaled to the energy, then
   ``scipy.optimize.differential_evolution`` (derivative-free, vectorized: one batched
   closed-loop run per generation) over ``w(c) = v_1 + sum_i c_i v_(i+1)``, ``c in
   [-1, 1]^(p-1)``, each candidate scaled to the energy.

Random gain: the largest gain of white Gaussian disturbances of the same energy.
"""

from __future__ import annotations

import copy
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import differential_evolution

from testbed.rigs.disturbances import SampledDisturbance


# ---------------------------------------------------------------------------- linear model
def plant_markov(A_d: np.ndarray, G_d: np.ndarray, C: np.ndarray, Hw: np.ndarray,
                 lags: int) -> tuple[np.ndarray, np.ndarray]:
    """Responses of state and measurement to a unit ``w`` at lag 0.

    ``x_(i+l) = A_d^(l-1) G_d w_i`` (``l >= 1``) and ``y_(i+l) = C x_(i+l) + Hw w_i [l = 0]``
    (the simulator's timing: ``w_i`` is held over step ``i`` and is the disturbance sample of
    ``y_i``).

    Returns
    -------
    gx : ndarray, shape (lags, n, s)
    gy : ndarray, shape (lags, m, s)
    """
    n, s = G_d.shape
    gx = np.zeros((lags, n, s))
    if lags > 1:
        gx[1] = G_d
        for lag in range(2, lags):
            gx[lag] = A_d @ gx[lag - 1]
    gy = np.einsum("mn,lns->lms", C, gx)
    gy[0] += Hw
    return gx, gy


def causal_conv(a: np.ndarray, b: np.ndarray, lags: int) -> np.ndarray:
    """``c_l = sum_(i+j=l) a_i b_j`` for ``l < lags`` (matrix-valued, by FFT).

    ``a``: (La, p, r), ``b``: (Lb, r, s) -> (lags, p, s).
    """
    nfft = _fft_size(len(a) + len(b))
    A = np.fft.rfft(a, nfft, axis=0)
    B = np.fft.rfft(b, nfft, axis=0)
    c = np.fft.irfft(np.einsum("fpr,frs->fps", A, B), nfft, axis=0)[:lags]
    if len(c) < lags:
        c = np.concatenate([c, np.zeros((lags - len(c), *c.shape[1:]))])
    return c


def _fft_size(n: int) -> int:
    from scipy.fft import next_fast_len

    return next_fast_len(int(n), real=True)


class ErrorOperator:
    """The error system over ``K`` steps as a causal convolution ``w (K, s) -> dz (K, q)``.

    ``dz_k = sum_(i=0)^(K-1) t_(k-i) w_i`` for ``k = 1..K`` (row ``k-1`` of the output).

    Parameters
    ----------
    t : ndarray, shape (lags, q, s)
        Impulse response (``t_l`` for lags ``l = 0..lags-1``; zero beyond).
    steps : int
        Horizon ``K``.
    """

    def __init__(self, t: np.ndarray, steps: int):
        self.K = int(steps)
        self.q, self.s = t.shape[1:]
        t = t[: self.K + 1]
        self.nfft = _fft_size(2 * self.K + 2)
        self._T = np.fft.rfft(t, self.nfft, axis=0)  # (f, q, s)
        self._TH = np.conj(self._T).transpose(0, 2, 1)

    def forward(self, w: np.ndarray) -> np.ndarray:
        """``dz`` for a batch ``w`` (B, K, s) -> (B, K, q)."""
        W = np.fft.rfft(w, self.nfft, axis=1)
        z = np.fft.irfft(np.einsum("fqs,bfs->bfq", self._T, W), self.nfft, axis=1)
        return z[:, 1:self.K + 1]

    def adjoint(self, z: np.ndarray) -> np.ndarray:
        """``T^T dz`` for a batch ``dz`` (B, K, q) -> (B, K, s)."""
        padded = np.zeros((z.shape[0], self.nfft, self.q))
        padded[:, 1:self.K + 1] = z
        Z = np.fft.rfft(padded, axis=1)
        return np.fft.irfft(np.einsum("fsq,bfq->bfs", self._TH, Z), self.nfft,
                            axis=1)[:, : self.K]


def top_singular(op: ErrorOperator, p: int, rng: np.random.Generator, *, max_iter: int = 150,
                 rtol: float = 1e-6) -> tuple[np.ndarray, np.ndarray, int]:
    """Top ``p`` singular values and right singular vectors by subspace (power) iteration.

    Each iteration applies ``T^T T`` (:meth:`ErrorOperator.forward` then
    :meth:`ErrorOperator.adjoint`) to ``p`` vectors, orthonormalizes them (QR) and takes the
    Rayleigh-Ritz values; it stops when the largest changes by less than ``rtol``.

    Returns
    -------
    gains : ndarray, shape (p,)
        Decreasing.
    V : ndarray, shape (p, K, s)
        Orthonormal (in the plain sum over steps and channels).
    iterations : int
    """
    K, s = op.K, op.s
    p = min(p, K * s)
    V = rng.standard_normal((p, K * s))
    V = np.linalg.qr(V.T)[0].T
    previous, iteration = 0.0, 0
    while iteration < max_iter:
        iteration += 1
        Z = op.forward(V.reshape(p, K, s))
        V = op.adjoint(Z).reshape(p, K * s)
        Q = np.linalg.qr(V.T)[0].T
        Z = op.forward(Q.reshape(p, K, s)).reshape(p, -1)
        _, sv, vt = np.linalg.svd(Z @ Z.T)  # Rayleigh-Ritz in the span of Q
        V = vt @ Q
        gains = np.sqrt(np.maximum(sv, 0.0))
        if abs(gains[0] - previous) <= rtol * gains[0]:
            break
        previous = gains[0]
    return gains, V.reshape(p, K, s), iteration


@dataclass(frozen=True)
class ImpulseNorm:
    """Infinite-horizon H-infinity norm of an error system from its measured impulse
    response (:func:`hinf_from_impulse`), in the response's units.

    Attributes
    ----------
    value : float
        The norm: that of the realized LTI system when the realization reproduces the
        measured response (``method == "realization"``), else ``fft_value``.
    method : {"realization", "truncated FFT"}
    fft_value : float
        ``max_w sigma_max(T_L(e^jw))`` of the response truncated at ``lags`` lags.
    truncation : float
        Estimated tail ``sum_(l >= lags) ||t_l||_2`` (from the decay of the envelope of the
        last half of the response; ``inf`` when it does not decay): ``fft_value`` is within
        this of the norm of the measured system.
    order : int
        Order of the realization (0: none).
    fit : float
        Relative l2 misfit of the realization's impulse response over the measured lags
        (``inf``: none).
    lags : int
    horizon_s : float
        ``lags * dt_s``, the measured horizon.
    peak_hz : float
        Frequency of the maximum of the truncated response.
    """

    value: float
    method: str
    fft_value: float
    truncation: float
    order: int
    fit: float
    lags: int
    horizon_s: float
    peak_hz: float

    def describe(self) -> dict[str, Any]:
        """JSON-ready (non-finite numbers as None)."""
        return {"value": self.value, "method": self.method, "fft_value": self.fft_value,
                "truncation": _finite(self.truncation), "order": self.order,
                "fit": _finite(self.fit), "impulse_lags": self.lags,
                "impulse_horizon_s": self.horizon_s, "peak_hz": self.peak_hz}


def _sigma_max(t: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``sigma_max(sum_l t_l e^(-j omega l))`` at each ``omega`` (rad per step)."""
    phase = np.exp(-1j * np.outer(omega, np.arange(len(t))))  # (f, L)
    T = np.einsum("fl,lqs->fqs", phase, t)
    return np.linalg.svd(T, compute_uv=False)[:, 0]


def _truncated_norm(t: np.ndarray, oversample: int) -> tuple[float, float]:
    """Peak of ``sigma_max`` of the truncated response (zero-padded FFT, refined on a fine
    grid around the largest bin) and its frequency in rad per step."""
    nfft = _fft_size(oversample * len(t))
    coarse = np.linalg.svd(np.fft.rfft(t, nfft, axis=0), compute_uv=False)[:, 0]
    k = int(np.argmax(coarse))
    step = 2 * np.pi / nfft
    omega = np.clip(k * step + np.linspace(-step, step, 65), 0.0, np.pi)
    fine = _sigma_max(t, omega)
    j = int(np.argmax(fine))
    if fine[j] >= coarse[k]:
        return float(fine[j]), float(omega[j])
    return float(coarse[k]), k * step


def _tail(t: np.ndarray, windows: int) -> float:
    """Estimated ``sum_(l >= L) ||t_l||_2`` from a geometric decay fitted to the envelope
    (window maxima) of the last half of the response."""
    norms = np.linalg.norm(t, ord=2, axis=(1, 2))
    half = norms[len(t) // 2:]
    width = len(half) // windows
    envelope = half[: width * windows].reshape(windows, width).max(axis=1)
    if np.all(envelope == 0):
        return 0.0
    if np.any(envelope == 0) or envelope[-1] >= envelope[0]:
        return float("inf")
    rho = float(np.exp(np.polyfit(np.arange(windows), np.log(envelope), 1)[0]))
    # each later window at most the last one's envelope, decaying by rho from the second on
    return float("inf") if rho >= 1 else float(envelope[-1] * width / (1 - rho))


def realize(t: np.ndarray, rows: int = 100, rtol: float = 1e-6, max_order: int = 40
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A state-space realization ``(A, B, C, D)`` of an impulse response by the eigensystem
    realization algorithm (Ho & Kalman 1966; Juang & Pappa 1985): the SVD of the block
    Hankel matrix of ``t_1`` to ``t_(2 rows)``, truncated at the singular values above ``rtol``
    times the largest (at most ``max_order``), ``A`` from the shifted Hankel matrix,
    ``D = t_0``.

    Parameters
    ----------
    t : ndarray, shape (L, q, s), L >= 2 rows + 2
    rows, max_order : int
    rtol : float

    Returns
    -------
    A (r, r), B (r, s), C (q, r), D (q, s)
    """
    L, q, s = t.shape
    rows = min(rows, (L - 2) // 2)
    if rows < 1:
        raise ValueError(f"t needs at least 4 lags, got {L}")
    lag = 1 + np.add.outer(np.arange(rows), np.arange(rows))  # block (i, j): t_(1 + i + j)
    H0 = t[lag].transpose(0, 2, 1, 3).reshape(rows * q, rows * s)
    H1 = t[lag + 1].transpose(0, 2, 1, 3).reshape(rows * q, rows * s)
    U, S, Vt = np.linalg.svd(H0, full_matrices=False)
    if S[0] == 0:
        return np.zeros((0, 0)), np.zeros((0, s)), np.zeros((q, 0)), t[0].copy()
    r = int(min(np.sum(S > rtol * S[0]), max_order))
    root = np.sqrt(S[:r])
    A = (U[:, :r] / root).T @ H1 @ (Vt[:r].T / root)
    B = (root[:, None] * Vt[:r])[:, :s]
    C = (U[:, :r] * root)[:q]
    return A, B, C, t[0].copy()


def hinf_from_impulse(t: np.ndarray, dt_s: float, oversample: int = 8, windows: int = 8,
                      max_fit: float = 1e-3) -> ImpulseNorm:
    """Infinite-horizon H-infinity norm of the discrete system whose impulse response is
    ``t`` (the sampled error system: ``t_l`` the response at lag ``l`` to a unit ``w`` held
    over one period).

    Two estimates: the norm of the realized LTI system (:func:`realize`;
    :func:`filters.analysis.hinf_norm`, to 1e-6), used when the realization is stable and
    reproduces the measured response over all its lags within ``max_fit`` (relative l2);
    and the peak of the frequency response of the truncated response (zero-padded FFT,
    ``oversample`` times its length, refined around the largest bin), whose distance to the
    norm is at most the tail ``sum_(l >= L) ||t_l||``, estimated from a geometric decay
    ``rho`` per window fitted to the envelope (the window maxima of ``||t_l||``) of the last
    half of the response in ``windows`` windows: ``width e / (1 - rho)``, ``e`` the last
    window's maximum (an estimate, not a proof). Without a valid realization the FFT value
    is the result.

    Parameters
    ----------
    t : ndarray, shape (L, q, s)
    dt_s : float
        Sampling period (for ``horizon_s`` and ``peak_hz``).
    oversample, windows : int
    max_fit : float

    Returns
    -------
    ImpulseNorm
    """
    from filters.analysis import hinf_norm

    t = np.asarray(t, dtype=float)
    if t.ndim != 3 or len(t) < 2 * windows or not np.all(np.isfinite(t)):
        raise ValueError(f"t must be finite with shape (L, q, s), L >= {2 * windows}, got "
                         f"{t.shape}")
    L = len(t)
    fft_value, peak = _truncated_norm(t, oversample)
    truncation = _tail(t, windows)
    A, B, C, D = realize(t)
    value, method, fit, order = fft_value, "truncated FFT", float("inf"), len(A)
    if order and np.all(np.isfinite(A)) and np.max(np.abs(np.linalg.eigvals(A))) < 1:
        h = np.empty_like(t)
        h[0], x = D, B
        for lag in range(1, L):
            h[lag] = C @ x
            x = A @ x
        scale = np.linalg.norm(t)
        fit = float(np.linalg.norm(h - t) / scale) if scale > 0 else 0.0
        if fit <= max_fit:
            value, method = float(hinf_norm(A, B, C, D, discrete=True)), "realization"
    return ImpulseNorm(value=value, method=method, fft_value=fft_value,
                       truncation=truncation, order=order, fit=fit, lags=L,
                       horizon_s=L * dt_s, peak_hz=peak / (2 * np.pi * dt_s))


def estimator_markov(estimator: Any, input_transform: Any, prior: tuple[np.ndarray, Any],
                     y: np.ndarray, u: np.ndarray, k0: int, deltas: np.ndarray,
                     batch: int) -> np.ndarray:
    """Markov parameters ``h_a`` of an estimator's response to its measurements.

    One batched run of the estimator on the recorded measurements ``y`` and applied inputs
    ``u`` (through the loop's input transform, at each member's own estimate): member 0 as
    recorded, member ``1 + j`` with ``deltas[j]`` added to channel ``j`` of the measurement
    of step ``k0``; ``h_a[:, j] = (x_hat_(1+j) - x_hat_0)[k0 + a] / deltas[j]``.

    Parameters
    ----------
    estimator : batched estimator (the loop's)
        Reset here; the loop resets it again before its next episode.
    input_transform : callable or None
    prior : (x0 (n,), P0 or None)
    y : ndarray, shape (K + 1, m)
        Measurements (row 0 at reset).
    u : ndarray, shape (K, nu)
        Inputs applied over steps 0..K-1 (rig units).
    k0 : int
        Step of the impulses (1 <= k0 <= K).
    deltas : ndarray, shape (m,)
    batch : int
        Members of the estimator (>= m + 1).

    Returns
    -------
    ndarray, shape (K + 1 - k0, n, m)
    """
    K, m = len(u), y.shape[1]
    if batch < m + 1:
        raise ValueError(f"the estimator batch ({batch}) must exceed the channels ({m})")
    x0, P0 = prior
    estimator.reset(np.tile(x0, (batch, 1)), P0)
    prime = getattr(estimator, "prime", None)
    if prime is not None:
        prime(np.tile(y[0], (batch, 1)))
    rows = np.arange(1, m + 1)
    out = np.zeros((K + 1 - k0, x0.shape[0], m))
    for k in range(K):
        x_hat = np.asarray(estimator.x, dtype=float)
        uk = np.tile(u[k], (batch, 1))
        if input_transform is not None:
            uk = input_transform(uk, x_hat)
        yk = np.tile(y[k + 1], (batch, 1))
        if k + 1 == k0:
            yk[rows, np.arange(m)] += deltas
        x_hat = np.asarray(estimator.step(yk, uk), dtype=float)
        if k + 1 >= k0:
            out[k + 1 - k0] = ((x_hat[1:m + 1] - x_hat[0]) / deltas[:, None]).T
    return out


def error_response(gx: np.ndarray, gy: np.ndarray, h: np.ndarray, L: np.ndarray
                   ) -> np.ndarray:
    """``t_l = L (g^x_l - sum_(a+b=l) h_a g^y_b)``, shape (lags, q, s)."""
    lags = len(gx)
    xhat = causal_conv(h, gy, lags)
    return np.einsum("qn,lns->lqs", L, gx - xhat)


# ---------------------------------------------------------------------------- probe sensors
def _unquantized_class() -> type:
    from testbed.sensors import Quantize
    from testbed.sensors.decorators import Decorator

    class Unquantized(Decorator):
        """A :class:`~testbed.sensors.Quantize` with the rounding removed: the measurement
        passes through, the linear model keeps the quantizer's ``q^2 / 12`` (so the design
        model built from the probe sensors is the original one)."""

        def __init__(self, quantizer: Quantize):
            super().__init__(quantizer.inner)
            self.step = quantizer.step

        linear_model = Quantize.linear_model

    return Unquantized


def without_quantization(sensor: Any) -> tuple[Any, list[str]]:
    """A copy of a sensor suite whose :class:`~testbed.sensors.Quantize` decorators pass the
    measurement through unrounded.

    The tree of :class:`~testbed.sensors.Suite` members and
    :class:`~testbed.sensors.decorators.Decorator` wrappers (the way sensors are composed) is
    copied (deep: no state is shared with the original) and each ``Quantize`` is replaced by
    an ``Unquantized`` decorator around the same inner sensor: no rounding, the same linear
    model (``R`` keeps the quantizer's ``q^2 / 12``, so a design model built from the copy is
    the original's). Every other decorator (noise, bias, delay, hold, tap) stays in its place
    and draws the same noise. A quantizer inside a sensor that is neither a ``Suite`` nor a
    ``Decorator`` (a rig's own composite channel) is not found.

    Returns
    -------
    sensor : Sensor
        The copy (the original object itself when nothing is quantized).
    removed : list of str
        The channels whose quantization was removed, in the suite's order.
    """
    from testbed.sensors import Quantize, Suite
    from testbed.sensors.decorators import Decorator

    unquantized = _unquantized_class()
    removed: list[str] = []

    def strip(s: Any) -> Any:
        if isinstance(s, Suite):
            parts = [strip(p) for p in s.sensors]
            if all(a is b for a, b in zip(parts, s.sensors, strict=True)):
                return s
            return Suite(*parts)
        if isinstance(s, Quantize):
            removed.extend(s.names)
            s.inner = strip(s.inner)
            return unquantized(s)
        if isinstance(s, Decorator):
            inner = strip(s.inner)
            if inner is s.inner:
                return s
            s.inner = inner
            return s
        return s

    stripped = strip(copy.deepcopy(sensor))
    if not removed:
        return sensor, []
    order = {name: i for i, name in enumerate(sensor.names)}
    return stripped, sorted(removed, key=order.get)


# ---------------------------------------------------------------------------- loop side
def _finite(value: float) -> float | None:
    """``value``, or None when it is not finite (JSON has no infinity)."""
    return float(value) if np.isfinite(value) else None


@dataclass
class SearchResult:
    """Outcome of :func:`search` (gains in the channel's units: output unit per w unit).

    Attributes
    ----------
    worst_case_gain : float
        Largest measured gain of the search's candidates.
    worst_case_w : ndarray, shape (K, s)
        The disturbance attaining it (energy ``energy``).
    random_gain : float
        Largest measured gain of the random disturbances.
    linear_gain : float
        ``sigma_max`` of the linearized error system over the horizon (a prediction, and a
        lower bound of its H-infinity norm).
    evaluations : int
        Closed-loop candidate runs (random ones included).
    iterations : int
        Power iterations.
    energy : float
    horizon_s : float
    notes : list of str
    probe_sensors : str
        Description of the sensors of the probe runs (:meth:`Sensor.describe`).
    quantization_removed : list of str
        Channels measured without their quantization in the probe runs
        (:func:`without_quantization`).
    hinf : ImpulseNorm, optional
        The infinite-horizon H-infinity norm of the measured error system
        (:func:`hinf_from_impulse`).
    restart_gains : list of float
        The best gain of each restart of the refinement (``worst_case_gain`` is their
        maximum; their range is the search's spread).
    """

    worst_case_gain: float
    worst_case_w: np.ndarray
    random_gain: float
    linear_gain: float
    evaluations: int
    iterations: int
    energy: float
    horizon_s: float
    notes: list[str] = field(default_factory=list)
    probe_sensors: str = ""
    quantization_removed: list[str] = field(default_factory=list)
    hinf: ImpulseNorm | None = None
    restart_gains: list[float] = field(default_factory=list)

    def describe(self) -> dict[str, Any]:
        """JSON-ready: the search's settings, its linear prediction (finite horizon) and the
        infinite-horizon norm (the report's ``worst_case_search``)."""
        norm = None if self.hinf is None else self.hinf.describe()
        return {"linear_gain": self.linear_gain, "hinf_norm": norm,
                "restart_gains": list(self.restart_gains), "energy": self.energy,
                "horizon_s": self.horizon_s, "evaluations": self.evaluations,
                "iterations": self.iterations, "probe_sensors": self.probe_sensors,
                "quantization_removed": list(self.quantization_removed),
                "quantization": "removed" if self.quantization_removed else "none"}


class LoopEvaluator:
    """Measured gains of candidate disturbances on a built closed loop (batched).

    Two builds of the same probe loop: ``candidates``, whose member 0 runs without ``w`` (the
    baseline of its batch) and every other member a candidate disturbance, and ``impulse``,
    with ``s + 1`` members (member 0 without ``w``; member ``1 + j`` an impulse on channel
    ``j``). Every member of both has the same seed. Each candidate's ``dz`` is taken against
    the baseline of its own batch, not one run elsewhere: an estimator whose arithmetic
    depends on its batch companions (poly-hinf chooses its integration substeps for the whole
    batch) would otherwise put the difference of two integrations into ``dz`` (on
    ``vehicle-step-steer`` it moved poly-hinf's random gain by a factor 3 under a 1e-9
    change of the energy).

    Parameters
    ----------
    candidates : testbed.experiment.runner.Experiment
        Its simulator's disturbance must be ``disturbance``.
    disturbance : SampledDisturbance
        Values (num, >= K, s), rewritten per batch.
    impulse : testbed.experiment.runner.Experiment
        The same loop with ``s + 1`` members; its simulator's disturbance must be
        ``impulse_disturbance``.
    impulse_disturbance : SampledDisturbance
        Values (s + 1, >= 1, s).
    seed : int
    steps : int
        Horizon K.
    output_matrix : ndarray, shape (q, n)
    """

    def __init__(self, candidates: Any, disturbance: SampledDisturbance, impulse: Any,
                 impulse_disturbance: SampledDisturbance, seed: int, steps: int,
                 output_matrix: np.ndarray):
        self.loop, self.dist = candidates.loop, disturbance
        self.impulse_loop, self.impulse_dist = impulse.loop, impulse_disturbance
        s = disturbance.values.shape[2]
        if self.impulse_loop.sim.num != s + 1 or impulse_disturbance.values.shape[2] != s:
            raise ValueError(f"the impulse loop needs {s + 1} members and {s} channels, got "
                             f"{self.impulse_loop.sim.num} and "
                             f"{impulse_disturbance.values.shape[2]}")
        self.seed, self.K = int(seed), int(steps)
        self.L = np.asarray(output_matrix, float)
        self.num = self.loop.sim.num
        if self.num < 2:
            raise ValueError(f"the candidates' loop needs at least 2 members (a baseline and "
                             f"a candidate), got {self.num}")
        self.dt_s = self.loop.sim.dt_s
        self.evaluations = 0
        #: The baseline's output error, (steps, q) from step 1 (set by the impulse response).
        self._baseline: np.ndarray | None = None

    def _errors(self, loop: Any, steps: int) -> np.ndarray:
        """Output errors ``z`` (members, steps run, q) of one run of ``loop``, from step 1."""
        return self._output_errors(loop.run(np.full(loop.sim.num, self.seed),
                                            steps * self.dt_s, record=True))

    def _output_errors(self, result: Any) -> np.ndarray:
        """Output errors ``z`` (members, steps, q) of a recorded run, from step 1."""
        rec = result.trajectory
        return np.einsum("qn,btn->btq", self.L, rec["estimate"] - rec["state"])[:, 1:]

    def baseline(self) -> np.ndarray:
        """The output error of the run without ``w``, (K, q) (or fewer steps, if the episode
        ended): member 0 of the impulse response's run, run now without impulses if that has
        not run yet."""
        if self._baseline is None or len(self._baseline) < self.K:  # none, or cut short
            self.impulse_dist.values[:] = 0.0
            self._baseline = self._errors(self.impulse_loop, self.K)[0]
        return self._baseline[: self.K]

    def run(self, W: np.ndarray) -> np.ndarray:
        """Gains of the candidates ``W`` (B, K, s), in batches of ``num - 1``: member 0 of
        every batch runs without ``w`` and is that batch's baseline (an estimator whose
        arithmetic depends on its batch companions, such as one integrating with a step
        chosen for the whole batch, then differs from the baseline only by ``w``)."""
        W = np.asarray(W, dtype=float)
        gains = np.empty(len(W))
        size = self.num - 1
        for start in range(0, len(W), size):
            chunk = W[start:start + size]
            self.dist.values[:] = 0.0
            self.dist.values[1:1 + len(chunk), : self.K] = chunk
            z = self._errors(self.loop, self.K)
            z0 = z[0]
            steps = z.shape[1]
            dz = z[1:1 + len(chunk)] - z0
            w_energy = np.sum(chunk[:, :steps] ** 2, axis=(1, 2))
            gains[start:start + len(chunk)] = np.sqrt(np.sum(dz**2, axis=(1, 2))
                                                      / np.maximum(w_energy, 1e-300))
            self.evaluations += len(chunk)
        if not np.all(np.isfinite(gains)):
            raise FloatingPointError("a worst-case candidate gave a non-finite gain")
        return gains

    def impulse_response(self, k0: int, eps: float, *, tapes: dict[str, Any] | None = None,
                         key: str = "") -> np.ndarray:
        """The loop's error system measured: ``t_l`` for ``l = 0..K``, shape (K + 1, q, s).

        One batched closed-loop run of ``k0 + K`` steps of the impulse loop: member 0 without
        ``w`` (the baseline, kept for :meth:`run`), member ``1 + j`` with ``w_(k0) = eps e_j``
        (one step, channel ``j``); ``t_l[:, j] = dz_(k0 + l) / eps`` (the timing of
        :class:`ErrorOperator`). The controller's reaction to the disturbed truth (or
        estimate), the estimator's response to the measurements and to the inputs, the
        sensors' delays and holds are all in it; for a linear loop it is exact, otherwise the
        linearization about the run (``eps`` small) at step ``k0`` (an estimator whose gains
        still move after ``k0`` is taken as time-invariant).

        With ``tapes`` and a loop whose controller acts on the truth, the run is simulated
        once per ``key`` (the caller's: everything the run depends on but the estimator) and
        replayed for every further estimator (:meth:`ClosedLoop.replay`, bitwise the same).
        """
        s = self.impulse_dist.values.shape[2]
        if not 1 <= k0 <= self.K:
            raise ValueError(f"k0 must be in [1, {self.K}], got {k0}")
        self.impulse_dist.values[:] = 0.0
        self.impulse_dist.values[1 + np.arange(s), k0, np.arange(s)] = eps
        loop = self.impulse_loop
        if tapes is not None and loop.truth_feedback and key in tapes:
            z = self._output_errors(loop.replay(tapes[key], record=True))
        else:
            shared = tapes is not None and loop.truth_feedback
            result = loop.run(np.full(loop.sim.num, self.seed), (k0 + self.K) * self.dt_s,
                              record=True, tape=shared)
            if shared:
                tapes[key] = result.tape  # type: ignore[index]
            z = self._output_errors(result)
        self.impulse_dist.values[:] = 0.0
        self._baseline = z[0]
        dz = (z[1:1 + s] - z[0]) / eps  # (s, steps, q), row k - 1 is step k
        t = np.zeros((self.K + 1, self.L.shape[0], s))
        rows = dz[:, k0 - 1:k0 + self.K].transpose(1, 2, 0)  # l = 0..K
        t[: len(rows)] = rows
        if not np.all(np.isfinite(t)):
            raise FloatingPointError("the loop's impulse response is not finite")
        return t


def population(dimensions: int) -> int:
    """Members of the refinement's population for ``dimensions`` coefficients (DE's
    ``popsize`` times the dimensions, at least 5)."""
    return dimensions * max(2, int(np.ceil(5 / dimensions))) if dimensions > 0 else 0


def scaled(w: np.ndarray, energy: float, dt_s: float) -> np.ndarray:
    """``w`` (..., K, s) scaled to ``sum_k |w_k|^2 dt = energy`` (each leading index)."""
    norm = np.sqrt(np.sum(w**2, axis=(-2, -1), keepdims=True) * dt_s)
    return w * np.sqrt(energy) / norm


#: Independent restarts of the refinement (their candidates share each closed-loop batch).
RESTARTS = 3


class _Gather:
    """Candidates of several callers (threads) evaluated as one batch per round.

    Each caller hands its candidates to :meth:`__call__` and waits; when every active caller
    has handed its own, they are evaluated together, in the callers' order (deterministic
    whatever the threads' timing), and each gets its part. :meth:`done` retires a caller.
    """

    def __init__(self, evaluate: Any, parties: int):
        self.evaluate = evaluate
        self.cond = threading.Condition()
        self.active = set(range(parties))
        self.pending: dict[int, np.ndarray] = {}
        self.results: dict[int, np.ndarray] = {}
        self.error: BaseException | None = None
        self.round = 0

    def _flush(self) -> None:
        order = sorted(self.pending)
        sizes = [len(self.pending[i]) for i in order]
        try:
            gains = self.evaluate(np.concatenate([self.pending[i] for i in order]))
        except BaseException as err:  # handed to every waiting caller
            self.error = err
        else:
            for i, part in zip(order, np.split(gains, np.cumsum(sizes)[:-1]), strict=True):
                self.results[i] = part
        self.pending.clear()
        self.round += 1
        self.cond.notify_all()

    def __call__(self, index: int, W: np.ndarray) -> np.ndarray:
        with self.cond:
            if self.error is None:
                self.pending[index] = W
                current = self.round
                if set(self.pending) >= self.active:
                    self._flush()
                while self.round == current and self.error is None:
                    self.cond.wait()
            if self.error is not None:
                raise RuntimeError("a batch of the worst-case refinement failed") \
                    from self.error
            return self.results.pop(index)

    def done(self, index: int) -> None:
        with self.cond:
            self.active.discard(index)
            if self.pending and set(self.pending) >= self.active:
                self._flush()


def search(evaluator: LoopEvaluator, t: np.ndarray, *, energy: float, random_draws: int,
           basis: int, generations: int, rng: np.random.Generator,
           restarts: int = RESTARTS) -> SearchResult:
    """The worst-case search on one closed loop (see the module docstring).

    Parameters
    ----------
    evaluator : LoopEvaluator
        Its candidates' loop should have ``restarts * population(basis - 1) + 1`` members
        (one batch per generation of all restarts).
    t : ndarray, shape (lags, q, s)
        Impulse response of the error system (:meth:`LoopEvaluator.impulse_response`, or
        :func:`error_response` of a model), zero beyond ``lags``.
    energy : float
    random_draws, basis, generations : int
    rng : numpy.random.Generator
        Start of the power iteration, the random disturbances, the refinements' streams
        (:meth:`numpy.random.Generator.spawn`).
    restarts : int
        Independent differential-evolution refinements, run in lockstep (one batched
        closed-loop run per generation for all of them): the result is their maximum, and
        the restarts' best gains (``restart_gains``) show its spread.
    """
    if int(restarts) != restarts or restarts < 1:
        raise ValueError(f"restarts must be a positive integer, got {restarts}")
    K, dt = evaluator.K, evaluator.dt_s
    s = t.shape[2]
    op = ErrorOperator(t, K)
    gains, V, iterations = top_singular(op, basis, rng)
    notes: list[str] = []

    random_w = scaled(rng.standard_normal((random_draws, K, s)), energy, dt)
    v1 = scaled(V[0], energy, dt)
    first = evaluator.run(np.concatenate([v1[None], -v1[None], random_w]))
    random_gain = float(first[2:].max())
    best = int(np.argmax(first[:2]))
    sign = 1.0 if best == 0 else -1.0
    worst, worst_w = float(first[best]), sign * v1
    restart_gains = [worst]

    d = len(V) - 1
    if generations > 0 and d > 0:
        streams = rng.spawn(int(restarts))
        records = [{"gain": worst, "w": worst_w} for _ in streams]
        gather = _Gather(evaluator.run, len(streams))

        def candidates(c: np.ndarray) -> np.ndarray:
            c = np.atleast_2d(c.T).reshape(-1, d)  # (S, d)
            w = sign * (V[0][None] + np.einsum("bd,dks->bks", c, V[1:]))
            return scaled(w, energy, dt)

        def refine(index: int) -> None:
            record = records[index]

            def objective(c: np.ndarray) -> np.ndarray:
                w = candidates(c)
                g = gather(index, w)
                j = int(np.argmax(g))
                if g[j] > record["gain"]:
                    record["gain"], record["w"] = float(g[j]), w[j]
                return -g

            try:
                differential_evolution(objective, [(-1.0, 1.0)] * d, maxiter=generations,
                                       popsize=population(d) // d, x0=np.zeros(d),
                                       vectorized=True, updating="deferred", polish=False,
                                       tol=0.0, rng=streams[index])
            except BaseException as err:  # re-raised by the caller
                record["error"] = err
            finally:
                gather.done(index)

        threads = [threading.Thread(target=refine, args=(i,), daemon=True)
                   for i in range(len(streams))]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        for record in records:
            if "error" in record:
                error = record["error"]
                raise error.__cause__ if isinstance(error, RuntimeError) and \
                    error.__cause__ is not None else error
        restart_gains = [r["gain"] for r in records]
        top = int(np.argmax(restart_gains))
        worst, worst_w = records[top]["gain"], records[top]["w"]
    if worst < random_gain:
        notes.append(f"the search ({worst:.2g}) stayed below a random disturbance "
                     f"({random_gain:.2g})")
    return SearchResult(worst_case_gain=worst, worst_case_w=worst_w, random_gain=random_gain,
                        linear_gain=float(gains[0]), evaluations=evaluator.evaluations,
                        iterations=iterations, energy=energy, horizon_s=K * dt, notes=notes,
                        hinf=hinf_from_impulse(t, dt), restart_gains=restart_gains)
