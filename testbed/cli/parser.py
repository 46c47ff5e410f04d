"""The argument parser of the ``testbed`` command: the top level and one subparser per
command, each added by its command module (:data:`COMMANDS`)."""

from __future__ import annotations

import argparse
import importlib
from typing import Any, NoReturn

from testbed import __version__
from testbed.cli.main import EXIT_USAGE
from testbed.completion import add_completion
from testbed.experiment import scenario_file

#: The commands, in ``--help`` order: ``testbed.cli.NAME`` has ``add_parser(sub)`` and
#: ``command(args) -> exit code``.
COMMANDS = ("run", "mc", "sweep", "reproduce", "score", "view")

DEBUG_HELP = ("on a failure, also print the Python traceback (or set TESTBED_DEBUG=1)")


class _Parser(argparse.ArgumentParser):
    """``parser.error`` as one line ``testbed: error: --NAME ...`` and exit code 2."""

    def error(self, message: str) -> NoReturn:
        if message.startswith("argument "):
            message = message[len("argument "):]
        self.exit(EXIT_USAGE, f"testbed: error: {message}\n")

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        # the deferred defaults of run/mc/sweep: a scenario file's values yield only to the
        # options typed (testbed.experiment.scenario_file.defer_defaults)
        namespace, extras = super().parse_known_args(args, namespace)
        return scenario_file.fill_deferred(self, namespace), extras


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used by the docs and tests)."""
    import testbed.cli

    parser = _Parser(prog="testbed", description=testbed.cli.__doc__.splitlines()[0],
                     epilog="exit codes: 0 success, 1 unexpected failure (--debug shows it), "
                     "2 bad input (nothing ran), 3 failure of the filter, 4 diverged "
                     "simulation, 5 output or Ray cluster unreachable, 130/143 interrupted "
                     "by SIGINT/SIGTERM")
    parser.add_argument("--version", action="version", version=f"testbed {__version__}")
    add_completion(parser)
    parser.add_argument("--debug", action="store_true", default=False, help=DEBUG_HELP)
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        command_module(name).add_parser(sub)
    for command in sub.choices.values():  # also after the command: testbed run ... --debug
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                             help=DEBUG_HELP)
    return parser


def command_module(name: str) -> Any:
    """The module of command ``name`` (``testbed.cli.NAME``)."""
    return importlib.import_module(f"testbed.cli.{name}")
