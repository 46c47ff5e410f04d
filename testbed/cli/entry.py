"""The ``testbed`` command's entry point: the command run with its failures as one line
and an exit code (the table in :mod:`testbed.cli`), SIGINT/SIGTERM, MuJoCo's warnings."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from testbed.cli.exits import (
    EXIT_DIVERGED,
    EXIT_FAILURE,
    EXIT_FILTER,
    EXIT_OUTPUT,
    EXIT_PIPE,
    EXIT_SIGINT,
    EXIT_SIGTERM,
    EXIT_USAGE,
)


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that ``finally`` blocks remove temporaries."""


class _StoppedBySignal(BaseException):
    """A command that ended normally after it caught SIGINT or SIGTERM as its way to stop
    (``run --serve`` serves until Ctrl-C): still an interrupted command (exit 130/143);
    the outputs it had made appear are kept, any others are not."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def _sigterm_raises() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`_Terminated` and SIGINT
    ``KeyboardInterrupt``, both remembered in :data:`_SIGNALLED` (main thread only): an
    interrupt that lands inside a library (matplotlib's drawing, say) and comes out as
    another exception is still reported as the interrupt it was."""
    _SIGNALLED.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_term(signum: int, frame: Any) -> None:
        _SIGNALLED.append(signum)
        raise _Terminated

    def on_int(signum: int, frame: Any) -> None:
        _SIGNALLED.append(signum)
        raise KeyboardInterrupt

    previous = {sig: signal.signal(sig, handler)
                for sig, handler in ((signal.SIGTERM, on_term), (signal.SIGINT, on_int))
                if signal.getsignal(sig) is not signal.SIG_IGN or sig == signal.SIGTERM}
    try:
        yield
    finally:
        for sig, handler in ((signal.SIGTERM, on_term), (signal.SIGINT, on_int)):
            if sig in previous and signal.getsignal(sig) is handler:  # not ignored at the end
                signal.signal(sig, previous[sig])


#: The signals received while the command ran (see :func:`_sigterm_raises`).
_SIGNALLED: list[int] = []


@contextlib.contextmanager
def _mujoco_warnings_logged() -> Iterator[None]:
    """Within the block, MuJoCo's warnings go to the ``testbed.mujoco`` logger (debug level)
    instead of stderr and a ``MUJOCO_LOG.TXT`` in the working directory: the simulator reads
    MuJoCo's warning counters and reports an instability itself, in one line."""
    import logging

    import mujoco

    log = logging.getLogger("testbed.mujoco")
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda message: log.debug("%s", message))
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(previous)


def _fail(code: int, message: str) -> int:
    print(message.replace("\n", " "), file=sys.stderr)
    return code


def _debug(args: argparse.Namespace | None) -> bool:
    """``--debug`` or ``TESTBED_DEBUG=1``: show the traceback of a failure."""
    return (args is not None and bool(args.debug)) or os.environ.get("TESTBED_DEBUG", "") \
        not in ("", "0")


def _plugin_flag(args: argparse.Namespace) -> str:
    """How messages name the estimator of the command (``--filter 'x'``, ``--estimator``)."""
    if args.command == "score":
        return "--estimator"
    return f"--filter {args.filter!r}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``testbed`` command (exit codes in :mod:`testbed.cli`)."""
    import testbed
    from testbed import _startup
    from testbed.cli.parser import build_parser, command_module, command_named

    args = None
    try:
        # the start-up: the named command's module and its imports (MuJoCo, SciPy...), and
        # the Gymnasium ids for plug-ins that make environments; a Ctrl-C in it is deferred
        words = list(sys.argv[1:] if argv is None else argv)
        named = command_named(words)
        only = [named] if named else [] if "--print-completion" not in words else None
        parser = build_parser(only)
        if named is not None:
            testbed.register()
        if _startup.end_of_startup():  # a Ctrl-C while the command started
            raise KeyboardInterrupt
        args = parser.parse_args(words)
        command = command_module(args.command).command
        with _sigterm_raises(), _mujoco_warnings_logged():
            return _run_command(command, args)
    except KeyboardInterrupt:  # during start-up or parsing
        if _debug(args):
            traceback.print_exc()
        return _fail(EXIT_SIGINT, "testbed: interrupted (SIGINT)")


