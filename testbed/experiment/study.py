"""Monte-Carlo studies (:func:`monte_carlo`): batched runs in lanes of threads or shards of
processes / Ray tasks, the per-run metrics, and the memory estimate checked before anything is
allocated."""

from __future__ import annotations

import contextlib
import os
import threading
import time
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from filters.kalman import CovarianceMemo
from testbed.estimators import optional
from testbed.experiment.backend import check_backend, map_jobs
from testbed.experiment.build import Experiment, build, run_seeds
from testbed.experiment.envelope import ErrorEnvelope
from testbed.experiment.loop import Stopped
from testbed.experiment.scenario import Scenario
from testbed.io.trajectory_stream import NpzStream
from testbed.sim.simulator import default_num_threads, positive_int

#: Default number of trajectories stepped together by :func:`monte_carlo`.
DEFAULT_BATCH_SIZE = 1000


#: Keys of a result that measure time, not the estimator.
TIMING_KEYS = ("wall_s", "traj_steps_per_s", "threads")


class StudyTooLarge(ValueError):
    """A Monte-Carlo study whose per-run results would not fit in memory (refused before
    anything is allocated); ``needed`` and ``available`` in bytes."""

    def __init__(self, message: str, needed: int = 0, available: int = 0):
        super().__init__(message)
        self.needed, self.available = needed, available

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (str(self), self.needed, self.available))


