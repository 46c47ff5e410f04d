"""The ``testbed`` command line: parse, build a scenario, run it, write the outputs.

``testbed run helicopter --filter kalman --duration 20 --seed 0 --json runs/demo.json``
``testbed mc vehicle-roll --filter kalman --runs 64 --duration 10 --json runs/mc.json``
``testbed sweep helicopter --grid process_noise=0,1 --runs 50``
``testbed run helicopter --filter mymodule:make`` (a user's estimator factory)

Every argument is checked before anything is simulated; a bad one ends the command with one
line ``testbed: error: --NAME ...``. Exit codes:

====  =====================================================================================
0     success
2     bad command line or input (nothing was simulated, nothing written)
3     numerical failure of the filter (``filters.FilterError``: time and quantity named;
      or a user's estimator returned a non-finite estimate)
4     the simulation diverged (``testbed.sim.simulator.SimulationDiverged``: time and state)
5     an output could not be written, or the Ray cluster could not be reached
130   interrupted by SIGINT (Ctrl-C); 143: terminated by SIGTERM (temporaries removed)
====  =====================================================================================
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NoReturn

import numpy as np

from filters import FilterError
from testbed.estimators import ESTIMATORS
from testbed.experiment.control import CONTROLLERS
from testbed.experiment.scenario import MAX_SEED, Scenario, ScenarioError
from testbed.io import check_output_path, write_json
from testbed.outputs.units import display
from testbed.rigs import RIGS, resolve_rig
from testbed.sim.simulator import SimulationDiverged

#: Longest ``--duration`` (simulated seconds) accepted without ``--allow-long``.
MAX_DURATION_S = 3600.0
EXIT_USAGE, EXIT_FILTER, EXIT_DIVERGED, EXIT_OUTPUT = 2, 3, 4, 5
EXIT_SIGINT, EXIT_SIGTERM = 130, 143
#: Command-line flag of each scenario field (error messages name the flag).
FLAGS = {"rig": "rig", "estimator": "--filter", "estimator_options": "--filter-option",
         "controller": "--controller", "duration_s": "--duration", "seed": "--seed",
         "sensors": "--sensors", "sensor_options": "--encoder-noise",
         "manoeuvre": "--manoeuvre", "manoeuvre_params": "--manoeuvre-param",
         "disturbance": "--disturbance", "process_noise": "--process-noise",
         "design_options": "--design-option", "params": "--param", "profile": "--profile",
         "ambient_noise": "--ambient-noise", "reset_noise_scale": "--reset-noise-scale"}


class _Parser(argparse.ArgumentParser):
    """``parser.error`` as one line ``testbed: error: --NAME ...`` and exit code 2."""

    def error(self, message: str) -> NoReturn:
        if message.startswith("argument "):
            message = message[len("argument "):]
        self.exit(EXIT_USAGE, f"testbed: error: {message}\n")


def _name_value(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not np.isfinite(number):
        raise argparse.ArgumentTypeError(f"{name}: value must be a finite number, got "
                                         f"{value!r}")
    return name.strip(), number


def _number(text: str, ok: Callable[[float], bool], what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and ok(value)):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def _positive(text: str) -> float:
    return _number(text, lambda v: v > 0, "a finite number > 0")


def _non_negative(text: str) -> float:
    return _number(text, lambda v: v >= 0, "a finite number >= 0")


def _integer(text: str, low: int, high: int | None, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if value < low or (high is not None and value > high):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


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
    p.add_argument("rig", help=f"one of {', '.join(RIGS)} or package.module:RigClass")
    p.add_argument("--profile", default="paper", choices=("paper", "hardware"),
                   help="paper: the papers' idealizations; hardware: motor lag, amplifier "
                   "limits, deadband, IMU and sensor timing of the real rig (see docs)")
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
    p.add_argument("--ambient-noise", type=float, default=1.0,
                   help="scale of the rig's small ambient disturbance (air turbulence, gusts; "
                   "default 1, 0: none)")
    p.add_argument("--reset-noise-scale", type=float, default=1.0,
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
                     epilog="exit codes: 0 success, 2 bad input (nothing ran), 3 numerical "
                     "failure of the filter, 4 diverged simulation, 5 output or Ray cluster "
                     "unreachable, 130/143 interrupted by SIGINT/SIGTERM")
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
    run.add_argument("--grpc-port", type=int, default=9876,
                     help="with --spawn/--serve: the viewer's gRPC port")
    run.add_argument("--web-port", type=int, default=9090, help="with --serve: the web port")
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
                    metavar="NAME=V1,V2,...", required=True,
                    help="a swept scenario field (process_noise, ...), params.<field>, "
                    "estimator.<option> or design.<option>; repeatable")
    sw.add_argument("--backend", default="local", choices=("local", "ray"))
    sw.add_argument("--workers", type=_positive_int, default=None)
    sw.add_argument("--address", default=None,
                    help="Ray cluster address host:port (backend ray); unreachable within "
                    "10 s: exit code 5")
    sw.add_argument("--json", help="write the results here")
    sw.add_argument("--plot", help="write RMSE versus the first --grid parameter (PNG) here")

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
    rep.add_argument("--out-dir", default="runs/reproductions",
                     help="with 'all': where the JSON/PNG/RRD files go")
    rep.add_argument("--doc", default="docs/reproductions.md",
                     help="with 'all': the Markdown table to regenerate")
    _add_score_parser(sub)
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
    sc.add_argument("--no-worst-case", action="store_true", help="skip the worst-case search")
    sc.add_argument("--backend", default="local", choices=("local", "ray"))
    sc.add_argument("--workers", type=_positive_int, default=None,
                    help="processes (entries in parallel)")
    sc.add_argument("--json", help="write the results here")
    sc.add_argument("--markdown", help="write the leaderboard as Markdown here")
    sc.add_argument("--plot", help="write a PNG here")
    sc.add_argument("--rrd", help="write the comparison Rerun recording here")


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The checked :class:`Scenario` of ``run``/``mc``/``sweep`` arguments.

    Raises
    ------
    ValueError
        A bad value or an option the rig does not have, the message starting with the flag.
    """
    try:
        rig = resolve_rig(args.rig)
    except ValueError as exc:
        raise ValueError(f"rig: {exc}") from None
    if args.duration > MAX_DURATION_S and not args.allow_long:
        raise ValueError(f"--duration {args.duration:g} s is above the limit of "
                         f"{MAX_DURATION_S:g} s; add --allow-long to run it anyway")
    sensor_options: dict[str, Any] = {}
    if args.encoder_noise is not None:
        if rig.name != "helicopter":
            raise ValueError(f"--encoder-noise does not apply to rig {rig.name!r} (it has no "
                             "encoders)")
        sensor_options["noise_std_rad"] = args.encoder_noise
    design_options: dict[str, Any] = dict(args.design_option)
    if args.a_y_source is not None:
        if "a_y_source" not in rig.scenario_options:
            raise ValueError(f"--a-y-source does not apply to rig {rig.name!r} (its input is "
                             "not a lateral acceleration)")
        design_options["a_y_source"] = args.a_y_source
    scenario = Scenario(rig=args.rig, profile=args.profile, estimator=args.filter,
                        estimator_options=dict(args.filter_option), controller=args.controller,
                        sensors=args.sensors, sensor_options=sensor_options,
                        disturbance=args.disturbance, process_noise=args.process_noise or 0.0,
                        ambient_noise=args.ambient_noise,
                        reset_noise_scale=args.reset_noise_scale,
                        manoeuvre=args.manoeuvre, manoeuvre_params=dict(args.manoeuvre_param),
                        params=dict(args.param), design_options=design_options,
                        duration_s=args.duration, seed=args.seed)
    try:
        scenario.check()
    except ScenarioError as exc:
        raise ValueError(f"{FLAGS.get(exc.field, exc.field)}: {exc}") from None
    return scenario


