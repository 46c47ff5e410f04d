"""What a replay gives (:class:`ReplayResult`, its JSON summary) and the statistics computed
from it: the innovations' consistency without truth (:func:`innovation_consistency`) and
the RMSE of a held-out reference channel (:func:`reference_error`).

See :mod:`testbed.experiment.replay` for the definitions (ANIS and its band, the per-step
band fraction, the whiteness test, the reference's prediction ``C_j x_hat + D_j u``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from testbed.sensors import Sensor
from testbed.stats import (
    CONSISTENT,
    LEVEL,
    OVERCONFIDENT,
    UNDERCONFIDENT,
    chi2_bounds,
    clopper_pearson,
    whiteness_test,
)


@dataclass
class ReplayResult:
    """An estimator run over a recording.

    Attributes
    ----------
    source, sha256 : str
        The recording's.
    rig, profile, estimator, sensors : str
        What was replayed (``sensors``: the suite's description).
    period_s : float
        The estimator's period (a whole multiple ``every`` of the recording's).
    every : int
    time_s : ndarray, shape (K+1,)
        Times of the samples used (row 0: the reset).
    state_names, state_units : list of str
        The rig's physical states.
    x_hat : ndarray, shape (K+1, n)
        The estimate of the physical states after the reset and after each step.
    P_diag : ndarray, shape (K+1, n) or None
        Its variances (None: the estimator reports no covariance).
    measurement_names, measurement_units : list of str
        The channels of the estimator's sensor suite.
    measurement : ndarray, shape (K+1, m)
        The channels at the samples used (held-out ones included; a channel the estimator
        does not use and the recording lacks is NaN).
    innovation_names : list of str
        The channels of the innovation.
    innovations, innovation_var : ndarray, shape (K, p) or None
        The innovation ``nu_k`` and the diagonal of ``S_k`` after each step (None: the
        estimator exposes none).
    innovation_cov : ndarray, shape (K, p, p) or None
        ``S_k``.
    nis : ndarray, shape (K,) or None
    consistency : dict or None
        ANIS and its band and verdict, the per-step band fraction, the whiteness test
        (see the module docstring); None without innovations.
    reference : dict or None
        ``channel``, ``state`` (the state it measures, or None), ``unit``, ``rmse`` (SI),
        ``samples``; and the arrays ``reference_measured`` / ``reference_predicted`` (K+1,).
    measured_state : list of int or None
        The state each channel measures directly (the sensors' ``measured_state``).
    notes : list of str
    wall_s : float
        Seconds of the estimator loop.
    cpu_s : float
        The process's CPU seconds in the estimator loop (one thread: what ``wall_s`` is on
        an idle machine).
    design_meta : dict
    """

    source: str
    sha256: str
    rig: str
    profile: str
    estimator: str
    sensors: str
    period_s: float
    every: int
    time_s: np.ndarray
    state_names: list[str]
    state_units: list[str]
    x_hat: np.ndarray
    P_diag: np.ndarray | None
    measurement_names: list[str]
    measurement_units: list[str]
    measurement: np.ndarray
    innovation_names: list[str]
    innovations: np.ndarray | None
    innovation_var: np.ndarray | None
    innovation_cov: np.ndarray | None
    nis: np.ndarray | None
    consistency: dict[str, Any] | None
    reference: dict[str, Any] | None
    reference_measured: np.ndarray | None = None
    reference_predicted: np.ndarray | None = None
    measured_state: list[int | None] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    cpu_s: float = 0.0
    design_meta: dict[str, Any] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        """Estimator steps ``K``."""
        return len(self.time_s) - 1

    @property
    def real_time_factor(self) -> float:
        """Recorded seconds replayed per wall-clock second."""
        span = float(self.time_s[-1] - self.time_s[0])
        return span / self.wall_s if self.wall_s > 0 else math.inf

    @property
    def cpu_real_time_factor(self) -> float:
        """Recorded seconds replayed per CPU second of the loop (the factor on an idle
        machine: the machine's load does not change it)."""
        span = float(self.time_s[-1] - self.time_s[0])
        return span / self.cpu_s if self.cpu_s > 0 else math.inf

    def estimates_summary(self) -> dict[str, Any]:
        """Per state: the final estimate, its final standard deviation and the mean one."""
        out: dict[str, Any] = {}
        for i, name in enumerate(self.state_names):
            row: dict[str, Any] = {"final": float(self.x_hat[-1, i]),
                                   "min": float(np.min(self.x_hat[:, i])),
                                   "max": float(np.max(self.x_hat[:, i]))}
            if self.P_diag is not None:
                std = np.sqrt(np.maximum(self.P_diag[:, i], 0.0))
                row["std_final"], row["std_mean"] = float(std[-1]), float(np.mean(std[1:]))
            out[name] = row
        return out

    def to_json(self) -> dict[str, Any]:
        """The JSON-ready summary (no per-step arrays)."""
        units = dict(zip(self.state_names, self.state_units, strict=True))
        units.update({f"measurement:{n}": u for n, u in
                      zip(self.measurement_names, self.measurement_units, strict=True)})
        return {
            "recording": {"source": self.source, "sha256": self.sha256},
            "rig": self.rig, "profile": self.profile, "estimator": self.estimator,
            "sensors": self.sensors, "n_samples": self.steps + 1, "steps": self.steps,
            "period_s": self.period_s, "every": self.every,
            "duration_s": float(self.time_s[-1] - self.time_s[0]),
            "innovation_channels": list(self.innovation_names),
            "consistency": self.consistency, "reference": self.reference,
            "estimates": self.estimates_summary(), "design": self.design_meta,
            "notes": list(self.notes), "units": units,
            "wall_s": self.wall_s, "real_time_factor": self.real_time_factor,
            "cpu_s": self.cpu_s, "cpu_real_time_factor": self.cpu_real_time_factor,
        }



def innovation_consistency(nis: np.ndarray, z: np.ndarray, dim: int,
                           level: float = LEVEL) -> dict[str, Any]:
    """ANIS of one run with its band and verdict, the per-step band fraction and the
    whiteness test (see the module docstring).

    Parameters
    ----------
    nis : ndarray, shape (K,)
        NIS of each step.
    z : ndarray, shape (K, dim)
        The whitened innovations ``L^-1 nu`` (``S = L L^T``).
    dim : int
        Innovation dimension.
    level : float

    Returns
    -------
    dict
        ``dim``, ``steps``, ``anis``, ``band`` (the K-step average's), ``verdict``;
        ``step_band`` (one step's chi2(dim) band), ``steps_above``, ``steps_below``,
        ``band_fraction`` (outside), ``band_fraction_ci`` (Clopper-Pearson),
        ``band_fraction_expected`` (``1 - level``); ``whiteness`` (lags, z, p, verdict, or
        None when the run is too short).
    """
    K = len(nis)
    anis = float(np.mean(nis))
    lo, hi = chi2_bounds(K, dim, level)
    verdict = OVERCONFIDENT if anis > hi else UNDERCONFIDENT if anis < lo else CONSISTENT
    step_lo, step_hi = chi2_bounds(1, dim, level)
    above, below = int(np.sum(nis > step_hi)), int(np.sum(nis < step_lo))
    white = whiteness_test(z[None], level=level)
    return {"dim": int(dim), "steps": K, "level": level, "anis": anis, "band": [lo, hi],
            "verdict": verdict, "step_band": [step_lo, step_hi], "steps_above": above,
            "steps_below": below, "band_fraction": (above + below) / K,
            "band_fraction_ci": list(clopper_pearson(above + below, K, level)),
            "band_fraction_expected": 1.0 - level,
            "whiteness": None if white is None else
            {k: white[k] for k in ("lags", "autocorrelation", "z", "statistic", "p",
                                   "verdict")}}


def reference_error(suite: Sensor, j: int, name: str, Y: np.ndarray, U: np.ndarray,
                    x_hat: np.ndarray, state_names: list[str]
                    ) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """The held-out channel ``j`` against ``C_j x_hat + D_j u`` (its linear model; ``u`` the
    input over the interval that ended at the sample), over steps ``1..K``.

    Parameters
    ----------
    suite : Sensor
        The sensors (their linear model gives ``C_j`` and ``D_j``).
    j : int
        The channel's index in the suite.
    name : str
        Its name.
    Y : ndarray, shape (K+1, m)
        The channels at the samples used.
    U : ndarray, shape (K+1, nu)
        The inputs held over each sample's interval.
    x_hat : ndarray, shape (K+1, n)
        The physical estimate after the reset and after each step.
    state_names : list of str

    Returns
    -------
    summary : dict
        ``channel``, ``state`` (the state it measures, or None), ``unit``, ``rmse`` (the
        channel's unit, SI), ``samples`` (K), ``prediction``.
    measured, predicted : ndarray, shape (K+1,)
        The recorded channel and its prediction from the estimate.
    """
    model = suite.linear_model()
    C, D = np.asarray(model.C[j], float), np.asarray(model.D[j], float)
    predicted = x_hat @ C
    if np.any(D):
        predicted[1:] += U[:-1] @ D
    measured = Y[:, j]
    error = measured[1:] - predicted[1:]
    nonzero = np.flatnonzero(C)
    state = None
    if len(nonzero) == 1 and C[nonzero[0]] == 1.0 and not np.any(D):
        state = state_names[int(nonzero[0])]
    unit = suite.units[j]
    return ({"channel": name, "state": state, "unit": unit,
             "rmse": float(np.sqrt(np.mean(error**2))), "samples": int(len(error)),
             "prediction": "C x_hat" + (" + D u" if np.any(D) else "")},
            measured.copy(), predicted)
