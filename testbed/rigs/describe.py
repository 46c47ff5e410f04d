"""What a rig declares, for ``testbed describe RIG`` and for checking recordings.

:func:`describe_rig` collects a rig's inputs (names, units, limits), its sensor channels per
profile and preset (names, units), its profiles, construction options (:class:`RigOption`),
identifiable parameters (nominal value, unit, bounds) and state names and units, as a plain
dict (JSON-ready); :func:`format_description` prints it as tables. :func:`sensor_channels`
lists every channel name a recording of the rig may hold.

Sensor presets: a rig's ``sensor_presets`` class attribute (:attr:`Rig.sensor_presets`),
else only its default preset.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from typing import Any

from testbed.records import field_values
from testbed.rigs import resolve_rig
from testbed.rigs.base import Rig, RigOption

#: Field-name endings that give a parameter's unit.
_SUFFIX_UNITS = {"_kg": "kg", "_m": "m", "_s": "s", "_rad": "rad", "_rad_s": "rad/s",
                 "_v": "V", "_hz": "Hz", "_n": "N", "_nm": "N m", "_m_s2": "m/s^2"}
#: Tokens of a unit in a docstring ("N m s/rad", "kg m^2").
_UNIT_TOKEN = re.compile(r"^(kg|g|m|s|rad|deg|N|V|A|W|Hz|Ohm|counts|rev)(\^-?\d+)?$")


def _rig_class(rig: Any) -> tuple[type[Rig], Rig | None]:
    if isinstance(rig, Rig):
        return type(rig), rig
    return resolve_rig(rig), None


def sensor_presets(rig: Any) -> tuple[str | None, ...]:
    """A rig's sensor presets (``None``: only its default preset is known).

    Parameters
    ----------
    rig : str, Rig subclass or Rig
    """
    cls, _ = _rig_class(rig)
    return tuple(cls.sensor_presets) if cls.sensor_presets else (None,)


def _build(cls: type[Rig], profile: str, options: dict[str, Any] | None) -> Rig:
    try:
        return cls(profile=profile, options=options) if options else cls(profile=profile)
    except TypeError:
        raise ValueError(f"rig {cls.name!r} takes no options (got {sorted(options)})") from None


def _suites(rig: Rig) -> dict[str, dict[str, Any]]:
    """``{preset: {"channels": [(name, unit)...]} or {"error": text}}`` of one built rig."""
    out: dict[str, dict[str, Any]] = {}
    for preset in sensor_presets(rig):
        label = preset or "default"
        try:
            suite = rig.sensors(preset)
        except (ValueError, TypeError, NotImplementedError) as exc:  # options it lacks
            out[label] = {"error": str(exc).splitlines()[0]}
            continue
        out[label] = {"channels": [{"name": n, "unit": u}
                                   for n, u in zip(suite.names, suite.units, strict=True)]}
    return out


@functools.lru_cache(maxsize=32)
def _channels_of_class(cls: type[Rig]) -> tuple[tuple[str, str], ...]:
    seen: dict[str, str] = {}
    for profile in cls.profiles:
        for entry in _suites(cls(profile=profile)).values():
            for ch in entry.get("channels", []):
                seen.setdefault(ch["name"], ch["unit"])
    return tuple(seen.items())


def sensor_channels(rig: Any) -> dict[str, str]:
    """Every channel of a rig's sensor presets in every profile: ``{name: unit}``.

    Parameters
    ----------
    rig : str, Rig subclass or Rig
        A built rig gives its own profile's presets only.
    """
    cls, instance = _rig_class(rig)
    if instance is None:
        return dict(_channels_of_class(cls))
    return {ch["name"]: ch["unit"] for entry in _suites(instance).values()
            for ch in entry.get("channels", [])}


def _doc_units(params_type: type) -> dict[str, str]:
    """Units from a numpydoc ``Attributes`` section: ``name : float`` then a description
    whose first clause after a comma is a unit (``Viscous damping, N m s/rad.``)."""
    doc = params_type.__doc__ or ""
    units: dict[str, str] = {}
    entries = re.split(r"\n\s*(?=[A-Za-z_][A-Za-z0-9_, ]* : )", doc)
    for entry in entries:
        head, _, body = entry.partition(" : ")
        names = [n.strip() for n in head.split(",")]
        if not body or not all(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", n) for n in names):
            continue
        text = " ".join(body.split("\n", 1)[1:]).strip() if "\n" in body else ""
        text = re.sub(r"\([^)]*\)?", " ", re.sub(r"``[^`]*``", "X", " ".join(text.split())))
        for clause in text.split(",")[1:]:
            candidate = re.split(r"[.:;]\s|[.:;]$|\s\(", clause.strip() + " ")[0].strip()
            tokens = candidate.replace("/", " ").split()
            if tokens and all(_UNIT_TOKEN.match(tok) for tok in tokens):
                for n in names:
                    units[n] = candidate
                break
    return units


def parameter_unit(params_type: type, field: str) -> str:
    """A parameter's unit: the field's ``metadata["unit"]``, its docstring (numpydoc
    ``Attributes``), or its name's ending (``_kg``); ``""`` when unknown."""
    for f in dataclasses.fields(params_type):
        if f.name == field and "unit" in f.metadata:
            return str(f.metadata["unit"])
    documented = _doc_units(params_type).get(field)
    if documented:
        return documented
    lower = field.lower()
    for suffix in sorted(_SUFFIX_UNITS, key=len, reverse=True):
        if lower.endswith(suffix):
            return _SUFFIX_UNITS[suffix]
    return ""


