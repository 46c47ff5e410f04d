"""A rig's nominal dynamics expanded to third order: the capability the polynomial
H-infinity family (:mod:`testbed.estimators.poly`) asks a rig for
(:meth:`testbed.rigs.base.Rig.cubic_model`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CubicExpansion:
    """Third-order expansion of a rig's nominal dynamics in the design model's state.

    Attributes
    ----------
    a0 : ndarray, shape (n,)
        Constant term (e.g. the gravity torque at the expansion point).
    a1 : ndarray, shape (n, n)
        Linear term (the design model's ``A``).
    a2 : ndarray, shape (n, n, n) or None
        ``f_k += sum_ij a2[k, i, j] x_i x_j``.
    a3 : ndarray, shape (n, n, n, n) or None
        ``f_k += sum_ijl a3[k, i, j, l] x_i x_j x_l``.
    E : ndarray, shape (n, k)
        Input matrix of ``u_p``.
    input_offset : callable ``x_hat (N, n) -> (N, k)``, optional
        Added to the design-model input ``u`` to give ``u_p`` (None: ``u_p = u``).
    description : str
        What was expanded, about which point, and what the expansion leaves out.
    """

    a0: np.ndarray
    a1: np.ndarray
    a2: np.ndarray | None
    a3: np.ndarray | None
    E: np.ndarray
    input_offset: Callable[[np.ndarray], np.ndarray] | None = None
    description: str = ""

    def f(self, x: np.ndarray, u_p: np.ndarray | None = None) -> np.ndarray:
        """``a0 + a1 x + a2 x x + a3 x x x (+ E u_p)``, shape (..., n) for ``x`` (..., n)."""
        x = np.asarray(x, float)
        out = self.a0 + x @ self.a1.T
        if self.a2 is not None:
            out = out + np.einsum("kij,...i,...j->...k", self.a2, x, x)
        if self.a3 is not None:
            out = out + np.einsum("kijl,...i,...j,...l->...k", self.a3, x, x, x)
        if u_p is not None:
            out = out + np.asarray(u_p, float) @ self.E.T
        return out
