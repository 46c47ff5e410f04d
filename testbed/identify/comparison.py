"""A rig or a twin against a recording: the simulation with the recorded inputs, scored.

:func:`compare` simulates the rig (nominal parameters) or a twin (its parameters, sensor
model and identification method) with a recording's inputs from its recorded initial state,
and gives the fit per channel. The prediction is :func:`~testbed.identify.predict.
predict_channels`, the function the identification scores itself with, so the twin compared
on its own recording gives the identification's fit.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np

from testbed.identify.channels import IdentificationError
from testbed.identify.predict import predict_channels
from testbed.identify.result import fit_percent
from testbed.identify.simulate import RecordingModel, sensor_vectors
from testbed.identify.twin import Twin
from testbed.io.recording import Recording
from testbed.rigs.base import Rig

COMPARE_METHODS = ("output-error", "multiple-shooting")


def compare(source: Any, recording: Recording, *, profile: str | None = None,
            options: dict[str, Any] | None = None, sensors: Any = None, channels: Any = None,
            method: str | None = None, segment_s: float | None = None,
            holdout: float | None = None) -> dict[str, Any]:
    """Simulate a rig or a twin with a recording's inputs and score the fit.

    Parameters
    ----------
    source : Twin, Rig subclass or str
        A twin (:func:`~testbed.identify.twin.read_twin`): its rig, profile, options,
        parameters, sensor model and method; or a rig (class or registered name) at nominal
        parameters without a sensor model.
    recording : Recording
    profile : str, optional
        The rig's profile (default: the twin's, else ``"hardware"`` when the rig has it).
    options : dict, optional
        Rig options (a rig only; a twin has its own).
    sensors : Sensor or str, optional
        Sensor suite or preset (default: the twin's preset, else the profile's).
    channels : list of str, optional
        Channels to score (default: every recorded state channel).
    method : {"output-error", "multiple-shooting"}, optional
        Default: the twin's, else ``"output-error"`` (one free run over the recording).
    segment_s : float, optional
        Multiple-shooting segment length (default the twin's, else 1 s).
    holdout : float, optional
        Fraction at the end scored apart (default: the twin's, else 0).

    Returns
    -------
    dict
        ``rig``, ``profile``, ``options``, ``source`` (``"twin"`` or ``"nominal"``),
        ``twin`` (its path), ``method``, ``channels``, ``units``, ``fit_percent`` and
        ``holdout_fit_percent`` per channel, ``recording_sha256``, ``timings``; and
        ``series`` (not JSON): ``time_s`` (N,), ``measured`` and ``predicted`` (N, m),
        ``n_fit``. :func:`compare_json` drops ``series``.
    """
    t0 = time.perf_counter()
    src = _settings(source, recording, profile=profile, options=options, sensors=sensors,
                    channels=channels, method=method, segment_s=segment_s, holdout=holdout)
    rig_cls, profile, method = src.rig_cls, src.profile, src.method
    model = RecordingModel(rig_cls, recording, profile=profile, options=src.options,
                           sensors=src.sensors, channels=src.channels)
    params = model.nominal if src.params is None else src.params
    names = model.names
    bias, scale, delay, x0_bias = _sensor_model(source, model)
    N = model.n_samples
    n_fit = int(math.floor(N * (1.0 - src.holdout)))
    segment_len = max(int(round(src.segment_s / model.dt_s)), 10)
    predicted = predict_channels(model, [params], bias, scale, delay, method, segment_len, 0,
                                 n_fit, x0_bias)[0]
    hold: dict[str, float] = {}
    if n_fit < N:
        rest = predict_channels(model, [params], bias, scale, delay, method, segment_len,
                                n_fit, N, x0_bias)[0]
        hold = dict(zip(names, fit_percent(model.y[n_fit:], rest).tolist(), strict=True))
        predicted = np.vstack([predicted, rest])
    fits = dict(zip(names, fit_percent(model.y[:n_fit], predicted[:n_fit]).tolist(),
                    strict=True))
    return {
        "rig": rig_cls.name, "profile": profile, "options": dict(model.options),
        "source": "twin" if isinstance(source, Twin) else "nominal",
        "twin": source.path if isinstance(source, Twin) else None, "method": method,
        "segment_s": segment_len * model.dt_s, "channels": list(names),
        "units": [i.unit for i in model.infos], "fit_percent": fits,
        "holdout_fit_percent": hold, "recording_sha256": recording.sha256,
        "recording_source": recording.source,
        "timings": {"total_s": time.perf_counter() - t0},
        "series": {"time_s": np.asarray(recording.time_s), "measured": model.y,
                   "predicted": predicted, "n_fit": n_fit},
    }


@dataclasses.dataclass
class _Settings:
    """What a comparison simulates: the rig, its profile, options and parameters (None:
    nominal), the sensors and channels, the method, segment length (s) and held-out part."""

    rig_cls: type[Rig]
    profile: str
    options: dict[str, Any] | None
    params: Any
    sensors: Any
    channels: Any
    method: str
    segment_s: float
    holdout: float


def _settings(source: Any, recording: Recording, *, profile: str | None,
              options: dict[str, Any] | None, sensors: Any, channels: Any,
              method: str | None, segment_s: float | None, holdout: float | None
              ) -> _Settings:
    """The comparison's settings: the twin's where not given, else the rig's defaults
    (checked: one-line :class:`IdentificationError`)."""
    from testbed.rigs import resolve_rig

    if isinstance(source, Twin):
        if options is not None:
            raise IdentificationError("options come from the twin; do not pass them with one")
        rig_cls = source.rig_class()
        profile = source.profile if profile is None else profile
        options = source.options
        params = source.params()
        sensors = (source.sensor_preset or None) if sensors is None else sensors
        method = source.method if method is None else method
        segment_s = source.segment_s if segment_s is None else segment_s
        holdout = source.holdout if holdout is None else holdout
        if channels is None:
            channels = [c for c in source.sensors if c in recording.channels]
    else:
        try:
            rig_cls = resolve_rig(source)
        except ValueError as err:
            raise IdentificationError(str(err)) from None
        if not (isinstance(rig_cls, type) and issubclass(rig_cls, Rig)):
            raise IdentificationError(f"source must be a Twin or a rig, got {source!r}")
        if profile is None:
            profile = "hardware" if "hardware" in rig_cls.profiles else rig_cls.profiles[0]
        params = None
        method = "output-error" if method is None else method
        segment_s = 1.0 if segment_s is None else segment_s
        holdout = 0.0 if holdout is None else holdout
    if method not in COMPARE_METHODS:
        raise IdentificationError(f"method must be one of {COMPARE_METHODS}, got {method!r}")
    if not (isinstance(holdout, int | float) and 0.0 <= holdout < 0.9):
        raise IdentificationError(f"holdout must be a fraction in [0, 0.9), got {holdout!r}")
    if not (isinstance(segment_s, int | float) and np.isfinite(segment_s) and segment_s > 0):
        raise IdentificationError(f"segment_s must be a positive time in s, got {segment_s!r}")
    return _Settings(rig_cls=rig_cls, profile=profile, options=options, params=params,
                     sensors=sensors, channels=channels, method=method, segment_s=segment_s,
                     holdout=holdout)


def _sensor_model(source: Any, model: RecordingModel
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(bias, scale, delay, x0_bias)`` per channel: the twin's sensor model, or none."""
    names = model.names
    if not isinstance(source, Twin):
        bias, scale, delay = sensor_vectors(names, None, None, None)
        return bias, scale, delay, bias
    table = source.sensors
    bias, scale, delay = sensor_vectors(
        names, {n: table[n].get("bias", 0.0) for n in names if n in table},
        {n: table[n].get("scale", 0.0) for n in names if n in table},
        {n: table[n].get("delay_samples", 0) for n in names if n in table})
    x0_bias = np.array([float(table[n]["initial_state_bias"])
                        if n in table and "initial_state_bias" in table[n]
                        else bias[i] * model.x0_bias_mask[i] for i, n in enumerate(names)])
    return bias, scale, delay, x0_bias


def compare_json(result: dict[str, Any]) -> dict[str, Any]:
    """:func:`compare`'s result without its arrays (``series``): JSON-ready."""
    return {k: v for k, v in result.items() if k != "series"}
