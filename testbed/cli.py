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
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NoReturn

import numpy as np

from filters import FilterError
from testbed import __version__
from testbed.completion import add_completion
from testbed.estimators import ESTIMATORS
from testbed.experiment import scenario_file
from testbed.experiment.control import CONTROLLERS
from testbed.experiment.scenario import MAX_SEED, Scenario, ScenarioError
from testbed.io import check_output_path, write_json
from testbed.outputs.units import display
from testbed.rigs import RIGS, resolve_rig
from testbed.sim.simulator import SimulationDiverged

#: Longest ``--duration`` (simulated seconds) accepted without ``--allow-long``.
MAX_DURATION_S = 3600.0
EXIT_FAILURE, EXIT_USAGE, EXIT_FILTER, EXIT_DIVERGED, EXIT_OUTPUT = 1, 2, 3, 4, 5
EXIT_SIGINT, EXIT_SIGTERM = 130, 143
#: Command-line flag of each scenario field (error messages name the flag).
FLAGS = {"rig": "rig", "estimator": "--filter", "estimator_options": "--filter-option",
         "controller": "--controller", "duration_s": "--duration", "seed": "--seed",
         "sensors": "--sensors", "sensor_options": "--encoder-noise",
         "manoeuvre": "--manoeuvre", "manoeuvre_params": "--manoeuvre-param",
         "disturbance": "--disturbance", "process_noise": "--process-noise",
         "design_options": "--design-option", "params": "--param", "profile": "--profile",
         "design_profile": "--design-profile",
         "ambient_noise": "--ambient-noise", "reset_noise_scale": "--reset-noise-scale"}


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


#: A plain decimal number in ASCII (no ``1_0``, no ``0x10``, no other scripts' digits).
_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?", re.ASCII)
_INTEGER = re.compile(r"[+-]?[0-9]+", re.ASCII)


def _plain_float(text: str) -> float:
    """``float(text)`` of a plain ASCII decimal number; NaN for anything else."""
    text = text.strip()
    return float(text) if _DECIMAL.fullmatch(text) else float("nan")


