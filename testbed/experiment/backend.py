"""The one parallel backend: independent jobs on local processes or on Ray.

``testbed sweep`` (one Monte-Carlo study per grid point) and ``testbed score`` (one suite
entry per job) hand their jobs to :func:`map_jobs`; results come back in job order and do
not depend on the backend or the number of workers (the jobs carry their own seeds).

Nothing outlives the call. An exception or an interrupt in the caller (SIGINT, the CLI's
SIGTERM) cancels the jobs not started and stops the running ones: local workers are
terminated (SIGTERM, then SIGKILL after :data:`STOP_GRACE_S`) and reaped before the
exception goes on; Ray tasks are cancelled (``ray.cancel(force=True)``) and a Ray instance
started here is shut down. Local workers ignore SIGINT (a Ctrl-C in the terminal reaches the
whole process group: the caller stops them) and, on Linux, get SIGKILL when the caller dies
(``PR_SET_PDEATHSIG``, even when the caller is killed by SIGKILL); elsewhere a watchdog
thread ends them within :data:`WATCHDOG_PERIOD_S` of the caller's death.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from typing import Any

#: Parallel back-ends of :func:`map_jobs`.
BACKENDS = ("local", "ray")
#: Seconds to wait for a Ray cluster address to accept a connection.
RAY_CONNECT_TIMEOUT_S = 10.0
#: Seconds of each wait for a Ray task (an interrupt is acted on between two waits).
RAY_POLL_S = 0.2
#: Seconds a terminated local worker has to exit before it is killed (SIGKILL).
STOP_GRACE_S = 1.0
#: Seconds to wait for a killed (SIGKILL) worker to be reaped (on a loaded machine).
KILLED_JOIN_S = 10.0
#: Seconds between two checks of the watchdog that ends a worker whose caller died (where
#: the parent-death signal is not available).
WATCHDOG_PERIOD_S = 0.5
#: The signals that stop a study: held back while the local workers are being started.
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: ``prctl`` option: the signal a process gets when its parent dies (Linux).
_PR_SET_PDEATHSIG = 1


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
        return _local_pool(fn, jobs, order, min(workers, len(jobs)), done)
    try:
        import ray
    except ImportError as exc:
        raise ValueError("backend 'ray' needs Ray: pip install -e '.[ray]'") from exc
    started_here = not ray.is_initialized()
    launched: dict[int, Any] = {}
    try:
        if started_here:
            terminated = False
            with _own_signal_handlers():  # ray.init replaces them (SIGTERM: sys.exit(15))
                try:
                    if address:
                        ray.init(address=address, log_to_driver=False)
                    else:
                        ray.init(num_cpus=workers, include_dashboard=False,
                                 log_to_driver=False)
                except SystemExit as exc:  # a SIGTERM, through Ray's handler
                    if exc.code != signal.SIGTERM:
                        raise
                    terminated = True
            if terminated:  # to the handler in force before (the CLI's: exit 143)
                signal.raise_signal(signal.SIGTERM)
        task = ray.remote(num_cpus=1)(fn)
        for i in order:
            launched[i] = task.remote(*jobs[i])
        index = {ref: i for i, ref in launched.items()}
        pending, in_order = list(launched.values()), _InOrder(len(jobs), done)
        while pending:
            # a signal handler that raises inside ray.get/ray.wait is not seen until the
            # task ends (Ray catches only KeyboardInterrupt there): within each short wait
            # the handlers only remember, and run between two waits
            with _stop_signals_held(block=False):
                ready, pending = ray.wait(pending, num_returns=1, timeout=RAY_POLL_S)
                results = [(index[ref], ray.get(ref)) for ref in ready]  # a failure: now
            for i, result in results:
                in_order.add(i, result)
        return in_order.results()
    except BaseException:  # a failure or an interrupt: no task goes on
        for ref in launched.values():
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        raise
    finally:
        if started_here:
            ray.shutdown()


class _InOrder:
    """Results arriving in any order, handed to ``done`` in job order."""

    def __init__(self, n: int, done: Callable[[int], None]):
        self._results: dict[int, Any] = {}
        self._n, self._next, self._done = n, 0, done

    def add(self, i: int, result: Any) -> None:
        self._results[i] = result
        while self._next in self._results:
            self._done(self._next)
            self._next += 1

    def results(self) -> list[Any]:
        return [self._results[i] for i in range(self._n)]


def _local_pool(fn: Callable[..., Any], jobs: Sequence[tuple], order: list[int],
                workers: int, done: Callable[[int], None]) -> list[Any]:
    """The jobs on ``workers`` spawned processes, started in ``order``; results in job
    order. Any exception (an interrupt included) stops every worker before it goes on."""
    pool: ProcessPoolExecutor | None = None
    children_before = set(multiprocessing.active_children())
    try:
        # no SIGINT/SIGTERM handler runs while the workers start (an interrupt there could
        # leave a started worker unknown to the pool); one that came is raised right after
        with _stop_signals_held():
            pool = ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"),
                                       initializer=_worker_started, initargs=(os.getpid(),))
            submitted = {i: pool.submit(fn, *jobs[i]) for i in order}
        index = {future: i for i, future in submitted.items()}
        in_order = _InOrder(len(jobs), done)
        for future in as_completed(index):  # a failed job is seen when it fails
            in_order.add(index[future], future.result())
        out = in_order.results()
    except BaseException:
        if pool is not None:
            stop_pool(pool, children_before=children_before)
        raise
    pool.shutdown(wait=True)
    return out


def stop_pool(pool: ProcessPoolExecutor, grace_s: float = STOP_GRACE_S, *,
              children_before: set[Any] | None = None) -> None:
    """Cancel the queued jobs of ``pool`` and end its processes now: SIGTERM, then SIGKILL
    for those still alive after ``grace_s`` seconds; every one reaped.

    ``children_before``: this process's children before the pool was made; any child started
    since (a worker the pool was starting as the interrupt came, not yet in its table) is
    ended too."""
    # the pool's own table of its processes (Python 3.8 to 3.14; 3.14 adds
    # terminate_workers() doing the same): the processes must end, not only their queue
    # the table itself, not a copy: the pool's manager thread may still add a process to it
    # (one it was starting when the interrupt came)
    table = getattr(pool, "_processes", None) or {}
    pool.shutdown(wait=False, cancel_futures=True)
    deadline = time.monotonic() + grace_s + KILLED_JOIN_S
    while True:  # until no process of the pool is alive (one may start while we end others)
        late = [] if children_before is None else \
            [c for c in multiprocessing.active_children() if c not in children_before]
        alive = [p for p in {id(p): p for p in [*list(table.values()), *late]}.values()
                 if _is_alive(p)]
        if not alive or time.monotonic() > deadline:
            break
        _end(alive, grace_s)


def _is_alive(process: Any) -> bool:
    try:
        return bool(process.is_alive())
    except (AssertionError, ValueError, AttributeError):  # not started by us, or closed
        return False


def _end(processes: list[Any], grace_s: float) -> None:
    """SIGTERM to ``processes``, SIGKILL to those alive after ``grace_s`` s; all reaped."""
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            process.terminate()
    deadline = time.monotonic() + grace_s
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
            process.join(max(0.0, deadline - time.monotonic()))
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
            if process.is_alive():
                process.kill()
                process.join(KILLED_JOIN_S)  # SIGKILL cannot be refused: only the reaping


@contextlib.contextmanager
def _own_signal_handlers() -> Iterator[None]:
    """The SIGINT and SIGTERM handlers in force before the block are put back after it
    (main thread only): ``ray.init`` installs its own (SIGTERM: ``sys.exit(15)``, and a
    native handler that prints a stack trace), which would turn an interrupt into a
    failure."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in _STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            if handler is not None:
                signal.signal(sig, handler)


