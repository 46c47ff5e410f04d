"""``testbed mc``: a batched Monte-Carlo study."""

from __future__ import annotations

import argparse

from testbed.cli import deferred, values
from testbed.cli.outputs import units_note, wrote
from testbed.cli.scenario_options import (
    add_scenario_options,
    save_scenario,
    scenario_and_file,
    show_progress,
    study_value,
)
from testbed.io import write_json
from testbed.outputs.units import display


def add_arguments(mc: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``mc``."""
    add_scenario_options(mc, 10.0)
    mc.add_argument("--runs", type=values.positive_int, default=100)
    mc.add_argument("--batch-size", type=values.positive_int, default=None)
    mc.add_argument("--json", help="write the results here")
    mc.add_argument("--save-npz", help="also write every trajectory to this .npz")
    mc.add_argument("--plot", help="write the RMSE distribution and error envelope (PNG) here")
    mc.add_argument("--backend", default=None, choices=("local", "ray"),
                    help="shard the runs over local processes or Ray tasks (each run keeps "
                    "its seed: the same results as in one process); default: one process")
    mc.add_argument("--workers", type=values.positive_int, default=None,
                    help="shards / worker processes (alone: --backend local; default with a "
                         "backend: the CPUs)")
    mc.add_argument("--address", default=None,
                    help="Ray cluster address host:port (alone: --backend ray; default: a local "
                    "Ray instance)")
    deferred.defer_defaults(mc)


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
    note = units_note({k: result["units"].get(k, "") for k in result["rmse"]})
    if note:
        print(note)


def command(args: argparse.Namespace) -> int:
    """``testbed mc``: a batched Monte-Carlo study."""
    from testbed.experiment.runner import monte_carlo

    scenario, source = scenario_and_file(args)
    runs = study_value(args, source, "runs")
    if args.save_scenario:
        return save_scenario(args, scenario, runs=runs)
    backend = args.backend  # alone, a cluster address means Ray, worker processes local ones
    if backend is None and (args.address is not None or args.workers is not None):
        backend = "ray" if args.address is not None else "local"
    if backend is not None and (args.save_npz or args.plot):
        raise ValueError("--backend/--workers shard the runs: without --save-npz and --plot")
    if args.address is not None:
        from testbed.experiment.backend import check_ray_address

        if backend != "ray":
            raise ValueError("--address is only used with --backend ray")
        try:
            check_ray_address(args.address)  # unreachable: ConnectionError, exit code 5
        except ValueError as exc:
            raise ValueError(f"--address: {exc}") from None
    result = monte_carlo(scenario, runs, batch_size=args.batch_size,
                         progress=show_progress(args), save_npz=args.save_npz,
                         envelope_points=200 if args.plot else None, backend=backend,
                         workers=args.workers, address=args.address)
    _print_mc(result)
    if args.save_npz:
        wrote(args.save_npz)
    if args.json:
        wrote(write_json(args.json, result))
    if args.plot:
        from testbed.outputs.study_plots import plot_monte_carlo

        wrote(plot_monte_carlo(result, args.plot))
    return 0
