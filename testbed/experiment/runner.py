"""The runner: one scenario executed once (``run``), batched (``mc``) or over a grid (``sweep``).

All three build the same :class:`~testbed.experiment.loop.ClosedLoop` from a
:class:`~testbed.experiment.scenario.Scenario`; ``run`` is a batch of one. Run ``i`` of
``monte_carlo(scenario, runs=R)`` uses the seed ``run_seeds(scenario.seed, R)[i]`` (the
``i``-th word of ``numpy.random.SeedSequence(seed).generate_state(R)``: independent of the
batch size, prefix-stable, no overlap between nearby base seeds) and equals, bitwise,
``run(scenario.replace(seed=that seed))``.

The public face of :mod:`~testbed.experiment.build` (a scenario built into a closed loop),
:mod:`~testbed.experiment.episode` (one run), :mod:`~testbed.experiment.study` (Monte Carlo,
the memory estimate) and :mod:`~testbed.experiment.sweep` (grids); the ``.npz`` stream of a
study is :mod:`testbed.io.trajectory_stream`.
"""

from testbed.experiment.build import Experiment, build, described, run_seeds
from testbed.experiment.episode import RECORD_MAX_ROWS, run
from testbed.experiment.scenario import with_defaults
from testbed.experiment.study import (
    DEFAULT_BATCH_SIZE,
    TIMING_KEYS,
    StudyTooLarge,
    available_memory,
    check_study_size,
    monte_carlo,
    study_bytes,
)
from testbed.experiment.sweep import (
    GRID_FIELDS,
    check_grid_name,
    grid_points,
    point_scenario,
    sweep,
    without_timings,
)

__all__ = ["DEFAULT_BATCH_SIZE", "GRID_FIELDS", "RECORD_MAX_ROWS", "TIMING_KEYS", "Experiment",
           "StudyTooLarge", "available_memory", "build", "check_grid_name", "check_study_size",
           "described", "grid_points", "monte_carlo", "point_scenario", "run", "run_seeds",
           "study_bytes", "sweep", "with_defaults", "without_timings"]
