"""Central H-infinity filters for polynomial systems (Basin, Shi & Calderon-Alvarez): each
against something
independent (Gauss-Hermite quadrature, the paper's printed special case, the linear central
H-infinity filter of filters.hinf_mean_square, a closed-form Riccati solution, a transformed
problem)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from numpy.polynomial.hermite_e import hermegauss

from filters.base import Estimator
from filters.errors import FiniteEscapeError
from filters.hinf_mean_square import MeanSquareHInfFilter
from filters.hinf_polynomial import (
    LinearizedHInfFilter,
    NonOrthonormalPolynomialHInfFilter,
    PolynomialHInfFilter,
    f_hat,
    g_hat,
    moment_matrix,
)
from filters.polynomial_model import EscapeTest, PolynomialModel, symmetrize_tensor

GAMMA = 1.05


def paper_model(L):
    """(22)-(23) written out here (independently of
    testbed.reproductions.basin_polynomial.scenario)."""
    a1 = np.array([[0.0, 1.0], [0.0, 0.0]])
    a2 = np.zeros((2, 2, 2))
    a2[1, 1, 1] = 0.1

    def a3(t):
        out = np.zeros((2, 2, 2, 2))
        out[1, 1, 1, 1] = 0.1 + 0.1 * np.sin(50 * t)
        return out

    return PolynomialModel(a1=a1, a2=a2, a3=a3, B=[[0.0, 0.0], [1.0, 0.0]], C=[[1.0, 0.0]],
                           D=[[0.0, 1.0]], L=L)


def printed_25_26(x, P, y, t, g=GAMMA):
    """Eqs. (25)-(26) exactly as printed."""
    c = 0.1 + 0.1 * np.sin(50 * t)
    f1, f2 = x
    P11, P12, P22 = P[0, 0], P[0, 1], P[1, 1]
    k = 1 - g**-2
    inn = y[0] - f1
    dx = np.array([f2 + P11 * inn,
                   0.1 * f2**2 + 3 * c * P22 * f2 + 0.1 * P22 + c * f2**3 + P12 * inn])
    d11 = 2 * P12 - k * P11**2
    d12 = (P22 + 3 * c * f2**2 * P12 + 0.2 * f2 * P12 + 3 * c * P22 * P12
           - k * P11 * P12)
    d22 = 1 + 6 * c * f2**2 * P22 + 0.4 * f2 * P22 + 6 * c * P22**2 - k * P12**2
    return dx, np.array([[d11, d12], [d12, d22]])


def printed_27_28(m, P, y, t, g=GAMMA):
    """Eqs. (27)-(28) exactly as printed."""
    c3 = 0.3 + 0.3 * np.sin(50 * t)
    m1, m2 = m
    K11, K12, K22 = P[0, 0], P[0, 1], P[1, 1]
    k = 1 - g**-2
    inn = y[0] - m1
    dm = np.array([m2 + K11 * inn, 0.2 * m2**2 + c3 * m2**3 + K12 * inn])
    d11 = 2 * K12 - k * K11**2
    d12 = K22 + 0.2 * m2 * K12 + c3 * m2**2 * K12 - k * K11 * K12
    d22 = 1 + 0.4 * m2 * K22 + 2 * c3 * m2**2 * K22 - k * K12**2
    return dm, np.array([[d11, d12], [d12, d22]])


def random_point(rng, n=2):
    x = rng.normal(scale=2.0, size=n)
    A = rng.normal(size=(n, n))
    P = A @ A.T + 0.1 * np.eye(n)
    return x, P, rng.normal(size=1), float(rng.uniform(0, 3))


def rel_err(a, b):
    return float(np.max(np.abs(np.asarray(a) - b)) / max(1.0, np.max(np.abs(b))))


# ------------------------------------------------------------------ (14)-(15)
def test_f_hat_g_hat_equal_gaussian_expectations_by_quadrature(rng):
    """(14)-(15) are E[f] and E[f e^T] + E[e f^T] under N(m, P), for general (non-symmetric)
    tensors: tensor Gauss-Hermite quadrature is exact for these degree <= 4 integrands."""
    n = 3
    a0, a1 = rng.normal(size=n), rng.normal(size=(n, n))
    a2, a3 = rng.normal(size=(n, n, n)), rng.normal(size=(n, n, n, n))
    model = PolynomialModel(a0, a1, a2, a3, B=np.eye(n), C=np.eye(n)[:1], D=np.zeros((1, n)),
                            L=np.eye(n))
    c = model.at(0.0)
    nodes, weights = hermegauss(4)
    weights = weights / math.sqrt(2 * math.pi)
    grid = np.array(np.meshgrid(*[nodes] * n, indexing="ij")).reshape(n, -1).T
    wq = np.prod(np.array(np.meshgrid(*[weights] * n, indexing="ij")).reshape(n, -1), axis=0)
    for _ in range(3):
        m, P, _, _ = random_point(rng, n)
        e = grid @ np.linalg.cholesky(P).T  # samples of e ~ N(0, P)
        x = m + e
        f = (a0 + x @ a1.T + np.einsum("kij,si,sj->sk", a2, x, x)
             + np.einsum("kijl,si,sj,sl->sk", a3, x, x, x))  # raw, unsymmetrized tensors
        Ef = wq @ f
        Efe = np.einsum("s,sk,sl->kl", wq, f, e)
        assert rel_err(f_hat(c, m, P), Ef) < 1e-12
        assert rel_err(moment_matrix(c, m, P) @ P, Efe) < 1e-12
        assert rel_err(g_hat(c, m, P), Efe + Efe.T) < 1e-12
        assert rel_err(c.f(x), f) < 1e-12
        # Jacobian by central differences
        h = 1e-6
        J = np.array([(c.f(m + h * d) - c.f(m - h * d)) / (2 * h) for d in np.eye(n)]).T
        assert rel_err(c.jacobian(m), J) < 1e-7


def test_symmetrize_tensor_keeps_the_polynomial(rng):
    a3 = rng.normal(size=(2, 2, 2, 2))
    s = symmetrize_tensor(a3)
    x = rng.normal(size=2)
    assert np.allclose(np.einsum("kijl,i,j,l->k", a3, x, x, x),
                       np.einsum("kijl,i,j,l->k", s, x, x, x), atol=1e-14)
    assert np.allclose(s, s.transpose(0, 2, 1, 3)) and np.allclose(s, s.transpose(0, 3, 2, 1))


# --------------------------------------------------- reduction to the example
def test_general_filter_reduces_to_printed_25_26(rng):
    """Theorem 1 written once for tensors equals the printed (25)-(26) (which is (13) with
    L = C = [1 0]); with the example's L = I the difference is gamma^-2 P e2 e2^T P."""
    filt = PolynomialHInfFilter(paper_model(L=[[1.0, 0.0]]), GAMMA, np.eye(2), 1e-3)
    full = PolynomialHInfFilter(paper_model(L=np.eye(2)), GAMMA, np.eye(2), 1e-3)
    for _ in range(50):
        x, P, y, t = random_point(rng)
        dx, dP = filt.derivatives(x, P, y, t)
        ref_dx, ref_dP = printed_25_26(x, P, y, t)
        assert rel_err(dx, ref_dx) < 1e-12
        assert rel_err(dP, ref_dP) < 1e-12
        dx_i, dP_i = full.derivatives(x, P, y, t)
        assert rel_err(dx_i, ref_dx) < 1e-12
        Pe2 = P[:, 1:]
        assert rel_err(dP_i - dP, GAMMA**-2 * Pe2 @ Pe2.T) < 1e-12


