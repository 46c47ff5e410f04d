"""The twin file: a user's rig as identified from a recording (TOML).

Written by :func:`write_twin` from an :class:`~testbed.identify.fit.Identification`
(atomically, :func:`testbed.io.atomic_path`), read by :func:`read_twin` into a
:class:`Twin`, the form the rest of the project uses: :meth:`Twin.params_scales` gives the
scale factors relative to the rig's nominal parameters (what ``--params`` and the
scenario's ``params`` take), :meth:`Twin.params` the rig's parameter object.

Layout::

    format = "testbed-twin"
    format_version = 1
    testbed_version = "0.1.0"
    rig = "helicopter"
    profile = "hardware"
    method = "multiple-shooting"          # how it was identified
    segment_s = 1.0
    dt_s = 0.002
    recording_sha256 = "..."
    recording_source = "run.csv"

    [options]                             # the rig's construction options
    [parameters.K_pp]                     # absolute values
    value = 0.163
    nominal = 0.204
    ci95 = [0.161, 0.165]                 # absent when not identifiable
    identifiable = true
    [sensors.gyro_pitch]                  # the sensor model per channel
    bias = 0.0009
    scale = 0.0
    delay_samples = 3
    noise_std = 0.005
    ...
    [fit_percent]
    [holdout_fit_percent]
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from pathlib import Path
from typing import Any

from testbed.identify.result import Identification
from testbed.io import atomic_path
from testbed.records import field_values

FORMAT = "testbed-twin"
FORMAT_VERSION = 1
_SENSOR_NUMBERS = ("bias", "scale", "noise_std", "noise_density", "quantization_step",
                   "delay_s", "initial_state_bias")


class TwinError(ValueError):
    """A twin file that cannot be used: one line naming the file and the key."""


@dataclasses.dataclass(frozen=True)
class TwinParameter:
    """One identified parameter: absolute ``value`` (``nominal`` when not identifiable)."""

    value: float
    nominal: float
    ci95: tuple[float, float] | None
    identifiable: bool


@dataclasses.dataclass(frozen=True)
class Twin:
    """A twin file's content.

    Attributes
    ----------
    path : str
    rig, profile : str
    options : dict
    parameters : dict of str to TwinParameter
    sensors : dict of str to dict
        Per channel: ``bias``, ``scale``, ``delay_samples``, ``noise_std``...
    recording_sha256, recording_source : str
    fit_percent, holdout_fit_percent : dict of str to float
    testbed_version, method : str
    segment_s, dt_s : float
    holdout : float
        The held-out fraction of the identifying recording.
    sensor_preset : str
        The sensor preset of the channels (``""``: the profile's default).
    """

    path: str
    rig: str
    profile: str
    options: dict[str, Any]
    parameters: dict[str, TwinParameter]
    sensors: dict[str, dict[str, Any]]
    recording_sha256: str
    recording_source: str
    fit_percent: dict[str, float]
    holdout_fit_percent: dict[str, float]
    testbed_version: str
    method: str
    segment_s: float
    dt_s: float
    holdout: float = 0.0
    sensor_preset: str = ""

    def rig_class(self) -> type:
        """The rig's class (from the registry)."""
        from testbed.rigs import resolve_rig

        return resolve_rig(self.rig)

    def params_scales(self) -> dict[str, float]:
        """Scale factors of the identified parameters relative to the rig's nominal
        :class:`~testbed.rigs.base.Params` (those held at nominal left out): what the rest
        of the project takes (``params``)."""
        nominal = field_values(self.rig_class().params_type())
        return {name: p.value / nominal[name] for name, p in self.parameters.items()
                if p.identifiable}

    def params(self):
        """The rig's :class:`~testbed.rigs.base.Params` with the twin's values (exact, not
        through scale factors), validated."""
        nominal = self.rig_class().params_type()
        out = dataclasses.replace(nominal, **{n: p.value for n, p in self.parameters.items()
                                              if p.identifiable})
        try:
            out.validate()
        except ValueError as err:
            raise TwinError(f"{self.path}: parameters: {err}") from None
        return out


def _testbed_version() -> str:
    try:
        from importlib.metadata import version

        return version("testbed")
    except Exception:  # not installed: the source tree
        return "unknown"


def twin_dict(identification: Identification) -> dict[str, Any]:
    """The twin file's content (TOML-ready: no None) from an identification."""
    ident = identification
    params = {}
    for name, p in ident.parameters.items():
        entry: dict[str, Any] = {"value": p.value, "nominal": p.nominal,
                                 "identifiable": p.identifiable}
        if p.ci95 is not None:
            entry["ci95"] = [p.ci95[0], p.ci95[1]]
        if p.reason:
            entry["reason"] = p.reason
        params[name] = entry
    sensors = {name: {k: v for k, v in s.items() if v is not None}
               for name, s in ident.sensors.items()}
    return {"format": FORMAT, "format_version": FORMAT_VERSION,
            "testbed_version": _testbed_version(), "rig": ident.rig, "profile": ident.profile,
            "method": ident.method, "method_reason": ident.method_reason,
            "segment_s": ident.segment_s, "dt_s": ident.dt_s,
            "recording_sha256": ident.recording_sha256,
            "recording_source": ident.recording_source, "holdout": ident.holdout,
            "sensor_preset": ident.sensor_preset, "options": dict(ident.options),
            "parameters": params, "sensors": sensors, "fit_percent": dict(ident.fit_percent),
            "holdout_fit_percent": dict(ident.holdout_fit_percent)}


def write_twin(path: str | os.PathLike, identification: Identification) -> Path:
    """Write an identification as a twin file (TOML, atomically).

    Parameters
    ----------
    path : str or PathLike
        Destination, ``.toml``.
    identification : Identification

    Returns
    -------
    Path
    """
    import tomli_w

    final = Path(path)
    if final.suffix != ".toml":
        raise TwinError(f"{final}: a twin file must end in .toml")
    if not isinstance(identification, Identification):
        raise TwinError(f"{final}: identification must be an Identification, got "
                        f"{type(identification).__name__}")
    payload = tomli_w.dumps(twin_dict(identification))
    with atomic_path(final) as tmp:
        tmp.write_text(payload, encoding="utf-8")
    return final


def _get(table: dict, key: str, kind: Any, where: str, path: str, default: Any = ...) -> Any:
    if key not in table:
        if default is not ...:
            return default
        raise TwinError(f"{path}: missing key {where}{key!r}")
    value = table[key]
    ok = isinstance(value, kind) and not (kind in (int, float, (int, float))
                                          and isinstance(value, bool))
    if not ok:
        name = kind.__name__ if isinstance(kind, type) else "number"
        raise TwinError(f"{path}: key {where}{key!r} must be a {name}, got {value!r}")
    return value


def read_twin(path: str | os.PathLike) -> Twin:
    """Read and check a twin file.

    Raises
    ------
    TwinError
        One line naming the file and the key: unreadable TOML, another format, a missing
        or mistyped key, an unknown rig, profile or parameter, a non-finite value.
    """
    from testbed.rigs import resolve_rig

    p = str(path)
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise TwinError(f"{p}: no such twin file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise TwinError(f"{p}: not a readable TOML file ({err})") from None
    if data.get("format") != FORMAT:
        raise TwinError(f"{p}: key 'format' must be {FORMAT!r}, got {data.get('format')!r}")
    version = _get(data, "format_version", int, "", p)
    if version != FORMAT_VERSION:
        raise TwinError(f"{p}: key 'format_version' {version} is not supported (expected "
                        f"{FORMAT_VERSION})")
    rig = _get(data, "rig", str, "", p)
    try:
        rig_cls = resolve_rig(rig)
    except ValueError as err:
        raise TwinError(f"{p}: key 'rig': {err}") from None
    profile = _get(data, "profile", str, "", p)
    if profile not in rig_cls.profiles:
        raise TwinError(f"{p}: key 'profile' {profile!r} is not a profile of rig {rig!r} "
                        f"({list(rig_cls.profiles)})")
    options = _get(data, "options", dict, "", p, {})
    try:
        options = rig_cls.resolve_options(options)
    except ValueError as err:
        raise TwinError(f"{p}: key 'options': {err}") from None
    fields = set(rig_cls.params_type.__dataclass_fields__)
    parameters = {}
    for name, entry in _get(data, "parameters", dict, "", p).items():
        where = f"parameters.{name}."
        if name not in fields:
            raise TwinError(f"{p}: key 'parameters.{name}' is not a parameter of rig {rig!r} "
                            f"({sorted(fields)})")
        if not isinstance(entry, dict):
            raise TwinError(f"{p}: key 'parameters.{name}' must be a table")
        value = float(_get(entry, "value", (int, float), where, p))
        nominal = float(_get(entry, "nominal", (int, float), where, p))
        identifiable = _get(entry, "identifiable", bool, where, p)
        ci = _get(entry, "ci95", list, where, p, None)
        if ci is not None and (len(ci) != 2 or not all(isinstance(v, int | float)
                                                        for v in ci)):
            raise TwinError(f"{p}: key '{where}ci95' must be two numbers [lo, hi]")
        if not (math.isfinite(value) and math.isfinite(nominal)):
            raise TwinError(f"{p}: key '{where}value' must be finite, got {value}")
        parameters[name] = TwinParameter(value, nominal, None if ci is None
                                         else (float(ci[0]), float(ci[1])), identifiable)
    sensors = {}
    for name, entry in _get(data, "sensors", dict, "", p, {}).items():
        if not isinstance(entry, dict):
            raise TwinError(f"{p}: key 'sensors.{name}' must be a table")
        for key in _SENSOR_NUMBERS:
            if key in entry:
                _get(entry, key, (int, float), f"sensors.{name}.", p)
        delay = _get(entry, "delay_samples", int, f"sensors.{name}.", p, 0)
        if delay < 0:
            raise TwinError(f"{p}: key 'sensors.{name}.delay_samples' must be >= 0")
        sensors[name] = dict(entry)
    method = _get(data, "method", str, "", p)
    if method not in ("output-error", "multiple-shooting"):
        raise TwinError(f"{p}: key 'method' must be 'output-error' or 'multiple-shooting', "
                        f"got {method!r}")
    fits = {k: float(v) for k, v in _get(data, "fit_percent", dict, "", p, {}).items()}
    hold = {k: float(v) for k, v in _get(data, "holdout_fit_percent", dict, "", p, {}).items()}
    twin = Twin(path=p, rig=rig, profile=profile, options=options, parameters=parameters,
                sensors=sensors, recording_sha256=_get(data, "recording_sha256", str, "", p, ""),
                recording_source=_get(data, "recording_source", str, "", p, ""),
                fit_percent=fits, holdout_fit_percent=hold,
                testbed_version=_get(data, "testbed_version", str, "", p, "unknown"),
                method=method, segment_s=float(_get(data, "segment_s", (int, float), "", p)),
                dt_s=float(_get(data, "dt_s", (int, float), "", p)),
                holdout=float(_get(data, "holdout", (int, float), "", p, 0.0)),
                sensor_preset=_get(data, "sensor_preset", str, "", p, ""))
    twin.params()  # the values must make a physical rig
    return twin
