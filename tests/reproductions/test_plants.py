"""Plain plants: the paper's linear model of the mean-square H-infinity example (a degree-1
PolynomialPlant) and the rollout loop."""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from filters import PolynomialModel
from testbed.experiment.numpy_plant import rollout
from testbed.reproductions.basin_ms_hinf.helicopter import _plant
from testbed.reproductions.basin_ms_hinf.scenario import MsHinfHelicopterScenario
from testbed.reproductions.basin_polynomial.plant import PolynomialPlant


def test_noise_free_integration_is_fourth_order():
    s = MsHinfHelicopterScenario()
    m = s.model

    def rhs(t, x):
        return m.A @ x + m.B @ s.u + m.G @ s.w(t)

    ref = solve_ivp(rhs, (0, 2.0), s.x0, rtol=1e-12, atol=1e-12).y[:, -1]
    errors = []
    for dt in (0.2, 0.1, 0.05):
        x = rollout(_plant(s, dt, s.w), s.x0, int(round(2.0 / dt)), u=lambda k: s.u).x
        errors.append(np.abs(x[-1] - ref).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 3.5) & (orders < 4.5)), orders


def test_noise_adds_b_b_t_dt_to_the_state_and_h_h_t_over_dt_to_y1():
    s, dt = MsHinfHelicopterScenario(), 0.1
    m, plant, rng = s.model, _plant(s, dt, noisy=True), np.random.default_rng(0)
    runs = [rollout(plant, np.zeros(4), 1, noise=rng) for _ in range(4000)]
    x = np.array([r.x[-1] for r in runs])
    y1 = np.array([r.y[-1, :2] for r in runs])
    for sample, cov in ((x, m.b @ m.b.T * dt), (y1, m.h @ m.h.T / dt)):  # 4000 draws: ~3 %
        np.testing.assert_allclose(np.cov(sample.T), cov, atol=0.1 * np.abs(cov).max())


def test_interval_average_output():
    """x' = 1 from 0: the average of x over [k dt, (k+1) dt] is (k + 1/2) dt."""
    plant = PolynomialPlant(PolynomialModel(B=[[0.0]], C=[[1.0]], D=[[0.0]], L=[[1.0]],
                                            E=[[1.0]]), dt_s=0.1)
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

    plant = PolynomialPlant(PolynomialModel(B=[[0.0]], C=[[1.0], [2.0]], D=[[0.0], [0.0]],
                                            L=[[1.0]], E=[[1.0]]), dt_s=0.1)
    fail, keep = Failing(3), Failing(99)
    run = rollout(plant, np.zeros(1), 6, u=lambda k: np.ones(1),
                  estimators={"fail": fail, "keep": (keep, lambda y: y[1:])})
    assert run.failures["fail"][0] == 3 and run.estimates["fail"].shape == (4, 1)
    assert run.estimates["keep"].shape == (7, 1) and "keep" not in run.failures
    np.testing.assert_allclose(run.estimates["keep"][-1, 0], 2 * run.y[:, 0].sum())
    assert fail.x[0] == run.estimates["fail"][-1, 0]  # the state before the failing step
    assert keep.seen == [(1,)] * 6 and run.x.shape == (7, 1) and run.escape is None
