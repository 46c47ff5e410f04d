"""A scenario built into a closed loop: the simulator, the design model, the estimator stage
and the controller (:func:`build`); the per-run seeds of a study (:func:`run_seeds`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from filters.base import Batched
from testbed import estimators
from testbed.design import DesignModel
from testbed.estimators import optional
from testbed.experiment.control import make_controller
from testbed.experiment.loop import ClosedLoop, EstimatorStage, check_estimate
from testbed.experiment.metrics import EpisodeMetrics
from testbed.experiment.scenario import Scenario, blame, resolve
from testbed.plugins import factory_name
from testbed.rigs.base import build_rig
from testbed.sim import build_simulator


def run_seeds(seed: int, runs: int) -> np.ndarray:
    """Per-run seeds of ``monte_carlo`` (uint32 words of ``SeedSequence(seed)``), (runs,)."""
    return np.random.SeedSequence(seed).generate_state(runs).astype(np.int64)


@dataclass
class Experiment:
    """A built scenario: the closed loop of N members and its design model."""

    scenario: Scenario
    loop: ClosedLoop
    design: DesignModel
    meta: dict[str, Any]

    def close(self) -> None:
        """Stop the physics threads."""
        self.loop.close()


def described(scenario: Scenario) -> dict[str, Any]:
    """The ``scenario`` block of the outputs: :meth:`Scenario.describe` without the fields
    left at None (TOML has no null; a missing key is the default), so that the block saved
    as TOML or JSON is a scenario file (:mod:`testbed.experiment.scenario_file`)."""
    return {k: v for k, v in scenario.describe().items() if v is not None}


def build(scenario: Scenario, num: int = 1, *, num_threads: int | None = None) -> Experiment:
    """The closed loop of ``num`` members for a scenario (everything validated first).

    Raises
    ------
    ScenarioError
        A bad or inapplicable option (a ``ValueError`` naming the field), before any
        simulation runs.
    """
    resolved = resolve(scenario)
    scenario = resolved.scenario  # the rig's and the estimator's defaults filled
    sim = build_simulator(resolved.rig, num, physics_dt_s=scenario.physics_dt_s,
                          frame_skip=scenario.frame_skip, sensors=resolved.sensors,
                          disturbance=scenario.disturbance,
                          process_noise=scenario.process_noise, setpoints=scenario.setpoints,
                          manoeuvre=scenario.manoeuvre,
                          manoeuvre_params=scenario.manoeuvre_params or None,
                          params=scenario.params or None, num_threads=num_threads,
                          profile=scenario.profile, ambient_noise=scenario.ambient_noise,
                          reset_noise_scale=scenario.reset_noise_scale)
    rig = sim.rig
    # the designer's rigs: nominal parameters; the controller's is always the paper
    # profile's (the same controller whatever the estimator's design), the estimator's
    # knows the scenario's profile unless design_profile is "paper"
    # (nominal: the scenario's nominal parameters and rig options, a twin's when given)
    control_rig = build_rig(type(rig), rig.params, physics_dt_s=scenario.physics_dt_s,
                            options=rig.options)
    matched = scenario.design_profile == "matched" and scenario.profile != "paper"
    design_rig = (build_rig(type(rig), rig.params, physics_dt_s=scenario.physics_dt_s,
                            profile=scenario.profile, options=rig.options)
                  if matched else control_rig)
    # a design's failure is the design options' when some were given (else the scenario's)
    with blame("design_options" if scenario.design_options else "scenario"):
        design = design_rig.design_model(sim.sensors, sim.dt_s, sim.known_disturbance,
                                         **scenario.design_options)
        control_design = design
        if design.augmented:
            control_design = design.extras.get("paper_design") or control_rig.design_model(
                sim.sensors, sim.dt_s, sim.known_disturbance, **scenario.design_options)
    name = factory_name(scenario.estimator)
    with blame("estimator"):
        design, fallback = estimators.design_for(scenario.estimator, design)
        est = estimators.build(scenario.estimator, design, **scenario.estimator_options)
        check_estimate(name, est.x, optional.covariance(est), design.n, "after the factory")
        if not (isinstance(est, Batched) and est.batched):
            est = estimators.PerMember([est, *(estimators.build(scenario.estimator, design,
                                                                **scenario.estimator_options)
                                               for _ in range(num - 1))])
    P = optional.covariance(est)
    prior = (np.array(design.x0, copy=True), None if P is None else np.array(design.P0))
    metrics = EpisodeMetrics(list(rig.state_names), sim.dt_s, list(sim.sensors.measured_state),
                             design.output_matrix[:, design.physical])
    stage = EstimatorStage(est, design.input_transform, metrics, prior,
                           channels=estimators.channels_for(est, design),
                           physical_index=design.physical, name=name)
    controller = make_controller(scenario.controller, control_rig, control_design,
                                 lambda t: sim.setpoints_at(t))
    meta = {"rig": rig.name, "scenario": described(scenario), "sensors": sim.sensors.describe(),
            "control_dt_s": sim.dt_s, "units": sim.units()}
    if matched:
        meta["design_profile"] = "paper (fallback: " + fallback + ")" if fallback else "matched"
        meta["design_states"] = list(design.state_names)
    design_meta = optional.design_facts(est)
    if design_meta:
        meta["design"] = design_meta
    return Experiment(scenario, ClosedLoop(sim, stage, controller), design, meta)