def _default_preset(rig: Rig, suites: dict[str, dict[str, Any]]) -> str:
    """The preset ``rig.sensors()`` builds (the first with the same description)."""
    try:
        default = rig.sensors().describe()
    except (ValueError, TypeError, NotImplementedError):
        return ""
    for preset in suites:
        if "channels" in suites[preset] and preset != "default" and \
                rig.sensors(preset).describe() == default:
            return preset
    return "default"


def _option(name: str, opt: RigOption) -> dict[str, Any]:
    return {"name": name, "type": type(opt.default).__name__, "default": opt.default,
            "help": opt.help, "choices": list(opt.choices)}


def describe_rig(rig: Any, *, profile: str | None = None,
                 options: dict[str, Any] | None = None) -> dict[str, Any]:
    """What a rig declares, as a JSON-ready dict.

    Parameters
    ----------
    rig : str, Rig subclass or Rig
        A registered name, ``"module:Class"``, a class or a built rig.
    profile : str, optional
        Describe only this profile (default: every one of :attr:`Rig.profiles`).
    options : dict, optional
        Construction options (:attr:`Rig.rig_options`) the rigs are built with.

    Returns
    -------
    dict
        ``name``, ``class``, ``summary`` (the docstring's first line), ``states``
        (``[{name, unit}]``), ``profiles`` (``{profile: {"inputs": [{name, unit, low,
        high}], "default_sensors": preset, "sensors": {preset: {"channels": [{name,
        unit}]}} or {"error": text}}}``), ``options`` (``[{name, type, default, help,
        choices}]``), ``identifiable`` (``[{field, nominal, unit, low, high, low_factor,
        high_factor}]``: bounds absolute and as factors of the nominal value), ``tracked``.

    Raises
    ------
    ValueError
        An unknown rig, profile or option (named).
    """
    cls, _ = _rig_class(rig)
    profiles = cls.profiles if profile is None else (profile,)
    if profile is not None and profile not in cls.profiles:
        raise ValueError(f"unknown profile {profile!r} for rig {cls.name!r}; expected one of "
                         f"{list(cls.profiles)}")
    resolved = cls.resolve_options(options)
    described: dict[str, Any] = {}
    for prof in profiles:
        built = _build(cls, prof, options)
        suites = _suites(built)
        described[prof] = {
            "inputs": [{"name": n, "unit": u, "low": float(lo), "high": float(hi)}
                       for n, u, lo, hi in zip(built.action_names, built.action_units,
                                               built.action_low, built.action_high,
                                               strict=True)],
            "default_sensors": _default_preset(built, suites),
            "sensors": suites,
        }
    nominal = field_values(cls.params_type())
    identifiable = []
    for field, (lo, hi) in cls.identifiable.items():
        value = float(nominal[field])
        identifiable.append({"field": field, "nominal": value,
                             "unit": parameter_unit(cls.params_type, field),
                             "low": min(lo * value, hi * value),
                             "high": max(lo * value, hi * value),
                             "low_factor": float(lo), "high_factor": float(hi)})
    summary = (cls.__doc__ or "").strip().split("\n", 1)[0]  # (the states: of the built rig)
    return {
        "name": cls.name, "class": f"{cls.__module__}:{cls.__qualname__}", "summary": summary,
        "states": [{"name": n, "unit": u} for n, u in zip(built.state_names, built.state_units,
                                                          strict=True)],
        "tracked": list(built.tracked_states),
        "profiles": described,
        "options": [dict(_option(n, o), value=resolved[n]) for n, o in cls.rig_options.items()],
        "identifiable": identifiable,
    }


