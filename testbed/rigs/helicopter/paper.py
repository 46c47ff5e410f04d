"""Basin et al.'s helicopter example: the printed linear model (misprints corrected), the
mean-square H-infinity example's gamma and initial weight, and its disturbance ``G w(t)``,
``b dW``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from testbed.rigs.disturbances import Disturbance


@dataclass(frozen=True)
class LinearModel:
    """Continuous-time linear model ``x' = A x + B u`` (+ noise/disturbance inputs).

    Attributes
    ----------
    A : ndarray, shape (4, 4)
    B : ndarray, shape (4, 2)
    b : ndarray, shape (4, 2) or None
        White-noise input matrix (``b dW``), intensity ``b b^T``.
    G : ndarray, shape (4, s) or None
        Deterministic disturbance input matrix.
    C1, C2, L, h, H : ndarray or None
        Observation, output and noise matrices of Basin et al. (12)-(15).
    """

    A: np.ndarray
    B: np.ndarray
    b: np.ndarray | None = None
    G: np.ndarray | None = None
    C1: np.ndarray | None = None
    C2: np.ndarray | None = None
    L: np.ndarray | None = None
    h: np.ndarray | None = None
    H: np.ndarray | None = None


def paper_model() -> LinearModel:
    """The linear helicopter model of Basin et al., eqs. (12)-(15), as printed.

    Corrected misprints (docs/references.md):

    - ``B`` is printed with three rows; the missing first row is ``[0, 0]`` (pitch angle
      row), giving ``B = [[0,0],[0,0],[2.3667,0.0790],[0.2410,0.7913]]``.
    - The constant matrix of (17)/(18) is ``G G^T`` (= ``b b^T``) whose first two rows are
      zero; the ``1`` entries printed there are not used (we compute ``G G^T``).

    Returns
    -------
    LinearModel
        ``A`` (4, 4), ``B`` (4, 2), ``b`` (4, 2), ``G`` (4, 4), ``C1 = C2 = L`` (2, 4),
        ``h`` (2, 2), ``H`` (2, 4).
    """
    A = np.array([[0.0, 0.0, 1.0, 0.0],
                  [0.0, 0.0, 0.0, 1.0],
                  [0.0, 0.0, -9.2751, 0.0],
                  [0.0, 0.0, 0.0, -3.4955]])
    B = np.array([[0.0, 0.0], [0.0, 0.0], [2.3667, 0.0790], [0.2410, 0.7913]])
    b = np.array([[0.0, 0.0], [0.0, 0.0], [0.9024, 0.0876], [0.0919, 0.8772]])
    G = np.zeros((4, 4))
    G[2:, :2] = b[2:]
    C = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
    H = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    return LinearModel(A=A, B=B, b=b, G=G, C1=C.copy(), C2=C.copy(), L=C.copy(),
                       h=np.eye(2), H=H)


#: The mean-square H-infinity example's attenuation level and initial-condition weight ``R``
#: of (6) (``S(0) = R^-1``), as printed.
PAPER_GAMMA = 1.1
PAPER_INITIAL_WEIGHT = np.array([[0.8, 0.5, 0.2, 0.1],
                                 [0.5, 0.8, 0.7, 0.2],
                                 [0.2, 0.7, 0.9, 0.4],
                                 [0.1, 0.2, 0.4, 0.9]])
PAPER_INITIAL_WEIGHT.flags.writeable = False


def basin_helicopter_w(t_s: float) -> np.ndarray:
    """Basin et al.'s (helicopter example) deterministic disturbance ``w(t)``, shape (4,).

    ``w1 = 1/(1+t)``, ``w2 = 0.1 (1 - exp(-0.3 t))``, ``w3 = 0.1745/(1+t)``,
    ``w4 = 0.0873 (1 - exp(-0.3 t))``. ``w2`` and ``w4`` do not decay, so ``||w||_2`` grows
    with the horizon (docs/references.md).
    """
    rise = 1.0 - np.exp(-0.3 * t_s)
    return np.array([1.0 / (1.0 + t_s), 0.1 * rise, 0.1745 / (1.0 + t_s), 0.0873 * rise])


def basin_helicopter_disturbance(noise_scale: float = 1.0,
                                 deterministic: bool = True) -> Disturbance:
    """Basin et al.'s helicopter disturbance: printed ``G w(t)`` and ``b dW``.

    Parameters
    ----------
    noise_scale : float
        Multiplies the printed ``b`` (0 removes the white noise).
    deterministic : bool
        Include ``G w(t)``.
    """
    pm = paper_model()
    if not (np.isfinite(noise_scale) and noise_scale >= 0):
        raise ValueError(f"noise_scale must be finite and >= 0, got {noise_scale}")
    return Disturbance(G=pm.G if deterministic else None,
                       w=basin_helicopter_w if deterministic else None,
                       b=pm.b * noise_scale if noise_scale > 0 else None)


def basin_signal():
    """The ``basin-helicopter`` disturbance signal: ``(G, w)`` of the printed model."""
    return paper_model().G, basin_helicopter_w
