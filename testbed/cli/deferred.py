"""Defaults applied after parsing, so that a command knows which options were typed: a
``--scenario`` file's values are overridden only by those, never by a default
(:mod:`testbed.experiment.scenario_file`)."""

from __future__ import annotations

import argparse

#: Attribute of a parser holding the defaults it applies after parsing.
_DEFERRED = "_testbed_deferred_defaults"
#: Attribute of the parsed namespace: the options given on the command line.
GIVEN = "given_options"


def defer_defaults(parser: argparse.ArgumentParser, dests: list[str] | None = None) -> None:
    """Apply the defaults of these options (default: all) after parsing, so that
    :data:`GIVEN` lists the options typed on the command line: a scenario file's values
    are overridden only by those, never by a default."""
    deferred = getattr(parser, _DEFERRED, {})
    for action in parser._actions:
        if action.dest in ("help", "version", argparse.SUPPRESS):
            continue
        if (dests is None or action.dest in dests) and action.default is not argparse.SUPPRESS:
            deferred[action.dest] = action.default
            action.default = argparse.SUPPRESS
    setattr(parser, _DEFERRED, deferred)


def fill_deferred(parser: argparse.ArgumentParser, namespace: argparse.Namespace
                  ) -> argparse.Namespace:
    """After parsing with ``parser``: record the given options in :data:`GIVEN` and set the
    deferred defaults of the others."""
    deferred = getattr(parser, _DEFERRED, None)
    if not deferred:
        return namespace
    given = {dest for dest in deferred if hasattr(namespace, dest)}
    setattr(namespace, GIVEN, given | set(getattr(namespace, GIVEN, set())))
    for dest, default in deferred.items():
        if dest not in given:
            setattr(namespace, dest, list(default) if isinstance(default, list) else default)
    return namespace