def test_linearized_filter_reduces_to_printed_27_28(rng):
    model = paper_model(L=[[1.0, 0.0]])
    jac = LinearizedHInfFilter(model, GAMMA, np.eye(2), 1e-3, state_equation="jacobian")
    sysf = LinearizedHInfFilter(model, GAMMA, np.eye(2), 1e-3)
    assert sysf.state_equation == "system"
    for _ in range(50):
        x, P, y, t = random_point(rng)
        dx, dP = jac.derivatives(x, P, y, t)
        ref_dx, ref_dP = printed_27_28(x, P, y, t)
        assert rel_err(dx, ref_dx) < 1e-12
        assert rel_err(dP, ref_dP) < 1e-12
        dx_s, dP_s = sysf.derivatives(x, P, y, t)
        c = 0.1 + 0.1 * np.sin(50 * t)
        expected = ref_dx[1] - (0.2 * x[1] ** 2 + 3 * c * x[1] ** 3) + \
            (0.1 * x[1] ** 2 + c * x[1] ** 3)
        assert rel_err(dx_s, [ref_dx[0], expected]) < 1e-12
        assert rel_err(dP_s, ref_dP) < 1e-12


# --------------------------------------------------------------- linear case
def linear_model(L=None):
    A = np.array([[0.0, 1.0], [-2.0, -0.5]])
    B = np.array([[0.3, 0.0, 0.0], [0.5, 1.0, 0.0]])
    D = np.array([[0.0, 0.0, 1.0]])  # D B^T = 0, D D^T = 1: (C3)
    C = np.array([[1.0, 0.2]])
    L = np.eye(2) if L is None else L
    return A, B, C, D, L


