"""The ROS2 integrator (filters.stiff) against independent references: the matrix exponential
(convergence order 2), a stiff relaxation (L-stability, where RK4 at the same step diverges),
and the polynomial H-infinity filter integrated by RK4 with fine substeps."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from filters.errors import FiniteEscapeError
from filters.hinf_polynomial import PolynomialHInfFilter
from filters.polynomial_model import PolynomialModel
from filters.stiff import difference_solver, rosenbrock2


def linear(A):
    return lambda t, s: s @ A.T


def ros(A, s0, h, steps, after=None):
    return rosenbrock2(linear(A), s0, 0.0, h, steps,
                       difference_solver(linear(A), np.ones(s0.shape[-1])), after)


@pytest.mark.parametrize("n", [1, 3, 5])
def test_order_two_on_linear_systems(rng, n):
    """Error at t = 1 against expm(A) s0 falls by 4 when the step halves (any dimension),
    with a batch of initial states."""
    A = rng.normal(size=(n, n)) - 2.0 * np.eye(n)
    s0 = rng.normal(size=(3, n))
    exact = s0 @ expm(A).T
    errors = []
    for substeps in (64, 128, 256):
        s = ros(A, s0, 1.0 / substeps, substeps)
        errors.append(np.abs(s - exact).max())
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 1.85) & (orders < 2.2)), orders


def test_l_stable_on_a_stiff_system(rng):
    """A = V diag(-1e6, -1) V^-1, h = 0.05 (h |lambda_fast| = 5e4): ROS2 damps the fast mode
    (L-stable) and follows the slow one, expm(A t) s0, with order 2; RK4 at the same step
    diverges."""
    V = np.array([[1.0, 0.3], [0.2, 1.0]])
    A = V @ np.diag([-1e6, -1.0]) @ np.linalg.inv(V)
    s0, h, steps = np.array([3.0, -1.0]), 0.05, 40
    exact = expm(A * h * steps) @ s0
    s = ros(A, s0, h, steps)
    error = np.abs(s - exact).max()
    assert error < 1e-2 * np.abs(exact).max()
    half = ros(A, s0, h / 2, 2 * steps)
    assert 3.0 < error / np.abs(half - exact).max() < 5.0  # still order 2
    r = s0.copy()
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(steps):
            k1 = A @ r
            k2 = A @ (r + h / 2 * k1)
            k3 = A @ (r + h / 2 * k2)
            k4 = A @ (r + h * k3)
            r = r + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    assert not np.abs(r).max() < 1e3


def test_after_substep_sees_every_substep_and_can_stop():
    times = []

    def after(i, t, s):
        times.append((i, t))
        if i == 2:
            raise RuntimeError("stop")
        return s

    with pytest.raises(RuntimeError):
        rosenbrock2(linear(-np.eye(2)), np.ones(2), 1.0, 0.1, 5,
                    difference_solver(linear(-np.eye(2)), np.ones(2)), after)
    assert [i for i, _ in times] == [0, 1, 2]
    np.testing.assert_allclose([t for _, t in times], [1.1, 1.2, 1.3])


def stiff_model(n, rng, accuracy):
    """A random stable cubic system observed in every state with measurement intensity
    1/accuracy^2 (the Riccati rate ~ accuracy)."""
    a1 = rng.normal(size=(n, n)) - 2.0 * np.eye(n)
    a2 = 0.05 * rng.normal(size=(n, n, n))
    a3 = np.zeros((n, n, n, n))
    for i in range(n):
        a3[i, i, i, i] = -0.1
    B = np.hstack([np.eye(n), np.zeros((n, n))])
    C = accuracy * np.eye(n)
    D = np.hstack([np.zeros((n, n)), np.eye(n)])
    return PolynomialModel(a1=a1, a2=a2, a3=a3, B=B, C=C, D=D, L=np.eye(n))


def run(model, x0, ys, substeps, method="rk4"):
    filt = PolynomialHInfFilter(model, 20.0, np.eye(model.n), 0.01, x0, substeps=substeps,
                                method=method)
    for y in ys:
        filt.step(y)
    return filt


@pytest.mark.parametrize("n", [2, 4])
def test_filter_rosenbrock_converges_to_rk4(rng, n):
    """PolynomialHInfFilter with method="rosenbrock" on a non-stiff system (batch of 3,
    30 periods of 10 ms): its error against RK4 with 64 substeps falls with order 2."""
    model = stiff_model(n, rng, 1.0)
    x0, ys = rng.normal(size=(3, n)), rng.normal(size=(30, 3, n))
    ref = run(model, x0, ys, 64)
    errors = [np.abs(run(model, x0, ys, k, "rosenbrock").x - ref.x).max() for k in (4, 8)]
    assert errors[1] < 1e-4 * np.abs(ref.x).max()
    assert 3.0 < errors[0] / errors[1] < 5.0


@pytest.mark.parametrize("n", [2, 4])
def test_filter_rosenbrock_on_a_stiff_riccati_equation(rng, n):
    """Accurate observations (Riccati rate ~ 2e4 1/s, dt = 10 ms): 12 ROS2 substeps match RK4
    with 400 to 1 % of the estimate's size and 1e-5 of P's (P symmetric), with order 2 (24
    substeps: error / 4), while RK4 with 12 escapes."""
    model = stiff_model(n, rng, 100.0)
    x0, ys = rng.normal(size=(3, n)), rng.normal(size=(30, 3, n))
    ref = run(model, x0, ys, 400)
    ros = run(model, x0, ys, 12, "rosenbrock")
    error = np.abs(ros.x - ref.x).max()
    assert error < 1e-2 * np.abs(ref.x).max()
    assert np.abs(ros.P - ref.P).max() < 1e-5 * np.abs(ref.P).max()
    np.testing.assert_array_equal(ros.P, np.swapaxes(ros.P, -1, -2))
    assert error / np.abs(run(model, x0, ys, 24, "rosenbrock").x - ref.x).max() > 3.0
    with pytest.raises(FiniteEscapeError), np.errstate(all="ignore"):
        run(model, x0, ys, 12)


def test_filter_method_is_validated():
    model = PolynomialModel(a1=[[0.0]], B=[[1.0, 0.0]], C=[[1.0]], D=[[0.0, 1.0]], L=[[1.0]])
    with pytest.raises(ValueError, match="method must be one of"):
        PolynomialHInfFilter(model, 1.0, [[1.0]], 1e-3, method="euler")
    with pytest.raises(ValueError, match="jacobian_every must be"):
        PolynomialHInfFilter(model, 1.0, [[1.0]], 1e-3, jacobian_every=0)


def test_a_frozen_jacobian_keeps_order_two(rng):
    """jacobian_every = substeps (one Jacobian for the call, a W-method): still order 2 on
    a linear system (any J keeps the order), and exact J = same result as every substep."""
    A = rng.normal(size=(3, 3)) - 2.0 * np.eye(3)
    s0 = rng.normal(size=3)
    exact = expm(A) @ s0

    def frozen(steps):
        return rosenbrock2(linear(A), s0, 0.0, 1.0 / steps, steps,
                           difference_solver(linear(A), np.ones(3)), None, steps)

    errors = [np.abs(frozen(k) - exact).max() for k in (64, 128)]
    assert 3.5 < errors[0] / errors[1] < 4.5
    np.testing.assert_allclose(frozen(64), ros(A, s0, 1.0 / 64, 64), rtol=1e-6)


def test_integrator_for_switches_at_the_stated_limits():
    from filters.stiff import RK4_MAX_SUBSTEPS, TRANSIENT_SUBSTEPS, integrator_for

    assert integrator_for(3) == ("rk4", 3, 1)
    assert integrator_for(RK4_MAX_SUBSTEPS) == ("rk4", RK4_MAX_SUBSTEPS, 1)
    assert integrator_for(170) == ("rosenbrock", 14, 14)  # one Jacobian per interval
    assert integrator_for(TRANSIENT_SUBSTEPS) == ("rosenbrock", 16, 16)
    assert integrator_for(TRANSIENT_SUBSTEPS + 1) == ("rk4", TRANSIENT_SUBSTEPS + 1, 1)
