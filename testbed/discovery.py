"""Rigs, estimators and suites of installed packages, found through entry points.

A distribution adds them in its ``pyproject.toml``::

    [project.entry-points."testbed.rigs"]
    pendulum = "my_package.pendulum:PendulumRig"      # a Rig subclass; its name = the key

    [project.entry-points."testbed.estimators"]
    my-kf = "my_package.filters:make"                 # factory(design, **options)

    [project.entry-points."testbed.suites"]
    my-suite = "my_package.suites:entries"            # () -> list of SuiteEntry

Each name is then accepted where a built-in one is (``testbed run pendulum --filter
my-kf``, ``testbed score --suite my-suite``); a built-in name wins over an entry point of
the same name. Entry points are read from the installed distributions
(:func:`importlib.metadata.entry_points`) when a name is not a built-in one, and loaded on
first use (then kept): an installed package that fails to import costs nothing until its
name is asked for, and then fails with one line naming the entry point
(:class:`testbed.plugins.PluginError`).
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points
from typing import Any

from testbed.plugins import PLUGIN_FAILURES, PluginError

#: The entry-point groups, by the kind of thing they add.
GROUPS = {"rig": "testbed.rigs", "estimator": "testbed.estimators", "suite": "testbed.suites"}

_loaded: dict[tuple[str, str], Any] = {}


def _group(kind: str) -> str:
    if kind not in GROUPS:
        raise ValueError(f"kind must be one of {sorted(GROUPS)}, got {kind!r}")
    return GROUPS[kind]


def names(kind: str) -> list[str]:
    """The names the installed distributions declare for ``kind`` (``"rig"``,
    ``"estimator"`` or ``"suite"``), sorted; nothing is imported."""
    return sorted({ep.name for ep in entry_points(group=_group(kind))})


def find(kind: str, name: str) -> EntryPoint | None:
    """The entry point ``name`` of ``kind``, or None when no installed distribution declares
    it.

    Raises
    ------
    ValueError
        Two distributions declare ``name`` with different targets (both named).
    """
    found = {ep.value: ep for ep in entry_points(group=_group(kind)) if ep.name == name}
    if len(found) > 1:
        raise ValueError(f"{kind} {name!r}: installed distributions declare it more than once "
                         f"in entry-point group {GROUPS[kind]!r}: {sorted(found)}")
    return next(iter(found.values()), None)


def describe(ep: EntryPoint) -> str:
    """``entry point 'NAME = module:attr' (group G)``: how errors name an entry point."""
    return f"entry point '{ep.name} = {ep.value}' (group {ep.group})"


def load(kind: str, name: str) -> Any | None:
    """The object the entry point ``name`` of ``kind`` names, loaded once (None when there
    is no such entry point).

    Raises
    ------
    testbed.plugins.PluginError
        The entry point's module or attribute fails to load (a ``ValueError``): one line
        naming the entry point and the exception.
    """
    key = (_group(kind), name)
    if key in _loaded:  # loaded once per process: no second scan of the distributions
        return _loaded[key]
    ep = find(kind, name)
    if ep is None:
        return None
    try:
        _loaded[key] = ep.load()
    except PLUGIN_FAILURES as exc:
        raise PluginError(describe(ep), "load", exc) from None
    return _loaded[key]


__all__ = ["GROUPS", "describe", "find", "load", "names"]