def test_linear_case_equals_linear_central_hinf_filter(rng):
    """a2 = a3 = 0: Theorem 1 (and the linearized filter) equal the linear central
    H-infinity filter, here MeanSquareHInfFilter with an inert stochastic channel (C1 = 0):
    m' = A m + S C2^T (H H^T)^-1 (y2 - C2 m), S' = A S + S A^T + G G^T - S [C2^T (H H^T)^-1 C2
    - gamma^-2 L^T L] S."""
    A, B, C, D, L = linear_model()
    gamma, R, dt = 2.0, np.array([[2.0, 0.3], [0.3, 1.0]]), 0.01
    x0 = np.array([0.5, -1.0])
    model = PolynomialModel(a1=A, B=B, C=C, D=D, L=L)
    poly = PolynomialHInfFilter(model, gamma, R, dt, x0, substeps=2)
    lin = LinearizedHInfFilter(model, gamma, R, dt, x0, substeps=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (C1) with b = 0 is reported, irrelevant here
        ref = MeanSquareHInfFilter(A, None, np.zeros((1, 2)), np.eye(1), C, D, B,
                                   np.zeros((2, 1)), L, gamma, R, x0, np.eye(2), dt, substeps=2)
    np.testing.assert_allclose(poly.P, ref.S, rtol=0, atol=1e-15)
    for _ in range(300):
        y = rng.normal(size=1)
        poly.step(y)
        lin.step(y)
        ref.step(np.concatenate([[0.0], y]))
    np.testing.assert_allclose(poly.x, ref.x, rtol=0, atol=1e-11)
    np.testing.assert_allclose(poly.P, ref.S, rtol=0, atol=1e-11)
    np.testing.assert_allclose(lin.x, poly.x, rtol=0, atol=1e-13)
    np.testing.assert_allclose(lin.P, poly.P, rtol=0, atol=1e-13)


@pytest.mark.parametrize(("method", "rel", "late_s"), [("rk4", 1e-10, 0.0),
                                                     ("rosenbrock", 1e-5, 1e-3)])
def test_scalar_riccati_closed_form_and_escape_of_P(method, rel, late_s):
    """n = 1, A = 0, C = 0, B B^T = 1, L = 1, gamma = 1: P' = 1 + P^2, P(0) = 1, so
    P = tan(t + pi/4), which escapes at pi/4. Detected by the growth test, never NaN, with
    RK4 and with ROS2 (order 2: a looser closed form, the escape up to a step late)."""
    model = PolynomialModel(a1=[[0.0]], B=[[1.0, 0.0]], C=[[0.0]], D=[[0.0, 1.0]], L=[[1.0]])
    filt = PolynomialHInfFilter(model, 1.0, [[1.0]], 1e-3, substeps=2, method=method)
    for _ in range(500):
        filt.step([0.0])
    assert filt.P[0, 0] == pytest.approx(math.tan(0.5 + math.pi / 4), rel=rel)
    with pytest.raises(FiniteEscapeError) as info:
        for _ in range(1000):
            filt.step([0.0])
    err = info.value
    assert err.quantity == "P"
    assert math.pi / 4 - 0.01 < err.time <= math.pi / 4 + late_s
    assert np.isfinite(filt.P).all() and filt.t_s < err.time  # unchanged by the failed step
    assert "extrapolated blow-up" in str(err)


def test_escape_of_the_estimate_is_reported_as_x():
    """x' = x^3 (+ 3 x P with P ~ 1e-12) from x = 1 escapes at t = 1/2. With a growth floor
    below the magnitude where RK4 (h = 1 ms) stops resolving x (~30) the growth test names x;
    with the default floor (100) the step that crosses it blows up x and P together."""
    a3 = np.ones((1, 1, 1, 1))
    model = PolynomialModel(a3=a3, B=[[0.0]], C=[[1e-3]], D=[[1.0]], L=[[1.0]], n=1)
    for escape in (EscapeTest(growth_floor=10.0), None):
        filt = PolynomialHInfFilter(model, math.inf, [[1e12]], 1e-3, x0=[1.0], escape=escape)
        with pytest.raises(FiniteEscapeError) as info:
            for _ in range(1000):
                filt.step([0.0])
        assert 0.49 < info.value.time <= 0.501
        assert np.isfinite(filt.x).all() and np.isfinite(filt.P).all()
        if escape is not None:
            assert info.value.quantity == "x"
            assert "growth test" in str(info.value)


def test_escape_test_bound_growth_floor_and_nan():
    esc = EscapeTest(bound=1e3, growth_rtol=0.1, growth_floor=10.0)
    mag = esc.check("x", 5.0, np.array([1.0, 8.0]), time=1.0, step_s=0.1, core_ndim=1)
    assert mag == 8.0  # +60 % but below the floor
    esc.check("x", 100.0, np.array([105.0]), time=1.0, step_s=0.1, core_ndim=1)
    with pytest.raises(FiniteEscapeError, match="growth test") as info:
        esc.check("x", 100.0, np.array([120.0]), time=2.0, step_s=0.1, core_ndim=1)
    assert info.value.time == 2.0 and "t ~ 2.5" in str(info.value)  # 0.1 * 100 / 20 ahead
    with pytest.raises(FiniteEscapeError, match="bound test"):
        esc.check("P", 999.0, np.full((2, 2), 1001.0), time=0.0, step_s=0.1, core_ndim=2)
    with pytest.raises(FiniteEscapeError, match="bound test"):
        esc.check("P", 1.0, np.array([[np.nan, 0.0], [0.0, 1.0]]), time=0.0, step_s=0.1,
                  core_ndim=2)
    batch = np.array([[1.0, 2.0], [50.0, 0.0]])  # batch of two vectors
    with pytest.raises(FiniteEscapeError, match=r"batch index \(1,\)"):
        esc.check("x", np.array([2.0, 20.0]), batch, time=0.0, step_s=0.1, core_ndim=1)
    with pytest.raises(ValueError, match="growth_rtol"):
        EscapeTest(growth_rtol=0.0)


# ------------------------------------------------------------ Corollary 1
def test_nonorthonormal_equals_theorem1_on_the_transformed_problem(rng):
    """Corollary 1 with D B^T != 0, D D^T != I equals Theorem 1 applied to the equivalent
    orthonormal problem: a1 - B D^T W C, input B D^T W y, disturbance B (I - D^T W D) B^T,
    whitened observation Lc^-1 y (W = (D D^T)^-1 = Lc^-T Lc^-1)."""
    n = 2
    a1 = np.array([[0.0, 1.0], [-1.0, -0.3]])
    a2 = 0.05 * rng.normal(size=(n, n, n))
    a3 = -0.02 * np.abs(rng.normal(size=(n, n, n, n)))
    B = np.array([[0.2, 0.1, 0.0], [0.4, 0.3, 0.5]])
    D = np.array([[0.3, 0.5, 0.0], [0.1, 0.0, 0.7]])
    C = np.array([[1.0, 0.0], [0.5, 1.0]])
    L = np.array([[0.0, 1.0]])
    gamma, R, dt = 3.0, np.eye(2), 0.01
    y = np.array([0.3, -0.2])
    corollary = NonOrthonormalPolynomialHInfFilter(
        PolynomialModel(a1=a1, a2=a2, a3=a3, B=B, C=C, D=D, L=L), gamma, R, dt, substeps=2)
    with pytest.raises(ValueError, match="C3"):
        PolynomialHInfFilter(PolynomialModel(a1=a1, B=B, C=C, D=D, L=L), gamma, R, dt)
    W = np.linalg.inv(D @ D.T)
    Lc = np.linalg.cholesky(D @ D.T)
    Q = B @ (np.eye(3) - D.T @ W @ D) @ B.T
    ev, V = np.linalg.eigh(0.5 * (Q + Q.T))
    Bq = V * np.sqrt(np.clip(ev, 0, None))
    m = C.shape[0]
    B_t = np.hstack([Bq, np.zeros((n, m))])
    D_t = np.hstack([np.zeros((m, n)), np.eye(m)])
    transformed = PolynomialModel(a0=B @ D.T @ W @ y, a1=a1 - B @ D.T @ W @ C, a2=a2, a3=a3,
                                  B=B_t, C=np.linalg.solve(Lc, C), D=D_t, L=L)
    theorem1 = PolynomialHInfFilter(transformed, gamma, R, dt, substeps=2)
    y_t = np.linalg.solve(Lc, y)
    for _ in range(200):
        corollary.step(y)
        theorem1.step(y_t)
    np.testing.assert_allclose(corollary.x, theorem1.x, rtol=0, atol=1e-11)
    np.testing.assert_allclose(corollary.P, theorem1.P, rtol=0, atol=1e-11)


def test_corollary_equals_theorem_under_c3(rng):
    model = paper_model(L=np.eye(2))
    a = PolynomialHInfFilter(model, GAMMA, np.eye(2), 1e-3)
    b = NonOrthonormalPolynomialHInfFilter(model, GAMMA, np.eye(2), 1e-3)
    for _ in range(100):
        y = rng.normal(size=1)
        a.step(y)
        b.step(y)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)


