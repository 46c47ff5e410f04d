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
"""

from __future__ import annotations

import contextlib
import copy
import json
import os
import shutil
import stat
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from filters import FilterError
from testbed.estimators import EstimatorWrapper, PerMember, memo, paper_design_only
from testbed.experiment import runner
from testbed.experiment.backend import check_backend, map_jobs
from testbed.io import process_alive
from testbed.rigs import resolve_rig
from testbed.rigs.base import build_rig
from testbed.rigs.disturbances import SampledDisturbance
from testbed.score import stats
from testbed.score.consistency import whiten
from testbed.score.progress import pair_channel, pair_reporter
from testbed.score.suite import SuiteEntry
from testbed.score.worst_case import (
    RESTARTS,
    LoopEvaluator,
    population,
    search,
    without_quantization,
)
from testbed.sim.simulator import SimulationDiverged

#: The timing reference.
REFERENCE = "kalman"


class Probe(EstimatorWrapper):
    """A transparent wrapper that times ``step`` and collects normalized innovations.

    ``innovation`` (N, m) and ``innovation_cov`` (N, m, m), when the estimator exposes both
    after a step (the optional members of the estimator protocol), give
    ``NIS = nu^T S^-1 nu`` per member and the whitened innovation ``L^-1 nu`` (``S = L L^T``)
    for the whiteness test.

    Parameters
    ----------
    inner : batched estimator
    """

    batched = True

    def __init__(self, inner: Any):
        super().__init__(inner)
        self.elapsed_ns = 0
        self.calls = 0
        self.nis: list[np.ndarray] = []
        self.whitened: list[np.ndarray] = []
        self.nis_dim: int | None = None
        self.nis_missing = False
        self.nis_error: str | None = None

    def reset(self, x0: Any, P0: Any) -> None:
        """Reset the inner estimator and the records."""
        self.inner.reset(x0, P0)
        self.elapsed_ns, self.calls, self.nis, self.nis_missing = 0, 0, [], False
        self.whitened, self.nis_error = [], None

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Step the inner estimator (timed), then record its NIS and whitened innovation."""
        start = time.perf_counter_ns()
        x = self.inner.step(y, u)
        self.elapsed_ns += time.perf_counter_ns() - start
        self.calls += 1
        nu = getattr(self.inner, "innovation", None)
        S = getattr(self.inner, "innovation_cov", None)
        if nu is None or S is None:
            self.nis_missing = True
        elif not self.nis_missing:
            nu = np.asarray(nu, dtype=float).reshape(len(x), -1)
            S = np.broadcast_to(np.asarray(S, dtype=float), (*nu.shape, nu.shape[1]))
            try:
                z = whiten(nu, S)
            except np.linalg.LinAlgError:
                self.nis_missing = True
                self.nis_error = (f"innovation covariance not positive definite at step "
                                  f"{self.calls}: NIS and whiteness not computed")
                return x
            self.whitened.append(z)
            self.nis.append(np.sum(z * z, axis=-1))
            self.nis_dim = nu.shape[1]
        return x


@dataclass
class PairResult:
    """Raw results of one estimator on one entry (JSON-ready apart from the arrays).

    ``cpu_s``: CPU seconds of the stages (``build``: simulator, design and estimator;
    ``monte_carlo``: the runs, simulated or replayed, and their statistics; ``worst_case``:
    the search), where the time of ``testbed score`` goes.
    """

    estimator: str
    scenario: str
    runs: int
    skipped: str | None = None
    state_names: list[str] = field(default_factory=list)
    rmse_per_run: dict[str, np.ndarray] = field(default_factory=dict)
    nees: np.ndarray | None = None
    nis: np.ndarray | None = None
    nis_dim: int | None = None
    innovations: np.ndarray | None = None
    step_us: float | None = None
    certified_gamma: float | None = None
    gamma_kind: str | None = None
    worst: Any = None
    worst_skipped: str | None = None
    trajectory: dict[str, np.ndarray] | None = None
    units: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    cpu_s: dict[str, float] = field(default_factory=dict)


def _name(estimator: Any) -> str:
    return estimator if isinstance(estimator, str) else getattr(estimator, "__name__",
                                                                repr(estimator))


