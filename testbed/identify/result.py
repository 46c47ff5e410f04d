"""What an identification found: the per-parameter estimates, the :class:`Identification`
record (its JSON form), the NRMSE fit of a prediction and the sensor model it implies."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from testbed.identify.simulate import sensor_vectors


@dataclasses.dataclass
class ParameterEstimate:
    """One free parameter's result.

    Attributes
    ----------
    name : str
    value : float
        Absolute value (the nominal one when not identifiable).
    ci95 : tuple of float or None
        95 % interval, absolute (None when not identifiable).
    nominal : float
    scale : float
        ``value / nominal``.
    identifiable : bool
        False: the recording does not determine it; held at nominal (``reason`` says why).
    reason : str
    """

    name: str
    value: float
    ci95: tuple[float, float] | None
    nominal: float
    scale: float
    identifiable: bool
    reason: str = ""

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict."""
        return {"value": self.value, "ci95": None if self.ci95 is None else list(self.ci95),
                "nominal": self.nominal, "identifiable": self.identifiable,
                "scale": self.scale, **({"reason": self.reason} if self.reason else {})}


@dataclasses.dataclass
class Identification:
    """What :func:`identify` found (see :meth:`to_json` for the file form).

    Attributes
    ----------
    rig, profile : str
    options : dict
    parameters : dict of str to ParameterEstimate
        The free parameters, fitted or held at nominal.
    correlation : ndarray, shape (q, q)
        Correlations of the fitted (identifiable) parameters, order ``correlation_names``.
    correlation_names : tuple of str
    sensors : dict of str to dict
        Per channel: ``bias``, ``scale``, ``delay_samples``, ``noise_std``,
        ``noise_density``, ``quantization_step``, ``still_bias`` (None without a still
        segment), ``initial_state_bias`` (what the initial states were read with).
    fit_percent, holdout_fit_percent, free_run_fit_percent : dict of str to float
        NRMSE fit per channel ``100 (1 - |y - y_hat| / |y - mean(y)|)``: the method's
        prediction over the fitted part and over the held-out end (empty without one); the
        whole fitted part simulated from its first sample (for information).
    method : str
        ``"output-error"`` or ``"multiple-shooting"``.
    method_reason : str
    segment_s : float
    still_segment_s : tuple or None
    recording_sha256, recording_source : str
    dt_s : float
    n_fit : int
        Samples fitted (the rest is held out).
    timings : dict
    time_s, measured, predicted : ndarray
        The recording's times (N,), its channels (N, m) and their prediction (N, m).
    channels, units : tuple of str
    holdout : float
        The held-out fraction.
    sensor_preset : str
        The sensor preset the channels were read with (``""``: the profile's default;
        ``"<custom>"``: a sensor object the caller passed).
    """

    rig: str
    profile: str
    options: dict[str, Any]
    parameters: dict[str, ParameterEstimate]
    correlation: np.ndarray
    correlation_names: tuple[str, ...]
    sensors: dict[str, dict[str, Any]]
    fit_percent: dict[str, float]
    holdout_fit_percent: dict[str, float]
    free_run_fit_percent: dict[str, float]
    method: str
    method_reason: str
    segment_s: float
    still_segment_s: tuple[float, float] | None
    recording_sha256: str
    recording_source: str
    dt_s: float
    n_fit: int
    timings: dict[str, float]
    time_s: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    channels: tuple[str, ...]
    units: tuple[str, ...]
    holdout: float = 0.0
    sensor_preset: str = ""

    def holdout_signal_to_noise(self) -> dict[str, float]:
        """Per channel, the held-out part's spread over the channel's noise level
        (``std(y_holdout) / sqrt(noise_std^2 + q^2 / 12)`` with ``q`` the quantization step;
        empty without a held-out part). Near 1 the held-out part has no excitation: its NRMSE
        fit compares the prediction with the noise and says nothing of the model (a still
        end of the recording fits near 0 %)."""
        if self.n_fit >= len(self.time_s):
            return {}
        out = {}
        for c, name in enumerate(self.channels):
            sensor = self.sensors.get(name, {})
            noise = math.hypot(float(sensor.get("noise_std") or 0.0),
                               float(sensor.get("quantization_step") or 0.0) / math.sqrt(12))
            spread = float(np.std(self.measured[self.n_fit:, c]))
            out[name] = spread / noise if noise > 0 else float("inf")
        return out

    def params_scales(self) -> dict[str, float]:
        """Scale factors of the fitted parameters relative to nominal (held ones omitted)."""
        return {n: p.scale for n, p in self.parameters.items() if p.identifiable}

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict: ``parameters``, ``correlation``, ``sensors``, ``fit_percent``,
        ``holdout_fit_percent``, ``method``, ``recording_sha256``, ``timings``..."""
        return {
            "rig": self.rig, "profile": self.profile, "options": dict(self.options),
            "parameters": {n: p.to_json() for n, p in self.parameters.items()},
            "unidentifiable": [n for n, p in self.parameters.items() if not p.identifiable],
            "correlation": {"names": list(self.correlation_names),
                            "matrix": np.round(self.correlation, 6).tolist()},
            "sensors": self.sensors, "fit_percent": self.fit_percent,
            "holdout_fit_percent": self.holdout_fit_percent,
            "holdout_signal_to_noise": self.holdout_signal_to_noise(),
            "free_run_fit_percent": self.free_run_fit_percent,
            "method": self.method, "method_reason": self.method_reason,
            "segment_s": self.segment_s,
            "still_segment_s": None if self.still_segment_s is None
            else list(self.still_segment_s),
            "recording_sha256": self.recording_sha256,
            "recording_source": self.recording_source, "dt_s": self.dt_s,
            "n_samples": len(self.time_s), "n_fit": self.n_fit, "holdout": self.holdout,
            "sensor_preset": self.sensor_preset, "channels": list(self.channels),
            "timings": self.timings,
        }


def fit_percent(y: np.ndarray, y_hat: np.ndarray) -> np.ndarray:
    """NRMSE fit per column: ``100 (1 - |y - y_hat| / |y - mean(y)|)``, shape (m,)
    (``-inf`` for a constant channel predicted wrong, 100 predicted right)."""
    err = np.linalg.norm(y - y_hat, axis=0)
    spread = np.linalg.norm(y - y.mean(axis=0), axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 100.0 * (1.0 - err / spread)
    out[(spread == 0) & (err == 0)] = 100.0
    return np.where(np.isnan(out), -np.inf, out)


def sensor_model_of(identification: Identification, names: tuple[str, ...]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(bias, scale, delay)`` vectors of ``names`` from an identification's sensors."""
    sensors = identification.sensors
    return sensor_vectors(names, {n: sensors[n]["bias"] for n in names if n in sensors},
                          {n: sensors[n]["scale"] for n in names if n in sensors},
                          {n: sensors[n]["delay_samples"] for n in names if n in sensors})
