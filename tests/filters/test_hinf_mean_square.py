"""Mean-square H-infinity filter of Basin, Elvira-Ceja & Sanchez
(:class:`filters.MeanSquareHInfFilter`)."""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Callable

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import solve_continuous_are

from filters import (
    Estimator,
    FilterError,
    FiniteEscapeError,
    KalmanBucyFilter,
    LinearSystem,
    MeanSquareHInfFilter,
)
from filters.analysis import noise_output_ratio
from filters.hinf_mean_square import AssumptionWarning

# ----------------------------------------------------------------- the helicopter example
# Section IV, with the misprints corrected (B's first row [0, 0]; G G^T computed).
A_EX = np.array([[0.0, 0.0, 1.0, 0.0],
                 [0.0, 0.0, 0.0, 1.0],
                 [0.0, 0.0, -9.2751, 0.0],
                 [0.0, 0.0, 0.0, -3.4955]])
B_EX = np.array([[0.0, 0.0], [0.0, 0.0], [2.3667, 0.0790], [0.2410, 0.7913]])
b_EX = np.array([[0.0, 0.0], [0.0, 0.0], [0.9024, 0.0876], [0.0919, 0.8772]])
G_EX = np.hstack([b_EX, np.zeros((4, 2))])
C_EX = np.eye(4)[:2]  # C1 = C2 = L
h_EX = np.eye(2)
H_EX = np.eye(4)[2:]
R_EX = np.array([[0.8, 0.5, 0.2, 0.1],
                 [0.5, 0.8, 0.7, 0.2],
                 [0.2, 0.7, 0.9, 0.4],
                 [0.1, 0.2, 0.4, 0.9]])
GAMMA_EX = 1.1
P0_EX = np.diag([10.0, 10.0, 15.0, 5.0])
M0_EX = np.array([0.1745, -0.5236, -0.15, -0.4])
X0_EX = np.array([-0.7069, 0.0, 0.0, 0.0])
U_EX = np.array([12.495, -3.835])


def w_ex(t: float) -> np.ndarray:
    """The printed L2 disturbance w(t), shape (4,)."""
    return np.array([1.0 / (1.0 + t), 0.1 * (1.0 - math.exp(-0.3 * t)),
                     0.1745 / (1.0 + t), 0.0873 * (1.0 - math.exp(-0.3 * t))])


def paper_filter(dt: float = 0.01, **kw: object) -> MeanSquareHInfFilter:
    args: dict[str, object] = dict(gamma=GAMMA_EX, x0=M0_EX, P0=P0_EX, substeps=1)
    args.update(kw)
    return MeanSquareHInfFilter(A_EX, B_EX, C_EX, h_EX, C_EX, H_EX, G_EX, b_EX, C_EX,
                                R=R_EX, dt_s=dt, **args)  # type: ignore[arg-type]


def joint_rhs(mats: Callable[[float], dict[str, np.ndarray]], y: np.ndarray,
              u: np.ndarray | None, gamma: float, n: int) -> Callable[[float, np.ndarray],
                                                                   np.ndarray]:
    """(7)-(9) as a flat ODE for solve_ivp; ``mats(t)`` returns the matrices at t."""
    m1 = mats(0.0)["C1"].shape[0]
    y1, y2 = y[:m1], y[m1:]

    def rhs(t: float, z: np.ndarray) -> np.ndarray:
        M = mats(t)
        m, P, S = z[:n], z[n:n + n * n].reshape(n, n), z[n + n * n:].reshape(n, n)
        hhi = np.linalg.inv(M["h"] @ M["h"].T)
        HHi = np.linalg.inv(M["H"] @ M["H"].T)
        A, C1, C2, L = M["A"], M["C1"], M["C2"], M["L"]
        dm = (A @ m + P @ C1.T @ hhi @ (y1 - C1 @ m) + S @ C2.T @ HHi @ (y2 - C2 @ m))
        if u is not None:
            dm = dm + M["B"] @ u
        dP = A @ P + P @ A.T + M["b"] @ M["b"].T - P @ C1.T @ hhi @ C1 @ P
        dS = (A @ S + S @ A.T + M["G"] @ M["G"].T
              - S @ (C2.T @ HHi @ C2 - L.T @ L / gamma**2) @ S)
        return np.concatenate([dm, dP.ravel(), dS.ravel()])

    return rhs


def paper_mats(_t: float) -> dict[str, np.ndarray]:
    return dict(A=A_EX, B=B_EX, C1=C_EX, h=h_EX, C2=C_EX, H=H_EX, G=G_EX, b=b_EX, L=C_EX)


