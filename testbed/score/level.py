"""Level and power of the consistency verdict, by Monte Carlo on the calibration plant.

The calibration entry's design model is exact (``LinearPlantRig.design_model``: the
simulator's own linear control step, its held acceleration noise and the sensor's
covariance), so the Kalman filter on it is the minimum-variance estimator of what the harness
simulates and its NEES and NIS are chi-square at every step. Its estimation error does not
depend on the (known) input, so it is simulated here directly, without MuJoCo, for many
independent studies of ``N`` runs x ``K`` steps:

    e_0 ~ N(0, P0),  e_k^- = F e_(k-1) - w_k,  nu_k = -H e_k^- + v_k,  e_k = e_k^- + K_k nu_k

with ``w ~ N(0, Q)``, ``v ~ N(0, R)`` and the filter's deterministic gains ``K_k``,
covariances ``P_k`` and ``S_k``. A filter that reports ``c P`` (and ``c S``) instead has
NEES and NIS divided by ``c`` on the same runs: ``c = 0.9`` is overconfident (NEES 11 % too
large), ``c = 1.1`` underconfident. The rate of each verdict of
:func:`testbed.score.consistency.consistency_test` over the studies is the verdict's level
(``c = 1``: how often a consistent filter is called over- or underconfident) and power.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from testbed.score.consistency import (
    CONSISTENT,
    INCONCLUSIVE,
    NO_VERDICT,
    OVERCONFIDENT,
    UNDERCONFIDENT,
    clopper_pearson,
    consistency_test,
)

#: Verdicts counted by :func:`verdict_rates`.
VERDICTS = (CONSISTENT, OVERCONFIDENT, UNDERCONFIDENT, INCONCLUSIVE, NO_VERDICT)


@dataclass(frozen=True)
class LinearGaussianModel:
    """A discrete linear-Gaussian model and its prior (shapes: ``F`` (n, n), ``H`` (m, n),
    ``Q`` (n, n), ``R`` (m, m), ``P0`` (n, n)); ``dt_s`` the period in seconds."""

    F: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    P0: np.ndarray
    dt_s: float


def calibration_model() -> LinearGaussianModel:
    """The calibration entry's exact design model, as the harness builds it."""
    from testbed.experiment import runner
    from testbed.score.suite import calibration_entry

    scenario = calibration_entry(2, 1.0, None).resolved_scenario().replace(estimator="kalman")
    experiment = runner.build(scenario, 1)
    try:
        d = experiment.design
        plant = d.discrete
        return LinearGaussianModel(F=np.array(plant.F), H=np.array(plant.H),
                                   Q=np.array(plant.Q), R=np.array(plant.R),
                                   P0=np.array(d.P0), dt_s=float(plant.dt_s))
    finally:
        experiment.close()


def kalman_sequence(model: LinearGaussianModel, steps: int
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The Kalman filter's gains ``K_k`` (steps, n, m), covariances ``P_k`` (steps, n, n)
    and innovation covariances ``S_k`` (steps, m, m) for ``k = 1..steps`` from ``P0``
    (predict, then update; Joseph form)."""
    F, H, Q, R = model.F, model.H, model.Q, model.R
    n, m = H.shape[1], H.shape[0]
    gains, covs, innov = np.empty((steps, n, m)), np.empty((steps, n, n)), np.empty((steps, m, m))
    P = model.P0
    eye = np.eye(n)
    for k in range(steps):
        P = F @ P @ F.T + Q
        S = H @ P @ H.T + R
        G = np.linalg.solve(S, H @ P).T
        A = eye - G @ H
        P = A @ P @ A.T + G @ R @ G.T
        P = 0.5 * (P + P.T)
        gains[k], covs[k], innov[k] = G, P, S
    return gains, covs, innov


def kalman_nees_nis(model: LinearGaussianModel, members: int, steps: int,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """NEES (members, steps) and NIS (members, steps) of the exact Kalman filter on
    ``members`` independent runs of ``steps`` steps (see the module docstring)."""
    if members < 1 or steps < 1:
        raise ValueError(f"members and steps must be positive, got {members}, {steps}")
    gains, covs, innov = kalman_sequence(model, steps)
    F, H = model.F, model.H
    n, m = H.shape[1], H.shape[0]
    lam, vec = np.linalg.eigh(model.Q)  # Q may be singular (one noise input)
    lq = vec * np.sqrt(np.maximum(lam, 0.0))
    lr = np.linalg.cholesky(model.R)
    e = rng.standard_normal((members, n)) @ np.linalg.cholesky(model.P0).T
    nees, nis = np.empty((members, steps)), np.empty((members, steps))
    for k in range(steps):
        prior = e @ F.T - rng.standard_normal((members, n)) @ lq.T
        nu = -prior @ H.T + rng.standard_normal((members, m)) @ lr.T
        e = prior + nu @ gains[k].T
        nees[:, k] = np.einsum("bi,bi->b", e @ np.linalg.inv(covs[k]), e)
        nis[:, k] = np.einsum("bi,bi->b", nu @ np.linalg.inv(innov[k]), nu)
    return nees, nis


def verdict_rates(model: LinearGaussianModel, runs: int, steps: int, studies: int,
                  seed: int, scales: tuple[float, ...] = (1.0, 0.9, 1.1),
                  members_per_batch: int = 400_000) -> dict[str, Any]:
    """Counts of the NEES and NIS verdicts of ``studies`` independent studies of ``runs``
    runs x ``steps`` steps of the calibration Kalman filter reporting ``scale`` times its
    covariances.

    Parameters
    ----------
    model : LinearGaussianModel
    runs, steps, studies : int
        ``runs >= 2``.
    seed : int
    scales : tuple of float
        Factors of the reported covariances (1: the consistent filter).
    members_per_batch : int
        Runs simulated at once (memory: about 16 bytes per run-step).

    Returns
    -------
    dict
        ``runs``, ``steps``, ``studies``, ``seed`` and ``counts``: ``{"nees" | "nis":
        {scale: {verdict: count}}}``.
    """
    if runs < 2 or steps < 1 or studies < 1:
        raise ValueError(f"need runs >= 2, steps >= 1, studies >= 1, got {runs}, {steps}, "
                         f"{studies}")
    rng = np.random.default_rng(seed)
    n, m = model.H.shape[1], model.H.shape[0]
    counts = {kind: {c: dict.fromkeys(VERDICTS, 0) for c in scales} for kind in ("nees", "nis")}
    per_batch = max(1, members_per_batch // (runs * steps))
    done = 0
    while done < studies:
        batch = min(per_batch, studies - done)
        nees, nis = kalman_nees_nis(model, batch * runs, steps, rng)
        for kind, values, dim in (("nees", nees, n), ("nis", nis, m)):
            values = values.reshape(batch, runs, steps)
            for c in scales:
                for study in values:
                    counts[kind][c][consistency_test(study / c, dim)["verdict"]] += 1
        done += batch
    return {"runs": runs, "steps": steps, "studies": studies, "seed": seed, "counts": counts}


def rate(count: int, total: int) -> tuple[float, tuple[float, float]]:
    """``count / total`` and its 95 % Clopper-Pearson interval."""
    return count / total, clopper_pearson(count, total)
