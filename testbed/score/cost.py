"""The cost model of ``testbed score``: an entry's expected run time relative to the other
entries' (:func:`entry_cost`), for scheduling the entries over workers longest first and for
the progress bar's estimate (:mod:`testbed.score.progress`)."""

from __future__ import annotations

from testbed.score.suite import SuiteEntry
from testbed.score.worst_case import RESTARTS, population

#: Fixed cost of one step of a batched closed loop, in member-steps (measured on the
#: helicopter with the Kalman filter, one thread: 0.56 ms per step of 1 member, 0.91 ms of
#: 7, 3.5 ms of 100: about 0.5 ms plus 35 us per member).
STEP_OVERHEAD = 15
#: Cost per member-step of an entry's estimators relative to the paper helicopter's, where it
#: differs (measured on the standard suite with all eight built-in estimators, 2026-11-26,
#: from the pairs' ``cpu_s`` per estimated member-step: the hardware helicopter 1.5 times
#: (its augmented design gives the ekf and ukf 10 states instead of 4), the vehicle roll
#: 0.55, the linear calibration plant 0.4; the open-loop basin-ms-hinf entry, 0.5, is not
#: told apart from the helicopter's other paper entries; the Aero's hardware entries 1.48 and
#: 1.38 on the suite of 2026-12-02, its paper entry 1.07).
ENTRY_COST_FACTORS = {("helicopter", "hardware"): 1.5, ("vehicle-roll", "paper"): 0.55,
                      ("vehicle-roll", "hardware"): 0.55, ("linear-plant", None): 0.4,
                      ("aero", "hardware"): 1.45}


def entry_cost(entry: SuiteEntry) -> float:
    """A rough estimate of an entry's run time, relative to the other entries', for
    scheduling the entries over workers longest first (:func:`testbed.score.harness.run_entries`).

    Member-steps of the Monte Carlo and of the worst-case search's closed-loop runs (the
    impulse response over ``K / 4 + K`` steps with the baseline and, typically, one channel,
    then ``2 + generations`` runs of ``K`` steps of the candidates) plus
    :data:`STEP_OVERHEAD` per step, times :data:`ENTRY_COST_FACTORS`.
    """
    if entry.unavailable():
        return 0.0
    scenario = entry.scenario
    rig = scenario.rig if isinstance(scenario.rig, str) else scenario.rig.name
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