def _sampled(entry: SuiteEntry, scenario, num: int, steps: int,
             nominal: bool) -> SampledDisturbance | None:
    """The entry's disturbance as per-member samples (the named signal's values when
    ``nominal``, else zeros) for ``steps + 1`` control instants, with its white noise."""
    rig = build_rig(resolve_rig(scenario.rig), physics_dt_s=scenario.physics_dt_s,
                    options=scenario.rig_options)
    dt_s = scenario.physics_dt_s * scenario.frame_skip
    base = rig.disturbance(scenario.disturbance, scenario.process_noise)
    channel = None if entry.worst_case is None else entry.worst_case.channel
    if base is not None and base.has_signal:
        G = base.G
        t = np.arange(steps + 1) * dt_s
        values = np.array([base.signal(ti) for ti in t]) if nominal else None
        s = base.signal(0.0).shape[0]
    elif channel is not None:
        G = np.asarray(channel, dtype=float)
        s = G.shape[1]
        values = np.zeros((steps + 1, s)) if nominal else None
    else:
        return None
    b = None if base is None else base.b
    tiled = (np.broadcast_to(values, (num, steps + 1, s)).copy() if values is not None
             else np.zeros((num, steps + 1, s)))
    return SampledDisturbance(G, tiled, dt_s, b=b, n_positions=len(rig.joints))


#: Spawn key of the stream the true initial states are drawn from: ``default_rng([seed,
#: PRIOR_STREAM])``. Not ``default_rng(seed)``: that is the simulator's own noise stream of the
#: run (``gymnasium.utils.seeding.np_random(seed)``), so the initial state would equal a
#: multiple of the first process and measurement noise draws, and the first steps' NEES of
#: the Kalman filter would be far above its band (3.1 at step 1 for n = 2).
PRIOR_STREAM = 17


def _trajectory_x0(entry: SuiteEntry, design: Any, seeds: np.ndarray) -> Any:
    if not entry.x0_from_prior:
        return None
    i = getattr(design, "physical", np.arange(len(design.x0)))  # the rig's states' prior
    x0, P0 = design.x0[i], design.P0[np.ix_(i, i)]
    return [{"x0": np.random.default_rng([int(s), PRIOR_STREAM]).multivariate_normal(x0, P0)}
            for s in seeds]


def _unwrap(estimator: Any) -> Any:
    return estimator.instances[0] if isinstance(estimator, PerMember) else estimator


def _tape_key(experiment: Any, seeds: np.ndarray, options: Any) -> str:
    """What a recorded Monte Carlo (:class:`~testbed.experiment.loop.Tape`) depends on
    besides the estimator: the built scenario (an estimator's scenario defaults may change
    its sensors or disturbance), the sensors, the seeds and the reset options. The entry's
    sampled disturbance is named, not hashed: within one entry it is always the same one
    (:func:`_sampled`)."""
    scenario = {k: v for k, v in experiment.meta["scenario"].items()
                if k not in ("estimator", "estimator_options")}
    if isinstance(scenario.get("disturbance"), SampledDisturbance):
        scenario["disturbance"] = "the entry's sampled disturbance"
    x0 = [] if options is None else [np.asarray(o["x0"]).tolist() for o in options]
    return json.dumps([scenario, experiment.meta["sensors"], np.asarray(seeds).tolist(), x0,
                       experiment.loop.truth_feedback], sort_keys=True, default=repr)