# ------------------------------------------------------------------ a time-varying system
def tv_mats(t: float) -> dict[str, np.ndarray]:
    """n = 3, m1 = 2, m2 = 1, s = 2, k = 1; H G^T = 0 for all t by construction."""
    A = np.array([[-0.5, 1.0, 0.0], [0.0, -0.2, 1.0], [-0.3, 0.1, -0.8]])
    A = A + 0.4 * math.sin(3.0 * t) * np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0],
                                                [0.0, 0.0, 1.0]])
    return dict(
        A=A,
        B=np.array([[0.0], [1.0 + 0.2 * math.cos(t)], [0.5]]),
        C1=np.array([[1.0, 0.0, 0.0], [0.0, 0.5 + 0.3 * math.sin(2.0 * t), 1.0]]),
        h=np.array([[0.7, 0.1], [0.0, 0.9 + 0.2 * math.cos(t)]]),
        C2=np.array([[0.2, 1.0 + 0.5 * math.cos(2.0 * t), 0.0]]),
        H=np.array([[0.0, 0.8 + 0.3 * math.sin(t)]]),
        G=np.array([[1.0 + 0.3 * math.cos(t), 0.0], [0.2, 0.0], [0.5, 0.0]]),
        b=np.array([[0.3, 0.0], [0.1, 0.4], [0.0, 0.5]]),
        L=np.array([[1.0, 0.0, 0.5 + 0.2 * math.sin(t)]]),
    )


def tv_filter(x0: np.ndarray, P0: np.ndarray, dt: float, substeps: int | str,
              gamma: float = 2.0) -> MeanSquareHInfFilter:
    def f(key: str) -> Callable[[float], np.ndarray]:
        return lambda t: tv_mats(t)[key]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AssumptionWarning)
        return MeanSquareHInfFilter(
            f("A"), f("B"), f("C1"), f("h"), f("C2"), f("H"), f("G"), f("b"), f("L"),
            gamma, np.eye(3), x0, P0, dt, substeps=substeps)


