"""The one parallel backend: independent jobs on local processes or on Ray.

``testbed sweep`` (one Monte-Carlo study per grid point) and ``testbed score`` (one suite
entry per job) hand their jobs to :func:`map_jobs`; results come back in job order and do
not depend on the backend or the number of workers (the jobs carry their own seeds).
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any

#: Parallel back-ends of :func:`map_jobs`.
BACKENDS = ("local", "ray")
#: Seconds to wait for a Ray cluster address to accept a connection.
RAY_CONNECT_TIMEOUT_S = 10.0


def check_backend(backend: str, workers: int | None, address: str | None) -> int:
    """Validate the backend options before any work; returns the number of workers
    (default ``os.cpu_count()``).

    Raises
    ------
    ValueError
        An unknown backend, ``address`` without Ray, or ``workers`` not a positive integer.
    ConnectionError
        Nothing accepts a connection at ``address`` (:func:`check_ray_address`).
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; expected one of {BACKENDS}")
    if address is not None and backend != "ray":
        raise ValueError("address is only used with backend='ray'")
    if workers is not None and (isinstance(workers, bool) or int(workers) != workers
                                or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers}")
    if address is not None:
        check_ray_address(address)
    return int(workers or os.cpu_count() or 1)


def check_ray_address(address: str, timeout_s: float = RAY_CONNECT_TIMEOUT_S) -> None:
    """Check that a Ray cluster address accepts connections, within ``timeout_s`` seconds.

    ``ray.init(address=...)`` retries an unreachable cluster for minutes; this TCP probe
    fails fast instead. ``"auto"`` (the local cluster Ray finds itself) is not probed.

    Parameters
    ----------
    address : str
        ``host:port`` (the GCS port, 6379 by default), ``ray://host:port`` or ``"auto"``.
    timeout_s : float

    Raises
    ------
    ValueError
        ``address`` is not of one of these forms.
    ConnectionError
        Nothing accepts a connection at ``host:port`` within ``timeout_s`` seconds.
    """
    if address == "auto":
        return
    target = address.split("://", 1)[1] if address.startswith("ray://") else address
    host, sep, port = target.rpartition(":")
    if not (sep and host and port.isascii() and port.isdigit() and 0 < int(port) < 65536):
        raise ValueError(f"address must be 'host:port', 'ray://host:port' or 'auto', got "
                         f"{address!r}")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise ConnectionError(f"no Ray cluster reachable at {address!r} within {timeout_s:g} s "
                              f"({exc.strerror or exc}); start one with 'ray start --head' or "
                              "leave the address unset for a local instance") from None


def map_jobs(fn: Callable[..., Any], jobs: Sequence[tuple], *, backend: str = "local",
             workers: int = 1, address: str | None = None,
             on_done: Callable[[int], None] | None = None,
             costs: Sequence[float] | None = None) -> list[Any]:
    """``[fn(*job) for job in jobs]`` on ``workers`` local processes or Ray tasks.

    Parameters
    ----------
    fn : callable
        A module-level function (picklable).
    jobs : sequence of tuple
        The arguments of each call.
    backend : {"local", "ray"}
        ``"local"`` with one worker runs in this process; with more, in spawned processes.
        ``"ray"`` runs one task per job (one CPU each) on the cluster at ``address`` or on a
        local instance of ``workers`` CPUs.
    workers : int
    address : str, optional
        Ray cluster address (checked by :func:`check_backend` beforehand).
    on_done : callable, optional
        Called with the job index as each result arrives, in job order (progress bars).
    costs : sequence of float, optional
        An estimate of each job's run time (any unit). Jobs then start most costly first
        (longest-processing-time-first list scheduling: each free worker takes the next
        one), so that a long job does not start last and keep one worker busy while the
        others idle. Results are in job order whatever the order of execution.

    Returns
    -------
    list
        The results, in job order.
    """
    def done(i: int) -> None:
        if on_done is not None:
            on_done(i)

    if costs is not None and len(costs) != len(jobs):
        raise ValueError(f"got {len(costs)} costs for {len(jobs)} jobs")
    # execution order: most costly first (stable: job order among equal costs)
    order = (list(range(len(jobs))) if costs is None
             else sorted(range(len(jobs)), key=lambda i: -float(costs[i])))
    out: list[Any] = []
    if backend == "local" and (workers == 1 or len(jobs) <= 1):
        for i, job in enumerate(jobs):
            out.append(fn(*job))
            done(i)
        return out
    if backend == "local":
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs)),
                                 mp_context=get_context("spawn")) as pool:
            submitted = {i: pool.submit(fn, *jobs[i]) for i in order}
            futures = [submitted[i] for i in range(len(jobs))]
            for i, future in enumerate(futures):
                out.append(future.result())
                done(i)
        return out
    try:
        import ray
    except ImportError as exc:
        raise ValueError("backend 'ray' needs Ray: pip install -e '.[ray]'") from exc
    started_here = not ray.is_initialized()
    if started_here:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1)(fn)
        launched = {i: task.remote(*jobs[i]) for i in order}
        refs = [launched[i] for i in range(len(jobs))]
        for i, ref in enumerate(refs):
            out.append(ray.get(ref))
            done(i)
        return out
    finally:
        if started_here:
            ray.shutdown()
