"""Autocorrelation-consistent (HAC) intervals of a least-squares fit: Sokal's window, the
Bartlett long-run covariance of the scores, prewhitened by a VAR(1) (Andrews and Monahan 1992;
Newey and West 1987), as a variance ratio over the white-noise formula."""

from __future__ import annotations

import numpy as np

#: Largest singular value of the scores' prewhitening VAR(1) (Andrews and Monahan 1992
#: cap theirs at 0.97).
MAX_PREWHITEN_EIGENVALUE = 0.97


def sokal_bandwidth(g: np.ndarray) -> int:
    """Sokal's (1997) automatic window of each column's integrated autocorrelation time
    (the smallest M with M >= 5 tau(M)), the largest over the columns, at most T / 4."""
    T, p = g.shape
    bandwidth = 1
    for i in range(p):
        x = g[:, i] - g[:, i].mean()
        denom = float(x @ x)
        if denom <= 0:
            continue
        f = np.fft.rfft(x, 2 * T)
        acf = np.fft.irfft(f * np.conj(f))[:T] / denom
        tau = 1.0 + 2.0 * np.cumsum(acf[1:])
        window = np.flatnonzero(np.arange(1, T) >= 5.0 * tau)
        bandwidth = max(bandwidth, int(window[0]) + 1 if len(window) else T // 4)
    return int(min(bandwidth, max(T // 4, 1)))


def bartlett(g: np.ndarray, bandwidth: int) -> np.ndarray:
    """``sum_l w_l Gamma_l`` with Bartlett weights ``1 - |l| / (L + 1)``, (p, p)."""
    T, p = g.shape
    G = np.fft.rfft(g, 2 * T, axis=0)
    S = np.zeros((p, p))
    weights = 1.0 - np.arange(bandwidth + 1) / (bandwidth + 1.0)
    for i in range(p):
        for k in range(i, p):
            cc = np.fft.irfft(G[:, i] * np.conj(G[:, k]), 2 * T)  # sum_t g_i[t+l] g_k[t]
            pos = cc[:bandwidth + 1]  # lags 0..L
            neg = cc[::-1][:bandwidth]  # lags -1..-L
            S[i, k] = S[k, i] = weights[0] * pos[0] + np.sum(weights[1:] * (pos[1:] + neg))
    return S


def hac_inflation(J: np.ndarray, r: np.ndarray, T: int, m: int
                   ) -> tuple[np.ndarray, int, np.ndarray]:
    """Autocorrelation-consistent over white-noise variance ratios per parameter (>= 1), the
    bandwidth and the autocorrelation-consistent covariance.

    The sandwich ``H^-1 S H^-1`` (``H = J'J``) with the long-run covariance ``S`` of the
    per-sample scores ``g_t = J_t' r_t`` prewhitened (Andrews and Monahan 1992): a VAR(1)
    ``g_t = A g_(t-1) + u_t`` fitted by least squares (its eigenvalues held within
    :data:`MAX_PREWHITEN_EIGENVALUE`), the Newey and West (1987) Bartlett estimate of the
    whitened ``u``'s (the bandwidth by Sokal's window on them), recoloured
    ``S = (I - A)^-1 S_u (I - A)^-T``. Without the prewhitening a Bartlett window at the
    bandwidth of an AR(1) of ``rho = 0.8`` falls 20 % short of the long-run variance.

    ``J`` (T m, p), ``r`` (T m,) ordered sample-major.
    """
    p = J.shape[1]
    g = (J.reshape(T, m, p) * r.reshape(T, m, 1)).sum(axis=1)  # (T, p) scores per sample
    A = np.zeros((p, p))
    if T > 4 * p + 4:
        past, now = g[:-1], g[1:]
        A = np.linalg.lstsq(past, now, rcond=None)[0].T  # g_t ~ A g_(t-1)
        # Andrews and Monahan's adjustment: singular values capped (a near-unit root makes
        # (I - A)^-1 explode)
        U, sv, Vt = np.linalg.svd(A)
        A = U @ np.diag(np.minimum(sv, MAX_PREWHITEN_EIGENVALUE)) @ Vt
        u = np.vstack([g[:1], now - past @ A.T])
    else:
        u = g
    bandwidth = sokal_bandwidth(u)
    S_u = bartlett(u, bandwidth)
    recolour = np.linalg.inv(np.eye(p) - A)
    S = recolour @ S_u @ recolour.T
    H = J.T @ J
    Hinv = np.linalg.pinv(H)
    hac = Hinv @ S @ Hinv
    dof = max(J.shape[0] - p, 1)
    white = float(r @ r) / dof * np.diag(Hinv)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(white > 0, np.diag(hac) / white, 1.0)
    return np.maximum(ratio, 1.0), bandwidth, hac

