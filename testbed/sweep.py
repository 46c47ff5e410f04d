"""Parameter sweeps: one Monte-Carlo study (:func:`testbed.batch.monte_carlo`) per grid point.

A grid maps names to lists of values; the points are their Cartesian product. Names are
:func:`testbed.experiment.build_helicopter` arguments (``process_noise_scale``, ``gamma``,
``process_noise_floor``...) or ``params.<field>`` for a scale factor of the simulated rig's
:class:`~testbed.rigs.helicopter.HelicopterParams` (model mismatch).

Every point uses the same base seed (common random numbers: differences between points are
not blurred by different noise). Back-ends:

- ``local`` (default): a pool of local processes (``workers``);
- ``ray``: one Ray task per point, on a cluster (``address``) or a local Ray instance with
  ``workers`` CPUs (``pip install -e .[ray]``).

Both return the same numbers (timings aside): the points are deterministic.
"""

from __future__ import annotations

import itertools
import os
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any

from tqdm import tqdm

BACKENDS = ("local", "ray")
#: Keys of a Monte-Carlo result that measure time, not the estimator.
TIMING_KEYS = ("wall_s", "traj_steps_per_s", "threads")


def grid_points(grid: dict[str, list]) -> list[dict[str, Any]]:
    """The Cartesian product of ``grid`` as a list of ``{name: value}`` points.

    Raises
    ------
    ValueError
        Empty grid or a name with no values.
    """
    if not grid:
        raise ValueError("grid must name at least one parameter")
    for name, values in grid.items():
        if len(values) == 0:
            raise ValueError(f"grid[{name!r}] has no values")
    names = list(grid)
    return [dict(zip(names, combo, strict=True))
            for combo in itertools.product(*(grid[n] for n in names))]


def point_kwargs(point: dict[str, Any], common: dict[str, Any] | None = None) -> dict[str, Any]:
    """``build_helicopter`` keyword arguments of one grid point over the shared ones.

    The point's values override ``common``; ``params.<field>`` entries are merged into
    ``common["params"]``.
    """
    kwargs = dict(common or {})
    params = dict(kwargs.get("params") or {})
    for name, value in point.items():
        if name.startswith("params."):
            params[name.removeprefix("params.")] = value
        else:
            kwargs[name] = value
    kwargs["params"] = params or None
    return kwargs


def _run_point(point: dict[str, Any], study: dict[str, Any],
               common: dict[str, Any]) -> dict[str, Any]:
    from testbed.batch import monte_carlo

    # one physics thread per point: the pool supplies the parallelism
    return monte_carlo(progress=False, num_threads=1, **study, **point_kwargs(point, common))


def sweep(grid: dict[str, list], *, filter_name: str = "kalman", runs: int = 100,
          duration_s: float = 10.0, seed: int = 0, backend: str = "local",
          workers: int | None = None, address: str | None = None, progress: bool = True,
          **common: Any) -> dict[str, Any]:
    """Run one Monte-Carlo study per grid point.

    Parameters
    ----------
    grid : dict of str to list
        Swept names and their values (see the module docstring).
    filter_name, runs, duration_s, seed
        Passed to :func:`testbed.batch.monte_carlo` for every point.
    backend : {"local", "ray"}
    workers : int, optional
        Local processes or local Ray CPUs (default: ``os.cpu_count()``).
    address : str, optional
        Ray cluster address (``backend="ray"``); default a local instance.
    progress : bool
        A progress bar over the points.
    **common
        Further ``build_helicopter`` arguments shared by all points.

    Returns
    -------
    dict
        ``backend``, ``workers``, ``wall_s``, ``points`` (list of ``{"point", "result"}``).
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {BACKENDS}")
    if address is not None and backend != "ray":
        raise ValueError("address is only used with backend='ray'")
    points = grid_points(grid)
    workers = int(workers or os.cpu_count() or 1)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    from testbed.experiment import build_helicopter

    for point in points:  # fail fast on a bad name or value, before any work starts
        build_helicopter(filter_name, **point_kwargs(point, common))
    study = {"filter_name": filter_name, "runs": runs, "duration_s": duration_s, "seed": seed}
    start = time.perf_counter()
    bar = tqdm(total=len(points), desc=f"sweep ({backend})", unit="point", disable=not progress)
    with bar:
        if backend == "local":
            results = _run_local(points, study, common, workers, bar)
        else:
            results = _run_ray(points, study, common, workers, address, bar)
    return {"backend": backend, "workers": workers, "wall_s": time.perf_counter() - start,
            "points": [{"point": p, "result": r} for p, r in zip(points, results, strict=True)]}


def _run_local(points: list[dict], study: dict, common: dict, workers: int,
               bar: tqdm) -> list[dict]:
    if workers == 1:
        out = []
        for point in points:
            out.append(_run_point(point, study, common))
            bar.update()
        return out
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(_run_point, point, study, common) for point in points]
        out = []
        for future in futures:
            out.append(future.result())
            bar.update()
        return out


def _run_ray(points: list[dict], study: dict, common: dict, workers: int,
             address: str | None, bar: tqdm) -> list[dict]:
    try:
        import ray
    except ImportError as exc:
        raise ValueError("backend='ray' needs Ray: pip install -e '.[ray]'") from exc
    started_here = not ray.is_initialized()
    if started_here:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1)(_run_point)
        refs = [task.remote(point, study, common) for point in points]
        out = []
        for ref in refs:
            out.append(ray.get(ref))
            bar.update()
        return out
    finally:
        if started_here:
            ray.shutdown()


def without_timings(result: dict[str, Any]) -> dict[str, Any]:
    """A sweep result with the timing keys removed (for comparing back-ends)."""
    return {
        **{k: v for k, v in result.items() if k not in ("wall_s", "backend", "workers")},
        "points": [{"point": p["point"],
                    "result": {k: v for k, v in p["result"].items() if k not in TIMING_KEYS}}
                   for p in result["points"]],
    }
