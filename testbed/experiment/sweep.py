"""Sweeps (:func:`sweep`): one Monte-Carlo study per point of a parameter grid, on local
processes or Ray (common random numbers: one base seed)."""

from __future__ import annotations

import dataclasses
import itertools
import time
from typing import Any

from tqdm import tqdm

from testbed.experiment.backend import check_backend, map_jobs
from testbed.experiment.build import build, described
from testbed.experiment.scenario import Scenario, with_defaults
from testbed.experiment.study import TIMING_KEYS, monte_carlo
from testbed.records import field_values
from testbed.rigs import resolve_rig


def grid_points(grid: dict[str, list]) -> list[dict[str, Any]]:
    """The Cartesian product of ``grid`` as a list of ``{name: value}`` points."""
    if not grid:
        raise ValueError("grid must name at least one parameter")
    for name, values in grid.items():
        if len(values) == 0:
            raise ValueError(f"grid[{name!r}] has no values")
    names = list(grid)
    return [dict(zip(names, combo, strict=True))
            for combo in itertools.product(*(grid[n] for n in names))]


#: Scenario fields a grid may sweep directly (numbers).
GRID_FIELDS = ("process_noise", "duration_s", "seed", "physics_dt_s", "frame_skip")


_GRID_GROUPS = {"params": "params", "estimator": "estimator_options",
                "design": "design_options", "sensors": "sensor_options"}


def check_grid_name(scenario: Scenario, name: str) -> None:
    """Raise ``ValueError`` listing the valid names unless ``name`` can be swept.

    Valid: :data:`GRID_FIELDS`, ``params.<field>`` (a parameter of the rig, scaled),
    ``design.<option>`` (the rig's design options), ``estimator.<option>`` and
    ``sensors.<option>`` (options of the estimator factory and of the sensor preset, checked
    when the point is built).
    """
    rig = resolve_rig(scenario.rig)
    params = sorted(f.name for f in dataclasses.fields(rig.params_type))
    prefix, dot, key = name.partition(".")
    if (not dot and name in GRID_FIELDS) or (dot and key and (
            (prefix == "params" and key in params)
            or (prefix == "design" and key in rig.scenario_options)
            or prefix in ("estimator", "sensors"))):
        return
    hint = f" (did you mean 'params.{name}'?)" if not dot and name in params else ""
    design = "|".join(sorted(rig.scenario_options)) or "none"
    raise ValueError(f"unknown grid name {name!r}{hint}; valid names: "
                     f"{', '.join(GRID_FIELDS)}, params.<{'|'.join(params)}>, "
                     f"design.<{design}>, estimator.<option>, sensors.<option>")


def point_scenario(scenario: Scenario, point: dict[str, Any]) -> Scenario:
    """The scenario of one grid point.

    Names: see :func:`check_grid_name`.
    """
    changes: dict[str, Any] = {}
    groups = _GRID_GROUPS
    for name, value in point.items():
        check_grid_name(scenario, name)
        if name in ("seed", "frame_skip") and float(value).is_integer():
            value = int(value)
        prefix, dot, key = name.partition(".")
        if dot:
            field_name = groups[prefix]
            merged = dict(changes.get(field_name, field_values(scenario)[field_name]))
            merged[key] = value
            changes[field_name] = merged
        else:
            changes[name] = value
    return scenario.replace(**changes)


def _run_point(scenario: Scenario, runs: int) -> dict[str, Any]:
    # one physics thread per point: the pool supplies the parallelism
    return monte_carlo(scenario, runs, progress=False, num_threads=1)


def sweep(scenario: Scenario, grid: dict[str, list], *, runs: int = 100,
          backend: str = "local", workers: int | None = None, address: str | None = None,
          progress: bool = False) -> dict[str, Any]:
    """One Monte-Carlo study per grid point (common random numbers: one base seed).

    Parameters
    ----------
    scenario : Scenario
    grid : dict of str to list
        Swept names (see :func:`point_scenario`) and their values.
    runs : int
    backend : {"local", "ray"}
        Local processes or Ray tasks (a cluster at ``address`` or a local instance).
    address : str, optional
        Ray cluster (``host:port``, ``ray://host:port`` or ``"auto"``); unreachable within
        :data:`RAY_CONNECT_TIMEOUT_S` seconds: ``ConnectionError`` before any work.
    workers : int, optional
        Processes or local Ray CPUs (default ``os.cpu_count()``).
    progress : bool
        Show a progress bar (on stderr; default off).

    Returns
    -------
    dict
        ``backend``, ``workers``, ``wall_s``, ``scenario`` (the base scenario, as in
        :func:`monte_carlo`), ``grid``, ``runs``, ``units``, ``points`` (list of ``{"point",
        "result"}``).
    """
    workers = check_backend(backend, workers, address)
    points = grid_points(grid)
    scenarios = [point_scenario(scenario, p) for p in points]
    for s in scenarios:  # fail fast on a bad name or value, before any work starts
        build(s, 1, num_threads=1).close()
    start = time.perf_counter()
    bar = tqdm(total=len(points), desc=f"sweep ({backend})", unit="point", disable=not progress)
    with bar:
        results = map_jobs(_run_point, [(s, runs) for s in scenarios], backend=backend,
                           workers=workers, address=address, on_done=lambda _: bar.update())
    return {"backend": backend, "workers": workers, "wall_s": time.perf_counter() - start,
            "scenario": described(with_defaults(scenario)), "grid": dict(grid), "runs": runs,
            "units": results[0]["units"],
            "points": [{"point": p, "result": r} for p, r in zip(points, results, strict=True)]}


def without_timings(result: dict[str, Any]) -> dict[str, Any]:
    """A sweep result with the timing keys removed (for comparing back-ends)."""
    return {
        **{k: v for k, v in result.items() if k not in ("wall_s", "backend", "workers")},
        "points": [{"point": p["point"],
                    "result": {k: v for k, v in p["result"].items() if k not in TIMING_KEYS}}
                   for p in result["points"]],
    }
