"""The ``testbed`` command line.

``testbed run helicopter --filter kalman --controller lqr --duration 20 --seed 0 \\
--rrd runs/demo.rrd --json runs/demo.json --plot runs/demo.png``

``testbed run vehicle-roll --filter kalman --manoeuvre double-lane-change --sensors imu \\
--duration 10 --seed 0 --json PATH --rrd PATH --plot PATH``
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

import numpy as np

from filters import FilterError
from testbed.experiment import CONTROLLERS, DISTURBANCES, FILTERS, build_helicopter, run_episode
from testbed.io import write_json
from testbed.manoeuvres import MANOEUVRES
from testbed.sensors import SENSOR_SUITES
from testbed.vehicle_experiment import FILTERS as VEHICLE_FILTERS
from testbed.vehicle_sensors import VEHICLE_SENSOR_SUITES

RIGS = ("helicopter", "vehicle-roll")


def _name_value(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: value must be a number, got "
                                         f"{value!r}") from None


def _positive(text: str) -> float:
    value = float(text)
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used by the docs and tests)."""
    parser = argparse.ArgumentParser(prog="testbed", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="fly a rig with an estimator in the loop")
    run.add_argument("rig", choices=RIGS)
    run.add_argument("--filter", default="kalman", choices=sorted(set(FILTERS) | set(
        VEHICLE_FILTERS)), help=f"helicopter: {', '.join(FILTERS)}; vehicle-roll: "
        f"{', '.join(VEHICLE_FILTERS)}")
    run.add_argument("--controller", default="lqr", choices=CONTROLLERS)
    run.add_argument("--duration", type=_positive, default=20.0, help="simulated seconds")
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--sensors", default=None,
                     choices=sorted(set(SENSOR_SUITES) | set(VEHICLE_SENSOR_SUITES)),
                     help=f"helicopter: {', '.join(SENSOR_SUITES)} (default encoders); "
                     f"vehicle-roll: {', '.join(VEHICLE_SENSOR_SUITES)} (default imu)")
    run.add_argument("--manoeuvre", default="double-lane-change", choices=sorted(MANOEUVRES),
                     help="vehicle-roll: lateral-acceleration profile driving a_y")
    run.add_argument("--manoeuvre-param", type=_name_value, action="append", default=[],
                     metavar="NAME=VALUE", help="vehicle-roll: manoeuvre parameter, repeatable")
    run.add_argument("--encoder-noise", type=float, default=0.0,
                     help="extra Gaussian noise std on the encoder angles, rad")
    run.add_argument("--disturbance", default=None, choices=DISTURBANCES,
                     help="helicopter: deterministic disturbance (default: seed000 for "
                     "ms-hinf, none otherwise)")
    run.add_argument("--process-noise", type=float, default=0.0,
                     help="scale of seed-000's white-noise matrix b applied to the rig")
    run.add_argument("--process-noise-floor", type=float, default=0.05,
                     help="filter's extra process-noise intensity on each acceleration row "
                     "(rad^2/s^3) for unmodelled dynamics")
    run.add_argument("--param", type=_name_value, action="append", default=[],
                     metavar="NAME=SCALE", help="scale a physical parameter of the simulated "
                     "rig (model mismatch), e.g. --param mass_kg=1.1; repeatable")
    run.add_argument("--rrd", help="write a Rerun recording here")
    run.add_argument("--json", help="write the summary JSON here")
    run.add_argument("--plot", help="write a PNG plot here")
    run.add_argument("--no-progress", action="store_true", help="never show a progress bar")

    def add_helicopter_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("rig", choices=("helicopter",))
        p.add_argument("--filter", default="kalman", choices=FILTERS)
        p.add_argument("--controller", default="lqr", choices=CONTROLLERS)
        p.add_argument("--runs", type=int, default=1000)
        p.add_argument("--duration", type=_positive, default=80.0, help="simulated s per run")
        p.add_argument("--seed", type=int, default=0)
        p.add_argument("--sensors", default="encoders", choices=SENSOR_SUITES)
        p.add_argument("--disturbance", default=None, choices=DISTURBANCES,
                       help="default: seed000 for ms-hinf, none otherwise")
        p.add_argument("--process-noise", type=float, default=0.0)
        p.add_argument("--param", type=_name_value, action="append", default=[],
                       metavar="NAME=SCALE")
        p.add_argument("--json", help="write the results here")
        p.add_argument("--no-progress", action="store_true")

    mc = sub.add_parser("mc", help="Monte-Carlo study: many closed-loop runs, batched")
    add_helicopter_options(mc)
    mc.add_argument("--batch-size", type=int, default=None)
    mc.add_argument("--save-npz", help="also write every trajectory to this .npz")

    sw = sub.add_parser("sweep", help="one Monte-Carlo study per point of a parameter grid")
    add_helicopter_options(sw)
    sw.add_argument("--grid", action="append", default=[], metavar="NAME=V1,V2,...",
                    required=True, help="a swept build argument (process_noise_scale, gamma, "
                    "params.mass_kg, ...) and its values; repeatable (Cartesian product)")
    sw.add_argument("--backend", default="local", choices=("local", "ray"))
    sw.add_argument("--workers", type=int, default=None)
    sw.add_argument("--address", default=None, help="Ray cluster address (backend ray)")

    from testbed.reproductions import REPRODUCTIONS

    rep = sub.add_parser("reproduce", help="run a paper example and compare with its numbers")
    rep.add_argument("name", choices=[*sorted(REPRODUCTIONS), "all"])
    rep.add_argument("--horizon", type=_positive, default=None,
                     help="simulated seconds (default: the paper's horizon)")
    rep.add_argument("--seed", type=int, default=0)
    rep.add_argument("--json")
    rep.add_argument("--plot")
    rep.add_argument("--rrd")
    rep.add_argument("--out-dir", default="runs/reproductions",
                     help="with 'all': where the JSON/PNG/RRD files go")
    rep.add_argument("--doc", default="docs/reproductions.md",
                     help="with 'all': the Markdown table to regenerate")
    return parser