def _name_value(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    number = _plain_float(value)
    if not np.isfinite(number):
        raise argparse.ArgumentTypeError(f"{name}: value must be a finite number, got "
                                         f"{value!r}")
    return name.strip(), number


def _number(text: str, ok: Callable[[float], bool], what: str) -> float:
    value = _plain_float(text)
    if not (np.isfinite(value) and ok(value)):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def _positive(text: str) -> float:
    return _number(text, lambda v: v > 0, "a finite number > 0")


def _non_negative(text: str) -> float:
    return _number(text, lambda v: v >= 0, "a finite number >= 0")


def _integer(text: str, low: int, high: int | None, what: str) -> int:
    if not _INTEGER.fullmatch(text.strip()):
        raise argparse.ArgumentTypeError(f"expected {what} (plain decimal digits), got "
                                         f"{text!r}")
    value = int(text)
    if value < low or (high is not None and value > high):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def _finite(text: str) -> float:
    return _number(text, lambda v: True, "a finite number")


def _port(text: str) -> int:
    return _integer(text, 1, 65535, "a port number in 1-65535")


def _seed(text: str) -> int:
    return _integer(text, 0, MAX_SEED, "an integer in [0, 2**63)")


def _positive_int(text: str) -> int:
    return _integer(text, 1, None, "a positive integer")


def _grid_axis(text: str) -> tuple[str, list[float]]:
    name, sep, values = text.partition("=")
    if not sep or not name.strip() or not values:
        raise argparse.ArgumentTypeError(f"expected NAME=V1,V2,..., got {text!r}")
    numbers = [_number(v, lambda _: True, f"finite numbers for {name.strip()}")
               for v in values.split(",")]
    return name.strip(), numbers


def _add_scenario_options(p: argparse.ArgumentParser, duration_s: float) -> None:
    p.add_argument("rig", nargs="?", default=None,
                   help=f"one of {', '.join(RIGS)} or package.module:RigClass (default: the "
                   "--scenario file's)")
    p.add_argument("--scenario", metavar="FILE", default=None,
                   help="read the scenario from a TOML or JSON file; the options given beside "
                   "it override its fields (docs/examples/*.toml)")
    p.add_argument("--save-scenario", metavar="FILE", default=None,
                   help="write the effective scenario (.toml or .json) and exit without running")
    p.add_argument("--profile", default="paper", choices=("paper", "hardware"),
                   help="paper: the papers' idealizations; hardware: motor lag, amplifier "
                   "limits, deadband, IMU and sensor timing of the real rig (see docs)")
    p.add_argument("--design-profile", default="matched", choices=("matched", "paper"),
                   help="matched: the filter designs from the rig as its profile declares it "
                   "(hardware: motor, bias and delay states); paper: from the papers' model "
                   "(model-mismatch study)")
    p.add_argument("--filter", default="kalman",
                   help=f"{', '.join(ESTIMATORS)} or package.module:factory")
    p.add_argument("--filter-option", type=_name_value, action="append", default=[],
                   metavar="NAME=VALUE", help="keyword option of the filter factory")
    p.add_argument("--controller", default=None, choices=CONTROLLERS,
                   help="default: the rig's (helicopter lqr, vehicle-roll open-loop)")
    p.add_argument("--duration", type=_positive, default=duration_s,
                   help=f"simulated seconds (at most {MAX_DURATION_S:g} without --allow-long)")
    p.add_argument("--allow-long", action="store_true",
                   help=f"accept a --duration above {MAX_DURATION_S:g} s")
    p.add_argument("--seed", type=_seed, default=0, help="integer in [0, 2**63)")
    p.add_argument("--sensors", default=None, help="a sensor preset of the rig")
    p.add_argument("--encoder-noise", type=_non_negative, default=None,
                   help="helicopter: extra Gaussian noise std on the encoder angles, rad")
    p.add_argument("--manoeuvre", default=None,
                   help="vehicle-roll: lateral-acceleration profile (or 'none')")
    p.add_argument("--manoeuvre-param", type=_name_value, action="append", default=[],
                   metavar="NAME=VALUE", help="manoeuvre parameter, repeatable")
    p.add_argument("--disturbance", default=None,
                   help="a named disturbance of the rig (helicopter: basin-helicopter)")
    p.add_argument("--process-noise", type=_non_negative, default=None,
                   help="scale of the rig's white process noise (helicopter)")
    p.add_argument("--a-y-source", default=None, choices=("auto", "measured", "oracle"),
                   help="vehicle-roll: the filter's input a_y from measured speed x yaw rate "
                   "(measured; auto = when the sensors have them) or exact (oracle)")
    p.add_argument("--ambient-noise", type=_finite, default=1.0,
                   help="scale of the rig's small ambient disturbance (air turbulence, gusts; "
                   "default 1, 0: none)")
    p.add_argument("--reset-noise-scale", type=_finite, default=1.0,
                   help="scale of the rig's initial-state distribution (default 1; 0: the "
                   "fixed initial state of the papers)")
    p.add_argument("--design-option", type=_name_value, action="append", default=[],
                   metavar="NAME=VALUE", help="rig design option (helicopter: "
                   "process_noise_floor; vehicle-roll: a_y_std, design_roll_rate)")
    p.add_argument("--param", type=_name_value, action="append", default=[],
                   metavar="NAME=SCALE", help="scale a physical parameter of the simulated "
                   "rig (model mismatch), e.g. --param mass_kg=1.1; repeatable")
    p.add_argument("--no-progress", action="store_true", help="never show a progress bar")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used by the docs and tests)."""
    parser = _Parser(prog="testbed", description=__doc__.splitlines()[0],
                     epilog="exit codes: 0 success, 1 unexpected failure (--debug shows it), "
                     "2 bad input (nothing ran), 3 failure of the filter, 4 diverged "
                     "simulation, 5 output or Ray cluster unreachable, 130/143 interrupted "
                     "by SIGINT/SIGTERM")
    parser.add_argument("--version", action="version", version=f"testbed {__version__}")
    add_completion(parser)
    parser.add_argument("--debug", action="store_true", default=False, help=DEBUG_HELP)
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="fly a rig with an estimator in the loop")
    _add_scenario_options(run, 20.0)
    run.add_argument("--rrd", help="write a Rerun recording here")
    run.add_argument("--json", help="write the summary JSON here")
    run.add_argument("--plot", help="write a PNG plot here")
    live = run.add_mutually_exclusive_group()
    live.add_argument("--spawn", action="store_true",
                      help="stream the run to a native Rerun viewer started here")
    live.add_argument("--connect", metavar="URL", help="stream the run to a running viewer, "
                      "e.g. rerun+http://127.0.0.1:9876/proxy")
    live.add_argument("--serve", action="store_true", help="serve the run to Rerun's web "
                      "viewer (headless machines): prints the URL, serves until Ctrl-C")
    run.add_argument("--grpc-port", type=_port, default=9876,
                     help="with --spawn/--serve: the viewer's gRPC port")
    run.add_argument("--web-port", type=_port, default=9090, help="with --serve: the web port")
    run.add_argument("--bind", metavar="ADDRESS", default=None,
                     help="with --spawn/--serve: the IP address the viewer or server listens "
                     "on (default 127.0.0.1: this machine only; 0.0.0.0: every interface)")
    run.add_argument("--video", help="write an MP4 video of the run here (needs the 'video' "
                     "extra: imageio-ffmpeg)")
    run.add_argument("--realtime", action="store_true", help="pace the run to the wall clock "
                     "(a background thread samples the rig; late commands count as overruns)")
    run.add_argument("--realtime-factor", type=_positive, default=1.0,
                     help="with --realtime: simulated seconds per wall-clock second")

    mc = sub.add_parser("mc", help="Monte-Carlo study: many closed-loop runs, batched")
    _add_scenario_options(mc, 10.0)
    mc.add_argument("--runs", type=_positive_int, default=100)
    mc.add_argument("--batch-size", type=_positive_int, default=None)
    mc.add_argument("--json", help="write the results here")
    mc.add_argument("--save-npz", help="also write every trajectory to this .npz")
    mc.add_argument("--plot", help="write the RMSE distribution and error envelope (PNG) here")
    mc.add_argument("--backend", default=None, choices=("local", "ray"),
                    help="shard the runs over local processes or Ray tasks (each run keeps "
                    "its seed: the same results as in one process); default: one process")
    mc.add_argument("--workers", type=_positive_int, default=None,
                    help="shards / worker processes with --backend (default: the CPUs)")
    mc.add_argument("--address", default=None,
                    help="Ray cluster address host:port (with --backend ray; default: a local "
                    "Ray instance)")

    sw = sub.add_parser("sweep", help="one Monte-Carlo study per point of a parameter grid")
    _add_scenario_options(sw, 10.0)
    sw.add_argument("--runs", type=_positive_int, default=100)
    sw.add_argument("--grid", type=_grid_axis, action="append", default=[],
                    metavar="NAME=V1,V2,...",
                    help="a swept scenario field (process_noise, ...), params.<field>, "
                    "estimator.<option> or design.<option>; repeatable (or the --scenario "
                    "file's [study] grid)")
    sw.add_argument("--backend", default="local", choices=("local", "ray"))
    sw.add_argument("--workers", type=_positive_int, default=None)
    sw.add_argument("--address", default=None,
                    help="Ray cluster address host:port (backend ray); unreachable within "
                    "10 s: exit code 5")
    sw.add_argument("--json", help="write the results here")
    sw.add_argument("--plot", help="write RMSE versus the first --grid parameter (PNG) here")
    for p in (run, mc, sw):
        scenario_file.defer_defaults(p)

    from testbed.reproductions import REPRODUCTIONS

    rep = sub.add_parser("reproduce", help="run a paper example and compare with its numbers")
    rep.add_argument("name", choices=[*sorted(REPRODUCTIONS), "all"])
    rep.add_argument("--horizon", type=_positive, default=None,
                     help="simulated seconds (default: the paper's horizon; at most "
                     f"{MAX_DURATION_S:g} without --allow-long)")
    rep.add_argument("--allow-long", action="store_true",
                     help=f"accept a --horizon above {MAX_DURATION_S:g} s")
    rep.add_argument("--seed", type=_seed, default=0)
    rep.add_argument("--json")
    rep.add_argument("--plot")
    rep.add_argument("--rrd")
    rep.add_argument("--out-dir", default=None,
                     help=f"with 'all' only: where the JSON/PNG/RRD files go (default "
                     f"{REPRODUCE_OUT_DIR})")
    rep.add_argument("--doc", default=None,
                     help=f"with 'all' only: the Markdown table to regenerate (default "
                     f"{REPRODUCE_DOC})")
    _add_score_parser(sub)
    from testbed.outputs import view

    view.add_parser(sub)
    for command in sub.choices.values():  # also after the command: testbed run ... --debug
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                             help=DEBUG_HELP)
    return parser


def _add_score_parser(sub: Any) -> None:
    sc = sub.add_parser("score", help="score estimators on a scenario suite (RMSE, "
                        "consistency, worst-case gain, cost, mismatch)")
    sc.add_argument("--estimator", action="append", default=[], metavar="NAME_OR_MODULE:FACTORY",
                    help=f"{', '.join(ESTIMATORS)} or package.module:factory; repeatable")
    sc.add_argument("--suite", default="quick", help="quick or standard")
    sc.add_argument("--list", action="store_true", help="list the suite's scenarios and exit")
    sc.add_argument("--scenario", action="append", default=None, metavar="NAME",
                    help="only this scenario of the suite; repeatable")
    sc.add_argument("--runs", type=_positive_int, default=None,
                    help="override the runs of every entry")
    sc.add_argument("--seed", type=_seed, default=0)
    sc.add_argument("--reference", default="kalman", metavar="NAME_OR_MODULE:FACTORY",
                    help="estimator the others are compared with, paired (default kalman)")
    sc.add_argument("--no-worst-case", action="store_true", help="skip the worst-case search")
    sc.add_argument("--backend", default="local", choices=("local", "ray"))
    sc.add_argument("--workers", type=_positive_int, default=None,
                    help="processes (entries in parallel)")
    sc.add_argument("--json", help="write the results here")
    sc.add_argument("--markdown", help="write the leaderboard as Markdown here")
    sc.add_argument("--plot", help="write a PNG here")
    sc.add_argument("--rrd", help="write the comparison Rerun recording here")
    sc.add_argument("--no-progress", action="store_true",
                    help="do not report each scored entry on stderr")


#: ``run``/``mc``/``sweep`` options that set one scenario field (others: _cli_fields).
ARG_FIELDS = {"rig": "rig", "profile": "profile", "design_profile": "design_profile",
              "filter": "estimator",
              "controller": "controller", "duration": "duration_s", "seed": "seed",
              "sensors": "sensors", "manoeuvre": "manoeuvre", "disturbance": "disturbance",
              "process_noise": "process_noise", "ambient_noise": "ambient_noise",
              "reset_noise_scale": "reset_noise_scale", "filter_option": "estimator_options",
              "manoeuvre_param": "manoeuvre_params", "design_option": "design_options",
              "param": "params"}


def _cli_fields(args: argparse.Namespace, rig: Any, dests: set[str]) -> dict[str, Any]:
    """The scenario fields set by the options ``dests`` (unset ones, None, left out)."""
    out: dict[str, Any] = {}
    for dest, name in ARG_FIELDS.items():
        value = getattr(args, dest, None)
        if dest in dests and value is not None:
            out[name] = dict(value) if isinstance(value, list) else value
    if "encoder_noise" in dests and args.encoder_noise is not None:
        if rig.name != "helicopter":
            raise ValueError(f"--encoder-noise does not apply to rig {rig.name!r} (it has no "
                             "encoders)")
        out["sensor_options"] = {"noise_std_rad": args.encoder_noise}
    if "a_y_source" in dests and args.a_y_source is not None:
        if "a_y_source" not in rig.scenario_options:
            raise ValueError(f"--a-y-source does not apply to rig {rig.name!r} (its input is "
                             "not a lateral acceleration)")
        out["design_options"] = {**out.get("design_options", {}), "a_y_source": args.a_y_source}
    return out


def scenario_and_file(args: argparse.Namespace
                      ) -> tuple[Scenario, scenario_file.ScenarioFile | None]:
    """The checked :class:`Scenario` of ``run``/``mc``/``sweep`` arguments and the
    ``--scenario`` file read (or None): the command's defaults, then the file's fields, then
    the options typed on the command line (testbed.experiment.scenario_file).

    Raises
    ------
    ValueError
        A bad value or an option the rig does not have, the message starting with the flag
        (or with the file and its key).
    """
    source = scenario_file.read(args.scenario) if getattr(args, "scenario", None) else None
    every = set(ARG_FIELDS) | {"encoder_noise", "a_y_source"}
    given = getattr(args, scenario_file.GIVEN, every) if source is not None else every
    from_file = source.fields if source is not None else {}
    rig_name = args.rig if args.rig is not None else from_file.get("rig")
    if rig_name is None:
        raise ValueError(f"rig: give a rig ({', '.join(RIGS)} or package.module:RigClass) "
                         "or --scenario FILE")
    try:
        rig = resolve_rig(rig_name)
    except ValueError as exc:
        where = f"{source.path}: rig" if args.rig is None and source else "rig"
        raise ValueError(f"{where}: {exc}") from None
    typed = _cli_fields(args, rig, given)
    defaults = {k: v for k, v in _cli_fields(args, rig, every).items() if k not in from_file}
    values = scenario_file.merge(scenario_file.merge(defaults, from_file), typed)
    scenario = Scenario(**values)

    def message(field: str, text: str) -> str:
        return scenario_file.scenario_error(source, set(typed), field, text,
                                            FLAGS.get(field, field))

    if scenario.duration_s > MAX_DURATION_S and not args.allow_long:
        raise ValueError(message("duration_s", f"{scenario.duration_s:g} s is above the limit "
                                 f"of {MAX_DURATION_S:g} s; add --allow-long to run it anyway"))
    try:
        scenario.check()
    except ScenarioError as exc:
        raise ValueError(message(exc.field, str(exc))) from None
    return scenario, source


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The checked :class:`Scenario` of ``run``/``mc``/``sweep`` arguments
    (:func:`scenario_and_file`)."""
    return scenario_and_file(args)[0]