#: Output flags and the suffix of the file each writes.
OUTPUTS = {"json": ".json", "plot": ".png", "rrd": ".rrd", "save_npz": ".npz"}


def check_outputs(args: argparse.Namespace) -> None:
    """Check every output path of the command before anything runs (``ValueError``)."""
    for attr, suffix in OUTPUTS.items():
        path = getattr(args, attr, None)
        if path is not None:
            check_output_path(path, "--" + attr.replace("_", "-"), suffix)
    if args.command == "reproduce" and args.name == "all":
        check_output_path(args.out_dir, "--out-dir", None)
        check_output_path(args.doc, "--doc", ".md")


def _format_table(summary: dict, units: dict[str, str]) -> str:
    lines = [f"{'state':<14}{'estimate RMSE':>18}{'measurement RMSE':>22}"]
    for name, value in summary["rmse"].items():
        scale, unit = display(units.get(name, ""))
        meas = summary["measurement_rmse"].get(name)
        meas_txt = f"{meas * scale:.4f} {unit}" if meas is not None else "-"
        lines.append(f"{name:<14}{value * scale:>11.4f} {unit:<6}{meas_txt:>22}")
    if summary.get("nees_mean") is not None:
        lines.append(f"mean NEES {summary['nees_mean']:.3f} (consistent filter: "
                     f"{len(summary['rmse'])})")
    if summary.get("T_final") is not None:
        lines.append(f"noise-output ratio T = {summary['T_final']:.4f}")
    return "\n".join(lines)