def _run_command(command: Callable[[argparse.Namespace], int],
                 args: argparse.Namespace) -> int:
    """``command(args)`` with its failures as one line and an exit code."""
    from testbed.cli.outputs import check_outputs, say_written
    from testbed.io import outputs_together

    try:
        say_written(done=False)
        with outputs_together():  # all of the command's outputs, or none of them
            check_outputs(args)
            code = command(args)
            if _SIGNALLED:  # caught by the command to stop (run --serve: Ctrl-C)
                raise _StoppedBySignal(_SIGNALLED[-1])
            _done_with_signals()
        say_written()
        return code
    except BaseException as exc:
        say_written(done=False)
        if _debug(args) and not isinstance(exc, SystemExit | KeyboardInterrupt | _Terminated
                                           | _StoppedBySignal):
            traceback.print_exc()
        return _failure_code(exc, args)


def _done_with_signals() -> None:
    """The ``testbed`` process whose command has done its work: SIGINT/SIGTERM are ignored
    from here to the exit, so that the outputs being renamed into place all appear and a
    late Ctrl-C cannot turn a complete command into exit 130 (or kill the interpreter while
    it shuts down). Only in the command's own process, not for callers of :func:`main`."""
    from testbed import _startup

    if _startup.CLI_PROCESS and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)


def _failure_code(exc: BaseException, args: argparse.Namespace) -> int:
    """The exit code of a failure (printed as one line); re-raises what is not a failure."""
    from filters import FilterError
    from testbed.cli.scenario_options import FLAGS
    from testbed.experiment.runner import StudyTooLarge
    from testbed.experiment.scenario import ScenarioError
    from testbed.io import OutputError
    from testbed.plugins import EstimatorFailed, describe
    from testbed.sim.simulator import SimulationDiverged

    if isinstance(exc, _StoppedBySignal):
        name = "SIGTERM" if exc.signum == signal.SIGTERM else "SIGINT"
        return _fail(EXIT_SIGTERM if exc.signum == signal.SIGTERM else EXIT_SIGINT,
                     f"testbed: stopped ({name})")
    if _SIGNALLED and not isinstance(exc, KeyboardInterrupt | _Terminated):
        # the signal landed in a library, which turned it into another exception
        exc = _Terminated() if _SIGNALLED[-1] == signal.SIGTERM else KeyboardInterrupt()
    if isinstance(exc, StudyTooLarge):
        return _fail(EXIT_USAGE, f"testbed: error: --{exc}")
    if isinstance(exc, ScenarioError):
        return _fail(EXIT_USAGE, f"testbed: error: {FLAGS.get(exc.field, exc.field)}: {exc}")
    if isinstance(exc, ValueError):
        return _fail(EXIT_USAGE, f"testbed: error: {exc}")
    if isinstance(exc, EstimatorFailed):
        return _fail(EXIT_FILTER, f"testbed: {_plugin_flag(args)} failed while running: {exc}")
    if isinstance(exc, FilterError | FloatingPointError):  # typed, or a user's filter's NaN
        return _fail(EXIT_FILTER, f"testbed: numerical failure of the filter: {exc}")
    if isinstance(exc, SimulationDiverged):
        return _fail(EXIT_DIVERGED, f"testbed: {exc}")
    if isinstance(exc, OutputError):
        return _fail(EXIT_OUTPUT, f"testbed: {_output_flag(args, exc.path)}{exc}")
    if isinstance(exc, BrokenPipeError):  # the reader went away (testbed ... | head)
        with contextlib.suppress(OSError):
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - nothing more to print
        return EXIT_PIPE
    if isinstance(exc, OSError):
        return _fail(EXIT_OUTPUT, f"testbed: {exc}")
    if isinstance(exc, KeyboardInterrupt):
        return _fail(EXIT_SIGINT, "testbed: interrupted (SIGINT); partial outputs removed")
    if isinstance(exc, _Terminated):
        return _fail(EXIT_SIGTERM, "testbed: terminated (SIGTERM); partial outputs removed")
    if isinstance(exc, SystemExit):  # only plug-in code calls sys.exit inside a command
        return _fail(EXIT_FAILURE, f"testbed: a plug-in ({_plugin_flag(args)} or the rig) "
                     f"called sys.exit({exc.code!r}) while the command ran")
    if isinstance(exc, Exception):
        hint = "" if _debug(args) else " (--debug or TESTBED_DEBUG=1 shows the traceback)"
        return _fail(EXIT_FAILURE, f"testbed: unexpected failure: {describe(exc)}{hint}")
    raise exc


def _output_flag(args: argparse.Namespace, path: Any) -> str:
    """``--json `` when ``path`` is (or derives from) the file of an output flag."""
    if path is None:
        return ""
    from testbed.cli.outputs import output_paths

    target = os.path.abspath(os.fspath(path))
    for flag, value in output_paths(args).items():
        if os.path.abspath(os.fspath(value)) == target:
            return f"{flag}: "
    return ""