def _table(header: tuple[str, ...], rows: list[tuple[Any, ...]], indent: str = "  ") -> str:
    cells = [[_cell(v) for v in row] for row in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h)
              for i, h in enumerate(header)]
    lines = [indent + "  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)).rstrip(),
             indent + "  ".join("-" * w for w in widths)]
    lines += [indent + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
              for r in cells]
    return "\n".join(lines)


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return "inf" if math.isinf(value) and value > 0 else \
            "-inf" if math.isinf(value) else f"{value:.6g}"
    if isinstance(value, list | tuple):
        return ", ".join(_cell(v) for v in value) if value else "-"
    return "" if value is None else "-" if value == "" else str(value)


def format_description(d: dict[str, Any]) -> str:
    """:func:`describe_rig`'s dict as text for a terminal: a table per section.

    Parameters
    ----------
    d : dict
        As returned by :func:`describe_rig`.

    Returns
    -------
    str
        Lines without a trailing newline.
    """
    out = [f"rig {d['name']} ({d['class']})"]
    if d.get("summary"):
        out.append(f"  {d['summary']}")
    out += ["", "states", _table(("name", "unit"), [(s["name"], s["unit"])
                                                     for s in d["states"]])]
    for prof, entry in d["profiles"].items():
        out += ["", f"profile {prof}: inputs",
                _table(("name", "unit", "low", "high"),
                       [(i["name"], i["unit"], i["low"], i["high"]) for i in entry["inputs"]])]
        rows = []
        for preset, suite in entry["sensors"].items():
            if "error" in suite:
                rows.append((preset, "-", f"({suite['error']})"))
            for k, ch in enumerate(suite.get("channels", [])):
                rows.append((preset if k == 0 else None, ch["name"], ch["unit"]))
        out += ["", f"profile {prof}: sensor channels by preset (default: "
                    f"{entry['default_sensors'] or '-'})",
                _table(("preset", "channel", "unit"), rows)]
    out += ["", "options (--rig-option NAME=VALUE)"]
    out.append(_table(("name", "type", "default", "choices", "help"),
                      [(o["name"], o["type"], o["default"], o["choices"], o["help"])
                       for o in d["options"]]) if d["options"] else "  none")
    out += ["", "identifiable parameters (bounds: low..high, as factors of nominal)"]
    out.append(_table(("field", "nominal", "unit", "low", "high", "factors"),
                      [(p["field"], p["nominal"], p["unit"], p["low"], p["high"],
                        f"{p['low_factor']:g}..{p['high_factor']:g}")
                       for p in d["identifiable"]]) if d["identifiable"] else "  none")
    return "\n".join(out)