# ------------------------------------------------------------------ protocol
def test_batch_equals_single_filters(rng):
    model = paper_model(L=np.eye(2))
    x0 = rng.normal(scale=0.3, size=(3, 2))
    ys = rng.normal(size=(40, 3, 1))
    for cls in (PolynomialHInfFilter, LinearizedHInfFilter):
        batch = cls(model, GAMMA, np.eye(2), 1e-3, x0)
        singles = [cls(model, GAMMA, np.eye(2), 1e-3, x0[i]) for i in range(3)]
        for y in ys:
            batch.step(y)
            for i, f in enumerate(singles):
                f.step(y[i])
        assert batch.x.shape == (3, 2) and batch.P.shape == (3, 2, 2)
        for i, f in enumerate(singles):
            np.testing.assert_allclose(batch.x[i], f.x, rtol=0, atol=1e-14)
            np.testing.assert_allclose(batch.P[i], f.P, rtol=0, atol=1e-14)


def test_protocol_reset_input_and_validation():
    model = paper_model(L=np.eye(2)).replace(E=[[0.0], [1.0]])
    filt = PolynomialHInfFilter(model, GAMMA, np.eye(2), 1e-3)
    assert isinstance(filt, Estimator) and filt.name == "poly-hinf"
    assert LinearizedHInfFilter.name == "linearized-hinf"
    np.testing.assert_array_equal(filt.x, [0.0, 0.0])
    np.testing.assert_array_equal(filt.P, np.eye(2))
    x1 = filt.step([0.5], u=[2.0]).copy()
    no_u = PolynomialHInfFilter(model, GAMMA, np.eye(2), 1e-3)
    no_u.step([0.5])
    assert x1[1] - no_u.x[1] == pytest.approx(2.0 * 1e-3, rel=1e-3)  # E u enters dx2/dt
    assert filt.t_s == pytest.approx(1e-3)
    before = (filt.x.copy(), filt.P.copy(), filt.t_s)
    for bad in ([np.nan], [1.0, 2.0], "a"):
        with pytest.raises(ValueError, match="y"):
            filt.step(bad)
    np.testing.assert_array_equal(filt.x, before[0])
    assert filt.t_s == before[2]
    filt.reset([1.0, 1.0], 2 * np.eye(2))
    assert filt.t_s == 0.0 and filt.P[0, 0] == 2.0
    with pytest.raises(ValueError, match="gamma"):
        PolynomialHInfFilter(model, 0.0, np.eye(2), 1e-3)
    with pytest.raises(ValueError, match="R"):
        PolynomialHInfFilter(model, GAMMA, -np.eye(2), 1e-3)
    with pytest.raises(ValueError, match="state_equation"):
        LinearizedHInfFilter(model, GAMMA, np.eye(2), 1e-3, state_equation="exact")
    with pytest.raises(ValueError, match="a3"):
        PolynomialModel(a3=np.zeros((2, 2, 2)), B=np.eye(2), C=[[1.0, 0.0]], D=[[0.0, 1.0]],
                        L=np.eye(2))
    with pytest.raises(ValueError, match="D D"):
        NonOrthonormalPolynomialHInfFilter(paper_model(np.eye(2)).replace(D=[[0.0, 0.0]]),
                                           GAMMA, np.eye(2), 1e-3)