def score_pair(entry: SuiteEntry, estimator: Any, seed: int, *, worst_case: bool = True,
               num_threads: int | None = None,
               tapes: dict[str, Any] | None = None) -> PairResult:
    """One estimator on one entry: Monte Carlo, consistency, cost, worst case.

    Parameters
    ----------
    entry : SuiteEntry
    estimator : str or callable
        A registered name, ``module:factory`` or a factory.
    seed : int
        Base seed (``runner.run_seeds(seed, entry.runs)`` per run).
    worst_case : bool
        Run the entry's worst-case search (when it has one).
    tapes : dict, optional
        Recorded Monte Carlos of this entry shared between its estimators (filled here):
        with ``feedback = "truth"`` the simulated episodes do not depend on the estimator,
        so every estimator after the first is replayed on the first one's episodes
        (:meth:`~testbed.experiment.loop.ClosedLoop.replay`; the same result, bitwise,
        without simulating again).
    """
    name = _name(estimator)
    out = PairResult(estimator=name, scenario=entry.name, runs=entry.runs)
    reason = entry.unavailable()
    if reason:
        out.skipped = reason
        return out
    clock = time.process_time()

    def lap(stage: str) -> None:
        nonlocal clock
        now = time.process_time()
        out.cpu_s[stage] = out.cpu_s.get(stage, 0.0) + now - clock
        clock = now

    scenario = entry.resolved_scenario()
    dt_s = scenario.physics_dt_s * scenario.frame_skip
    steps = int(round(scenario.duration_s / dt_s))
    dist = _sampled(entry, scenario, entry.runs, steps, nominal=True)
    sc = scenario.replace(estimator=estimator)
    if dist is not None:
        sc = sc.replace(disturbance=dist, process_noise=0.0)

    try:
        experiment = runner.build(sc, entry.runs, num_threads=num_threads)
    except (ValueError, FilterError) as err:
        out.skipped = f"the factory raised {type(err).__name__}: {err}"
        return out
    finally:
        lap("build")
    seeds = runner.run_seeds(seed, entry.runs)
    experiment.loop.truth_feedback = entry.feedback == "truth"
    profile = str(experiment.meta.get("design_profile", ""))
    if profile.startswith("paper (fallback: "):  # a family that cannot take the matched model
        out.notes.append(f"paper design: designed from the rig's paper model, not the entry's "
                         f"matched one ({profile[len('paper (fallback: '):-1]}); compare it "
                         "with kalman on the same model (design_profile 'paper')")
    try:
        inner = experiment.loop.stage.estimator
        probe = Probe(inner)
        experiment.loop.stage.estimator = probe
        options = _trajectory_x0(entry, experiment.design, seeds)
        shared = tapes is not None and experiment.loop.truth_feedback
        key = _tape_key(experiment, seeds, options) if shared else ""
        try:
            if shared and key in tapes:
                result = experiment.loop.replay(tapes[key], options, record=True)
            else:
                result = experiment.loop.run(seeds, steps * dt_s, options, record=True,
                                             tape=shared)
                if shared:
                    tapes[key] = result.tape
        except (FilterError, FloatingPointError, SimulationDiverged) as err:
            out.skipped = f"failed: {type(err).__name__}: {err}"
            return out
        sim = experiment.loop.sim
        out.state_names = list(sim.rig.state_names)
        out.units = experiment.meta["units"]
        rec = result.trajectory
        out.rmse_per_run = {k: np.asarray(v, float) for k, v in result.metrics.rmse().items()}
        if "covariance" in rec:
            error = rec["estimate"][:, 1:] - rec["state"][:, 1:]
            try:
                out.nees = stats.nees(error, rec["covariance"][:, 1:])
            except ValueError as err:
                out.notes.append(str(err))
        if probe.nis and not probe.nis_missing:
            out.nis, out.nis_dim = np.stack(probe.nis, axis=1), probe.nis_dim
            out.innovations = np.stack(probe.whitened, axis=1)
        if probe.nis_error:
            out.notes.append(probe.nis_error)
        out.step_us = probe.elapsed_ns / 1e3 / max(probe.calls * entry.runs, 1)
        design_meta = experiment.meta.get("design") or {}
        gamma = design_meta.get("gamma")
        if gamma is not None and design_meta.get("gamma_channel") == "scenario":
            out.certified_gamma = float(gamma)
            out.gamma_kind = design_meta.get("gamma_kind", "unstated")
        elif gamma is not None:
            out.notes.append(f"the design states gamma = {gamma:.4g} for its own disturbance "
                             "model, not for this scenario's channel (no gamma_channel = "
                             "'scenario' in design_meta): not compared")
        out.trajectory = {"t_s": rec["t_s"], "state": rec["state"][0],
                          "estimate": rec["estimate"][0],
                          "measurement": rec["measurement"][0], "action": rec["action"][0]}
        experiment.loop.stage.estimator = inner
        lap("monte_carlo")
        if worst_case and entry.worst_case is not None:
            try:
                out.worst = _worst_case(entry, scenario, estimator, _unwrap(inner), experiment,
                                        seeds[0], tapes)
            except (ValueError, FilterError, FloatingPointError,
                    SimulationDiverged) as err:
                out.worst_skipped = f"worst-case search failed: {type(err).__name__}: {err}"
            lap("worst_case")
    finally:
        experiment.close()
    return out