def available_memory() -> int:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``; otherwise the
    physical memory)."""
    with contextlib.suppress(OSError, ValueError, IndexError):
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    with contextlib.suppress(ValueError, OSError, AttributeError):
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    return 1 << 62


def size_text(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} PB"  # pragma: no cover


def study_bytes(n_states: int, n_measured: int, runs: int,
                envelope_points: int | None = None) -> int:
    """Estimated memory of the per-run results of a study of ``runs`` runs: seeds, per-run
    metrics (arrays, the JSON lists and text) and, with an envelope, its errors."""
    per_run = 3 * 8 + 2 * 8 * (n_states + n_measured + 3)  # seeds, metric arrays (+ joins)
    per_run += 64 * (n_states + 1) + 32 * (n_states + 1)    # Python floats in lists, JSON
    if envelope_points is not None:
        per_run += 8 * n_states * int(envelope_points)
    return int(runs) * per_run


def check_study_size(scenario: Scenario, runs: int,
                     envelope_points: int | None = None) -> None:
    """Refuse a study whose per-run results cannot fit in the available memory.

    Raises
    ------
    StudyTooLarge
        With the estimate and what is available (nothing allocated yet).
    """
    resolved = scenario.check()
    n = resolved.rig.n_states
    m = len(resolved.sensors.measured_state or []) or n
    needed = study_bytes(n, m, runs, envelope_points)
    available = available_memory()
    if needed > available // 2:
        raise StudyTooLarge(
            f"runs {runs:,} would need about {size_text(needed)} of memory for the per-run "
            f"results ({size_text(needed / runs)} per run), more than half of the "
            f"{size_text(available)} available; use fewer runs (at most about "
            f"{max(1, available // 2 // max(1, needed // runs)):,})", needed, available)


def _stats(values: np.ndarray) -> dict[str, float]:
    q05, q95 = np.quantile(values, [0.05, 0.95])
    return {"mean": float(np.mean(values)), "q05": float(q05), "q95": float(q95)}


def monte_carlo(scenario: Scenario, runs: int = 100, *, batch_size: int | None = None,
                progress: bool = False, save_npz: str | Path | None = None,
                num_threads: int | None = None,
                envelope_points: int | None = None, backend: str | None = None,
                workers: int | None = None, address: str | None = None) -> dict[str, Any]:
    """``runs`` episodes of ``scenario``, stepped in batches.

    Parameters
    ----------
    scenario : Scenario
        ``scenario.seed`` is the base seed; run ``i`` uses ``run_seeds(seed, runs)[i]``.
    runs : int
    batch_size : int, optional
        Members stepped together (default ``min(runs, 1000)``); results do not depend on it.
    progress : bool
        Show a progress bar (on stderr; default off).
    save_npz : path, optional
        Also write every trajectory (``(runs, steps + 1, ...)``) and the per-run metrics.
    num_threads : int, optional
        Threads (default: the CPUs available; with a ``backend``, 1 per job). In one
        process, ``T > 1`` threads run the runs in ``T`` lanes (contiguous parts, each on a
        Python thread of its own with one physics thread), so that one lane's Python overlaps
        the others' physics; without ``save_npz`` and ``envelope_points`` (one lane then, on
        ``T`` physics threads). The results do not depend on it.
    envelope_points : int, optional
        Also gather the error envelope over runs on this many time points
        (:class:`testbed.experiment.envelope.ErrorEnvelope`: streaming, no trajectory kept); the
        result then has ``error_envelope``.
    backend : {None, "local", "ray"}, optional
        None (default): every batch in this process. ``"local"`` / ``"ray"``: the runs in
        ``workers`` contiguous shards, each a job of :func:`~testbed.experiment.backend.
        map_jobs` (local processes, or Ray tasks on the cluster at ``address`` or a local
        instance); each run keeps its seed, so every per-run result equals the in-process
        study's bitwise. Without ``save_npz`` and ``envelope_points``.
    workers, address : optional
        Shards (default the CPUs, at most ``runs``) and the Ray cluster address.

    Returns
    -------
    dict
        JSON-ready: ``runs``, ``seeds`` (the per-run seeds), ``steps_per_run``, ``wall_s``,
        ``traj_steps_per_s``, ``rmse``/``measurement_rmse`` ``{name: {mean, q05, q95}}``,
        ``nees_mean``, ``nees``, ``T_final``, ``clipped_fraction_mean``, ``units``,
        ``scenario`` (every field, the rig's defaults filled in: what ran; a scenario file
        holding it reproduces the study, see :mod:`testbed.experiment.scenario_file`) and
        ``meta`` (rig, sensors, control period, units, design).
    """
    if isinstance(runs, bool) or int(runs) != runs or runs < 1:
        raise ValueError(f"runs must be a positive integer, got {runs}")
    if batch_size is not None and (int(batch_size) != batch_size or batch_size < 1):
        raise ValueError(f"batch_size must be a positive integer, got {batch_size}")
    if envelope_points is not None and (isinstance(envelope_points, bool)
                                        or int(envelope_points) != envelope_points
                                        or envelope_points < 2):
        raise ValueError(f"envelope_points must be an integer >= 2, got {envelope_points}")
    runs = int(runs)
    if backend is not None:
        if save_npz is not None or envelope_points is not None:
            raise ValueError("a sharded Monte Carlo (backend) writes no npz and no envelope")
        return _sharded_monte_carlo(scenario, runs, batch_size, progress, num_threads,
                                    backend, workers, address)
    # BLAS single-threaded for the whole study, its builds included: their products are
    # tiny, and a second BLAS thread only slows them down (by far on a busy machine)
    start_time = time.perf_counter()
    with threadpool_limits(1):
        return _local_monte_carlo(scenario, runs, batch_size, progress, save_npz, num_threads,
                                  envelope_points, start_time)


def _local_monte_carlo(scenario: Scenario, runs: int, batch_size: int | None, progress: bool,
                       save_npz: str | Path | None, num_threads: int | None,
                       envelope_points: int | None, start_time: float) -> dict[str, Any]:
    """:func:`monte_carlo` in this process (its arguments checked; its wall time counted
    from ``start_time``, a ``time.perf_counter()``)."""
    batch_size = min(runs, int(batch_size or DEFAULT_BATCH_SIZE))
    check_study_size(scenario, runs, envelope_points)
    seeds = run_seeds(scenario.seed, runs)
    threads = (default_num_threads() if num_threads is None
               else positive_int(num_threads, "num_threads"))
    # lanes: contiguous parts of the runs stepped in as many Python threads, one physics
    # thread each, so that one lane's Python (sensors, estimator, controller; it holds the
    # GIL) runs while the other lanes' physics runs (MuJoCo releases the GIL); a run's
    # results do not depend on its batch. A stream or an envelope keeps one lane.
    lanes = min(threads, runs) if save_npz is None and envelope_points is None else 1
    if lanes > 1:
        batch_size = min(batch_size, -(-runs // lanes))
    experiments: dict[int, Experiment] = {}
    # the batches of the study (every lane's, one after the other) compute one covariance
    # sequence when their estimator's covariance does not depend on the data: computed once
    # for all of them (the study's own memo, dropped with it; the same values without it)
    memo = CovarianceMemo()

    def experiment_for(size: int) -> Experiment:
        if size not in experiments:
            experiments[size] = _sharing(build(scenario, size,
                                               num_threads=1 if lanes > 1 else num_threads),
                                         memo)
        return experiments[size]

    first = experiment_for(batch_size)
    dt_s = first.loop.sim.dt_s
    n_steps = int(round(scenario.duration_s / dt_s))
    if n_steps < 1:
        raise ValueError(f"duration_s must cover at least one control period ({dt_s} s), "
                         f"got {scenario.duration_s}")
    stream = None
    state_names = list(first.loop.sim.rig.state_names)
    envelope = None
    if envelope_points is not None:
        envelope = ErrorEnvelope(runs, n_steps, dt_s, state_names, envelope_points)
    gathered = RunMetrics(state_names)
    try:
        if save_npz is not None:
            shapes = {k: (runs, *s[1:])
                      for k, s in first.loop.trajectory_shapes(n_steps).items()}
            stream = NpzStream(save_npz, shapes)
        parts = [part for part in np.array_split(seeds, lanes) if len(part)]
        batches = sum(-(-len(part) // batch_size) for part in parts)
        bar = tqdm(total=batches * n_steps, desc=f"monte carlo ({first.meta['rig']})",
                   unit="step", disable=not progress)
        with bar:
            if lanes > 1:
                gathered = _run_lanes(scenario, parts, batch_size, experiments, bar, memo)
            else:
                for start in range(0, runs, batch_size):
                    size = min(batch_size, runs - start)
                    loop = experiment_for(size).loop
                    record = stream.rows(start, start + size) if stream is not None else False
                    on_step = None if envelope is None else envelope.observer(start)
                    result = loop.run(seeds[start:start + size], scenario.duration_s,
                                      record=record, bar=bar, on_step=on_step)
                    if stream is not None:
                        stream.flush()
                    gathered.add(result)
    except BaseException:
        if stream is not None:
            stream.abort()
        raise
    finally:
        for experiment in experiments.values():
            experiment.close()
    try:
        per_run = gathered.arrays()
    except BaseException:
        if stream is not None:
            stream.abort()
        raise
    if stream is not None:
        stream.finish(_npz_extra(per_run, seeds, n_steps, dt_s, state_names,
                                 list(first.loop.sim.sensors.names)))  # removes temporaries
    result = _study_result(scenario, first, seeds, per_run, n_steps, batch_size, lanes,
                           time.perf_counter() - start_time, save_npz)
    if envelope is not None:
        result["error_envelope"] = envelope.result()
    return result


def _study_result(scenario: Scenario, first: Experiment, seeds: np.ndarray,
                  per_run: dict[str, Any], n_steps: int, batch_size: int, lanes: int,
                  wall_s: float, save_npz: str | Path | None) -> dict[str, Any]:
    """The JSON-ready result of a local study (:func:`_local_monte_carlo`)."""
    runs, dt_s = len(seeds), first.loop.sim.dt_s
    return {
        "filter": scenario.describe()["estimator"],
        "runs": runs,
        "duration_s": n_steps * dt_s,
        "steps_per_run": n_steps,
        "seed": scenario.seed,
        "seeds": seeds.tolist(),
        "seed_rule": "numpy.random.SeedSequence(seed).generate_state(runs)",
        "batch_size": batch_size,
        "threads": first.loop.sim.physics.num_threads * lanes,
        "wall_s": wall_s,
        "traj_steps_per_s": runs * n_steps / wall_s,
        **per_run_summary(per_run),
        "npz": None if save_npz is None else str(save_npz),
        "units": first.meta["units"],
        "scenario": first.meta["scenario"],
        "meta": {k: v for k, v in first.meta.items() if k != "scenario"},
    }


def _sharing(experiment: Experiment, memo: CovarianceMemo) -> Experiment:
    """``experiment``, its estimator given the study's covariance memo if it takes one
    (:meth:`filters.kalman.KalmanFilter.share_covariance_memo`)."""
    optional.share_covariance_memo(experiment.loop.stage.estimator, memo)
    return experiment


def _run_lanes(scenario: Scenario, parts: list[np.ndarray], batch_size: int,
               experiments: dict[int, Experiment], bar: tqdm,
               memo: CovarianceMemo) -> RunMetrics:
    """The runs of ``parts`` (contiguous seeds, in order), each part in batches of at most
    ``batch_size`` on a thread of its own with its own one-thread experiments (the first
    part's are ``experiments``, closed by the caller; the others' are closed here); every
    lane's estimators share ``memo`` (:class:`filters.kalman.CovarianceMemo`).

    A failure or an interrupt stops every lane within a step (:class:`Stopped`) and is
    raised once they have stopped.
    """
    stop = threading.Event()
    own: list[dict[int, Experiment]] = [experiments] + [{} for _ in parts[1:]]

    state_names = list(experiments[batch_size].loop.sim.rig.state_names)

    def lane(j: int) -> RunMetrics:
        gathered = RunMetrics(state_names)
        for start in range(0, len(parts[j]), batch_size):
            size = min(batch_size, len(parts[j]) - start)
            gathered.add(own[j][size].loop.run(parts[j][start:start + size],
                                               scenario.duration_s, bar=bar, stop=stop))
        return gathered

    try:
        # every lane's experiments built here, one after the other (the builds' MJCF
        # compilations would only compete for the threads the lanes run on)
        for j, part in enumerate(parts):
            for size in {min(batch_size, len(part) - start)
                         for start in range(0, len(part), batch_size)}:
                if size not in own[j]:
                    own[j][size] = _sharing(build(scenario, size, num_threads=1), memo)
        with ThreadPoolExecutor(len(parts)) as pool:  # (BLAS limited by the caller)
            futures = [pool.submit(lane, j) for j in range(len(parts))]
            try:
                _, pending = wait(futures, return_when=FIRST_EXCEPTION)
            except BaseException:  # an interrupt: the lanes stop within a step
                stop.set()
                raise
            if pending:  # a lane failed: the others stop within a step
                stop.set()
        failures = [f.exception() for f in futures
                    if f.exception() is not None and not isinstance(f.exception(), Stopped)]
        if failures:
            raise failures[0]
        results = [f.result() for f in futures]
    finally:
        for cache in own[1:]:
            for experiment in cache.values():
                experiment.close()
    gathered = results[0]
    for part in results[1:]:
        gathered.extend(part)
    return gathered


def _mc_shard(scenario: Scenario, seeds: np.ndarray, batch_size: int | None,
              num_threads: int | None) -> dict[str, Any]:
    """The runs of one shard (their own seeds): per-run arrays and what the study reports."""
    batch_size = min(len(seeds), int(batch_size or DEFAULT_BATCH_SIZE))
    experiments: dict[int, Experiment] = {}
    gathered: RunMetrics | None = None
    try:
        for start in range(0, len(seeds), batch_size):
            size = min(batch_size, len(seeds) - start)
            if size not in experiments:
                experiments[size] = build(scenario, size, num_threads=num_threads)
            loop = experiments[size].loop
            if gathered is None:
                gathered = RunMetrics(list(loop.sim.rig.state_names))
                first = experiments[size]
            result = loop.run(seeds[start:start + size], scenario.duration_s, record=False)
            gathered.add(result)
    finally:
        for experiment in experiments.values():
            experiment.close()
    dt_s = first.loop.sim.dt_s
    return {"per_run": gathered.arrays(), "steps": int(round(scenario.duration_s / dt_s)),
            "dt_s": dt_s, "threads": first.loop.sim.physics.num_threads,
            "units": first.meta["units"], "meta": first.meta}


def _sharded_monte_carlo(scenario: Scenario, runs: int, batch_size: int | None,
                         progress: bool, num_threads: int | None, backend: str,
                         workers: int | None, address: str | None) -> dict[str, Any]:
    """:func:`monte_carlo` in contiguous shards of the runs on :func:`map_jobs` (each job
    holds one CPU: its physics runs on ``num_threads``, default 1, threads)."""
    workers = check_backend(backend, workers, address)
    scenario.check()
    start_time = time.perf_counter()
    seeds = run_seeds(scenario.seed, runs)
    shards = [part for part in np.array_split(seeds, min(workers, runs)) if len(part)]
    bar = tqdm(total=len(shards), desc=f"monte carlo ({backend})", unit="shard",
               disable=not progress)
    with bar:
        parts = map_jobs(_mc_shard, [(scenario, part, batch_size, num_threads or 1)
                                     for part in shards], backend=backend, workers=workers,
                         address=address, on_done=lambda _: bar.update())

    def joined(values: list) -> np.ndarray | None:
        return None if values[0] is None else np.concatenate(values)

    arrays = [p["per_run"] for p in parts]
    per_run = {"rmse": {k: np.concatenate([a["rmse"][k] for a in arrays])
                        for k in arrays[0]["rmse"]},
               "measurement_rmse": {k: np.concatenate([a["measurement_rmse"][k]
                                                       for a in arrays])
                                    for k in arrays[0]["measurement_rmse"]},
               "nees": joined([a["nees"] for a in arrays]),
               "T": joined([a["T"] for a in arrays]),
               "clipped": np.concatenate([a["clipped"] for a in arrays])}
    first = parts[0]
    wall_s = time.perf_counter() - start_time
    n_steps = first["steps"]
    return {
        "filter": scenario.describe()["estimator"],
        "runs": runs,
        "duration_s": n_steps * first["dt_s"],
        "steps_per_run": n_steps,
        "seed": scenario.seed,
        "seeds": seeds.tolist(),
        "seed_rule": "numpy.random.SeedSequence(seed).generate_state(runs)",
        "batch_size": min(len(shards[0]), int(batch_size or DEFAULT_BATCH_SIZE)),
        "threads": first["threads"],
        "backend": backend,
        "workers": workers,
        "wall_s": wall_s,
        "traj_steps_per_s": runs * n_steps / wall_s,
        **per_run_summary(per_run),
        "npz": None,
        "units": first["units"],
        "scenario": first["meta"]["scenario"],
        "meta": {k: v for k, v in first["meta"].items() if k != "scenario"},
    }


class RunMetrics:
    """Per-run metrics of a Monte-Carlo study, gathered batch by batch.

    Parameters
    ----------
    state_names : list of str
    """

    def __init__(self, state_names: list[str]):
        self.rmse: dict[str, list[np.ndarray]] = {k: [] for k in state_names}
        self.measurement_rmse: dict[str, list[np.ndarray]] = {}
        self.nees: list[np.ndarray | None] = []
        self.T: list[np.ndarray | None] = []
        self.clipped: list[np.ndarray] = []

    def add(self, result: Any) -> None:
        """The runs of one batch (a :meth:`ClosedLoop.run` result)."""
        for k, v in result.metrics.rmse().items():
            self.rmse[k].append(v)
        for k, v in result.metrics.measurement_rmse().items():
            self.measurement_rmse.setdefault(k, []).append(v)
        self.nees.append(result.metrics.nees_mean())
        self.T.append(result.metrics.noise_output_ratio())
        self.clipped.append(result.clipped_fraction)

    def extend(self, other: RunMetrics) -> None:
        """The runs of ``other`` after this one's."""
        for k, v in other.rmse.items():
            self.rmse[k].extend(v)
        for k, v in other.measurement_rmse.items():
            self.measurement_rmse.setdefault(k, []).extend(v)
        self.nees.extend(other.nees)
        self.T.extend(other.T)
        self.clipped.extend(other.clipped)

    def arrays(self) -> dict[str, Any]:
        """``rmse``/``measurement_rmse`` ``{name: (runs,)}``, ``nees``, ``T`` ((runs,) or
        None when the estimator has no covariance / the rig no ratio), ``clipped`` (runs,)."""
        def joined(parts: list) -> np.ndarray | None:
            return None if not parts or parts[0] is None else np.concatenate(parts)

        return {"rmse": {k: np.concatenate(v) for k, v in self.rmse.items()},
                "measurement_rmse": {k: np.concatenate(v)
                                     for k, v in self.measurement_rmse.items()},
                "nees": joined(self.nees), "T": joined(self.T),
                "clipped": np.concatenate(self.clipped)}


