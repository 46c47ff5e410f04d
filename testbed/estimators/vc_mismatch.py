"""The uncertainty ``M Fu N`` of vc-discrete (:mod:`testbed.estimators.vc`): first order in
the declared parameter mismatch.

A rig declares its parameter-mismatch range (:attr:`testbed.rigs.base.Rig.mismatch_range`:
field ``p_i`` scaled by any ``s_i`` in ``[1 - r_i, 1 + r_i]``; the scoring suite's +-20 %
entries scale these fields). For each declared field:

1. ``A_i' = dA/ds_i`` at ``s = 1``: central differences of the rig's MuJoCo linearization
   at ``params.scaled({p_i: 1 +- 1e-3})`` (:meth:`~testbed.rigs.base.ParameterMismatch.
   derivatives`);
2. ``Delta_i = r_i dF/ds_i`` with the exact derivative of the ZOH map ``F = e^(A dt)``
   (the Frechet derivative, :func:`scipy.linalg.expm_frechet`): the first-order change of
   ``F`` at ``s_i = 1 +- r_i``. A matched (augmented) design (rotor, bias and delay states;
   a discrete model that is not the ZOH of its continuous one on the delay rows) has no
   such ``A``: steps 1-2 are then ``dF/ds_i`` of its own discrete model, central
   differences of the matched design rebuilt at ``params.scaled({p_i: 1 +- 1e-3})``
   (:meth:`testbed.design.mismatch.MatchedMismatch.discrete_derivatives`; the rebuild at
   the nominal parameters must reproduce the design's ``F``), ``Delta_i = r_i dF/ds_i``;
3. ``Delta_i = U_i S_i V_i^T`` (SVD; singular values below ``rank_tol = 1e-3`` of the
   block's largest dropped: directions of order ``dt^2`` that no physical parameter moves,
   which a full ``Fu`` would otherwise couple into every other block), split evenly,
   ``M_i = U_i S_i^(1/2)``, ``N_i = S_i^(1/2) V_i^T`` in the design model's units;
4. ``M = [M_1, ..., M_k]``, ``N = [N_1; ...; N_k]``: ``sum_i f_i Delta_i = M diag(f_1 I,
   ..., f_k I) N`` for ``|f_i| <= 1``. The design covers every ``||Fu||_2 <= 1``, a superset
   of these block-diagonal ``Fu``.

What this covers, and what it does not: the linearized, first-order effect of the mismatch
on ``F`` (the ``O(r^2)`` remainder and the nonlinear rig are outside it; the input matrix
``B``, the sensors and the noise are taken as nominal). The variance bound is a statement
about the stationary, noise-driven error: an input (a manoeuvre) moves the state far from
zero, and with a mismatch the error then has a part ``(Delta F) x_u`` that no design for
the input-free plant bounds. A rig that declares no range gets ``M = N = 0`` (the nominal
H2/H-infinity design with variance constraints).

"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import expm_frechet

#: Name of the family in the estimator registry (error messages).
FAMILY = "vc-discrete"
#: Singular values of a block ``Delta_i`` below this fraction of its largest are dropped.
RANK_TOL = 1e-3


@dataclass(frozen=True)
class MismatchUncertainty:
    """``Delta F = M Fu N`` from a rig's declared parameter-mismatch range (first order).

    Attributes
    ----------
    M : ndarray, shape (n, i)
    N : ndarray, shape (i, n)
    parameters : tuple of str
        The mismatched fields, in block order (empty: no range declared, ``M = N = 0``).
    ranges : tuple of float
        Their relative half-ranges ``r_i``.
    blocks : tuple of int
        Columns of ``M`` (rows of ``N``) per parameter.
    deltas : ndarray, shape (k, n, n)
        ``Delta_i = r_i dF/ds_i``.
    continuous : ndarray, shape (k, n, n) or (0, n, n)
        ``dA/ds_i`` of the rig's linearization (empty for a matched design, whose
        derivative is of ``F`` itself).
    dropped : float
        Largest ``||Delta_i - M_i N_i||_2 / ||Delta_i||_2`` (the truncated directions).
    source : str
        ``"linearization"`` (``dA/ds`` and the Frechet derivative of the ZOH map) or
        ``"matched design"`` (``dF/ds`` of the matched design rebuilt at scaled parameters).
    """

    M: np.ndarray
    N: np.ndarray
    parameters: tuple[str, ...]
    ranges: tuple[float, ...]
    blocks: tuple[int, ...]
    deltas: np.ndarray
    continuous: np.ndarray
    dropped: float
    source: str = "linearization"

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {"parameters": list(self.parameters), "ranges": list(self.ranges),
                "blocks": list(self.blocks), "f_shape": [self.M.shape[1], self.N.shape[0]],
                "truncated_relative": self.dropped, "source": self.source,
                "model": "first-order Delta F = M Fu N, ||Fu|| <= 1 (linearized mismatch)"}


def mismatch_uncertainty(design: Any, *, rank_tol: float = RANK_TOL,
                         step: float = 1e-3) -> MismatchUncertainty:
    """The norm-bounded uncertainty of a design model (see the module docstring).

    Parameters
    ----------
    design : testbed.design.DesignModel
    rank_tol : float
        Relative singular-value threshold of each block.
    step : float
        Relative finite-difference step of the scale factors.

    Returns
    -------
    MismatchUncertainty

    Raises
    ------
    ValueError
        The rig's linearization does not have the design model's state dimension, or a
        matched design rebuilt at the nominal parameters is not this design.
    """
    n = design.n
    mismatch = design.extras.get("parameter_mismatch")
    matched = design.extras.get("matched_mismatch")
    if mismatch is None and matched is None:
        return MismatchUncertainty(np.zeros((n, 1)), np.zeros((1, n)), (), (), (1,),
                                   np.zeros((0, n, n)), np.zeros((0, n, n)), 0.0)
    if mismatch is None:
        try:
            derivatives = matched.discrete_derivatives(design.discrete.F, step)
        except ValueError as err:
            raise ValueError(f"filter {FAMILY!r}: {err}") from None
        mismatch, source = matched, "matched design"
    else:
        derivatives, source = mismatch.derivatives(step), "linearization"
    A, dt = np.asarray(design.continuous.A, float), float(design.dt_s)
    Ms, Ns, names, ranges, blocks, deltas, conts = [], [], [], [], [], [], []
    dropped = 0.0
    for name, dA in derivatives.items():
        if dA.shape != (n, n):
            raise ValueError(f"filter {FAMILY!r}: the rig's linearization has shape "
                             f"{dA.shape}, the design model's state {n}: the mismatch "
                             "derivative cannot be placed in the design model")
        r = float(mismatch.ranges[name])
        # a matched design's derivative is of F already (dA is dF/ds)
        delta = (r * dA if source == "matched design"
                 else r * expm_frechet(A * dt, dA * dt, compute_expm=False))
        U, S, Vt = np.linalg.svd(delta)
        if S[0] <= 0.0:
            continue  # this parameter does not move F
        keep = S > rank_tol * S[0]
        Mi, Ni = U[:, keep] * np.sqrt(S[keep]), np.sqrt(S[keep])[:, None] * Vt[keep]
        dropped = max(dropped, float(np.linalg.norm(delta - Mi @ Ni, 2) / S[0]))
        Ms.append(Mi)
        Ns.append(Ni)
        names.append(name)
        ranges.append(r)
        blocks.append(int(keep.sum()))
        deltas.append(delta)
        if source == "linearization":
            conts.append(dA)
    if not Ms:
        return MismatchUncertainty(np.zeros((n, 1)), np.zeros((1, n)), (), (), (1,),
                                   np.zeros((0, n, n)), np.zeros((0, n, n)), 0.0, source)
    return MismatchUncertainty(np.hstack(Ms), np.vstack(Ns), tuple(names), tuple(ranges),
                               tuple(blocks), np.array(deltas),
                               np.array(conts) if conts else np.zeros((0, n, n)), dropped,
                               source)

