"""Defaults applied after parsing, so that a command knows which options were typed: a
``--scenario`` file's values are overridden only by those, never by a default
(:mod:`testbed.experiment.scenario_file`)."""

from __future__ import annotations

import argparse
import weakref
from typing import Any

#: The defaults each parser applies after parsing, by parser.
_DEFERRED: weakref.WeakKeyDictionary[argparse.ArgumentParser, dict[str, Any]] = \
    weakref.WeakKeyDictionary()
#: Attribute of the parsed namespace: the options given on the command line.
GIVEN = "given_options"


def defer_defaults(parser: argparse.ArgumentParser, dests: list[str] | None = None) -> None:
    """Apply the defaults of these options (default: all) after parsing, so that
    :data:`GIVEN` lists the options typed on the command line: a scenario file's values
    are overridden only by those, never by a default."""
    deferred = _DEFERRED.setdefault(parser, {})
    for action in parser._actions:
        if action.dest in ("help", "version", argparse.SUPPRESS):
            continue
        if (dests is None or action.dest in dests) and action.default is not argparse.SUPPRESS:
            deferred[action.dest] = action.default
            action.default = argparse.SUPPRESS


def fill_deferred(parser: argparse.ArgumentParser, namespace: argparse.Namespace
                  ) -> argparse.Namespace:
    """After parsing with ``parser``: record the given options in :data:`GIVEN` and set the
    deferred defaults of the others."""
    deferred = _DEFERRED.get(parser)
    if not deferred:
        return namespace
    given = {dest for dest in deferred if hasattr(namespace, dest)}
    setattr(namespace, GIVEN, given | set(given_options(namespace, set())))
    for dest, default in deferred.items():
        if dest not in given:
            setattr(namespace, dest, list(default) if isinstance(default, list) else default)
    return namespace


def given_options(namespace: argparse.Namespace, default: set[str]) -> set[str]:
    """The options typed on the command line (:data:`GIVEN`, set by :func:`fill_deferred`),
    or ``default`` for a namespace parsed without deferred defaults."""
    return getattr(namespace, GIVEN, default)


def deferred_defaults(parser: argparse.ArgumentParser) -> dict[str, Any]:
    """The defaults ``parser`` applies after parsing (:func:`defer_defaults`), by dest (empty
    for a parser without deferred defaults)."""
    return dict(_DEFERRED.get(parser, {}))
