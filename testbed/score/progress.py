"""Where ``testbed score`` is: the expected cost of each (entry, estimator) pair from the
harness's cost model (:func:`testbed.score.cost.entry_cost`) and the channel through which
the harness's jobs report each pair as it ends (:func:`pair_channel`).

A pair's cost is its entry's Monte-Carlo member-steps (every pair of the entry) plus the
worst-case search's (the estimators asked for only, when the search runs), times
:data:`UNBATCHED_FACTOR` for an estimator that runs one instance per run (no
``batched = True``). :data:`SECONDS_PER_UNIT` turns a cost into an expected time on one
unloaded core; the progress bar's ETA uses only the ratios (elapsed time over the cost done).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from multiprocessing import get_context
from typing import Any, Protocol, runtime_checkable

from testbed.estimators import optional
from testbed.plugins import LabelledFactory
from testbed.score.cost import entry_cost
from testbed.score.pair import REFERENCE

#: Cost per member-step of an estimator without ``batched = True`` (one Python instance per
#: run, stepped one by one) relative to a batched one's. Measured on ``testbed score --suite
#: quick`` (calibration, helicopter, vehicle-dlc; one worker, 2026-12-02, two cores under
#: load 7-9), CPU per pair over the built-in kalman's: docs/examples/userkf.py (a numpy
#: steady-state filter) 1.1-1.7, fp_ekf.py (filterpy's EKF) 6.8-7.6, the batched built-in
#: ekf 1.7-3.0 for comparison; the geometric middle of the plug-ins', rounded.
UNBATCHED_FACTOR = 3.0
#: Seconds of one unit of cost (a member-step of a batched estimator's closed loop) on one
#: core: the harness's measurement (:data:`testbed.score.cost.STEP_OVERHEAD`: about 35 us
#: per member); the same run: kalman took 4.1 s of CPU for the 1.2e5 units of its three
#: pairs (34 us).
SECONDS_PER_UNIT = 35e-6


@dataclass(frozen=True)
class PairCost:
    """One (entry, estimator) pair of a ``score`` call and its expected cost (units of
    :data:`SECONDS_PER_UNIT`)."""

    entry: str
    estimator: str
    cost: float
    worst_case: bool


def pair_costs(entries: list[Any], estimators: list[str], reference: str, *,
               worst_case: bool = True, unbatched: frozenset[str] | set[str] = frozenset()
               ) -> list[PairCost]:
    """The pairs :func:`testbed.score.harness.score_entry` runs, in its order, with their
    expected costs.

    Parameters
    ----------
    entries : list of SuiteEntry
    estimators : list of str
        The names of the estimators asked for (``testbed.score.pair.estimator_name``).
    reference : str
        The comparison reference's name (run on every entry, like the Kalman timing
        reference, without a worst-case search unless asked for).
    worst_case : bool
        Whether the worst-case searches run.
    unbatched : set of str
        Names of estimators that run one instance per run (:data:`UNBATCHED_FACTOR`).
    """

    names = list(estimators)
    todo = names + [n for n in dict.fromkeys((REFERENCE, reference)) if n not in names]
    out = []
    for entry in entries:
        monte_carlo = entry_cost(entry.replace(worst_case=None))
        search = entry_cost(entry) - monte_carlo
        for name in todo:
            searched = worst_case and name in names and entry.worst_case is not None
            cost = (monte_carlo + (search if searched else 0.0)) * (
                UNBATCHED_FACTOR if name in unbatched else 1.0)
            out.append(PairCost(entry.name, name, cost, searched))
    return out


def is_batched(factory: Any) -> bool | None:
    """Whether an estimator (a registered name, or ``testbed.estimators.labelled``'s
    factory) runs batched: True for the built-in names, a class's ``batched`` attribute for a
    class plug-in, None when only building it would tell (a factory function)."""
    from testbed.estimators import ESTIMATORS

    if isinstance(factory, str):
        return True if factory in ESTIMATORS else None
    obj = factory.target() if isinstance(factory, LabelledFactory) else factory
    if any(obj is builtin for builtin in ESTIMATORS.values()):  # a built-in under a label
        return True
    if isinstance(obj, type):
        return optional.is_batched(obj)
    return None


def pair_reporter(channel: Any) -> Any:
    """``on_pair(entry, estimator)`` for a job: puts the pair into ``channel``
    (:func:`pair_channel`'s; None: no reporting). A channel gone (its manager ended by an
    interrupt) does not fail the job."""
    if channel is None:
        return None

    def report(entry: str, estimator: str) -> None:
        with contextlib.suppress(OSError, EOFError):
            channel.put((entry, estimator))

    return report


class _Direct:
    """A channel for jobs that run in this process: ``put`` calls the callback."""

    def __init__(self, callback: Any):
        self.callback = callback

    def put(self, pair: tuple[str, str]) -> None:
        self.callback(*pair)


@runtime_checkable
class PairProgress(Protocol):
    """A progress whose ``pair(entry, estimator)`` is called as each pair ends (besides its
    call per entry; :func:`pair_channel`)."""

    def pair(self, entry: str, estimator: str) -> None: ...


@contextlib.contextmanager
def pair_channel(progress: Any, backend: str, workers: int) -> Iterator[Any]:
    """What the harness's jobs ``put((entry, estimator))`` into as each pair ends, so that
    ``progress.pair(entry, estimator)`` is called in this process; None when ``progress``
    has no ``pair`` method (or it is None) or on Ray (whose tasks cannot reach this
    process: the entry's own progress call stands for its pairs).

    Jobs in this process (one worker) call it directly; spawned worker processes through a
    ``multiprocessing`` manager's queue, drained by a thread of this process while the block
    runs (the manager is shut down when it ends, an interrupt included).
    """
    if not isinstance(progress, PairProgress) or backend != "local":
        yield None
        return
    pair = progress.pair
    if workers <= 1:
        yield _Direct(pair)
        return
    manager = get_context("spawn").Manager()
    queue = manager.Queue()

    def drain() -> None:
        while True:
            try:
                item = queue.get()
            except (OSError, EOFError):  # the manager went away (an interrupt)
                return
            if item is None:
                return
            pair(*item)

    thread = threading.Thread(target=drain, name="score-pairs", daemon=True)
    thread.start()
    try:
        yield queue
    finally:
        with contextlib.suppress(OSError, EOFError):
            queue.put(None)
        thread.join(timeout=5.0)
        manager.shutdown()


__all__ = ["SECONDS_PER_UNIT", "UNBATCHED_FACTOR", "PairCost", "PairProgress", "is_batched",
           "pair_channel", "pair_costs", "pair_reporter"]