def _grid_axis(text: str) -> tuple[str, list[float]]:
    name, sep, values = text.partition("=")
    if not sep or not values:
        raise ValueError(f"--grid expects NAME=V1,V2,..., got {text!r}")
    try:
        return name.strip(), [float(v) for v in values.split(",")]
    except ValueError:
        raise ValueError(f"--grid {name}: values must be numbers, got {values!r}") from None


def _mc_build_kwargs(args: argparse.Namespace) -> dict:
    return {"controller": args.controller, "sensors": args.sensors,
            "disturbance": args.disturbance or ("seed000" if args.filter == "ms-hinf"
                                                else "none"),
            "process_noise_scale": args.process_noise, "params": dict(args.param) or None}


def _print_mc(result: dict) -> None:
    print(f"{result['runs']} runs x {result['steps_per_run']} steps in {result['wall_s']:.2f} s "
          f"({result['traj_steps_per_s']:,.0f} trajectory-steps/s)")
    print(f"{'state':<12}{'RMSE mean':>14}{'5 %':>12}{'95 %':>12}")
    for name, stats in result["rmse"].items():
        scale = 180 / np.pi
        print(f"{name:<12}{stats['mean'] * scale:>14.4f}{stats['q05'] * scale:>12.4f}"
              f"{stats['q95'] * scale:>12.4f}  {'deg/s' if 'rate' in name else 'deg'}")
    if result.get("nees_mean") is not None:
        print(f"mean NEES {result['nees_mean']:.3f}")
    if result.get("T_final"):
        print(f"T_final mean {result['T_final']['mean']:.4f}")


