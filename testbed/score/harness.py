"""The scoring harness: every estimator on every entry of a suite, with common random numbers.

Per entry (one job; jobs run locally, in processes or on Ray) and estimator:

1. the entry's scenario is built by :func:`testbed.experiment.runner.build` with the
   estimator (a factory that raises ``ValueError`` or a failed build skips the pair, with
   the message); the scenario's disturbance becomes a
   :class:`~testbed.rigs.disturbances.SampledDisturbance` (the
   named signal sampled at the control instants: the same numbers the simulator would
   compute, plus the disturbance channel of the worst-case search);
2. one batched Monte-Carlo run with the per-run seeds ``runner.run_seeds(seed, runs)`` (the
   same for every estimator and entry), the true initial states drawn from the design prior
   when the entry asks, the estimator wrapped in a :class:`Probe` (step time, innovations);
   with ``feedback = "truth"`` the episodes do not depend on the estimator: the entry's
   first estimator simulates them, every other one is replayed on them (bitwise the same
   result, without the simulator's cost);
3. RMSE, NEES, NIS and the whitened innovations from the recorded trajectories
   (:mod:`testbed.score.stats`; the tests on them in :mod:`testbed.score.consistency` and
   :mod:`testbed.score.paired`, applied by :mod:`testbed.score.report`);
4. the worst-case search (:mod:`testbed.score.worst_case`) on a second loop of a few members
   whose estimator is a copy of the first and whose sensors are the entry's without
   quantization (:func:`~testbed.score.worst_case.without_quantization`).

Entries are the unit of parallel work, started longest first (:func:`entry_cost`).
The built-in Kalman filter runs on every entry as the timing reference, and the comparison
reference (``score(..., reference=...)``, default the Kalman filter) too (each reported only
when asked for).

Its parts: :mod:`testbed.score.pair` (one estimator on one entry, steps 1-4),
:mod:`testbed.score.probe` (the step-time and innovation wrapper),
:mod:`testbed.score.shared_designs` (the workers' design directory); this module schedules the
entries over the workers and checks the arguments.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from testbed.estimators import memo
from testbed.experiment.backend import check_backend, map_jobs
from testbed.score.cost import ENTRY_COST_FACTORS, STEP_OVERHEAD, entry_cost
from testbed.score.pair import PRIOR_STREAM, REFERENCE, PairResult, estimator_name, score_pair
from testbed.score.probe import Probe
from testbed.score.progress import pair_channel, pair_reporter
from testbed.score.shared_designs import (
    DESIGNS_PREFIX,
    designs_directory,
    remove_stale_designs,
)
from testbed.score.suite import SuiteEntry

__all__ = ["DESIGNS_PREFIX", "ENTRY_COST_FACTORS", "PRIOR_STREAM", "REFERENCE", "STEP_OVERHEAD",
           "PairResult", "Probe", "ScoreRun", "designs_directory", "entry_cost",
           "remove_stale_designs", "run_entries", "score", "score_entry", "score_pair",
           "twin_entries"]



def score_entry(entry: SuiteEntry, estimators: list[Any], seed: int, *,
                worst_case: bool = True, num_threads: int | None = None,
                reference: Any = REFERENCE, on_pair: Any = None) -> dict[str, PairResult]:
    """Every estimator, the Kalman timing reference and the comparison ``reference`` on one
    entry; keys: estimator names. ``on_pair(entry name, estimator name)`` after each pair."""
    names = [estimator_name(e) for e in estimators]
    todo = list(zip(names, estimators, strict=True))
    for extra in (REFERENCE, reference):
        if estimator_name(extra) not in [name for name, _ in todo]:
            todo.append((estimator_name(extra), extra))
    tapes: dict[str, Any] = {}  # the entry's simulated episodes, shared (see score_pair)
    out = {}
    for name, est in todo:
        out[name] = score_pair(entry, est, seed, worst_case=worst_case and name in names,
                               num_threads=num_threads, tapes=tapes)
        if on_pair is not None:
            on_pair(entry.name, name)
    return out


def _job(args: tuple) -> dict[str, PairResult]:
    entry, estimators, seed, worst_case, num_threads, reference, designs, pairs = args
    with memo.shared_directory(designs):
        return score_entry(entry, estimators, seed, worst_case=worst_case,
                           num_threads=num_threads, reference=reference,
                           on_pair=pair_reporter(pairs))


def run_entries(entries: list[SuiteEntry], estimators: list[Any], seed: int, *,
                backend: str = "local", workers: int | None = None,
                worst_case: bool = True, progress: Any = None,
                reference: Any = REFERENCE) -> list[dict[str, PairResult]]:
    """:func:`score_entry` for every entry, locally (``workers`` processes) or on Ray.

    Entries are the unit of work (one job each: its estimators share its simulated
    episodes); they start longest first (:func:`entry_cost`) so that the workers finish
    together. The jobs share their estimators' designs through a temporary directory
    (:func:`testbed.estimators.memo.shared_directory`; a worker that cannot reach it designs
    on its own). Results do not depend on the backend or the number of workers (apart from
    timings). ``progress(entry name)`` as each entry's job ends; a ``progress.pair(entry name,
    estimator name)`` method too, as each pair ends (locally; on Ray: not called, the entry's
    call stands for its pairs; :func:`testbed.score.progress.pair_channel`).
    """
    workers = check_backend(backend, 1 if workers is None else workers, None)
    # one physics thread per job: batches of tens of members gain nothing from the thread
    # pool on two cores (measured: 16 helicopter runs 2.6 s with one thread, 3.9 s with two)
    with designs_directory() as designs, pair_channel(progress, backend,
                                                         min(workers, len(entries))) as pairs:
        jobs = [(e, estimators, seed, worst_case, 1, reference, designs, pairs)
                for e in entries]
        return map_jobs(_job, [(job,) for job in jobs], backend=backend, workers=workers,
                        on_done=None if progress is None else lambda i: progress(
                            jobs[i][0].name),
                        costs=[entry_cost(e) for e in entries])




@dataclass
class ScoreRun:
    """Everything one ``testbed score`` call produced.

    Attributes
    ----------
    suite : str
    seed : int
    estimators : list of str
    entries : list of SuiteEntry
    pairs : list of dict of str to PairResult
        Per entry, per estimator name (the Kalman timing reference and the comparison
        reference included).
    wall_s : float
    reference : str
        The estimator the others are compared with (paired, on common random numbers).
    """

    suite: str
    seed: int
    estimators: list[str]
    entries: list[SuiteEntry]
    pairs: list[dict[str, PairResult]]
    wall_s: float
    reference: str = REFERENCE


def _check_memory(entries: list[SuiteEntry]) -> None:
    """Refuse entries whose recorded runs (every run's trajectory is kept) cannot fit in the
    available memory, before anything is allocated (``runner.StudyTooLarge``)."""
    from testbed.experiment.study import StudyTooLarge, available_memory, size_text

    available = available_memory()
    for entry in entries:
        if entry.unavailable():
            continue
        resolved = entry.resolved_scenario().check()
        rig, sensors = resolved.rig, resolved.sensors
        n, m, nu = rig.n_states, sensors.dim, rig.n_actions
        scenario = entry.resolved_scenario()
        steps = int(round(scenario.duration_s / (scenario.physics_dt_s * scenario.frame_skip)))
        per_run = 8 * (steps + 1) * (2 * n + n * n + m + nu + len(rig.tracked_states))
        needed = per_run * int(entry.runs)
        if needed > available // 2:
            raise StudyTooLarge(
                f"runs {entry.runs:,} of scenario {entry.name!r} would need about "
                f"{size_text(needed)} of memory (every run's trajectory is kept: "
                f"{size_text(per_run)} per run), more than half of the "
                f"{size_text(available)} available; use fewer runs", needed, available)


def twin_entries(entries: list[Any], twin: Any, suite: str, *,
                 selected: bool = False) -> list[Any]:
    """A suite's entries for a twin: those of its rig, with its identified parameters.

    Parameters
    ----------
    entries : list of SuiteEntry
    twin : str, PathLike or testbed.identify.twin.Twin
        A twin file or one read (:func:`testbed.identify.twin.read_twin`).
    suite : str
        The suite's name (for the errors).
    selected : bool
        The entries were chosen by name: every one must be of the twin's rig.

    Returns
    -------
    list of SuiteEntry
        Each with ``nominal_params`` = the twin's identified values (those not identifiable
        stay nominal) and the twin named in its description; the entry's own configuration
        (profile, rig options such as the Aero's ``yaw_locked``, sensors, disturbance and its
        worst-case channel) is kept: the same unit in the entry's setting.

    Raises
    ------
    ValueError
        Chosen entries of another rig (named), or no entry of the twin's rig (one line).
    """
    from testbed.identify.twin import Twin, read_twin
    from testbed.rigs import resolve_rig

    if not isinstance(twin, Twin):
        twin = read_twin(twin)
    other = [e.name for e in entries if resolve_rig(e.scenario.rig).name != twin.rig]
    if selected and other:
        raise ValueError(f"--twin {twin.path}: a twin of rig {twin.rig!r}; the entries "
                         f"{other} are of another rig")
    chosen = [e for e in entries if e.name not in other]
    if not chosen:
        raise ValueError(f"--twin {twin.path}: suite {suite!r} has no entry of rig "
                         f"{twin.rig!r} (its entries {other} are of other rigs)")
    params = {name: p.value for name, p in twin.parameters.items() if p.identifiable}
    return [e.replace(scenario=e.scenario.replace(
                          nominal_params={**e.scenario.nominal_params, **params}),
                      description=f"{e.description}; twin {twin.path}")
            for e in chosen]


def score(estimators: list[Any], suite: str = "quick", *, seed: int = 0,
          runs: int | None = None, scenarios: list[str] | None = None,
          backend: str = "local", workers: int | None = None, worst_case: bool = True,
          progress: Any = None, reference: Any = REFERENCE, twin: Any = None) -> ScoreRun:
    """Score estimators on a suite (see the module docstring).

    Parameters
    ----------
    estimators : list of str or callable
        Registered names, ``module:factory`` paths or factories (at least one; names unique).
    suite : {"quick", "standard"}
    seed : int
        Base seed of the per-run seeds (common to every estimator and entry).
    runs : int, optional
        Override every entry's number of runs (>= 2).
    scenarios : list of str, optional
        Only these entries of the suite.
    backend : {"local", "ray"}
    workers : int, optional
        Processes (local) or Ray CPUs; entries are the unit of work.
    worst_case : bool
        Run the worst-case searches.
    progress : callable ``entry name -> None``, optional
    reference : str or callable
        The estimator every other one is compared with (default ``"kalman"``); run on every
        entry, reported only when it is among ``estimators``.
    twin : str, PathLike or testbed.identify.twin.Twin, optional
        A twin of a unit (``testbed identify --twin``): only the entries of its rig (those
        of ``scenarios`` must all be), each with the twin's identified parameters as the
        nominal ones (the simulated unit and the designer's model; an entry's parameter
        scales apply on top); each entry keeps its own configuration (:func:`twin_entries`).

    Raises
    ------
    ValueError
        Bad arguments (named), before anything runs.
    """
    from testbed.estimators import resolve
    from testbed.score.suite import get_suite

    if not estimators:
        raise ValueError("give at least one estimator (a registered name or module:factory)")
    names = [estimator_name(e) for e in estimators]
    if len(set(names)) != len(names):
        raise ValueError(f"estimators must be distinct, got {names}")
    for est in [*estimators, reference]:
        resolve(est)  # unknown names and import paths fail here, naming them
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    entries = get_suite(suite)
    if scenarios is not None:
        known = {e.name for e in entries}
        unknown = [s for s in scenarios if s not in known]
        if unknown:
            raise ValueError(f"unknown scenario(s) {unknown} in suite {suite!r}; expected "
                             f"among {sorted(known)}")
        entries = [e for e in entries if e.name in scenarios]
    if twin is not None:
        entries = twin_entries(entries, twin, suite, selected=scenarios is not None)
    if runs is not None:
        if isinstance(runs, bool) or int(runs) != runs or runs < 2:
            raise ValueError(f"runs must be an integer >= 2, got {runs!r}")
        entries = [e.replace(runs=int(runs)) for e in entries]
    _check_memory(entries)
    start = time.perf_counter()
    pairs = run_entries(entries, list(estimators), int(seed), backend=backend,
                        workers=workers, worst_case=worst_case, progress=progress,
                        reference=reference)
    return ScoreRun(suite=suite, seed=int(seed), estimators=names, entries=entries,
                    pairs=pairs, wall_s=time.perf_counter() - start,
                    reference=estimator_name(reference))
