"""The loop's error system as a linear operator, for the worst-case search
(:mod:`testbed.score.worst_case`): Markov parameters of a plant and an estimator, the
causal convolution and its adjoint by FFT (:class:`ErrorOperator`), its top singular
vectors over a horizon (:func:`top_singular`), and the H-infinity norm of a measured
impulse response (:func:`hinf_from_impulse`, :func:`realize`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from filters.base import Primed


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
                "truncation": finite_or_none(self.truncation), "order": self.order,
                "fit": finite_or_none(self.fit), "impulse_lags": self.lags,
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
    if isinstance(estimator, Primed):
        estimator.prime(np.tile(y[0], (batch, 1)))
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


def finite_or_none(value: float) -> float | None:
    """``value``, or None when it is not finite (JSON has no infinity)."""
    return float(value) if np.isfinite(value) else None