def cmd_run(args: argparse.Namespace) -> int:
    """``testbed run``: one closed-loop episode, summary table and output files."""
    from testbed.experiment import runner

    scenario = scenario_from_args(args)
    if args.realtime:
        return _cmd_run_realtime(args, scenario)
    if args.video:
        from testbed.outputs.render import check_video_path

        check_video_path(args.video)
    live = _open_live(args, scenario)
    start = time.perf_counter()
    try:
        traj, summary = runner.run(scenario, record=bool(args.plot or args.rrd or args.video),
                                   progress=False if args.no_progress else None,
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
              "config": meta}
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
        result = {"rig": meta["rig"], "seed": scenario.seed, **summary, "config": meta}
        print(f"wrote {write_json(args.json, result)}")
    return 0


def _open_live(args: argparse.Namespace, scenario: Scenario) -> Any:
    """The live view asked for by --spawn / --connect / --serve, or None."""
    if not (args.spawn or args.connect or args.serve):
        return None
    from testbed.outputs.live import LiveView, open_recording

    rec, url = open_recording(f"testbed/{resolve_rig(scenario.rig).name}", spawn=args.spawn,
                              connect=args.connect, serve=args.serve,
                              grpc_port=args.grpc_port, web_port=args.web_port)
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
    print(f"{'state':<14}{'RMSE mean':>14}{'5 %':>12}{'95 %':>12}")
    for name, stats in result["rmse"].items():
        scale, unit = display(result["units"].get(name, ""))
        print(f"{name:<14}{stats['mean'] * scale:>14.4f}{stats['q05'] * scale:>12.4f}"
              f"{stats['q95'] * scale:>12.4f}  {unit}")
    if result.get("nees_mean") is not None:
        print(f"mean NEES {result['nees_mean']:.3f}")
    if result.get("T_final"):
        print(f"T_final mean {result['T_final']['mean']:.4f}")