# ================================================================== limit: Kalman-Bucy
def random_kb_setup(seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    n, m1, k = 3, 2, 1
    hm = rng.standard_normal((m1, m1)) + 2.0 * np.eye(m1)
    return dict(A=rng.standard_normal((n, n)), B=rng.standard_normal((n, k)),
                C1=rng.standard_normal((m1, n)), h=hm, b=rng.standard_normal((n, n)))


@pytest.mark.parametrize("seed", [0, 1])
def test_c2_zero_reduces_to_kalman_bucy(seed: int) -> None:
    """C2 = 0 is legal (H H^T > 0 still holds): (7)-(8) are then the Kalman-Bucy filter.

    (With C2 = 0, (9) reads S' = A S + S A^T + G G^T + gamma^-2 S L^T L S and escapes in
    finite time for any finite gamma; gamma = inf keeps it a Lyapunov equation.)"""
    s = random_kb_setup(seed)
    n = 3
    rng = np.random.default_rng(100 + seed)
    x0, P0 = rng.standard_normal(n), np.eye(n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AssumptionWarning)  # (C2, A) not detectable
        f = MeanSquareHInfFilter(s["A"], s["B"], s["C1"], s["h"], np.zeros((1, n)),
                                 [[0.0, 1.0]], np.hstack([s["b"][:, :1], np.zeros((n, 1))]),
                                 s["b"], np.eye(n), math.inf, np.eye(n), x0, P0, 0.05,
                                 substeps=3)
    kb = KalmanBucyFilter(LinearSystem(A=s["A"], B=s["B"], C=s["C1"], Q=s["b"] @ s["b"].T,
                                       R=s["h"] @ s["h"].T), x0, P0, 0.05, substeps=3)
    for _ in range(40):
        y1, y2, u = rng.standard_normal(2), rng.standard_normal(1), rng.standard_normal(1)
        f.step(np.concatenate([y1, y2]), u)
        kb.step(y1, u)
        scale = 1.0 + np.abs(kb.x).max()
        np.testing.assert_allclose(f.x, kb.x, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(f.P, kb.P, rtol=0, atol=1e-12 * np.abs(kb.P).max())


def test_negligible_hinf_gain_tends_to_kalman_bucy() -> None:
    """H H^T -> infinity (gamma large) makes the S-gain vanish: ||m - m_KB|| ~ 1/(H H^T)."""
    dt = 0.01
    rng = np.random.default_rng(7)
    kb = KalmanBucyFilter(LinearSystem(A=A_EX, B=B_EX, C=C_EX, Q=b_EX @ b_EX.T, R=np.eye(2)),
                          M0_EX, P0_EX, dt)
    ys = rng.standard_normal((100, 4))
    devs = []
    for scale in (1e4, 1e6):
        f = MeanSquareHInfFilter(A_EX, B_EX, C_EX, h_EX, C_EX, scale * H_EX, G_EX, b_EX, C_EX,
                                 1e6, R_EX, M0_EX, P0_EX, dt)
        kb.reset(M0_EX, P0_EX)
        for y in ys:
            f.step(y, U_EX)
            kb.step(y[:2], U_EX)
        np.testing.assert_allclose(f.P, kb.P, rtol=1e-12, atol=0)
        devs.append(np.abs(f.x - kb.x).max())
    assert devs[1] < 1e-6
    assert devs[0] / devs[1] == pytest.approx(1e4, rel=1e-2)  # linear in (H H^T)^-1


# ======================================================= S equation, RK4 order
def test_S_matches_solve_ivp_on_paper_example() -> None:
    f = paper_filter(dt=0.01, substeps=2)
    T = 3.0
    for _ in range(round(T / f.dt_s)):
        f.step(np.zeros(4), U_EX)
    M2 = C_EX.T @ C_EX - C_EX.T @ C_EX / GAMMA_EX**2  # C2^T (H H^T)^-1 C2 - L^T L / gamma^2

    def rhs(_t: float, s: np.ndarray) -> np.ndarray:
        S = s.reshape(4, 4)
        return (A_EX @ S + S @ A_EX.T + G_EX @ G_EX.T - S @ M2 @ S).ravel()

    ref = solve_ivp(rhs, (0.0, T), np.linalg.inv(R_EX).ravel(), method="DOP853",
                    rtol=1e-12, atol=1e-14).y[:, -1].reshape(4, 4)
    assert f.t_s == pytest.approx(T)
    err = np.abs(f.S - ref).max() / np.abs(ref).max()
    assert err < 1e-9, err
    np.testing.assert_allclose(f.S0, np.linalg.inv(R_EX), rtol=1e-15, atol=1e-15)


def _order_errors(make: Callable[[int], MeanSquareHInfFilter],
                  mats: Callable[[float], dict[str, np.ndarray]], y: np.ndarray,
                  u: np.ndarray, gamma: float, x0: np.ndarray, P0: np.ndarray, S0: np.ndarray,
                  dt: float, substeps: tuple[int, ...]) -> list[float]:
    n = x0.size
    z0 = np.concatenate([x0, P0.ravel(), S0.ravel()])
    ref = solve_ivp(joint_rhs(mats, y, u, gamma, n), (0.0, dt), z0, method="DOP853",
                    rtol=1e-13, atol=1e-14).y[:, -1]
    errors = []
    for ns in substeps:
        f = make(ns)
        f.step(y, u)
        z = np.concatenate([f.x, f.P.ravel(), f.S.ravel()])
        errors.append(float(np.abs(z - ref).max()))
    return errors


def test_rk4_convergence_order_paper_example() -> None:
    """Joint (m, P, S) over one interval (y, u held): error ratio 2^4 per halving of h."""
    rng = np.random.default_rng(3)
    y = rng.standard_normal(4)
    dt = 0.4
    errors = _order_errors(lambda ns: paper_filter(dt=dt, substeps=ns), paper_mats, y, U_EX,
                           GAMMA_EX, M0_EX, P0_EX, np.linalg.inv(R_EX), dt, (16, 32, 64))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    print(errors, orders)
    assert np.all((orders > 3.5) & (orders < 4.5)), (errors, orders)


def test_rk4_convergence_order_time_varying() -> None:
    """Stage-time evaluation of callable matrices keeps order 4 (t0 != 0)."""
    rng = np.random.default_rng(4)
    x0, P0 = rng.standard_normal(3), np.diag([2.0, 1.0, 0.5])
    y, u = rng.standard_normal(3), rng.standard_normal(1)
    dt, t0 = 0.5, 0.7

    errors = _order_errors(lambda ns: _with_t0(x0, P0, dt, ns, t0), lambda t: tv_mats(t + t0),
                           y, u, 2.0, x0, P0, np.eye(3), dt, (8, 16, 32))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    print(errors, orders)
    assert np.all((orders > 3.5) & (orders < 4.5)), (errors, orders)


def _with_t0(x0: np.ndarray, P0: np.ndarray, dt: float, ns: int,
             t0: float) -> MeanSquareHInfFilter:
    def f(key: str) -> Callable[[float], np.ndarray]:
        return lambda t: tv_mats(t)[key]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AssumptionWarning)
        filt = MeanSquareHInfFilter(
            f("A"), f("B"), f("C1"), f("h"), f("C2"), f("H"), f("G"), f("b"), f("L"),
            2.0, np.eye(3), x0, P0, dt, substeps=ns, t0=t0)
    assert filt.t_s == t0
    return filt


def test_constant_callables_match_constant_arrays() -> None:
    """Callables returning constants (generic path) = arrays (block fast path) to rounding."""
    fast = paper_filter()
    def constant(v: np.ndarray) -> Callable[[float], np.ndarray]:
        return lambda _t: v

    const = {k: constant(v) for k, v in paper_mats(0.0).items()}
    slow = MeanSquareHInfFilter(const["A"], const["B"], const["C1"], const["h"], const["C2"],
                                const["H"], const["G"], const["b"], const["L"], GAMMA_EX,
                                R_EX, M0_EX, P0_EX, 0.01)
    rng = np.random.default_rng(5)
    for y in rng.standard_normal((50, 4)):
        fast.step(y, U_EX)
        slow.step(y, U_EX)
    np.testing.assert_allclose(slow.x, fast.x, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(slow.P, fast.P, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(slow.S, fast.S, rtol=1e-13, atol=1e-13)


# ================================================================ steady state
def hinf_system(gamma: float, P0: np.ndarray | None = None) -> MeanSquareHInfFilter:
    """A small system whose closed-loop Riccati dynamics are fast (steady state in ~10 s)."""
    A = np.array([[-1.0, 2.0, 0.0], [-1.0, -0.5, 1.0], [0.0, 0.5, -2.0]])
    G = np.array([[1.0, 0.0, 0.0], [0.3, 1.0, 0.0], [0.0, 0.5, 0.0]])
    H = np.array([[0.0, 0.0, 0.5]])
    C2 = np.array([[1.0, 0.0, 0.5]])
    L = np.array([[0.0, 1.0, 1.0]])
    return MeanSquareHInfFilter(A, None, np.eye(3)[:1], [[1.0]], C2, H, G, 0.3 * np.eye(3), L,
                                gamma, 2.0 * np.eye(3), np.zeros(3),
                                np.eye(3) if P0 is None else P0, 0.02, substeps="auto")


def test_S_converges_to_stabilizing_hinf_are_solution() -> None:
    gamma = 2.0
    f = hinf_system(gamma)
    A, G = f._A.value, f._G.value
    C2, L, H = f._C2.value, f._L.value, f._H.value
    M2 = C2.T @ np.linalg.inv(H @ H.T) @ C2 - L.T @ L / gamma**2
    for _ in range(1000):  # 20 s
        f.step(np.zeros(2))
    S = f.S
    residual = A @ S + S @ A.T + G @ G.T - S @ M2 @ S
    assert np.abs(residual).max() < 1e-8
    assert np.linalg.eigvals(A - S @ M2).real.max() < 0.0
    assert np.all(np.linalg.eigvalsh(S) > 0.0)
    P_inf, S_inf = f.steady_state()
    np.testing.assert_allclose(S, S_inf, rtol=0, atol=1e-9)
    np.testing.assert_allclose(f.P, P_inf, rtol=0, atol=1e-9)
    # independent check of steady_state's S: residual and stabilizing
    assert np.abs(A @ S_inf + S_inf @ A.T + G @ G.T - S_inf @ M2 @ S_inf).max() < 1e-10
    assert np.linalg.eigvals(A - S_inf @ M2).real.max() < 0.0


def test_S_tends_to_kalman_are_as_gamma_grows() -> None:
    f = hinf_system(math.inf)
    A, G, C2, H = f._A.value, f._G.value, f._C2.value, f._H.value
    K = solve_continuous_are(A.T, C2.T, G @ G.T, H @ H.T)
    np.testing.assert_allclose(f.steady_state()[1], K, rtol=1e-12, atol=1e-12)
    gaps = [np.abs(hinf_system(g).steady_state()[1] - K).max() for g in (1e1, 1e2, 1e3)]
    assert gaps[0] > gaps[1] > gaps[2]
    assert gaps[0] / gaps[1] == pytest.approx(100.0, rel=0.05)  # O(gamma^-2)
    f = hinf_system(1e3)
    for _ in range(1000):
        f.step(np.zeros(2))
    np.testing.assert_allclose(f.S, K, rtol=0, atol=1e-5)


@pytest.mark.parametrize("gamma", [0.05, 0.3, 0.5])
def test_steady_state_reports_missing_stabilizing_solution(gamma: float) -> None:
    with pytest.raises(ValueError, match="stabilizing"):
        hinf_system(gamma).steady_state()


# ================================================================ finite escape of S
@pytest.mark.parametrize("batch", [(), (3,)])
def test_S_finite_escape_time_matches_closed_form(batch: tuple[int, ...]) -> None:
    """Scalar: S' = 2 a S + g^2 - k S^2 with k = c^2/r - 1/gamma^2 < 0 escapes at
    t_e = (pi/2 - atan((S0 + alpha)/beta)) / (kappa beta), kappa = -k, alpha = a/kappa,
    beta^2 = g^2/kappa - alpha^2 (S + alpha = beta tan(kappa beta t + phi))."""
    a, g, c, r, gamma, R0 = 0.5, 1.0, 1.0, 1.0, 0.5, 1.0
    kappa = 1.0 / gamma**2 - c**2 / r
    alpha = a / kappa
    beta = math.sqrt(g**2 / kappa - alpha**2)
    t_escape = (math.pi / 2 - math.atan((1.0 / R0 + alpha) / beta)) / (kappa * beta)
    dt, ns = 0.01, 4
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AssumptionWarning)  # no input: (A, B) unstabilizable
        f = MeanSquareHInfFilter([[a]], None, [[1.0]], [[1.0]], [[c]], [[0.0, math.sqrt(r)]],
                                 [[g, 0.0]], [[0.3]], [[1.0]], gamma, [[R0]],
                                 np.zeros((*batch, 1)), [[1.0]], dt, substeps=ns)
    y = np.zeros((*batch, 2))
    with pytest.raises(FiniteEscapeError) as info:
        for _ in range(100):
            f.step(y)
    err = info.value
    assert err.quantity == "S"
    assert abs(err.time - t_escape) < 2 * dt / ns, (err.time, t_escape)
    # the failing call left the filter unchanged (at the last completed interval)
    assert f.t_s < err.time <= f.t_s + dt + 1e-12
    assert np.isfinite(f.S).all() and float(f.S.max()) < 1e12


# ========================================================= stiffness, errors, auto
def test_stiff_fixed_step_fails_typed_and_auto_substeps_integrate() -> None:
    """h h^T = 1e-4 with P0 = diag(10, ...) needs h ~ 1e-5: one RK4 step explodes."""
    f = MeanSquareHInfFilter(A_EX, B_EX, C_EX, 1e-2 * h_EX, C_EX, H_EX, G_EX, b_EX, C_EX,
                             GAMMA_EX, R_EX, M0_EX, P0_EX, 0.01, substeps=1)
    with pytest.raises(FilterError) as info:
        f.step(np.zeros(4), U_EX)
    assert info.value.quantity == "P"
    assert f.t_s == 0.0 and np.array_equal(f.x, M0_EX) and np.array_equal(f.P, P0_EX)
    auto = MeanSquareHInfFilter(A_EX, B_EX, C_EX, 1e-2 * h_EX, C_EX, H_EX, G_EX, b_EX, C_EX,
                                GAMMA_EX, R_EX, M0_EX, P0_EX, 0.01, substeps="auto")
    y = np.array([0.1, -0.2, 0.0, 0.0])
    auto.step(y, U_EX)
    assert auto.substeps > 100

    def mats(_t: float) -> dict[str, np.ndarray]:
        return {**paper_mats(0.0), "h": 1e-2 * h_EX}

    ref = solve_ivp(joint_rhs(mats, y, U_EX, GAMMA_EX, 4), (0.0, 0.01),
                    np.concatenate([M0_EX, P0_EX.ravel(), np.linalg.inv(R_EX).ravel()]),
                    method="Radau", rtol=1e-10, atol=1e-12).y[:, -1]
    # "auto" aims at stability (h |rate| ~ 2.5), not accuracy: close, and exact with finer h
    np.testing.assert_allclose(auto.x, ref[:4], rtol=0, atol=1e-4)
    fine = MeanSquareHInfFilter(A_EX, B_EX, C_EX, 1e-2 * h_EX, C_EX, H_EX, G_EX, b_EX, C_EX,
                                GAMMA_EX, R_EX, M0_EX, P0_EX, 0.01, substeps=8 * auto.substeps)
    fine.step(y, U_EX)
    np.testing.assert_allclose(fine.x, ref[:4], rtol=0, atol=1e-7)
    np.testing.assert_allclose(fine.P, ref[4:20].reshape(4, 4), rtol=0, atol=1e-7)


def test_bad_inputs_leave_state_unchanged() -> None:
    f = paper_filter()
    f.step(np.ones(4), U_EX)
    x, P, S, t = f.x.copy(), f.P.copy(), f.S.copy(), f.t_s
    for y, u in ((np.ones(3), U_EX), (np.ones(4), np.ones(3)), (np.full(4, np.nan), U_EX)):
        with pytest.raises(ValueError):
            f.step(y, u)
    assert f.t_s == t
    np.testing.assert_array_equal(f.x, x)
    np.testing.assert_array_equal(f.P, P)
    np.testing.assert_array_equal(f.S, S)
    with pytest.raises(ValueError):
        f.x[0] = 1.0  # read-only


# ============================================================ assumptions (C1)-(C4)
def ex_kwargs(**over: object) -> dict[str, object]:
    kw: dict[str, object] = dict(A=A_EX, B=B_EX, C1=C_EX, h=h_EX, C2=C_EX, H=H_EX, G=G_EX,
                                 b=b_EX, L=C_EX, gamma=GAMMA_EX, R=R_EX, x0=M0_EX, P0=P0_EX,
                                 dt_s=0.01)
    kw.update(over)
    return kw


def test_paper_example_satisfies_all_assumptions() -> None:
    """A's double zero eigenvalue is stabilized through b, G, B and detected through C1, C2,
    L (the PBH tests pass on it): no AssumptionWarning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        f = MeanSquareHInfFilter(**ex_kwargs())  # type: ignore[arg-type]
    assert all(f.assumptions.values()), f.assumptions
    assert len(f.assumptions) == 6


@pytest.mark.parametrize(
    ("over", "match"),
    [
        (dict(G=np.hstack([b_EX, np.eye(4)[:, 2:]])), r"assumption C4 violated: H G\^T must be 0"),
        (dict(H=np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 2.0, 0.0]])),
         r"assumption C4 violated: H H\^T must be positive definite"),
        (dict(h=np.array([[1.0, 0.0], [1.0, 0.0]])), r"h h\^T must be positive definite"),
        (dict(R=R_EX + np.triu(0.1 * np.ones((4, 4)), 1)), r"R must be symmetric"),
        (dict(R=-R_EX), r"R must be symmetric positive definite"),
        (dict(gamma=0.0), "gamma"),
        (dict(gamma=float("nan")), "gamma"),
        (dict(C2=np.eye(3)), "C2 must have shape"),
        (dict(substeps=0), "substeps"),
    ],
)
def test_hard_assumption_violations_raise(over: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        MeanSquareHInfFilter(**ex_kwargs(**over))  # type: ignore[arg-type]


def test_C4_is_checked_for_callables_at_t0() -> None:
    G_bad = np.hstack([b_EX, np.eye(4)[:, 2:]])
    with pytest.raises(ValueError, match=r"C4 violated.*t = 2"):
        MeanSquareHInfFilter(**ex_kwargs(G=lambda t: G_bad, t0=2.0))  # type: ignore[arg-type]
    # an H H^T that degenerates later is caught when it is inverted
    f = MeanSquareHInfFilter(**ex_kwargs(H=lambda t: H_EX * max(0.0, 1.0 - t)))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"H H\^T must be positive definite"):
        for _ in range(200):
            f.step(np.zeros(4), U_EX)
    assert f.t_s == pytest.approx(0.99)


@pytest.mark.parametrize(
    ("over", "label"),
    [
        (dict(C2=np.zeros((2, 4))), "C2: (C2, A) detectable"),
        (dict(G=np.zeros((4, 4))), "C2: (A, G) stabilizable"),
        (dict(b=np.zeros((4, 2))), "C1: (A, b) stabilizable"),
        (dict(C1=np.eye(4)[2:]), "C1: (C1, A) detectable"),
        (dict(L=np.eye(4)[3:]), "C3: (L, A) detectable"),
        (dict(B=None), "C3: (A, B) stabilizable"),
    ],
)
def test_stabilizability_failures_warn(over: dict[str, object], label: str) -> None:
    with pytest.warns(AssumptionWarning, match=re.escape(label)):
        f = MeanSquareHInfFilter(**ex_kwargs(**over))  # type: ignore[arg-type]
    assert not f.assumptions[label]
    assert sum(not ok for ok in f.assumptions.values()) == 1


# ================================================== the paper's example, noise-free
def simulate_paper_example(T: float, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                          MeanSquareHInfFilter]:
    """Mean trajectory dx = (A x + B u + G w) dt by RK4 with the filter's step; the filter
    gets the exact interval averages of y1 = C1 x and y2 = C2 x + H w (integrated along)."""
    f = paper_filter(dt=dt)
    n = 4

    def rhs(t: float, z: np.ndarray) -> np.ndarray:
        x, w = z[:n], w_ex(t)
        return np.concatenate([A_EX @ x + B_EX @ U_EX + G_EX @ w, C_EX @ x, C_EX @ x + H_EX @ w])

    z = np.concatenate([X0_EX, np.zeros(4)])
    steps = round(T / dt)
    ts = np.arange(steps + 1) * dt
    errs = np.empty((steps + 1, 2))
    errs[0] = C_EX @ (X0_EX - M0_EX)
    for k in range(steps):
        t = ts[k]
        k1 = rhs(t, z)
        k2 = rhs(t + dt / 2, z + dt / 2 * k1)
        k3 = rhs(t + dt / 2, z + dt / 2 * k2)
        k4 = rhs(t + dt, z + dt * k3)
        z_new = z + dt / 6 * (k1 + 2 * (k2 + k3) + k4)
        y = (z_new[n:] - z[n:]) / dt
        z = z_new
        m = f.step(y, U_EX)
        errs[k + 1] = C_EX @ (z[:n] - m)  # z - L m with L = C
    ws = np.array([w_ex(t) for t in ts])
    return ts, errs, ws, f


def test_paper_example_noise_free_10s() -> None:
    ts, errs, ws, f = simulate_paper_example(10.0, 0.01)
    T = noise_output_ratio(ts, errs, ws, X0_EX, R_EX)
    print(f"\nhelicopter noise-free: T(10 s) = {T[-1]:.4f}, max over [0, 10] s = {T.max():.4f} "
          f"(at {ts[np.argmax(T)]:.2f} s)")
    assert T.max() < GAMMA_EX
    assert np.all(np.isfinite(T))
    # pitch error: 0.88 rad -> < 0.01; yaw error: 0.52 rad -> a bias of ~0.03 rad left by
    # the non-decaying w2, w4 (w4 enters y2 = yaw + w4 directly)
    assert abs(errs[-1, 0]) < 0.01 and abs(errs[0, 0]) > 0.8
    assert abs(errs[-1, 1]) < 0.05 and abs(errs[0, 1]) > 0.5
    assert np.abs(errs[-200:]).max() < 0.05  # last 2 s


def test_paper_example_80s_error_tends_to_the_disturbance_bias() -> None:
    """Over 80 s the error tends to e_inf = -F^-1 (G - S K2 H) w_inf, the bias that the
    non-decaying part w_inf = [0, 0.1, 0, 0.0873] of w leaves (F = A - P M1 - S N2 at the
    steady state); T(80 s) stays below gamma."""
    ts, errs, ws, f = simulate_paper_example(80.0, 0.01)
    T = noise_output_ratio(ts, errs, ws, X0_EX, R_EX)
    print(f"\nhelicopter noise-free: T(80 s) = {T[-1]:.4f}, max over [0, 80] s = {T.max():.4f}")
    assert T.max() < GAMMA_EX
    P, S = f.P, f.S
    F = A_EX - P @ C_EX.T @ C_EX - S @ C_EX.T @ C_EX
    w_inf = np.array([0.0, 0.1, 0.0, 0.0873])
    e_inf = -np.linalg.solve(F, (G_EX - S @ C_EX.T @ H_EX) @ w_inf)
    # w1, w3 still decay like 1/(1 + t): allow their residual effect
    np.testing.assert_allclose(errs[-1], C_EX @ e_inf, atol=3e-3)


# ==================================================================== batch, protocol
def test_batch_equals_separate_filters() -> None:
    rng = np.random.default_rng(11)
    x0 = rng.standard_normal((3, 4))
    G0 = rng.standard_normal((3, 4, 4))
    P0 = G0 @ np.swapaxes(G0, -1, -2) + np.eye(4)
    batch = paper_filter(x0=x0, P0=P0)
    singles = [paper_filter(x0=x0[i], P0=P0[i]) for i in range(3)]
    assert batch.batch_shape == (3,) and batch.S.shape == (3, 4, 4)
    for _ in range(60):
        y, u = rng.standard_normal((3, 4)), rng.standard_normal((3, 2))
        batch.step(y, u)
        for i, s in enumerate(singles):
            s.step(y[i], u[i])
    for i, s in enumerate(singles):
        np.testing.assert_allclose(batch.x[i], s.x, rtol=0, atol=1e-13)
        np.testing.assert_allclose(batch.P[i], s.P, rtol=0, atol=1e-13)
        np.testing.assert_allclose(batch.S[i], s.S, rtol=0, atol=1e-13)
        np.testing.assert_allclose(batch.innovation[i], s.innovation, rtol=0, atol=1e-13)


def test_batch_time_varying_equals_separate() -> None:
    rng = np.random.default_rng(12)
    x0 = rng.standard_normal((2, 3))
    batch = tv_filter(x0, np.eye(3), 0.05, 2)
    singles = [tv_filter(x0[i], np.eye(3), 0.05, 2) for i in range(2)]
    for _ in range(20):
        y, u = rng.standard_normal((2, 3)), rng.standard_normal(1)  # u broadcast
        batch.step(y, u)
        for i, s in enumerate(singles):
            s.step(y[i], u)
    for i, s in enumerate(singles):
        np.testing.assert_allclose(batch.x[i], s.x, rtol=0, atol=1e-13)
        np.testing.assert_allclose(batch.P[i], s.P, rtol=0, atol=1e-13)


def test_protocol_reset_and_attributes() -> None:
    f = paper_filter()
    assert isinstance(f, Estimator)
    assert MeanSquareHInfFilter.name == "ms-hinf"
    assert f.gamma == GAMMA_EX and f.measurement_layout == (2, 2)
    for _ in range(5):
        f.step(np.ones(4), U_EX)
    assert f.t_s == pytest.approx(0.05)
    np.testing.assert_allclose(f.innovation, np.ones(4) - np.vstack([C_EX, C_EX]) @ f.x, atol=1)
    f.reset(X0_EX, np.eye(4))
    assert f.t_s == 0.0 and f.innovation is None
    np.testing.assert_array_equal(f.x, X0_EX)
    np.testing.assert_array_equal(f.P, np.eye(4))
    np.testing.assert_allclose(f.S, np.linalg.inv(R_EX), rtol=1e-15)
    # symmetric by construction, P, S read-only
    f.step(np.ones(4), U_EX)
    np.testing.assert_array_equal(f.P, f.P.T)
    np.testing.assert_array_equal(f.S, f.S.T)
    with pytest.raises(ValueError):
        f.S[0, 0] = 0.0


def test_noise_intensities_equal_noise_matrices() -> None:
    f = paper_filter()
    g = MeanSquareHInfFilter(A_EX, B_EX, C_EX, 4.0 * np.eye(2), C_EX, H_EX, G_EX,
                             b_EX @ b_EX.T, C_EX, GAMMA_EX, R_EX, M0_EX, P0_EX, 0.01,
                             noise_intensities=True)
    f2 = MeanSquareHInfFilter(A_EX, B_EX, C_EX, 2.0 * h_EX, C_EX, H_EX, G_EX, b_EX, C_EX,
                              GAMMA_EX, R_EX, M0_EX, P0_EX, 0.01)
    for y in np.random.default_rng(6).standard_normal((20, 4)):
        f.step(y, U_EX)
        g.step(y, U_EX)
        f2.step(y, U_EX)
    np.testing.assert_allclose(g.x, f2.x, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(g.P, f2.P, rtol=1e-13, atol=1e-13)
    assert np.abs(g.P - f.P).max() > 1e-3  # h h^T = 4 I is not I
    with pytest.raises(ValueError, match="h h"):
        MeanSquareHInfFilter(A_EX, B_EX, C_EX, np.diag([1.0, -1.0]), C_EX, H_EX, G_EX,
                             b_EX @ b_EX.T, C_EX, GAMMA_EX, R_EX, M0_EX, P0_EX, 0.01,
                             noise_intensities=True)


def test_innovation_is_that_of_the_interval_start() -> None:
    f = paper_filter()
    f.step(np.ones(4), U_EX)
    m = f.x.copy()
    y = np.array([0.3, -0.1, 0.2, 0.4])
    f.step(y, U_EX)
    np.testing.assert_allclose(f.innovation, y - np.vstack([C_EX, C_EX]) @ m, rtol=1e-15)


# ==================================================================== speed
# ====================================================== noise_output_ratio helper
def test_noise_output_ratio_closed_forms() -> None:
    t = np.linspace(0.0, 2.0, 201)
    z = np.column_stack([np.full_like(t, 0.5), np.zeros_like(t)])  # |z|^2 = 0.25
    w = np.column_stack([t, np.zeros_like(t)])  # |w|^2 = t^2: trapezoid error O(dt^2)
    x0, R = np.array([1.0, 2.0]), np.diag([1.0, 0.5])  # x0^T R x0 = 3
    T = noise_output_ratio(t, z, w, x0, R)
    exact = np.sqrt(0.25 * t / (t**3 / 3.0 + 3.0))
    np.testing.assert_allclose(T, exact, rtol=1e-4)
    assert T[0] == 0.0
    # 1-D inputs; zero denominator
    T0 = noise_output_ratio(t, np.zeros_like(t), np.zeros_like(t), np.zeros(2), R)
    np.testing.assert_array_equal(T0, 0.0)
    Tinf = noise_output_ratio(t, np.ones_like(t), np.zeros_like(t), np.zeros(2), R)
    assert Tinf[0] == 0.0 and np.isinf(Tinf[1:]).all()
    with pytest.raises(ValueError):
        noise_output_ratio(t[::-1], z, w, x0, R)
    with pytest.raises(ValueError):
        noise_output_ratio(t, z[:-1], w, x0, R)


# ================================================================ ROS2 (filters.stiff)
def stiff_filter(batch: tuple[int, ...] = (), **kw: object) -> MeanSquareHInfFilter:
    """The example with h h^T = 1e-4: the first intervals need ~1e3 RK4 substeps."""
    x0 = np.broadcast_to(M0_EX, (*batch, 4))
    return MeanSquareHInfFilter(A_EX, B_EX, C_EX, 1e-2 * h_EX, C_EX, H_EX, G_EX, b_EX, C_EX,
                                GAMMA_EX, R_EX, x0, P0_EX, 0.01, **kw)  # type: ignore[arg-type]


def test_rosenbrock_stiff_interval_converges_to_radau() -> None:
    """The stiff interval of the test above (P falls from 10 to 0.01 within it) with ROS2
    and the analytic block Jacobian: converges to Radau, with order 2 on the non-stiff S and
    a reduced order (about 1.3, the known order reduction of Rosenbrock-W methods in a stiff
    nonlinear transient) on m and P; at 40 substeps P is within 0.5 % of its size."""
    y = np.array([0.1, -0.2, 0.0, 0.0])

    def mats(_t: float) -> dict[str, np.ndarray]:
        return {**paper_mats(0.0), "h": 1e-2 * h_EX}

    ref = solve_ivp(joint_rhs(mats, y, U_EX, GAMMA_EX, 4), (0.0, 0.01),
                    np.concatenate([M0_EX, P0_EX.ravel(), np.linalg.inv(R_EX).ravel()]),
                    method="Radau", rtol=1e-10, atol=1e-12).y[:, -1]
    errors = []
    for substeps in (40, 80, 160):
        f = stiff_filter(substeps=substeps, method="rosenbrock")
        f.step(y, U_EX)
        errors.append([np.abs(f.x - ref[:4]).max(),
                       np.abs(f.P - ref[4:20].reshape(4, 4)).max(),
                       np.abs(f.S - ref[20:].reshape(4, 4)).max()])
    e = np.array(errors)
    assert e[0, 1] < 5e-3 * np.abs(ref[4:20]).max()
    ratios = e[1:] / e[:-1]
    assert np.all(ratios[:, :2] < 0.5)  # m and P: order > 1
    assert np.all((ratios[:, 2] > 0.2) & (ratios[:, 2] < 0.3))  # S: order 2


def test_rosenbrock_analytic_jacobian_equals_differences(monkeypatch) -> None:
    """The block-triangular analytic Jacobian gives what forward differences of the joint
    right-hand side give (a wrong block would change every ROS2 step), batched."""
    import filters.hinf_mean_square as module
    from filters.stiff import difference_solver, rosenbrock2

    rng = np.random.default_rng(3)
    ys = rng.normal(size=(20, 3, 4))
    analytic = stiff_filter((3,), substeps=6, method="rosenbrock")
    for y in ys:
        analytic.step(y, U_EX)

    def with_differences(rhs, s, t0, h, ns, solver, after, every):
        typical = 1e-3 * np.maximum(np.abs(s).max(axis=-1, keepdims=True), 1e-12)
        return rosenbrock2(rhs, s, t0, h, ns, difference_solver(rhs_batched(rhs), typical),
                           after, every)

    def rhs_batched(rhs):  # the filter's rhs takes (..., d); differences add an axis
        return lambda t, S: np.stack([rhs(t, S[..., j, :]) for j in range(S.shape[-2])], -2)

    monkeypatch.setattr(module, "rosenbrock2", with_differences)
    fd = stiff_filter((3,), substeps=6, method="rosenbrock")
    for y in ys:
        fd.step(y, U_EX)
    np.testing.assert_allclose(analytic.x, fd.x, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(analytic.P, fd.P, rtol=1e-6, atol=1e-9)


def test_rosenbrock_batch_equals_single_and_auto_switches() -> None:
    rng = np.random.default_rng(4)
    ys = rng.normal(size=(30, 2, 4))
    batch = stiff_filter((2,), substeps="auto", method="auto")
    singles = [stiff_filter(substeps="auto", method="auto") for _ in range(2)]
    used = set()
    for y in ys:
        batch.step(y, U_EX)
        used.add(batch.substeps)
        for i, f in enumerate(singles):
            f.step(y[i], U_EX)
    for i, f in enumerate(singles):
        np.testing.assert_allclose(batch.x[i], f.x, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(batch.P[i], f.P, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(batch.S[0], batch.S[1])
    assert batch.S.shape == (2, 4, 4)
    assert max(used) > 1  # stiff first intervals on ROS2, then fewer substeps
    with pytest.raises(ValueError, match="method must be"):
        stiff_filter(method="euler")
    with pytest.raises(ValueError, match="needs substeps='auto'"):
        stiff_filter(substeps=3, method="auto")
