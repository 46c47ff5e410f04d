"""The argument parser of the ``testbed`` command: the top level and one subparser per
command, each added by its command module (:data:`COMMANDS`)."""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Iterable, Sequence
from typing import Any, NoReturn

from testbed import __version__
from testbed.cli import deferred
from testbed.cli.exits import EXIT_USAGE
from testbed.completion import add_completion

#: The commands, in ``--help`` order, with their one-line help: ``testbed.cli.NAME`` has
#: ``add_arguments(parser)`` and ``command(args) -> exit code``.
COMMANDS = {
    "run": "fly a rig with an estimator in the loop",
    "mc": "Monte-Carlo study: many closed-loop runs, batched",
    "sweep": "one Monte-Carlo study per point of a parameter grid",
    "reproduce": "run a paper example and compare with its numbers",
    "score": "score estimators on a scenario suite (RMSE, consistency, worst-case gain, "
             "cost, mismatch)",
    "view": "open a .rrd recording in Rerun's viewer (native or web)",
    "describe": "a rig's inputs, sensor channels, units, options and identifiable parameters",
    "replay": "an estimator over a recorded run (a unit's log): consistency from its "
              "innovations, RMSE against a held-out channel",
    "identify": "fit a rig's parameters and sensor model to a recording; write its twin",
    "compare": "simulate a rig or a twin with a recording's inputs; fit per channel",
}

DEBUG_HELP = ("on a failure, also print the Python traceback (or set TESTBED_DEBUG=1)")

#: The options the shared code (output checks, the scenario options, failure messages)
#: reads of every command, and their value for a command without the option: the top
#: parser's defaults, so that every command's namespace has them (``args.NAME``).
COMMON_DEFAULTS: dict[str, Any] = {
    "json": None, "plot": None, "rrd": None, "save_npz": None, "video": None,
    "markdown": None, "save_log": None, "twin": None, "scenario": None, "save_scenario": None,
    "filter": ""}


class _Parser(argparse.ArgumentParser):
    """``parser.error`` as one line ``testbed: error: --NAME ...`` and exit code 2."""

    def error(self, message: str) -> NoReturn:
        if message.startswith("argument "):
            message = message[len("argument "):]
        self.exit(EXIT_USAGE, f"testbed: error: {message}\n")

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        # the deferred defaults of run/mc/sweep: a scenario file's values yield only to the
        # options typed (testbed.cli.deferred.defer_defaults)
        namespace, extras = super().parse_known_args(args, namespace)
        return deferred.fill_deferred(self, namespace), extras


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser (also used by the docs and tests).

    Parameters
    ----------
    commands : iterable of str, optional
        The commands whose arguments are added (default: all); the others are listed with
        their help only, so that ``testbed --version`` and ``testbed --help`` import no
        command module (nor MuJoCo, SciPy or Gymnasium).
    """
    import testbed.cli

    parser = _Parser(prog="testbed", description=testbed.cli.__doc__.splitlines()[0],
                     epilog="exit codes: 0 success, 1 unexpected failure (--debug shows it), "
                     "2 bad input (nothing ran), 3 failure of the filter, 4 diverged "
                     "simulation, 5 output or Ray cluster unreachable, 130/143 interrupted "
                     "by SIGINT/SIGTERM")
    parser.add_argument("--version", action="version", version=f"testbed {__version__}")
    add_completion(parser)
    parser.add_argument("--debug", action="store_true", default=False, help=DEBUG_HELP)
    parser.set_defaults(**COMMON_DEFAULTS)
    sub = parser.add_subparsers(dest="command", required=True)
    wanted = set(COMMANDS if commands is None else commands)
    for name, text in COMMANDS.items():
        command = sub.add_parser(name, help=text)
        if name in wanted:
            command_module(name).add_arguments(command)
    for command in sub.choices.values():  # also after the command: testbed run ... --debug
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                             help=DEBUG_HELP)
    return parser


def command_module(name: str) -> Any:
    """The module of command ``name`` (``testbed.cli.NAME``)."""
    return importlib.import_module(f"testbed.cli.{name}")


def command_named(argv: Sequence[str]) -> str | None:
    """The command a command line names (its first word that is a command), or None."""
    for word in argv:
        if word in COMMANDS:
            return word
        if word == "--print-completion":
            return None  # completion needs every command's arguments
    return None
