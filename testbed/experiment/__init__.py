"""Experiments: a scenario built into a closed loop (rig, sensors, controller, estimator), run
once, as a Monte Carlo study or a sweep, in real time, or replayed on a recording."""