def _study(args: argparse.Namespace, source: scenario_file.ScenarioFile | None,
           name: str) -> Any:
    """``--runs``/``--grid`` if typed, else the ``--scenario`` file's ``[study]`` value, else
    the option's default."""
    if source is None or name in getattr(args, scenario_file.GIVEN, {name}):
        return getattr(args, name)
    return source.study.get(name, getattr(args, name))


def _save_scenario(args: argparse.Namespace, scenario: Scenario, **study: Any) -> int:
    """``--save-scenario FILE``: write the effective scenario, run nothing."""
    path = scenario_file.write(args.save_scenario, scenario_file.block(scenario), study)
    print(f"wrote {path}")
    return 0


def _progress(args: argparse.Namespace) -> bool:
    """Progress bars only on a terminal, and never with --no-progress."""
    return not args.no_progress and sys.stderr.isatty()


#: Output flags and the suffix of the file each writes.
OUTPUTS = {"json": ".json", "plot": ".png", "rrd": ".rrd", "save_npz": ".npz",
           "video": ".mp4", "markdown": ".md"}
#: Where ``testbed reproduce all`` writes by default.
REPRODUCE_OUT_DIR, REPRODUCE_DOC = "runs/reproductions", "docs/reproductions.md"


def worst_case_path(json_path: str | os.PathLike) -> str:
    """The ``.worst_case.npz`` that ``testbed score --json X.json`` writes beside ``X.json``."""
    return os.fspath(json_path).removesuffix(".json") + ".worst_case.npz"