def cmd_mc(args: argparse.Namespace) -> int:
    """``testbed mc``: a batched Monte-Carlo study."""
    from testbed.experiment.runner import monte_carlo

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
    result = monte_carlo(scenario_from_args(args), args.runs, batch_size=args.batch_size,
                         progress=not args.no_progress, save_npz=args.save_npz,
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

    scenario = scenario_from_args(args)
    grid = check_grid(scenario, args.grid)
    if args.address is not None:
        if args.backend != "ray":
            raise ValueError("--address is only used with --backend ray")
        try:
            check_ray_address(args.address)
        except ValueError as exc:
            raise ValueError(f"--address: {exc}") from None
    result = sweep(scenario, grid, runs=args.runs, backend=args.backend,
                   workers=args.workers, address=args.address, progress=not args.no_progress)
    names = list(grid)
    print(f"{len(result['points'])} points on {result['backend']} ({result['workers']} workers) "
          f"in {result['wall_s']:.2f} s")
    first = result["points"][0]["result"]
    states = list(first["rmse"])[:2]
    header = "".join(f"{s + ' RMSE ' + display(first['units'].get(s, ''))[1]:>22}"
                     for s in states)
    print("  ".join(f"{n:>16}" for n in names) + header)
    for entry in result["points"]:
        rmse, units = entry["result"]["rmse"], entry["result"]["units"]
        print("  ".join(f"{entry['point'][n]:>16g}" for n in names)
              + "".join(f"{rmse[s]['mean'] * display(units.get(s, ''))[0]:>22.4f}"
                        for s in states))
    if args.json:
        print(f"wrote {write_json(args.json, result)}")
    if args.plot:
        from testbed.outputs.study_plots import plot_sweep

        print(f"wrote {plot_sweep(result, args.plot, x=names[0])}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """``testbed reproduce``: one paper example (or all, regenerating the docs table)."""
    from testbed import reproductions

    if args.horizon is not None and args.horizon > MAX_DURATION_S and not args.allow_long:
        raise ValueError(f"--horizon {args.horizon:g} s is above the limit of "
                         f"{MAX_DURATION_S:g} s; add --allow-long to run it anyway")
    if args.name == "all":
        results = reproductions.reproduce_all(args.out_dir, args.doc)
        for name, result in results.items():
            print(f"{name}: {reproductions.load(name).row(result)['ours']}")
        print(f"wrote {args.doc} and {args.out_dir}/")
        return 0
    module = reproductions.load(args.name)
    result = module.reproduce(horizon_s=args.horizon, seed=args.seed, json_path=args.json,
                              plot_path=args.plot, rrd_path=args.rrd)
    row = module.row(result)
    print(f"{args.name}\n  paper: {row['claim']}\n  ours:  {row['ours']}\n"
          f"  agree: {row['agree']}")
    if result.get("claims"):
        from testbed.reproductions.outputs import format_claims

        print("  claims (paper | ours):\n" + format_claims(result["claims"]))
    for path in (args.json, args.plot, args.rrd):
        if path:
            print(f"wrote {path}")
    return 0


def cmd_score(args: argparse.Namespace) -> int:
    """``testbed score``: estimators on a scenario suite, leaderboard and output files."""
    from testbed.score import harness, report
    from testbed.score.suite import describe_suite

    if args.list:
        for entry in describe_suite(args.suite):
            status = f"skipped: {entry['skipped']}" if entry["skipped"] else \
                f"{entry['runs']} runs"
            search = "worst case" if entry["worst_case"] else ""
            print(f"{entry['name']:<28}{status:<44}{search:<12}{entry['description']}")
        return 0
    if not args.estimator:
        raise ValueError("give --estimator NAME (repeatable), or --list")
    for flag in ("json", "markdown", "plot", "rrd"):
        path = getattr(args, flag)
        if path is not None and not str(path).strip():
            raise ValueError(f"--{flag} needs a file path")
    run = harness.score(args.estimator, args.suite, seed=args.seed, runs=args.runs,
                        scenarios=args.scenario, backend=args.backend, workers=args.workers,
                        worst_case=not args.no_worst_case,
                        progress=lambda name: print(f"  scored {name}", file=sys.stderr))
    summary = report.results(run)
    remarks = report.notes(run)
    print(report.leaderboard(summary))
    for remark in remarks:
        print(f"note: {remark}")
    if args.json:
        print(f"wrote {report.write_results(args.json, summary)}")
        npz = report.write_worst_cases(str(args.json).removesuffix(".json")
                                       + ".worst_case.npz", run)
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
    """Within the block, SIGTERM raises :class:`_Terminated` (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: Any) -> None:
        raise _Terminated

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


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


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``testbed`` command (exit codes in the module docstring)."""
    args = build_parser().parse_args(argv)
    commands = {"run": cmd_run, "mc": cmd_mc, "sweep": cmd_sweep, "reproduce": cmd_reproduce,
                "score": cmd_score}
    with _sigterm_raises(), _mujoco_warnings_logged():
        try:
            check_outputs(args)
            return commands[args.command](args)
        except ScenarioError as exc:
            return _fail(EXIT_USAGE, f"testbed: error: {FLAGS.get(exc.field, exc.field)}: {exc}")
        except ValueError as exc:
            return _fail(EXIT_USAGE, f"testbed: error: {exc}")
        except (FilterError, FloatingPointError) as exc:  # typed, or a user's filter's NaN
            return _fail(EXIT_FILTER, f"testbed: numerical failure of the filter: {exc}")
        except SimulationDiverged as exc:
            return _fail(EXIT_DIVERGED, f"testbed: {exc}")
        except OSError as exc:
            return _fail(EXIT_OUTPUT, f"testbed: {exc}")
        except KeyboardInterrupt:
            return _fail(EXIT_SIGINT, "testbed: interrupted (SIGINT); partial outputs removed")
        except _Terminated:
            return _fail(EXIT_SIGTERM, "testbed: terminated (SIGTERM); partial outputs removed")


if __name__ == "__main__":
    sys.exit(main())
