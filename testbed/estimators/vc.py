"""The discrete variance-constrained H2/H-infinity filter designed from any rig's design model.

:mod:`filters.variance_discrete` (Liu, Deng & Wang; the second equation and the gains
reconstructed) designs the constant-gain one-step predictor ``xhat(k+1) = G xhat(k) + K y(k)``
for a plant with norm-bounded uncertainty. The design builds that plant
(:class:`~filters.analysis.UncertainPlant`) from a :class:`~testbed.design.DesignModel`::

    x(k+1) = (F + M Fu N) x(k) + D1 w(k),   D1 = [G_d, Q^(1/2), 0]
    y(k)   = H x(k)            + D2 w(k),   D2 = [0,   0,  R^(1/2)]
    z(k)   = L x(k)                                             (design.output_matrix)

``F, H, Q, R`` are the discrete design model's (exact ZOH), ``G_d`` the held scenario
disturbance matrix when the design has one (the noise part is
:func:`testbed.estimators.stochastic_system.design_system`'s, so ``gamma`` bounds the gain from the
scenario's ``w`` to ``z`` as lmi-hinf's does), ``||Fu||_2 <= 1``.

The uncertainty ``M Fu N`` (the rig's declared parameter mismatch, first order) is built by
:mod:`testbed.estimators.vc_mismatch`, the design (its rules, the output-injection loop of a
plant with free integrators, the verification) by :mod:`testbed.estimators.vc_design`; this
module holds the estimator.

In the loop
-----------
The design is a one-step predictor for a zero-mean stationary state: its error dynamics
``e(k+1) = G e(k) + (A - G - K C) x(k) + ...`` contain the state itself (the gains trade
bias for variance, ``G != A - K C``), so a state driven far from zero by a known input (a
manoeuvre) would enter the error. :class:`VarianceConstrainedPredictor` therefore splits
the state into the nominal response to the known input and the noise-driven rest,
``x = x_bar + x_tilde``: ``x_bar(k+1) = F0 x_bar(k) + B u(k) + L0 (y(k) - D u(k))`` from the
prior mean (``F0 = F``, ``L0 = 0`` on a stable design model), and the designed predictor
estimates ``x_tilde`` from ``y - D u - H x_bar``. On the nominal linear
plant ``x_tilde`` is exactly the design's stationary plant (whatever the input, also in
closed loop: ``u`` is known), so the design's bounds hold; with a mismatch, ``(Delta F)
x_bar`` drives ``x_tilde`` and is outside them (:mod:`testbed.estimators.vc_mismatch`).
Known means exogenous: an input the design model computes from the estimate (the matched
helicopter design's command past the current limit at the *estimated* rotor speed) closes a
loop through the predictor that no bound covers; measured there, a certified design
diverges (docs/scoring.md), which is why ``vc-discrete`` designs from the paper model on the
hardware entries (:func:`vc_discrete_matched` designs from the matched one).

Timing: ``xhat(k+1)`` uses ``y`` up to ``k``. The loop gives ``step(y_(k+1), u_k)`` with
``y`` measured at the end of the step; the estimator keeps the previous measurement, uses
it and returns its estimate of the state at the new measurement's time from the
measurements before it (one sample behind the Kalman filter's update: on the vehicle the
a-priori error of the optimal predictor is already 2.3 times the filter's in roll rate).
``prime(y_0)`` stores the first sample (taken with zero input, as the simulator measures at
reset); unprimed, the first step uses the measurement the prior predicts, ``H x0``. The
filter has no covariance (``P`` is None); the design's bound ``diag(P2)`` is in
``design_meta``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from filters import real_array
from filters.variance_constrained import LinearFilter
from testbed.estimators.vc_design import (
    DELTA,
    INJECTION_SCALES,
    VCDesign,
    design_vc_discrete,
    output_injection,
    reference_covariance,
    uncertain_plant,
)
from testbed.estimators.vc_mismatch import (
    FAMILY,
    RANK_TOL,
    MismatchUncertainty,
    mismatch_uncertainty,
)

__all__ = ["DELTA", "FAMILY", "INJECTION_SCALES", "RANK_TOL", "MismatchUncertainty",
           "VCDesign", "VarianceConstrainedPredictor", "design_vc_discrete",
           "mismatch_uncertainty", "output_injection", "reference_covariance",
           "uncertain_plant", "vc_discrete_estimator", "vc_discrete_matched"]


class VarianceConstrainedPredictor:
    """The designed one-step predictor in the loop (batch-first; see the module docstring).

    A :class:`~filters.variance_constrained.LinearFilter` on ``s = [x_bar; d_hat]``::

        x_bar(k+1) = F0 x_bar(k) + B u(k) + L0 y'(k)   (the known signals' response)
        d_hat(k+1) = G d_hat(k) + K (y'(k) - H x_bar(k))   (the design)
        x_hat      = x_bar + d_hat

    with ``y'(k) = y(k) - D u(k-1)`` and ``F0 = F - L0 H`` (``L0 = 0`` without injection).

    Parameters
    ----------
    G, K : ndarray, shapes (n, n), (n, p)
        The designed predictor.
    F, B : ndarray, shapes (n, n), (n, k)
        The design model's state and input matrices.
    D : ndarray, shape (p, k) or None
        Feedthrough of the measured channels.
    H : ndarray, shape (p, n)
        Measurement matrix.
    x0 : ndarray, shape (n,) or (N, n)
    dt_s : float
    injection : ndarray, shape (n, p), optional
        ``L0`` of the output-injection loop (:mod:`testbed.estimators.vc_design`).
    """

    batched = True
    #: A constant-gain predictor propagates no covariance.
    P = None

    def __init__(self, G: np.ndarray, K: np.ndarray, F: np.ndarray, B: np.ndarray,
                 D: np.ndarray | None, H: np.ndarray, x0: np.ndarray, dt_s: float,
                 injection: np.ndarray | None = None):
        n, p = K.shape
        k = B.shape[1]
        L0 = np.zeros((n, p)) if injection is None else np.asarray(injection, float)
        Ga = np.block([[F - L0 @ H, np.zeros((n, n))], [-K @ H, G]])
        Ka = np.vstack([L0, K])
        Ba = np.vstack([B, np.zeros((n, k))])
        self._n = n
        self.filter = LinearFilter(Ga, Ka, self._augment(x0), discrete=True, dt_s=dt_s,
                                   B=Ba)
        self._DT = None if D is None or not np.any(D) else np.ascontiguousarray(
            np.asarray(D, float).T)
        self._HT = np.ascontiguousarray(np.asarray(H, float).T)
        self._y: np.ndarray | None = None
        self.design_meta: dict[str, Any] = {}

    def _augment(self, x0: Any) -> np.ndarray:
        x = real_array(x0, "x0")
        if x.ndim < 1 or x.shape[-1] != self._n:
            raise ValueError(f"x0 must have shape ({self._n},) or (N, {self._n}), got "
                             f"{x.shape}")
        return np.concatenate([x, np.zeros_like(x)], axis=-1)

    @property
    def x(self) -> np.ndarray:
        """Estimate of the state at the last measurement's time, shape (N, n) or (n,)."""
        s = self.filter.x
        return s[..., :self._n] + s[..., self._n:]

    def reset(self, x0: np.ndarray, P0: Any = None) -> None:
        """Restart from ``x0`` (``P0`` is ignored: constant gains)."""
        self.filter.reset(self._augment(x0))
        self._y = None

    def prime(self, y: np.ndarray) -> None:
        """Keep the first measurement (zero input at reset), shape (N, p) or (p,)."""
        self._y = self._measurement(y)

    def _measurement(self, y: Any) -> np.ndarray:
        y = real_array(y, "y")
        shape = (*self.filter.x.shape[:-1], self._HT.shape[1])
        if y.shape != shape:
            raise ValueError(f"y must have shape {shape}, got {y.shape}")
        return y

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Advance with the previous measurement and ``u``; keep ``y - D u`` for the next.

        Parameters
        ----------
        y : ndarray, shape (N, p) or (p,)
            Measurement at the end of the step.
        u : ndarray, shape (N, k) or (k,), or None
            Input over the step (design-model coordinates).

        Returns
        -------
        ndarray, shape (N, n) or (n,)
            The estimate of the state at ``y``'s time.
        """
        y = self._measurement(y)
        s = self.filter.x
        previous = (self._y if self._y is not None
                    else np.vecmat(s[..., :self._n] + s[..., self._n:], self._HT))
        self.filter.step(previous, u)
        if self._DT is not None and u is not None:
            y = y - np.vecmat(np.asarray(u, float), self._DT)
        self._y = y
        return self.x


def vc_discrete_estimator(design: Any, **options: Any
                          ) -> tuple[VarianceConstrainedPredictor, dict[str, Any]]:
    """:class:`VarianceConstrainedPredictor` of :func:`design_vc_discrete` and its meta."""
    vc = design_vc_discrete(design, **options)
    plant = design.discrete
    est = VarianceConstrainedPredictor(vc.G, vc.K, plant.F, plant.B, plant.D, plant.H,
                                       design.x0, design.dt_s, injection=vc.injection)
    meta = vc.meta()
    est.design_meta = meta
    return est, meta


def vc_discrete_matched(design: Any, **options: Any) -> Any:
    """``vc-discrete`` designed from the entry's matched (augmented) model, for ``testbed score
    --estimator testbed.estimators.vc:vc_discrete_matched`` (``vc-discrete`` itself designs
    from the paper model on a hardware entry: its ``paper_design_only`` says why).

    The uncertainty ``M Fu N`` of a matched design comes from the derivatives of its own
    discrete model (:mod:`testbed.estimators.vc_mismatch`). A design the theory cannot make
    is refused with its reason (``ValueError``), never replaced by the paper design.
    """
    from testbed.estimators import vc_discrete

    return vc_discrete(design, **options)


vc_discrete_matched.name = "vc-discrete-matched"
