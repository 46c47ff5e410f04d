"""Plain plants: the linear SDE plant of the mean-square H-infinity example."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from testbed.experiment.numpy_plant import rollout
from testbed.reproductions.basin_ms_hinf.plant import LinearSDEPlant
from testbed.reproductions.basin_ms_hinf.scenario import MsHinfHelicopterScenario


def test_noise_free_integration_is_fourth_order():
    s = MsHinfHelicopterScenario()
    m = s.model

    def rhs(t, x):
        return m.A @ x + m.B @ s.u + m.G @ s.w(t)

    ref = solve_ivp(rhs, (0, 2.0), s.x0, rtol=1e-12, atol=1e-12).y[:, -1]
    errors = []
    for dt in (0.2, 0.1, 0.05):
        plant = LinearSDEPlant(m.A, m.B, m.G, m.b, s.w, dt)
        x = rollout(plant, s.x0, int(round(2.0 / dt)), u=lambda k: s.u).x
        errors.append(np.abs(x[-1] - ref).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 3.5) & (orders < 4.5)), orders


def test_noise_adds_b_b_t_dt_covariance():
    A = np.zeros((2, 2))
    plant = LinearSDEPlant(A, np.zeros((2, 1)), np.zeros((2, 1)), np.array([[0.0], [2.0]]),
                           lambda t: np.zeros(1), 0.1)
    rng = np.random.default_rng(0)
    finals = [rollout(plant, np.zeros(2), 10, noise=rng).x[-1] for _ in range(4000)]
    assert np.var(np.array(finals)[:, 1]) == pytest.approx(4.0 * 1.0, rel=0.08)


def test_bad_arguments():
    A = np.zeros((2, 2))
    with pytest.raises(ValueError, match="dt_s"):
        LinearSDEPlant(A, A, A, A, lambda t: np.zeros(2), -1.0)
    with pytest.raises(ValueError, match="x0"):
        rollout(LinearSDEPlant(A, A, A, A, lambda t: np.zeros(2), 0.1), np.zeros(3), 10)


def test_interval_average_output():
    """x' = 1 from 0: the average of x over [k dt, (k+1) dt] is (k + 1/2) dt."""
    plant = LinearSDEPlant(np.zeros((1, 1)), np.ones((1, 1)), np.zeros((1, 1)),
                           np.zeros((1, 1)), lambda t: np.zeros(1), 0.1)
    run = rollout(plant, np.zeros(1), 5, u=lambda k: np.ones(1))
    np.testing.assert_allclose(run.y[:, 0], (np.arange(5) + 0.5) * 0.1, atol=1e-14)
    np.testing.assert_allclose(run.x[:, 0], np.arange(6) * 0.1, atol=1e-14)


def test_rollout_records_a_failing_estimator_and_selects_channels():
    """An estimator's FilterError ends its rows at that step (its state kept), the others go
    on; ``select`` hands an estimator only its channels."""
    from filters.errors import FiniteEscapeError

    class Failing:
        P = None

        def __init__(self, fail_at: int):
            self.x, self.fail_at, self.seen = np.zeros(1), fail_at, []

        def step(self, y, u=None):
            self.seen.append(y.shape)
            if len(self.seen) > self.fail_at:
                raise FiniteEscapeError("escaped", time=1.0, quantity="x", value=None)
            self.x = self.x + y[..., :1]
            return self.x

    plant = LinearSDEPlant(np.zeros((1, 1)), np.ones((1, 1)), np.zeros((1, 1)),
                           np.zeros((1, 1)), lambda t: np.zeros(1), 0.1,
                           output=lambda t, x: np.concatenate([x, 2 * x]))
    fail, keep = Failing(3), Failing(99)
    run = rollout(plant, np.zeros(1), 6, u=lambda k: np.ones(1),
                  estimators={"fail": fail, "keep": (keep, lambda y: y[1:])})
    assert run.failures["fail"][0] == 3 and run.estimates["fail"].shape == (4, 1)
    assert run.estimates["keep"].shape == (7, 1) and "keep" not in run.failures
    np.testing.assert_allclose(run.estimates["keep"][-1, 0], 2 * run.y[:, 0].sum())
    assert fail.x[0] == run.estimates["fail"][-1, 0]  # the state before the failing step
    assert keep.seen == [(1,)] * 6 and run.x.shape == (7, 1) and run.escape is None