def output_paths(args: argparse.Namespace) -> dict[str, str]:
    """Every file (or directory) the command will write, derived ones included, by the flag
    that names it in messages."""
    paths = {}
    for attr in OUTPUTS:
        path = getattr(args, attr, None)
        if path is not None:
            paths["--" + attr.replace("_", "-")] = path
    if args.command == "score" and args.json is not None:
        paths["--json (its .worst_case.npz)"] = worst_case_path(args.json)
    if args.command == "reproduce" and args.name == "all":
        paths["--out-dir"] = args.out_dir or REPRODUCE_OUT_DIR
        paths["--doc"] = args.doc or REPRODUCE_DOC
    return paths


def check_outputs(args: argparse.Namespace) -> None:
    """Check every output path of the command, derived ones included, before anything runs
    (``ValueError`` naming the flag)."""
    if args.command == "reproduce" and args.name != "all":
        for flag, value in (("--out-dir", args.out_dir), ("--doc", args.doc)):
            if value is not None:
                raise ValueError(f"{flag} applies to 'reproduce all' only; for one example "
                                 "use --json, --plot and --rrd")
    suffixes = {**{"--" + a.replace("_", "-"): s for a, s in OUTPUTS.items()},
                "--json (its .worst_case.npz)": ".npz", "--out-dir": None, "--doc": ".md"}
    for flag, path in output_paths(args).items():
        check_output_path(path, flag, suffixes[flag])
    if getattr(args, "video", None) is not None:
        from testbed.outputs.render import check_rendering, check_video_path

        try:
            check_video_path(args.video)
            check_rendering()
        except ValueError as exc:
            raise ValueError(f"--video: {exc}") from None
    if getattr(args, "save_scenario", None) is not None:
        scenario_file.check_destination(args.save_scenario)


