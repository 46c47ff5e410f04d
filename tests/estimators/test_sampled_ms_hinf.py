"""ms-hinf's sampled-data option (``sampled=True``): the two-channel problem of Basin et al.
at the sampling period, designed as a discrete H-infinity filter on the hold-equivalent model,
with a discrete gamma that the harness compares with the sampled loop's measured gain."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from testbed import estimators
from testbed.estimators.stochastic_system import sampled_two_channel_system
from testbed.experiment import runner
from testbed.score.harness import score_pair
from testbed.score.suite import get_suite


def _helicopter_entry():
    return next(e for e in get_suite("quick") if e.name == "helicopter")


@pytest.fixture(scope="module")
def design():
    entry = _helicopter_entry()
    experiment = runner.build(entry.resolved_scenario().replace(estimator="kalman"), 1)
    experiment.close()
    return experiment.design


def test_the_sampled_problem_is_the_hold_equivalent_of_the_continuous_one(design):
    system, feedthrough, channels = sampled_two_channel_system(design)
    det = design.deterministic_index
    assert len(det) > 0
    np.testing.assert_array_equal(channels, np.concatenate([design.measurement_index, det]))
    m1 = len(design.measurement_index)
    np.testing.assert_allclose(system.C_y[m1:], design.sensors.C[det])
    G = design.disturbance_matrix
    s = G.shape[1]
    np.testing.assert_allclose(system.D_y[m1:, :s], design.sensors.Hw[det][:, :s])
    assert not np.any(system.D_y[m1:, s:])  # y2 is noise-free
    # the held w enters x(k+1) by the zero-order hold of (A, G): Van Loan's block exponential
    n, dt = design.n, design.dt_s
    M = np.zeros((n + s, n + s))
    M[:n, :n], M[:n, n:] = design.continuous.A, G
    E = expm(M * dt)
    np.testing.assert_allclose(system.A, E[:n, :n], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(system.B[:, :s], E[:n, n:], rtol=1e-9, atol=1e-12)
    assert feedthrough.shape == (len(channels), design.discrete.B.shape[1])


def test_sampled_option_states_a_discrete_gamma_it_verifies(design):
    est = estimators.build("ms-hinf", design, sampled=True)
    meta = est.design_meta
    assert meta["gamma_kind"] == "discrete" and meta["gamma_channel"] == "scenario"
    assert meta["plant_block"] is False  # the helicopter's free integrators
    assert meta["error_hinf_norm"] < meta["gamma"]
    # it reads y1 and y2: every channel here (the loop then gives it the whole vector)
    channels = estimators.channels_for(est, design)
    assert channels is None or set(design.deterministic_index) <= set(channels)
    assert est.C_y.shape[0] == len(design.measurement_index) + len(design.deterministic_index)
    continuous = estimators.build("ms-hinf", design)
    assert continuous.design_meta["gamma_kind"] == "continuous-observation"


def test_the_harness_finds_the_sampled_certificate_holding():
    entry = _helicopter_entry()
    pair = score_pair(entry.replace(runs=2), "testbed.estimators.stochastic_system:ms_hinf_sampled",
                      0)
    assert pair.skipped is None and pair.gamma_kind == "discrete"
    assert 0 < pair.worst.linear_gain <= pair.certified_gamma