def per_run_summary(per_run: dict[str, Any]) -> dict[str, Any]:
    """The JSON summary of :meth:`RunMetrics.arrays`: mean and 5/95 % quantiles."""
    nees, T = per_run["nees"], per_run["T"]
    return {
        "rmse": {k: _stats(v) for k, v in per_run["rmse"].items()},
        "rmse_per_run": {k: v.tolist() for k, v in per_run["rmse"].items()},
        "measurement_rmse": {k: _stats(v) for k, v in per_run["measurement_rmse"].items()},
        "nees_mean": None if nees is None else float(np.mean(nees)),
        "nees": None if nees is None else _stats(nees),
        "T_final": None if T is None else _stats(T),
        "clipped_fraction_mean": float(np.mean(per_run["clipped"])),
    }


def _npz_extra(per_run: dict[str, Any], seeds: np.ndarray, n_steps: int, dt_s: float,
               state_names: list[str], measurement_names: list[str]) -> dict[str, np.ndarray]:
    """The per-run metrics and names stored beside the trajectories of ``--save-npz``."""
    extra: dict[str, np.ndarray] = {
        "t_s": np.arange(n_steps + 1) * dt_s, "seeds": seeds,
        "state_names": np.array(state_names), "measurement_names": np.array(measurement_names),
        "rmse": np.stack([per_run["rmse"][k] for k in state_names], axis=1),
        "clipped_fraction": per_run["clipped"]}
    if per_run["nees"] is not None:
        extra["nees_mean"] = per_run["nees"]
    if per_run["T"] is not None:
        extra["T_final"] = per_run["T"]
    return extra