def _units_note(units: dict[str, str]) -> str | None:
    """The line saying that the console shows display units and the JSON SI units."""
    shown = sorted({f"{u} as {display(u)[1]}" for u in units.values() if display(u)[0] != 1})
    if not shown:
        return None
    return f"(shown: {', '.join(shown)}; the JSON is in SI units, see its 'units')"


def _format_table(summary: dict, units: dict[str, str]) -> str:
    width = max([len("state"), *map(len, summary["rmse"])]) + 2
    lines = [f"{'state':<{width}}{'estimate RMSE':>18}{'measurement RMSE':>22}"]
    for name, value in summary["rmse"].items():
        scale, unit = display(units.get(name, ""))
        meas = summary["measurement_rmse"].get(name)
        meas_txt = f"{meas * scale:.4f} {unit}" if meas is not None else "-"
        lines.append(f"{name:<{width}}{value * scale:>11.4f} {unit:<6}{meas_txt:>22}")
    if summary.get("nees_mean") is not None:
        lines.append(f"mean NEES {summary['nees_mean']:.3f} (consistent filter: "
                     f"{len(summary['rmse'])})")
    if summary.get("T_final") is not None:
        lines.append(f"noise-output ratio T = {summary['T_final']:.4f}")
    note = _units_note({k: units.get(k, "") for k in summary["rmse"]})
    return "\n".join(lines + ([note] if note else []))


def cmd_run(args: argparse.Namespace) -> int:
    """``testbed run``: one closed-loop episode, summary table and output files."""
    from testbed.experiment import runner

    scenario = scenario_from_args(args)
    _check_live_options(args)
    if args.save_scenario:
        return _save_scenario(args, scenario)
    if args.realtime:
        return _cmd_run_realtime(args, scenario)
    live = _open_live(args, scenario)
    start = time.perf_counter()
    try:
        traj, summary = runner.run(scenario, record=bool(args.plot or args.rrd or args.video),
                                   progress=None if _progress(args) else False,
                                   observe=None if live is None else live.attach)
    except BaseException:
        if live is not None:
            from testbed.outputs.live import stop

            stop(live.rec)
        raise
    wall_s = time.perf_counter() - start
    if live is not None:
        from testbed.outputs.viz import run_description

        live.close(run_description(summary["meta"], summary))
    meta = summary.pop("meta")
    result = {"rig": meta["rig"], "filter": meta["scenario"]["estimator"],
              "controller": meta["scenario"]["controller"], "seed": scenario.seed,
              "duration_s": float(scenario.duration_s), **summary, "wall_s": wall_s,
              **_scenario_and_meta(meta)}
    print(f"{meta['rig']} | filter {result['filter']} | controller {result['controller']} | "
          f"sensors {meta['sensors']} | {summary['steps']} steps in {wall_s:.2f} s wall")
    print(_format_table(summary, summary["units"]))
    if args.json:
        print(f"wrote {write_json(args.json, result)}")
    if args.plot:
        from testbed.outputs.plots import plot_trajectory

        title = (f"{meta['rig']}: {result['filter']} filter, {result['controller']} controller, "
                 f"seed {scenario.seed}")
        print(f"wrote {plot_trajectory(traj, args.plot, title=title, summary=summary)}")
    if args.rrd:
        from testbed.outputs.viz import run_description, write_rrd

        model = traj.rig.model
        app = f"testbed/{meta['rig']}"
        path = write_rrd(traj, args.rrd, model=model, application_id=app,
                         description=run_description(meta, summary))
        print(f"wrote {path}")
    if args.video:
        from testbed.outputs.render import frame_stride, iter_frames, write_video

        rig = traj.rig
        dt_s = traj.t_s[1] - traj.t_s[0]
        stride = frame_stride(dt_s)
        frames = iter_frames(rig, traj.state, stride)
        print(f"wrote {write_video(args.video, frames, 1.0 / (dt_s * stride))}")
    if live is not None:
        from testbed.io import commit_outputs

        commit_outputs()  # the files are complete: they appear before serving goes on
        _finish_live(args, live)
    return 0