@contextlib.contextmanager
def _stop_signals_held(block: bool = True) -> Iterator[None]:
    """Within the block the Python handlers of SIGINT and SIGTERM only remember the signals;
    afterwards each remembered signal is raised again (to the handlers in force before the
    block, which may raise). With ``block`` both are also blocked in this thread, and
    processes started within the block inherit the blocked mask (:func:`_worker_started`
    unblocks it once the worker's own handling is in place). Outside the main thread
    nothing is held."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    arrived: list[int] = []

    def remember(signum: int, frame: Any) -> None:
        arrived.append(signum)

    previous = {}
    for sig in _STOP_SIGNALS:
        handler = signal.getsignal(sig)
        if callable(handler):  # a Python handler (not SIG_IGN / SIG_DFL)
            previous[sig] = signal.signal(sig, remember)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS) if block else None
    try:
        yield
    finally:
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # a pending one: remember()
        for sig, handler in previous.items():
            if signal.getsignal(sig) is remember:
                signal.signal(sig, handler)
        for sig in dict.fromkeys(arrived):
            signal.raise_signal(sig)


def _worker_started(parent_pid: int) -> None:
    """Initializer of a local worker: SIGINT ignored (the caller stops its workers),
    SIGTERM ends it at once (:func:`_worker_terminated`), both unblocked; ended when the
    caller dies (:func:`die_with_parent`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_terminated)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
    die_with_parent(parent_pid)


def _worker_terminated(signum: int, frame: Any) -> None:
    """SIGTERM in a local worker (:func:`stop_pool`): the job is abandoned and the process
    ends now, after multiprocessing's own exit steps (the semaphores this worker made, a
    progress bar's lock for one, are released: the resource tracker has nothing left to
    warn about)."""
    from multiprocessing import util

    with contextlib.suppress(Exception):
        util._exit_function()
    os._exit(128 + signum)


def die_with_parent(parent_pid: int) -> None:
    """End this process (SIGKILL) when the process ``parent_pid``, its parent, dies.

    On Linux the kernel sends the signal (``prctl(PR_SET_PDEATHSIG, SIGKILL)``: also when
    the parent is killed by SIGKILL); elsewhere a daemon thread checks ``os.getppid()``
    every :data:`WATCHDOG_PERIOD_S` seconds. A parent already gone ends this process now.

    Parameters
    ----------
    parent_pid : int
        The process id of the parent that started this one.
    """
    armed = False
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            import ctypes

            armed = ctypes.CDLL(None, use_errno=True).prctl(
                _PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    if os.getppid() != parent_pid:  # died before the signal was armed
        os._exit(1)
    if not armed:
        def watch() -> None:
            while os.getppid() == parent_pid:
                time.sleep(WATCHDOG_PERIOD_S)
            os._exit(1)

        threading.Thread(target=watch, name="testbed-parent-watchdog", daemon=True).start()
