"""``testbed sweep``: one Monte-Carlo study per point of a parameter grid."""

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
from testbed.experiment.scenario import Scenario, ScenarioError
from testbed.io import write_json
from testbed.outputs.units import display


def add_arguments(sw: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``sw``."""
    add_scenario_options(sw, 10.0)
    sw.add_argument("--runs", type=values.positive_int, default=100)
    sw.add_argument("--grid", type=values.grid_axis, action="append", default=[],
                    metavar="NAME=V1,V2,...",
                    help="a swept scenario field (process_noise, ...), params.<field>, "
                    "estimator.<option> or design.<option>; repeatable (or the --scenario "
                    "file's [study] grid)")
    sw.add_argument("--backend", default="local", choices=("local", "ray"))
    sw.add_argument("--workers", type=values.positive_int, default=None)
    sw.add_argument("--address", default=None,
                    help="Ray cluster address host:port (backend ray); unreachable within "
                    "10 s: exit code 5")
    sw.add_argument("--json", help="write the results here")
    sw.add_argument("--plot", help="write RMSE versus the first --grid parameter (PNG) here")
    deferred.defer_defaults(sw)


def check_grid(scenario: Scenario, axes: list[tuple[str, list[float]]]) -> dict[str, list]:
    """The grid of ``--grid`` axes, every point's scenario checked (``ValueError`` naming
    ``--grid``)."""
    from testbed.experiment.runner import check_grid_name, grid_points, point_scenario

    grid: dict[str, list] = {}
    for name, axis in axes:
        if name in grid:
            raise ValueError(f"--grid {name} is given twice")
        try:
            check_grid_name(scenario, name)
        except ValueError as exc:
            raise ValueError(f"--grid: {exc}") from None
        grid[name] = axis
    for point in grid_points(grid):
        try:
            point_scenario(scenario, point).check()
        except ScenarioError as exc:
            where = ", ".join(f"{k}={v:g}" for k, v in point.items())
            raise ValueError(f"--grid {where}: {exc}") from None
    return grid


def command(args: argparse.Namespace) -> int:
    """``testbed sweep``: one Monte-Carlo study per grid point."""
    from testbed.experiment.backend import check_ray_address
    from testbed.experiment.runner import sweep

    scenario, source = scenario_and_file(args)
    axes = study_value(args, source, "grid")
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
    runs = study_value(args, source, "runs")
    from testbed.experiment.runner import check_study_size

    check_study_size(scenario, runs)
    if args.save_scenario:
        return save_scenario(args, scenario, runs=runs, grid=grid)
    if args.address is not None:
        if args.backend != "ray":
            raise ValueError("--address is only used with --backend ray")
        try:
            check_ray_address(args.address)
        except ValueError as exc:
            raise ValueError(f"--address: {exc}") from None
    result = sweep(scenario, grid, runs=runs, backend=args.backend,
                   workers=args.workers, address=args.address, progress=show_progress(args))
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
    note = units_note({s: first["units"].get(s, "") for s in states})
    if note:
        print(note)
    if args.json:
        wrote(write_json(args.json, result))
    if args.plot:
        from testbed.outputs.study_plots import plot_sweep

        wrote(plot_sweep(result, args.plot, x=names[0]))
    return 0
