"""Rigs: one folder per rig (the built-in MJCF in the top-level ``models/``) and this registry.

Register a rig with one line, ``register_rig(MyRig)`` (``MyRig.name`` becomes usable in
``testbed run NAME``, scenarios and :func:`testbed.envs.RigEnv`), or pass the class itself.
An installed package adds rigs through the entry-point group ``testbed.rigs``
(:mod:`testbed.discovery`); :func:`rig_names` lists both.
"""

from __future__ import annotations

from typing import Any

#: Rig name -> "module:Class" (imported on first use).
RIGS: dict[str, Any] = {
    "helicopter": "testbed.rigs.helicopter.rig:HelicopterRig",
    "aero": "testbed.rigs.aero.rig:AeroRig",
    "vehicle-roll": "testbed.rigs.vehicle_roll.rig:VehicleRollRig",
}


def register_rig(cls: type) -> type:
    """Add a :class:`~testbed.rigs.base.Rig` subclass to :data:`RIGS` under ``cls.name``.

    Raises
    ------
    ValueError
        ``cls`` is not a ``Rig`` subclass, or its ``name`` is not a non-empty string.
    """
    from testbed.rigs.base import Rig  # a rig being registered has imported it already

    if not (isinstance(cls, type) and issubclass(cls, Rig)):
        raise ValueError(f"register_rig: expected a Rig subclass, got {cls!r}")
    if not (isinstance(cls.name, str) and cls.name):
        raise ValueError(f"{cls.__name__}.name must be a non-empty string")
    RIGS[cls.name] = cls
    return cls


def rig_names() -> list[str]:
    """The rig names :func:`resolve_rig` accepts: the registered ones (:data:`RIGS`), then
    those of installed packages' ``testbed.rigs`` entry points (nothing is imported)."""
    from testbed import discovery

    return [*RIGS, *(name for name in discovery.names("rig") if name not in RIGS)]


def _installed_rig(name: str) -> type | None:
    """The rig of an installed package's entry point ``name`` (None: there is none)."""
    from testbed import discovery
    from testbed.rigs.base import Rig

    target = discovery.load("rig", name)
    if target is None:
        return None
    if not (isinstance(target, type) and issubclass(target, Rig)):
        problem = f"{target!r} is not a testbed.rigs.base.Rig subclass"
    elif target.name != name:
        problem = (f"the class's name is {target.name!r}; the entry point must carry the "
                   "rig's name")
    else:
        return target
    raise ValueError(f"{discovery.describe(discovery.find('rig', name))}: {problem}")


def resolve_rig(rig: Any) -> type:
    """A rig class from a registered name, a ``module:Class`` path or the class itself."""
    from testbed.rigs.base import Rig

    if isinstance(rig, type) and issubclass(rig, Rig):
        return rig
    if not isinstance(rig, str):
        raise ValueError(f"rig must be a name, 'module:Class' or a Rig subclass, got {rig!r}")
    target = RIGS.get(rig, rig)
    if isinstance(target, str) and ":" not in target:
        target = _installed_rig(rig) or target
    if isinstance(target, str):
        from testbed import plugins

        if ":" not in target:
            raise ValueError(f"unknown rig {rig!r}; expected one of {sorted(rig_names())}, "
                             "'package.module:RigClass' or 'path/to/file.py:RigClass'")
        target = plugins.load(target, f"rig {rig!r}")
        if rig in RIGS:
            RIGS[rig] = target
    if not (isinstance(target, type) and issubclass(target, Rig)):
        raise ValueError(f"{rig!r} is not a testbed.rigs.base.Rig subclass")
    return target