def _worst_case(entry: SuiteEntry, scenario, estimator: Any, template: Any, experiment: Any,
                seed: int, tapes: dict[str, Any] | None = None):
    spec = entry.worst_case
    dt_s = experiment.loop.sim.dt_s
    K = int(round((spec.horizon_s or scenario.duration_s) / dt_s))
    members = population(spec.basis - 1) if spec.generations else 0
    dist = _sampled(entry, scenario, 1, K, nominal=False)
    if dist is None:
        raise ValueError("the entry has no disturbance channel")
    s = dist.values.shape[2]
    # candidates per closed-loop run: +-v_1 and the random draws, or a DE population; the
    # run without w is member 0 of the impulse response's (s + 1 members), run once
    # + the batch's own baseline (member 0); the restarts' populations share a batch
    num = max(2 + spec.random_draws, RESTARTS * members) + 1
    dist = _sampled(entry, scenario, num, K, nominal=False)
    impulse_dist = _sampled(entry, scenario, s + 1, K, nominal=False)

    def copy_factory(design, **options):
        return copy.deepcopy(template)

    copy_factory.__name__ = _name(estimator)
    # the copy needs the design the original was built from (a paper-design-only family on
    # an augmented design: the paper design, not the matched one)
    reason = paper_design_only(estimator)
    if reason is not None:
        copy_factory.paper_design_only = reason  # type: ignore[attr-defined]
    probe_sensors, removed = without_quantization(experiment.loop.sim.sensors)
    sc = scenario.replace(estimator=copy_factory, disturbance=dist, process_noise=0.0)
    if removed:
        sc = sc.replace(sensors=probe_sensors, sensor_options={})
    wc = runner.build(sc, num, num_threads=1)
    impulse = None
    try:
        impulse = runner.build(sc.replace(disturbance=impulse_dist), s + 1, num_threads=1)
        for probe in (wc, impulse):
            probe.loop.truth_feedback = entry.feedback == "truth"
        # an augmented (matched) design's physical states: the loop records those
        evaluator = LoopEvaluator(wc, dist, impulse, impulse_dist, seed, K,
                                  wc.design.output_matrix[:, wc.design.physical])
        # impulses of 1e-3 of the candidates' mean amplitude, after a quarter of the horizon
        eps = 1e-3 * np.sqrt(spec.energy / (K * dt_s * s))
        k0 = max(1, K // 4)
        # the impulse run does not depend on the estimator when the controller acts on the
        # truth: simulated for the entry's first estimator, replayed for the others
        key = json.dumps(["worst-case impulse", _tape_key(impulse, np.full(s + 1, seed), None),
                          k0, K, float(eps)])
        t = evaluator.impulse_response(k0, eps, tapes=tapes, key=key)
        rng = np.random.default_rng([int(seed), 16])
        result = search(evaluator, t, energy=spec.energy, random_draws=spec.random_draws,
                        basis=spec.basis, generations=spec.generations, rng=rng)
        result.probe_sensors = wc.loop.sim.sensors.describe()
        result.quantization_removed = removed
        return result
    finally:
        wc.close()
        if impulse is not None:
            impulse.close()


def score_entry(entry: SuiteEntry, estimators: list[Any], seed: int, *,
                worst_case: bool = True, num_threads: int | None = None,
                reference: Any = REFERENCE, on_pair: Any = None) -> dict[str, PairResult]:
    """Every estimator, the Kalman timing reference and the comparison ``reference`` on one
    entry; keys: estimator names. ``on_pair(entry name, estimator name)`` after each pair."""
    names = [_name(e) for e in estimators]
    todo = list(zip(names, estimators, strict=True))
    for extra in (REFERENCE, reference):
        if _name(extra) not in [name for name, _ in todo]:
            todo.append((_name(extra), extra))
    tapes: dict[str, Any] = {}  # the entry's simulated episodes, shared (see score_pair)
    out = {}
    for name, est in todo:
        out[name] = score_pair(entry, est, seed, worst_case=worst_case and name in names,
                               num_threads=num_threads, tapes=tapes)
        if on_pair is not None:
            on_pair(entry.name, name)
    return out


#: Fixed cost of one step of a batched closed loop, in member-steps (measured on the
#: helicopter with the Kalman filter, one thread: 0.56 ms per step of 1 member, 0.91 ms of
#: 7, 3.5 ms of 100: about 0.5 ms plus 35 us per member).
STEP_OVERHEAD = 15
#: Cost per member-step of an entry's estimators relative to the paper helicopter's, where it
#: differs (measured on the standard suite with all eight built-in estimators, 2026-11-26,
#: from the pairs' ``cpu_s`` per estimated member-step: the hardware helicopter 1.5 times
#: (its augmented design gives the ekf and ukf 10 states instead of 4), the vehicle roll
#: 0.55, the linear calibration plant 0.4; the open-loop basin-ms-hinf entry, 0.5, is not
#: told apart from the helicopter's other paper entries).
ENTRY_COST_FACTORS = {("helicopter", "hardware"): 1.5, ("vehicle-roll", "paper"): 0.55,
                      ("vehicle-roll", "hardware"): 0.55, ("linear-plant", None): 0.4}


def entry_cost(entry: SuiteEntry) -> float:
    """A rough estimate of an entry's run time, relative to the other entries', for
    scheduling the entries over workers longest first (:func:`run_entries`).

    Member-steps of the Monte Carlo and of the worst-case search's closed-loop runs (the
    impulse response over ``K / 4 + K`` steps with the baseline and, typically, one channel,
    then ``2 + generations`` runs of ``K`` steps of the candidates) plus
    :data:`STEP_OVERHEAD` per step, times :data:`ENTRY_COST_FACTORS`.
    """
    if entry.unavailable():
        return 0.0
    scenario = entry.scenario
    rig = scenario.rig if isinstance(scenario.rig, str) else getattr(scenario.rig, "name", "")
    dt_s = scenario.physics_dt_s * scenario.frame_skip
    steps = scenario.duration_s / dt_s
    cost = steps * (entry.runs + STEP_OVERHEAD)
    spec = entry.worst_case
    if spec is not None:
        K = (spec.horizon_s or scenario.duration_s) / dt_s
        members = max(2 + spec.random_draws, RESTARTS * population(spec.basis - 1)) + 1
        cost += K * (1.25 * (2 + STEP_OVERHEAD)
                     + (2 + spec.generations) * (members + STEP_OVERHEAD))
    return cost * ENTRY_COST_FACTORS.get((rig, entry.profile), 1.0)


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


#: Name prefix of the temporary directory through which one ``score`` call's workers share
#: their designs: ``testbed-designs-<pid>-<random>`` (``pid``: the process that made it).
DESIGNS_PREFIX = "testbed-designs-"


@contextlib.contextmanager
def designs_directory(parent: str | os.PathLike[str] | None = None) -> Iterator[str]:
    """A new private directory (mode 0700) for the designs the workers of one call share,
    removed when the block ends (an exception or an interrupt included).

    Its name carries this process's id. A process killed by SIGKILL cannot remove its own;
    the next call removes it: every ``testbed-designs-<pid>-*`` directory of this user in
    ``parent`` whose process no longer exists (:func:`remove_stale_designs`).

    Parameters
    ----------
    parent : path-like, optional
        Where to make it (default ``tempfile.gettempdir()``).
    """
    parent = tempfile.gettempdir() if parent is None else os.fspath(parent)
    remove_stale_designs(parent)
    with tempfile.TemporaryDirectory(prefix=f"{DESIGNS_PREFIX}{os.getpid()}-",
                                     dir=parent) as designs:
        yield designs


def remove_stale_designs(parent: str | os.PathLike[str] | None = None) -> list[str]:
    """Remove the design directories (:func:`designs_directory`) of this user in ``parent``
    (default the temporary directory) left by processes that no longer exist; the removed
    paths. Directories of other users, of live processes, symbolic links and names
    without a process id are left alone."""
    parent = tempfile.gettempdir() if parent is None else os.fspath(parent)
    removed: list[str] = []
    try:
        names = os.listdir(parent)
    except OSError:
        return removed
    for name in names:
        pid = name[len(DESIGNS_PREFIX):].split("-", 1)[0]
        if not (name.startswith(DESIGNS_PREFIX) and pid.isdigit()) or process_alive(int(pid)):
            continue
        path = os.path.join(parent, name)
        try:
            st = os.lstat(path)
        except OSError:
            continue
        if stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid():
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed
    return True


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
    names = [_name(e) for e in estimators]
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
                    reference=_name(reference))