def _cmd_run_realtime(args: argparse.Namespace, scenario: Scenario) -> int:
    """``testbed run --realtime``: the episode paced to the wall clock
    (testbed.experiment.realtime)."""
    from testbed.experiment.realtime import run_scenario

    for flag, value in (("--plot", args.plot), ("--rrd", args.rrd), ("--video", args.video)):
        if value:
            raise ValueError(f"{flag} is not available with --realtime (use --json)")
    factor = args.realtime_factor
    print(f"running {scenario.duration_s:g} s of simulated time paced at {factor:g}x real time")
    summary = run_scenario(scenario, factor)
    meta = summary.pop("meta")
    pacing = summary["pacing"]
    print(f"{meta['rig']} | filter {meta['scenario']['estimator']} | sensors {meta['sensors']} "
          f"| {pacing['steps']} steps in {pacing['wall_s']:.3f} s wall (target "
          f"{pacing['target_wall_s']:.3f} s, pacing error {100 * pacing['pacing_error']:+.2f} %)")
    print(f"overruns (late commands) {pacing['overruns']}, missed samples "
          f"{pacing['missed_samples']}, simulation overruns {pacing['sim_overruns']}, max "
          f"lateness {1e3 * pacing['max_lateness_s']:.2f} ms")
    print(_format_table(summary, summary["units"]))
    if args.json:
        result = {"rig": meta["rig"], "seed": scenario.seed, **summary,
                  **_scenario_and_meta(meta)}
        print(f"wrote {write_json(args.json, result)}")
    return 0


def _scenario_and_meta(meta: dict[str, Any]) -> dict[str, Any]:
    """The JSON's ``scenario`` block (what ``--scenario`` reads) and ``meta`` (the rest)."""
    return {"scenario": meta["scenario"], "meta": {k: v for k, v in meta.items()
                                                   if k != "scenario"}}


def _check_live_options(args: argparse.Namespace) -> None:
    """``--bind`` (an IP address, with --spawn/--serve only; a warning when other machines
    can reach it) and the live options that do not go with --realtime."""
    if args.realtime and (args.spawn or args.connect or args.serve):
        raise ValueError("--spawn/--connect/--serve are not available with --realtime")
    if args.bind is None:
        return
    if not (args.spawn or args.serve):
        raise ValueError("--bind applies to --spawn and --serve (what listens)")
    from testbed.outputs.live import check_bind

    address, loopback = check_bind(args.bind)
    if not loopback:
        print(f"testbed: warning: --bind {address}: the viewer is reachable from other "
              "machines (anyone who can reach this one can watch the run)", file=sys.stderr,
              flush=True)


def _open_live(args: argparse.Namespace, scenario: Scenario) -> Any:
    """The live view asked for by --spawn / --connect / --serve, or None."""
    if not (args.spawn or args.connect or args.serve):
        return None
    from testbed.outputs.live import DEFAULT_BIND, LiveView, open_recording

    bind = DEFAULT_BIND if args.bind is None else args.bind
    rec, url = open_recording(f"testbed/{resolve_rig(scenario.rig).name}", spawn=args.spawn,
                              connect=args.connect, serve=args.serve,
                              grpc_port=args.grpc_port, web_port=args.web_port, bind=bind)
    if url is not None:
        print(f"Rerun web viewer: open {url}", flush=True)
    return LiveView(rec)


def _finish_live(args: argparse.Namespace, live: Any) -> None:
    """Keep a --serve server up until Ctrl-C; disconnect the others."""
    from testbed.outputs.live import stop

    try:
        if args.serve:
            print("serving the run; press Ctrl-C to stop", flush=True)
            while True:
                time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        stop(live.rec)


def _print_mc(result: dict) -> None:
    print(f"{result['runs']} runs x {result['steps_per_run']} steps in {result['wall_s']:.2f} s "
          f"({result['traj_steps_per_s']:,.0f} trajectory-steps/s)")
    width = max([len("state"), *map(len, result["rmse"])]) + 2
    print(f"{'state':<{width}}{'RMSE mean':>14}{'5 %':>12}{'95 %':>12}")
    for name, stats in result["rmse"].items():
        scale, unit = display(result["units"].get(name, ""))
        print(f"{name:<{width}}{stats['mean'] * scale:>14.4f}{stats['q05'] * scale:>12.4f}"
              f"{stats['q95'] * scale:>12.4f}  {unit}")
    if result.get("nees_mean") is not None:
        print(f"mean NEES {result['nees_mean']:.3f}")
    if result.get("T_final"):
        print(f"T_final mean {result['T_final']['mean']:.4f}")
    note = _units_note({k: result["units"].get(k, "") for k in result["rmse"]})
    if note:
        print(note)


