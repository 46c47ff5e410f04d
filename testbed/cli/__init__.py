"""The ``testbed`` command line: parse, build a scenario, run it, write the outputs.

``testbed run helicopter --filter kalman --duration 20 --seed 0 --json runs/demo.json``
``testbed mc vehicle-roll --filter kalman --runs 64 --duration 10 --json runs/mc.json``
``testbed sweep helicopter --grid process_noise=0,1 --runs 50``
``testbed run helicopter --filter mymodule:make`` (a user's estimator factory)

Every argument is checked before anything is simulated; a bad one ends the command with one
line ``testbed: error: --NAME ...``. Exit codes:

====  =====================================================================================
0     success
1     an unexpected failure (a plug-in called ``sys.exit``, or a bug): one line; ``--debug``
      or ``TESTBED_DEBUG=1`` also prints the traceback (of any failure)
2     bad command line or input (nothing was simulated, nothing written), including a
      plug-in (``--filter``, ``--estimator``, the rig) that fails while loading or building
3     failure of the filter while running (``filters.FilterError``: time and quantity
      named; a user's estimator returned a non-finite estimate; or its ``step`` raised
      anything, e.g. a ``LinAlgError``: ``testbed.plugins.EstimatorFailed``)
4     the simulation diverged (``testbed.sim.simulator.SimulationDiverged``: time and state)
5     an output could not be written (``testbed.io.OutputError``, the output named; none of
      the command's outputs is kept), or the Ray cluster could not be reached
130   interrupted by SIGINT (Ctrl-C), also during start-up; 143: terminated by SIGTERM
      (temporaries removed)
====  =====================================================================================

What ``--spawn``/``--serve`` start listens on 127.0.0.1 unless ``--bind ADDRESS``.

The package: :mod:`~testbed.cli.entry` (entry point, exit codes, signals),
:mod:`~testbed.cli.parser` (the top-level parser), :mod:`~testbed.cli.values` (value
parsers), :mod:`~testbed.cli.scenario_options` (the options of every scenario command),
:mod:`~testbed.cli.outputs` (output flags, tables) and one module per command, each with
``add_parser(sub)`` and ``command(args)``.
"""

from typing import Any

__all__ = ["build_parser", "main", "scenario_from_args"]

#: Where each name of :data:`__all__` lives (imported on first use: ``testbed --version``
#: imports no command).
_HOMES = {"main": "testbed.cli.entry", "build_parser": "testbed.cli.parser",
          "scenario_from_args": "testbed.cli.scenario_options"}


def __getattr__(name: str) -> Any:
    if name in _HOMES:
        import importlib

        return getattr(importlib.import_module(_HOMES[name]), name)
    raise AttributeError(f"module 'testbed.cli' has no attribute {name!r}")