# ------------------------------------------------------------------ fast step (cubic form)
def rk4_reference(model, variant, gamma, x, P, ys, us, dt, t0=0.0):
    """RK4 of the filter equations with the public einsum formulas f_hat / moment_matrix (and
    the Jacobian for the linearized filter), written here; ``us`` may be None."""
    gm2 = gamma**-2

    def rhs(t, x, P, y, u):
        c = model.at(t)
        if variant == "poly":
            F, A = f_hat(c, x, P), moment_matrix(c, x, P)
        else:
            A = c.jacobian(x)
            F = c.f(x) if variant == "system" else c.a0 + A @ x
        if u is not None and c.E is not None:
            F = F + c.E @ u
        W = np.linalg.inv(c.D @ c.D.T)
        K = (P @ c.C.T + c.B @ c.D.T) @ W
        dx = F + K @ (y - c.C @ x)
        dP = (A @ P + P @ A.T + c.B @ c.B.T - K @ (c.D @ c.B.T + c.C @ P)
              + gm2 * P @ c.L.T @ c.L @ P)
        return dx, dP

    out = []
    for k, y in enumerate(ys):
        u = None if us is None else us[k]
        t = t0 + k * dt
        k1 = rhs(t, x, P, y, u)
        k2 = rhs(t + dt / 2, x + dt / 2 * k1[0], P + dt / 2 * k1[1], y, u)
        k3 = rhs(t + dt / 2, x + dt / 2 * k2[0], P + dt / 2 * k2[1], y, u)
        k4 = rhs(t + dt, x + dt * k3[0], P + dt * k3[1], y, u)
        x = x + dt / 6 * (k1[0] + 2 * (k2[0] + k3[0]) + k4[0])
        P = P + dt / 6 * (k1[1] + 2 * (k2[1] + k3[1]) + k4[1])
        P = 0.5 * (P + P.T)
        out.append((x, P))
    return out