def cmd_mc(args: argparse.Namespace) -> int:
    """``testbed mc``: a batched Monte-Carlo study."""
    from testbed.experiment.runner import monte_carlo

    scenario, source = scenario_and_file(args)
    runs = _study(args, source, "runs")
    if args.save_scenario:
        return _save_scenario(args, scenario, runs=runs)
    if args.backend is None and (args.workers is not None or args.address is not None):
        raise ValueError("--workers and --address need --backend")
    if args.backend is not None and (args.save_npz or args.plot):
        raise ValueError("--backend shards the runs: without --save-npz and --plot")
    if args.address is not None:
        from testbed.experiment.backend import check_ray_address

        if args.backend != "ray":
            raise ValueError("--address is only used with --backend ray")
        try:
            check_ray_address(args.address)  # unreachable: ConnectionError, exit code 5
        except ValueError as exc:
            raise ValueError(f"--address: {exc}") from None
    result = monte_carlo(scenario, runs, batch_size=args.batch_size,
                         progress=_progress(args), save_npz=args.save_npz,
                         envelope_points=200 if args.plot else None, backend=args.backend,
                         workers=args.workers, address=args.address)
    _print_mc(result)
    if args.json:
        print(f"wrote {write_json(args.json, result)}")
    if args.plot:
        from testbed.outputs.study_plots import plot_monte_carlo

        print(f"wrote {plot_monte_carlo(result, args.plot)}")
    return 0


def check_grid(scenario: Scenario, axes: list[tuple[str, list[float]]]) -> dict[str, list]:
    """The grid of ``--grid`` axes, every point's scenario checked (``ValueError`` naming
    ``--grid``)."""
    from testbed.experiment.runner import check_grid_name, grid_points, point_scenario

    grid: dict[str, list] = {}
    for name, values in axes:
        if name in grid:
            raise ValueError(f"--grid {name} is given twice")
        try:
            check_grid_name(scenario, name)
        except ValueError as exc:
            raise ValueError(f"--grid: {exc}") from None
        grid[name] = values
    for point in grid_points(grid):
        try:
            point_scenario(scenario, point).check()
        except ScenarioError as exc:
            where = ", ".join(f"{k}={v:g}" for k, v in point.items())
            raise ValueError(f"--grid {where}: {exc}") from None
    return grid