def cmd_mc(args: argparse.Namespace) -> int:
    """``testbed mc``: a batched Monte-Carlo study."""
    from testbed.batch import monte_carlo

    result = monte_carlo(args.filter, runs=args.runs, duration_s=args.duration, seed=args.seed,
                         batch_size=args.batch_size, progress=not args.no_progress,
                         save_npz=args.save_npz, **_mc_build_kwargs(args))
    _print_mc(result)
    if args.json:
        print(f"wrote {write_json(args.json, result)}")
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    """``testbed sweep``: one Monte-Carlo study per grid point."""
    from testbed.sweep import sweep

    grid = dict(_grid_axis(text) for text in args.grid)
    result = sweep(grid, filter_name=args.filter, runs=args.runs, duration_s=args.duration,
                   seed=args.seed, backend=args.backend, workers=args.workers,
                   address=args.address, progress=not args.no_progress,
                   **_mc_build_kwargs(args))
    names = list(grid)
    print(f"{len(result['points'])} points on {result['backend']} ({result['workers']} workers) "
          f"in {result['wall_s']:.2f} s")
    print("  ".join(f"{n:>16}" for n in names) + f"{'pitch RMSE deg':>16}{'yaw RMSE deg':>14}")
    for entry in result["points"]:
        rmse = entry["result"]["rmse"]
        print("  ".join(f"{entry['point'][n]:>16g}" for n in names)
              + f"{np.degrees(rmse['pitch']['mean']):>16.4f}"
              f"{np.degrees(rmse['yaw']['mean']):>14.4f}")
    if args.json:
        print(f"wrote {write_json(args.json, result)}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    """``testbed reproduce``: one paper example (or all, regenerating the docs table)."""
    from testbed import reproductions

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
    for path in (args.json, args.plot, args.rrd):
        if path:
            print(f"wrote {path}")
    return 0


def _format_table(summary: dict) -> str:
    names = list(summary["rmse"])
    lines = [f"{'state':<12}{'estimate RMSE':>16}{'measurement RMSE':>20}"]
    for name in names:
        unit, scale = ("deg/s", 180 / np.pi) if "rate" in name else ("deg", 180 / np.pi)
        meas = summary["measurement_rmse"].get(name)
        meas_txt = f"{meas * scale:.4f} {unit}" if meas is not None else "-"
        lines.append(f"{name:<12}{summary['rmse'][name] * scale:>11.4f} {unit:<5}"
                     f"{meas_txt:>19}")
    if summary.get("nees_mean") is not None:
        lines.append(f"mean NEES {summary['nees_mean']:.3f} (consistent filter: "
                     f"{len(names)})")
    if summary.get("T_final") is not None:
        lines.append(f"noise-output ratio T = {summary['T_final']:.4f}")
    return "\n".join(lines)


def _build(args: argparse.Namespace):
    if args.rig == "vehicle-roll":
        from testbed.vehicle_experiment import build_vehicle_roll

        sensors = args.sensors or "imu"
        if sensors not in VEHICLE_SENSOR_SUITES:
            raise ValueError(f"--sensors {sensors!r} is not a vehicle-roll suite; expected one "
                             f"of {VEHICLE_SENSOR_SUITES}")
        return build_vehicle_roll(args.filter, manoeuvre=args.manoeuvre,
                                  manoeuvre_params=dict(args.manoeuvre_param) or None,
                                  sensors=sensors, params=dict(args.param) or None)
    sensors = args.sensors or "encoders"
    if sensors not in SENSOR_SUITES:
        raise ValueError(f"--sensors {sensors!r} is not a helicopter suite; expected one of "
                         f"{SENSOR_SUITES}")
    sensor_kwargs = {"noise_std_rad": args.encoder_noise} if sensors.startswith(
        "encoders") else None
    disturbance = args.disturbance or ("seed000" if args.filter == "ms-hinf" else "none")
    return build_helicopter(args.filter, args.controller, sensors=sensors,
                            sensor_kwargs=sensor_kwargs, disturbance=disturbance,
                            process_noise_scale=args.process_noise,
                            process_noise_floor=args.process_noise_floor,
                            params=dict(args.param) or None)


def cmd_run(args: argparse.Namespace) -> int:
    """``testbed run``: one closed-loop episode, summary table and output files."""
    experiment = _build(args)
    start = time.perf_counter()
    traj, summary = run_episode(experiment, args.duration, seed=args.seed,
                                progress=False if args.no_progress else None)
    wall_s = time.perf_counter() - start
    result = {
        "rig": args.rig,
        "filter": args.filter,
        "controller": experiment.meta.get("controller", args.controller),
        "seed": args.seed,
        "duration_s": float(args.duration),
        "steps": summary["steps"],
        "rmse": summary["rmse"],
        "measurement_rmse": summary["measurement_rmse"],
        "nees_mean": summary["nees_mean"],
        "T_final": summary["T_final"],
        "clipped_fraction": summary["clipped_fraction"],
        "wall_s": wall_s,
        "config": experiment.meta,
    }
    print(f"{args.rig} | filter {args.filter} | controller {result['controller']} | "
          f"{summary['steps']} steps in {wall_s:.2f} s wall")
    print(_format_table(summary))
    if args.json:
        print(f"wrote {write_json(args.json, result)}")
    if args.plot:
        from testbed.plots import plot_trajectory

        title = (f"{args.rig}: {args.filter} filter, {result['controller']} controller, "
                 f"seed {args.seed}")
        print(f"wrote {plot_trajectory(traj, args.plot, title=title)}")
    if args.rrd:
        from testbed.viz import write_rrd

        path = write_rrd(traj, args.rrd, model=experiment.env.unwrapped.rig.model,
                         application_id=f"testbed/{args.rig}")
        print(f"wrote {path}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``testbed`` command."""
    args = build_parser().parse_args(argv)
    try:
        if args.command == "run":
            return cmd_run(args)
        if args.command == "reproduce":
            return cmd_reproduce(args)
        if args.command == "mc":
            return cmd_mc(args)
        if args.command == "sweep":
            return cmd_sweep(args)
    except ValueError as exc:
        print(f"testbed: error: {exc}", file=sys.stderr)
        return 2
    except FilterError as exc:
        print(f"testbed: numerical failure of the filter: {exc}", file=sys.stderr)
        return 3
    return 1


if __name__ == "__main__":
    sys.exit(main())