def general_model(rng, n=3, time_varying=True):
    """A stable random cubic system with B D^T != 0, D D^T != I, an input and time-varying
    a0 and a3 (a full, non-symmetric tensor)."""
    a3_fixed = rng.normal(size=(n, n, n, n))

    def a3(t):
        out = 0.01 * np.sin(3 * t) * a3_fixed
        out[np.arange(n), np.arange(n), np.arange(n), np.arange(n)] -= 0.1
        return out

    a0_fixed = rng.normal(size=n)
    return PolynomialModel(a0=(lambda t: 0.1 * np.cos(t) * a0_fixed) if time_varying else
                           0.1 * a0_fixed,
                           a1=0.3 * rng.normal(size=(n, n)) - np.eye(n),
                           a2=0.05 * rng.normal(size=(n, n, n)),
                           a3=a3 if time_varying else a3(0.3), B=rng.normal(size=(n, 2)),
                           C=rng.normal(size=(2, n)), D=rng.normal(size=(2, 2)) + 2 * np.eye(2),
                           L=rng.normal(size=(1, n)), E=rng.normal(size=(n, 1)))


@pytest.mark.parametrize("variant", ["poly", "system", "jacobian"])
def test_fast_step_equals_the_term_by_term_formulas(rng, variant):
    """step() (the cubic form) against an RK4 of f_hat / moment_matrix / the Jacobian written
    in the test, and against the term-by-term evaluation, to 1e-12: the paper's model with
    both output matrices, and a general 3-state model (B D^T != 0, D D^T != I, input,
    time-varying a0 and a3)."""
    def make(model, gamma, dt, x0):
        if variant == "poly":
            cls = (PolynomialHInfFilter if np.allclose(model.at(0).B @ model.at(0).D.T, 0)
                   else NonOrthonormalPolynomialHInfFilter)
            return cls(model, gamma, np.eye(model.n), dt, x0)
        return LinearizedHInfFilter(model, gamma, np.eye(model.n), dt, x0,
                                    state_equation=variant)

    cases = [(paper_model(np.eye(2)), GAMMA, 1e-2, 40, None),
             (paper_model(np.array([[1.0, 0.0]])), GAMMA, 1e-2, 40, None),
             (general_model(rng), 5.0, 1e-2, 40, rng.normal(size=(40, 1)))]
    for model, gamma, dt, steps, us in cases:
        x0 = 0.1 * rng.normal(size=model.n)
        ys = rng.normal(size=(steps, model.m))
        fast, slow = make(model, gamma, dt, x0), make(model, gamma, dt, x0)
        assert fast._cubic is not None
        slow._cubic = None  # the term-by-term evaluation
        ref = rk4_reference(model, variant, gamma, x0, np.eye(model.n), ys, us, dt)
        for k, y in enumerate(ys):
            u = None if us is None else us[k]
            fast.step(y, u)
            slow.step(y, u)
            for got in (fast, slow):
                assert rel_err(got.x, ref[k][0]) < 1e-12 and rel_err(got.P, ref[k][1]) < 1e-12
        np.testing.assert_array_equal(fast.P, fast.P.swapaxes(-1, -2))
        np.testing.assert_allclose(fast.innovation, slow.innovation, rtol=1e-12, atol=1e-12)