def cmd_sweep(args: argparse.Namespace) -> int:
    """``testbed sweep``: one Monte-Carlo study per grid point."""
    from testbed.experiment.backend import check_ray_address
    from testbed.experiment.runner import sweep

    scenario, source = scenario_and_file(args)
    axes = _study(args, source, "grid")
    if not axes:
        raise ValueError("--grid: give NAME=V1,V2,... (repeatable) or a [study] grid in the "
                         "--scenario file")
    try:
        grid = check_grid(scenario, axes)
    except ValueError as exc:
        if axes is args.grid:
            raise
        detail = str(exc).removeprefix("--grid").lstrip(": ")
        raise ValueError(f"{source.path}: study.grid: {detail}") from None
    runs = _study(args, source, "runs")
    from testbed.experiment.runner import check_study_size

    check_study_size(scenario, runs)
    if args.save_scenario:
        return _save_scenario(args, scenario, runs=runs, grid=grid)
    if args.address is not None:
        if args.backend != "ray":
            raise ValueError("--address is only used with --backend ray")
        try:
            check_ray_address(args.address)
        except ValueError as exc:
            raise ValueError(f"--address: {exc}") from None
    result = sweep(scenario, grid, runs=runs, backend=args.backend,
                   workers=args.workers, address=args.address, progress=_progress(args))
    names = list(grid)
    print(f"{len(result['points'])} points on {result['backend']} ({result['workers']} workers) "
          f"in {result['wall_s']:.2f} s")
    first = result["points"][0]["result"]
    states = list(first["rmse"])[:2]
    titles = [f"{s} RMSE {display(first['units'].get(s, ''))[1]}".strip() for s in states]
    widths = [max(16, len(n)) for n in names] + [max(14, len(t)) for t in titles]
    print("  ".join(f"{t:>{w}}" for t, w in zip(names + titles, widths, strict=True)))
    for entry in result["points"]:
        rmse, units = entry["result"]["rmse"], entry["result"]["units"]
        cells = [f"{entry['point'][n]:g}" for n in names] + [
            f"{rmse[s]['mean'] * display(units.get(s, ''))[0]:.4f}" for s in states]
        print("  ".join(f"{c:>{w}}" for c, w in zip(cells, widths, strict=True)))
    note = _units_note({s: first["units"].get(s, "") for s in states})
    if note:
        print(note)
    if args.json:
        print(f"wrote {write_json(args.json, result)}")
    if args.plot:
        from testbed.outputs.study_plots import plot_sweep

        print(f"wrote {plot_sweep(result, args.plot, x=names[0])}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """``testbed reproduce``: one paper example (or all, regenerating the docs)."""
    from testbed import reproductions

    if args.horizon is not None and args.horizon > MAX_DURATION_S and not args.allow_long:
        raise ValueError(f"--horizon {args.horizon:g} s is above the limit of "
                         f"{MAX_DURATION_S:g} s; add --allow-long to run it anyway")
    from testbed.reproductions.outputs import agree_text, format_claims

    if args.name == "all":
        out_dir, doc = args.out_dir or REPRODUCE_OUT_DIR, args.doc or REPRODUCE_DOC
        results = reproductions.reproduce_all(out_dir, doc)
        for name, result in results.items():
            print(f"{name}: {agree_text(result['claims'])}")
        print(f"wrote {doc}, its figures and {out_dir}/")
        return 0
    module = reproductions.load(args.name)
    result = module.reproduce(horizon_s=args.horizon, seed=args.seed, json_path=args.json,
                              plot_path=args.plot, rrd_path=args.rrd)
    print(f"{args.name}: {module.PAPER.citation}\n  {agree_text(result['claims'])}\n"
          "  claims (paper | ours):\n" + format_claims(result["claims"]))
    for path in (args.json, args.plot, args.rrd):
        if path:
            print(f"wrote {path}")
    return 0


def cmd_score(args: argparse.Namespace) -> int:
    """``testbed score``: estimators on a scenario suite, leaderboard and output files."""
    from testbed.score import harness, report
    from testbed.score.suite import describe_suite, suite_identity

    if args.list:
        identity = suite_identity(args.suite)
        print(f"suite {identity['suite']} version {identity['version']} sha256 "
              f"{identity['hash']}")
        for entry in describe_suite(args.suite):
            status = f"skipped: {entry['skipped']}" if entry["skipped"] else \
                f"{entry['runs']} runs"
            search = "worst case" if entry["worst_case"] else ""
            print(f"{entry['name']:<28}{status:<44}{search:<12}{entry['description']}")
        return 0
    if not args.estimator:
        raise ValueError("give --estimator NAME (repeatable), or --list")
    from testbed import estimators

    for name in args.estimator:  # loaded (and a plug-in's failure named) before any work
        try:
            estimators.resolve(name)
        except ValueError as exc:
            raise ValueError(f"--estimator: {exc}") from None
    run = harness.score(args.estimator, args.suite, seed=args.seed, runs=args.runs,
                        scenarios=args.scenario, backend=args.backend, workers=args.workers,
                        worst_case=not args.no_worst_case, reference=args.reference,
                        progress=None if args.no_progress else
                        lambda name: print(f"  scored {name}", file=sys.stderr))
    summary = report.results(run)
    remarks = report.notes(run)
    print(report.leaderboard(summary))
    for remark in remarks:
        print(f"note: {remark}")
    if args.json:
        print(f"wrote {report.write_results(args.json, summary)}")
        npz = report.write_worst_cases(worst_case_path(args.json), run)
        if npz is not None:
            print(f"wrote {npz}")
    if args.markdown:
        print(f"wrote {report.write_markdown(args.markdown, summary, remarks)}")
    if args.plot:
        print(f"wrote {report.write_png(args.plot, summary)}")
    if args.rrd:
        print(f"wrote {report.write_rrd(args.rrd, run)}")
    return 0


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that ``finally`` blocks remove temporaries."""


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
    return bool(getattr(args, "debug", False)) or os.environ.get("TESTBED_DEBUG", "") not in (
        "", "0")


def _plugin_flag(args: argparse.Namespace) -> str:
    """How messages name the estimator of the command (``--filter 'x'``, ``--estimator``)."""
    if args.command == "score":
        return "--estimator"
    return f"--filter {getattr(args, 'filter', '')!r}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``testbed`` command (exit codes in the module docstring)."""
    import testbed

    args = None
    try:
        if testbed._end_of_startup():  # a Ctrl-C while the command started (its imports)
            raise KeyboardInterrupt
        args = build_parser().parse_args(argv)
        commands = {"run": cmd_run, "mc": cmd_mc, "sweep": cmd_sweep,
                    "reproduce": cmd_reproduce, "score": cmd_score}
        if args.command == "view":
            from testbed.outputs.view import cmd_view

            commands["view"] = cmd_view
        with _sigterm_raises(), _mujoco_warnings_logged():
            return _run_command(commands[args.command], args)
    except KeyboardInterrupt:  # during start-up or parsing
        if _debug(args):
            traceback.print_exc()
        return _fail(EXIT_SIGINT, "testbed: interrupted (SIGINT)")


def _run_command(command: Callable[[argparse.Namespace], int],
                 args: argparse.Namespace) -> int:
    """``command(args)`` with its failures as one line and an exit code."""
    from testbed.io import outputs_together

    try:
        with outputs_together():  # all of the command's outputs, or none of them
            check_outputs(args)
            code = command(args)
            _done_with_signals()
        return code
    except BaseException as exc:
        if _debug(args) and not isinstance(exc, SystemExit | KeyboardInterrupt | _Terminated):
            traceback.print_exc()
        return _failure_code(exc, args)


def _done_with_signals() -> None:
    """The ``testbed`` process whose command has done its work: SIGINT/SIGTERM are ignored
    from here to the exit, so that the outputs being renamed into place all appear and a
    late Ctrl-C cannot turn a complete command into exit 130 (or kill the interpreter while
    it shuts down). Only in the command's own process, not for callers of :func:`main`."""
    import testbed

    if testbed.CLI_PROCESS and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)


def _failure_code(exc: BaseException, args: argparse.Namespace) -> int:
    """The exit code of a failure (printed as one line); re-raises what is not a failure."""
    from testbed.experiment.runner import StudyTooLarge
    from testbed.io import OutputError
    from testbed.plugins import EstimatorFailed, describe

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
    target = os.path.abspath(os.fspath(path))
    for flag, value in output_paths(args).items():
        if os.path.abspath(os.fspath(value)) == target:
            return f"{flag}: "
    return ""


if __name__ == "__main__":
    sys.exit(main())
