"""One estimator on one suite entry: the Monte Carlo on common random numbers (simulated, or
replayed on the entry's recorded episodes), its consistency records and the worst-case
search (see :mod:`testbed.score.harness`)."""

from __future__ import annotations

import copy
import json
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from filters import FilterError
from testbed.estimators import PerMember, paper_design_only
from testbed.experiment import runner
from testbed.plugins import factory_name
from testbed.rigs import resolve_rig
from testbed.rigs.base import build_rig
from testbed.rigs.disturbances import SampledDisturbance
from testbed.score import stats
from testbed.score.probe import Probe
from testbed.score.suite import SuiteEntry
from testbed.score.worst_case import (
    RESTARTS,
    LoopEvaluator,
    population,
    search,
    without_quantization,
)
from testbed.sim.simulator import SimulationDiverged

#: The timing reference (and the default comparison reference) of ``testbed score``.
REFERENCE = "kalman"


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


#: A registered name, a factory's ``__name__`` (its ``repr`` without one).
estimator_name = factory_name


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
    i = design.physical  # the rig's states' prior
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
    name = estimator_name(estimator)
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
            result = _monte_carlo(experiment, seeds, steps * dt_s, options, tapes, key)
        except (FilterError, FloatingPointError, SimulationDiverged) as err:
            out.skipped = f"failed: {type(err).__name__}: {err}"
            return out
        _record(out, entry, experiment, result, probe)
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


def _monte_carlo(experiment: Any, seeds: np.ndarray, duration_s: float, options: Any,
                 tapes: dict[str, Any] | None, key: str) -> Any:
    """The entry's recorded Monte Carlo: simulated, or replayed on the episodes another
    estimator of the entry simulated (``feedback = "truth"``: ``key`` in ``tapes``)."""
    shared = tapes is not None and experiment.loop.truth_feedback
    if shared and key in tapes:
        return experiment.loop.replay(tapes[key], options, record=True)
    result = experiment.loop.run(seeds, duration_s, options, record=True, tape=shared)
    if shared:
        tapes[key] = result.tape
    return result


def _record(out: PairResult, entry: SuiteEntry, experiment: Any, result: Any,
            probe: Probe) -> None:
    """The Monte Carlo's RMSE, NEES, NIS, whitened innovations, step time, certified gamma
    and first trajectory into ``out``."""
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

    copy_factory.__name__ = estimator_name(estimator)
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