def test_fast_step_batch_equals_single_and_escapes_like_the_slow_path(rng):
    model = paper_model(np.array([[1.0, 0.0]]))
    x0 = rng.normal(scale=0.3, size=(4, 2))
    fast = PolynomialHInfFilter(model, GAMMA, np.eye(2), 1e-2, x0, substeps=3)
    slow = PolynomialHInfFilter(model, GAMMA, np.eye(2), 1e-2, x0, substeps=3)
    slow._cubic = None
    err_fast = err_slow = None
    for _ in range(200):  # P22 of the printed (26) escapes near t = 1.02 s
        y = rng.normal(size=(4, 1))
        try:
            fast.step(y)
        except FiniteEscapeError as exc:
            err_fast = exc
        try:
            slow.step(y)
        except FiniteEscapeError as exc:
            err_slow = exc
        assert rel_err(fast.x, slow.x) < 1e-12 and rel_err(fast.P, slow.P) < 1e-12
        if err_fast or err_slow:
            break
    assert err_fast is not None and err_slow is not None
    assert (err_fast.quantity, err_fast.time) == (err_slow.quantity, err_slow.time)
    assert "batch index" in str(err_fast)


def test_fast_step_only_for_small_constant_matrix_models(rng):
    big = PolynomialModel(a1=-np.eye(4), a3=np.zeros((4, 4, 4, 4)) - 0.01, B=np.eye(4),
                          C=np.eye(4)[:1], D=np.ones((1, 4)) / 2.0, L=np.eye(4))
    assert NonOrthonormalPolynomialHInfFilter(big, 2.0, np.eye(4), 1e-2)._cubic is None
    varying_c = paper_model(np.eye(2)).replace(C=lambda t: [[1.0, 0.1 * np.sin(t)]])
    filt = PolynomialHInfFilter(varying_c, GAMMA, np.eye(2), 1e-3)
    assert filt._cubic is None
    filt.step([0.3])  # the term-by-term path still works
    assert filt.x.shape == (2,)
