"""Batches of filters whose members share one covariance (one ``P0``).

The Kalman-Bucy and mean-square H-infinity filters integrate such a shared ``P`` once, on one
member, and the discrete Kalman filter computes its covariance recursion and gain once: the
results must be bitwise those of the member-by-member computation, and the covariance checks
must raise the errors of the whole stack.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import filters.hinf_mean_square as hms
import filters.kalman as kalman
from filters import (
    DiscreteLinearSystem,
    FilterError,
    FiniteEscapeError,
    KalmanBucyFilter,
    KalmanFilter,
    LinearSystem,
    LossOfDefinitenessError,
    MeanSquareHInfFilter,
    check_covariance,
)
from filters._linalg import max_abs_eigenvalue, shared_member
from filters.errors import check_shared_covariance


def _spd(rng: np.random.Generator, n: int, scale: float = 1.0) -> np.ndarray:
    X = rng.standard_normal((n, n))
    return scale * (X @ X.T / n + 0.5 * np.eye(n))


def test_shared_member() -> None:
    rng = np.random.default_rng(0)
    P = _spd(rng, 3)
    stack = np.array(np.broadcast_to(P, (2, 4, 3, 3)))
    first = shared_member(stack)
    assert first.shape == (1, 1, 3, 3)
    assert np.array_equal(first[0, 0], P)
    assert shared_member(P) is P  # no batch axes
    stack[1, 2, 0, 0] += 1e-16 * P[0, 0] + 1e-300
    assert shared_member(stack) is stack
    nan = np.full((2, 3, 3), np.nan)
    assert shared_member(nan) is nan
    assert shared_member(np.zeros((3, 2)), core_ndim=1).shape == (1, 2)


def test_max_abs_eigenvalue_of_a_shared_stack() -> None:
    rng = np.random.default_rng(1)
    M = rng.standard_normal((4, 4))
    stack = np.array(np.broadcast_to(M, (5, 4, 4)))
    assert max_abs_eigenvalue(stack) == float(np.abs(np.linalg.eigvals(stack)).max())
    stack[3] *= 2.0
    assert max_abs_eigenvalue(stack) == float(np.abs(np.linalg.eigvals(stack)).max())


@pytest.mark.parametrize("bad", ["indefinite", "nan", "huge"])
def test_check_shared_covariance_raises_the_stack_error(bad: str) -> None:
    P = np.diag([1.0, 2.0, 3.0])
    if bad == "indefinite":
        P[2, 2] = -1.0
    elif bad == "nan":
        P[0, 1] = np.nan
    else:
        P[1, 1] = 1e13
    batch = (4,)
    with pytest.raises(FilterError) as expected:
        check_covariance(np.broadcast_to(P, (*batch, 3, 3)), time=0.5, quantity="P")
    with pytest.raises(FilterError) as got:
        check_shared_covariance(P[None], batch, time=0.5, quantity="P")
    assert type(got.value) is type(expected.value)
    assert type(got.value) is (LossOfDefinitenessError if bad == "indefinite"
                               else FiniteEscapeError)
    assert str(got.value) == str(expected.value)
    assert got.value.value.shape == expected.value.value.shape == (4, 3, 3)
    assert np.array_equal(got.value.value, expected.value.value, equal_nan=True)


def test_check_shared_covariance_returns_the_symmetrized_member() -> None:
    P = np.array([[[2.0, 1.0], [0.0, 3.0]]])
    assert np.array_equal(check_shared_covariance(P, (5,), time=0.0),
                          check_covariance(P, time=0.0))


def _without_sharing(monkeypatch: pytest.MonkeyPatch) -> None:
    for module in (kalman, hms):
        monkeypatch.setattr(module, "shared_member", lambda X, core_ndim=2: X)


def _run(f, ys: np.ndarray, us: np.ndarray) -> list[np.ndarray]:
    out = []
    for y, u in zip(ys, us, strict=True):
        f.step(y, u)
        out += [np.array(f.x), np.array(f.P), np.array(f.substeps)]
    return out


@pytest.mark.parametrize("r", [1.0, 1e-4])
def test_kalman_bucy_shared_p_is_bitwise_the_member_integration(
        r: float, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(2)
    n, m, k = 3, 2, 1
    system = LinearSystem(A=rng.standard_normal((n, n)) - np.eye(n),
                          B=rng.standard_normal((n, k)), C=rng.standard_normal((m, n)),
                          Q=_spd(rng, n, 0.3), R=_spd(rng, m, r))
    x0 = rng.standard_normal((5, n))
    P0 = _spd(rng, n, 2.0)
    ys, us = rng.standard_normal((12, 5, m)), rng.standard_normal((12, 5, k))
    shared = _run(KalmanBucyFilter(system, x0, P0, 0.02, substeps="auto"), ys, us)
    _without_sharing(monkeypatch)
    members = _run(KalmanBucyFilter(system, x0, P0, 0.02, substeps="auto"), ys, us)
    assert all(np.array_equal(a, b) for a, b in zip(shared, members, strict=True))


@pytest.mark.parametrize("method", ["rk4", "rosenbrock"])
def test_mean_square_shared_p_is_bitwise_the_member_integration(
        method: str, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(3)
    n, m1, q2, k = 3, 2, 1, 1
    A = rng.standard_normal((n, n)) - 1.5 * np.eye(n)
    B = rng.standard_normal((n, k))
    C1, C2 = rng.standard_normal((m1, n)), rng.standard_normal((q2, n))
    G = np.hstack([rng.standard_normal((n, 2)), np.zeros((n, q2))])
    H = np.hstack([np.zeros((q2, 2)), 2.0 * np.eye(q2)])
    x0 = rng.standard_normal((4, n))
    P0 = _spd(rng, n, 2.0)
    ys, us = rng.standard_normal((8, 4, m1 + q2)), rng.standard_normal((8, 4, k))

    def make() -> MeanSquareHInfFilter:
        return MeanSquareHInfFilter(A, B, C1, _spd(np.random.default_rng(4), m1, 1e-3), C2, H,
                                    G, _spd(np.random.default_rng(5), n, 0.3), np.eye(n),
                                    10.0, np.eye(n), x0, P0, 0.02, substeps="auto",
                                    noise_intensities=True, method=method)

    shared = _run(make(), ys, us)
    _without_sharing(monkeypatch)
    members = _run(make(), ys, us)
    assert all(np.array_equal(a, b) for a, b in zip(shared, members, strict=True))


# ------------------------------------------------------------- the discrete Kalman filter
def _discrete(rng: np.random.Generator, n: int, m: int = 2, k: int = 1) -> DiscreteLinearSystem:
    return DiscreteLinearSystem(F=rng.standard_normal((n, n)) / np.sqrt(n),
                                B=rng.standard_normal((n, k)), H=rng.standard_normal((m, n)),
                                D=rng.standard_normal((m, k)), Q=_spd(rng, n, 0.1),
                                R=_spd(rng, m, 0.5), dt_s=0.01)


def _kalman_run(f: KalmanFilter, ys: np.ndarray, us: np.ndarray) -> list[np.ndarray]:
    """Steps, and every third interval predict + update; everything public after each."""
    out = []
    for i, (y, u) in enumerate(zip(ys, us, strict=True)):
        if i % 3 == 2:
            f.predict(u)
            out += [np.array(f.x), np.array(f.P)]
            f.update(y, u)
        else:
            f.step(y, u)
        assert not f.x.flags.writeable and not f.P.flags.writeable
        assert f.P.flags.c_contiguous and f.P.shape == (*f.batch_shape, f.system.n, f.system.n)
        out += [np.array(f.x), np.array(f.P), f.innovation, f.innovation_cov, f.gain,
                np.array(f.t_s)]
    return out


def _member(out: list[np.ndarray], i: int) -> list[np.ndarray]:
    return [a if a.ndim == 0 else a[i] for a in out]


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 6, 7])
@pytest.mark.parametrize("priors", ["shared", "different"])
def test_kalman_shared_p_is_bitwise_member_by_member(
        n: int, priors: str, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(10 + n)
    system = _discrete(rng, n)
    N = 6
    x0 = rng.standard_normal((N, n))
    P0 = _spd(rng, n) if priors == "shared" else np.array([_spd(rng, n) for _ in range(N)])
    ys, us = rng.standard_normal((10, N, 2)), rng.standard_normal((10, N, 1))
    ys[4] = ys[4, 0]  # one measurement broadcast to the batch
    f = KalmanFilter(system, x0, P0)
    assert (f._P_shared is not None) == (priors == "shared")
    batch = _kalman_run(f, ys, us)
    assert (f._P_shared is not None) == (priors == "shared")
    for i in range(N):  # each member alone, a batch of one
        alone = _kalman_run(KalmanFilter(system, x0[i:i + 1], P0 if P0.ndim == 2 else P0[i]),
                            ys[:, i:i + 1], us[:, i:i + 1])
        assert all(np.array_equal(a, b) for a, b in zip(_member(batch, i), _member(alone, 0),
                                                        strict=True))
    _without_sharing(monkeypatch)
    stack = _kalman_run(KalmanFilter(system, x0, P0), ys, us)
    assert all(np.array_equal(a, b) and a.shape == b.shape
               for a, b in zip(batch, stack, strict=True))


def _kalman_failure(case: str, shared: bool) -> tuple[FilterError, list[np.ndarray]]:
    """The error of a failing batched step and the filter's state after it."""
    rng = np.random.default_rng(20)
    n, N = 3, 4
    system = _discrete(rng, n)
    H = system.H
    if case == "escape":  # unmeasured, exploding third state
        system = DiscreteLinearSystem(F=np.diag([0.5, 0.5, 1e5]), B=system.B, H=np.eye(2, n),
                                      Q=system.Q, R=system.R, dt_s=0.01)
    f = KalmanFilter(system, rng.standard_normal((N, n)), _spd(rng, n))
    assert (f._P_shared is not None) == shared
    if case == "indefinite":
        f._Q = -10.0 * np.eye(n)
    elif case == "singular":  # S = H P H^T with a zero row
        f._H = H * np.array([[1.0], [0.0]])
        f._HT = np.ascontiguousarray(f._H.T)
        f._R = np.zeros((2, 2))
    before = [np.array(f.x), np.array(f.P)]
    with pytest.raises(FilterError) as caught:
        for _ in range(5):
            before = [np.array(f.x), np.array(f.P)]
            f.step(rng.standard_normal((N, 2)), rng.standard_normal((N, 1)))
    assert all(np.array_equal(a, b) for a, b in zip(before, [f.x, f.P], strict=True))
    return caught.value, [np.array(f.x), np.array(f.P)]


@pytest.mark.parametrize(("case", "error", "quantity"), [
    ("escape", FiniteEscapeError, "P"), ("indefinite", LossOfDefinitenessError, "P"),
    ("singular", LossOfDefinitenessError, "innovation_cov")])
def test_kalman_shared_p_failure_raises_the_stack_error(
        case: str, error: type, quantity: str, monkeypatch: pytest.MonkeyPatch) -> None:
    got, state = _kalman_failure(case, shared=True)
    _without_sharing(monkeypatch)
    expected, expected_state = _kalman_failure(case, shared=False)
    assert type(got) is type(expected) is error
    assert got.quantity == expected.quantity == quantity
    assert got.time == expected.time > 0.0
    assert str(got) == str(expected)
    assert got.value.shape == expected.value.shape == ((4, 3, 3) if quantity == "P"
                                                       else (4, 2, 2))
    assert np.array_equal(got.value, expected.value, equal_nan=True)
    assert all(np.array_equal(a, b) for a, b in zip(state, expected_state, strict=True))


def test_kalman_shared_p_settled_cycle_is_not_recomputed(monkeypatch: pytest.MonkeyPatch) -> None:
    """A shared covariance settles into a short cycle of floating-point values: the steps
    then reuse the kept results, bitwise what the computation gives (also after a reset)."""
    rng = np.random.default_rng(30)
    system = _discrete(rng, 3)
    N, T = 5, 200
    x0, P0 = rng.standard_normal((N, 3)), _spd(rng, 3)
    ys, us = rng.standard_normal((2 * T, N, 2)), rng.standard_normal((2 * T, N, 1))
    calls = []
    compute = KalmanFilter._gain_and_covariance

    def counted(self: KalmanFilter, P: np.ndarray, steps: int):
        calls.append(steps)
        return compute(self, P, steps)

    def run() -> list[np.ndarray]:
        f = KalmanFilter(system, x0, P0)
        out = []
        for i in range(2 * T):
            if i == T:
                f.reset(x0, P0)
            f.step(ys[i], us[i])
            out += [np.array(f.x), np.array(f.P), f.innovation, f.innovation_cov, f.gain]
        return out

    monkeypatch.setattr(KalmanFilter, "_gain_and_covariance", counted)
    shared = run()
    assert len(calls) < T  # computed until the cycle closed, twice
    calls.clear()
    _without_sharing(monkeypatch)
    members = run()
    assert len(calls) == 2 * T
    assert all(np.array_equal(a, b) for a, b in zip(shared, members, strict=True))


def test_kalman_shared_gain_is_stacked_when_read() -> None:
    """A shared batch keeps the gain and innovation covariance as its one member and stacks
    them when read: new C-contiguous stacks of the member, never the kept arrays."""
    rng = np.random.default_rng(42)
    system = _discrete(rng, 3)
    f = KalmanFilter(system, rng.standard_normal((4, 3)), _spd(rng, 3))
    assert f.gain is None and f.innovation_cov is None
    y, u = rng.standard_normal((4, 2)), rng.standard_normal((4, 1))
    f.step(y, u)
    K, S = f.gain, f.innovation_cov
    assert K.shape == (4, 3, 2) and S.shape == (4, 2, 2)
    assert K.flags.c_contiguous and S.flags.c_contiguous
    assert f.gain is K  # stacked once
    kept = f._memo[next(iter(f._memo))]
    assert all(K is not a and S is not a for a in kept)
    K[...] = np.nan  # the caller's copy: the kept results are untouched
    g = KalmanFilter(system, f.x, f.P[0])
    f.step(y, u)
    g.step(y, u)
    assert np.array_equal(f.gain, g.gain) and np.array_equal(f.P, g.P)


def test_all_finite_is_numpy_isfinite_all() -> None:
    """``filters.all_finite`` (one sum of squares, else the exact test) agrees with
    ``np.isfinite(a).all()``: NaN, infinities, sums that overflow with finite entries,
    other dtypes and empty arrays."""
    from filters import all_finite

    cases = [np.zeros((0, 3)), np.ones((4, 3)), np.array([1e200, 1e200, -1e300]),
             np.array([np.nan, 1.0]), np.array([[np.inf], [1.0]]), np.array([-np.inf, np.inf]),
             np.array([1.0, np.nan], dtype=np.float32), np.arange(6).reshape(2, 3),
             np.full((3, 2), 1e30, dtype=np.float32), np.ones((5, 4))[:, ::2]]
    for a in cases:
        assert all_finite(a) == bool(np.isfinite(a).all()), a


def test_kalman_covariance_memo_shared_between_threads_is_bitwise_unshared(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Batches of one model sharing a :class:`CovarianceMemo` in several threads (the lanes
    of a Monte Carlo): each covariance step is computed once for all of them, the results
    are bitwise those without the memo, and another model gets a table of its own."""
    import threading

    rng = np.random.default_rng(40)
    system = _discrete(rng, 4)
    other = _discrete(rng, 4)
    T = 150
    sizes = (5, 3, 5, 1)  # a batch of one is its own shared member: it uses the memo too
    x0s = [rng.standard_normal((N, 4)) for N in sizes]
    P0 = _spd(rng, 4)
    data = [(rng.standard_normal((T, N, 2)), rng.standard_normal((T, N, 1))) for N in sizes]
    calls: list[int] = []
    compute = KalmanFilter._gain_and_covariance

    def counted(self: KalmanFilter, P: np.ndarray, steps: int):
        calls.append(steps)
        return compute(self, P, steps)

    monkeypatch.setattr(KalmanFilter, "_gain_and_covariance", counted)

    def run(j: int, memo: kalman.CovarianceMemo | None, out: list) -> None:
        f = KalmanFilter(other if j == 2 else system, x0s[j], P0)
        f.share_covariance_memo(memo)
        ys, us = data[j]
        for i in range(T):
            f.step(ys[i], us[i])
            out += [np.array(f.x), np.array(f.P), f.innovation, f.innovation_cov, f.gain]

    alone: list[list] = [[] for _ in sizes]
    per_batch = []
    for j in range(len(sizes)):
        before = len(calls)
        run(j, None, alone[j])
        per_batch.append(len(calls) - before)
    # one sequence per batch (until it settles into a cycle), the batch of one's too
    assert per_batch[0] == per_batch[1] == per_batch[3] > 0 and per_batch[2] > 0
    assert per_batch[0] < T
    calls.clear()
    memo = kalman.CovarianceMemo()
    together: list[list] = [[] for _ in sizes]
    threads = [threading.Thread(target=run, args=(j, memo, together[j]))
               for j in range(len(sizes))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for a, b in zip(alone, together, strict=True):
        assert len(a) == len(b)
        assert all(np.array_equal(u, v) and u.shape == v.shape for u, v in zip(a, b, strict=True))
    # the three batches of `system` computed its sequence once, `other` its own
    assert len(calls) == per_batch[0] + per_batch[2]
    assert len(memo._tables) == 2 and len(memo) == per_batch[0] + per_batch[2]
    with pytest.raises(TypeError, match="CovarianceMemo"):
        KalmanFilter(system, x0s[0], P0).share_covariance_memo({})  # type: ignore[arg-type]


def test_kalman_covariance_memo_keeps_at_most_max_steps_and_only_checked_steps() -> None:
    rng = np.random.default_rng(41)
    system = _discrete(rng, 3)
    memo = kalman.CovarianceMemo(max_steps=7)
    f = KalmanFilter(system, rng.standard_normal((4, 3)), _spd(rng, 3))
    f.share_covariance_memo(memo)
    g = KalmanFilter(system, rng.standard_normal((4, 3)), _spd(rng, 3))
    for _ in range(30):
        y, u = rng.standard_normal((4, 2)), rng.standard_normal((4, 1))
        f.step(y, u)
        g.step(y, u)
    assert len(memo) == 7
    f.reset(np.zeros((4, 3)), g.P[0])  # reset keeps the memo (for the batch's rank)
    assert f._memo_table is next(iter(memo._tables.values()))
    with pytest.raises(ValueError, match="max_steps"):
        kalman.CovarianceMemo(max_steps=-1)
    # a step whose covariance check fails raises and is not kept
    bad = kalman.CovarianceMemo()
    h = KalmanFilter(system, np.zeros((2, 3)), 1e13 * np.eye(3))
    h.share_covariance_memo(bad)
    with pytest.raises(FiniteEscapeError):
        h.step(np.zeros((2, 2)), np.zeros((2, 1)))
    assert len(bad) == 0


def _defer_case(zero: str, failing: bool, priors: str) -> KalmanFilter:
    rng = np.random.default_rng(50)
    n, N = 3, 4
    s = _discrete(rng, n)
    F, B, H, D = s.F, s.B, s.H, s.D
    if zero == "gain":  # H = 0: K = 0
        H = np.zeros_like(H)
    elif zero == "input":  # u enters nowhere
        B, D = np.zeros_like(B), np.zeros_like(D)
    system = DiscreteLinearSystem(F=F, B=B, H=H, D=D, Q=s.Q, R=s.R, dt_s=0.01)
    P0 = _spd(rng, n) if priors == "shared" else np.array([_spd(rng, n) for _ in range(N)])
    f = KalmanFilter(system, rng.standard_normal((N, n)), P0)
    assert (f._P_shared is not None) == (priors == "shared")
    if failing:  # the covariance step raises LossOfDefinitenessError
        f._Q = -10.0 * np.eye(n)
    return f


@pytest.mark.parametrize("zero", ["none", "gain", "input"])
@pytest.mark.parametrize("failing", [False, True])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", ["y", "u", "both"])
def test_kalman_shared_step_non_finite_input_raises_its_value_error_first(
        zero: str, failing: bool, bad: float, where: str) -> None:
    """A shared batch's step with a non-finite whole-batch float64 y or u raises the same
    ValueError as member by member (y before u, before a covariance error), the filter
    unchanged; also when the gain, or B and D, are zero."""
    for priors in ("shared", "different"):
        f = _defer_case(zero, failing, priors)
        y, u = np.zeros((4, 2)), np.zeros((4, 1))
        if where in ("y", "both"):
            y[2, 1] = bad
        if where in ("u", "both"):
            u[1, 0] = bad
        before = [np.array(f.x), np.array(f.P), f.t_s]
        name = "u" if where == "u" else "y"
        with pytest.raises(ValueError, match=rf"^{name} must be finite, got non-finite entries$"):
            f.step(y, u)
        assert all(np.array_equal(a, b) for a, b in zip(before, [f.x, f.P, f.t_s], strict=True))
        assert f.innovation is None and f.gain is None
        if failing:  # finite inputs: the covariance error
            with pytest.raises(LossOfDefinitenessError):
                f.step(np.zeros((4, 2)), np.zeros((4, 1)))


def test_kalman_shared_step_validates_shapes_before_finiteness() -> None:
    f = _defer_case("none", False, "shared")
    nan_y = np.full((4, 2), np.nan)
    with pytest.raises(ValueError, match=r"^y must be finite"):  # before u's shape
        f.step(nan_y, np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"^u must have shape"):
        f.step(np.zeros((4, 2)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"^y must have shape"):
        f.step(np.zeros((4, 3)), np.full((4, 1), np.nan))
    with pytest.raises(ValueError, match=r"^y must be finite"):  # broadcast y: tested first
        f.step(np.array([0.0, np.nan]), np.zeros((4, 1)))
    with pytest.raises(ValueError, match=r"^u must be finite"):  # another dtype: tested first
        f.step(np.zeros((4, 2), dtype=np.float32), np.full((4, 1), np.inf, dtype=np.float32))
    f.step(np.zeros((4, 2)), None)
    assert f.t_s == pytest.approx(0.01)


def test_kalman_state_overflow_is_still_a_state_error() -> None:
    """Finite inputs whose state overflows: FiniteEscapeError for x, as before."""
    f = _defer_case("none", False, "shared")
    with pytest.raises(FiniteEscapeError) as caught:
        f.step(np.full((4, 2), 1e308), np.full((4, 1), 1e308))
    assert caught.value.quantity == "x"


def test_kalman_shared_p_steps_are_computed_ahead(monkeypatch: pytest.MonkeyPatch) -> None:
    """A shared batch's step computes the following steps too (kept): one computation burst
    per ``_AHEAD_STEPS`` steps, bitwise the member-by-member results."""
    rng = np.random.default_rng(60)
    system = _discrete(rng, 3)
    N, T = 3, kalman._AHEAD_STEPS + 3
    x0, P0 = rng.standard_normal((N, 3)), _spd(rng, 3, 100.0)  # far from settled
    ys, us = rng.standard_normal((T, N, 2)), rng.standard_normal((T, N, 1))
    bursts: list[int] = []
    compute = KalmanFilter._gain_and_covariance

    def counted(self: KalmanFilter, P: np.ndarray, steps: int):
        bursts.append(self._steps)  # the step being made when it is computed
        return compute(self, P, steps)

    def run(f: KalmanFilter) -> list[np.ndarray]:
        out = []
        for y, u in zip(ys, us, strict=True):
            f.step(y, u)
            out += [np.array(f.x), np.array(f.P), f.innovation, f.innovation_cov, f.gain]
        return out

    monkeypatch.setattr(KalmanFilter, "_gain_and_covariance", counted)
    shared = run(KalmanFilter(system, x0, P0))
    assert sorted(set(bursts)) == [0, kalman._AHEAD_STEPS]
    assert bursts[:kalman._AHEAD_STEPS] == [0] * kalman._AHEAD_STEPS
    assert kalman._AHEAD_STEPS < len(bursts) <= 2 * kalman._AHEAD_STEPS
    _without_sharing(monkeypatch)
    stack = run(KalmanFilter(system, x0, P0))
    assert all(np.array_equal(a, b) and a.shape == b.shape
               for a, b in zip(shared, stack, strict=True))


def _escaping(shared: bool) -> tuple[list[np.ndarray], FilterError]:
    """An unmeasured unstable state: P escapes the bound after about 20 steps."""
    system = DiscreteLinearSystem(F=np.diag([0.5, 2.0]), B=np.ones((2, 1)), H=np.eye(1, 2),
                                  Q=0.1 * np.eye(2), R=np.eye(1), dt_s=0.01)
    f = KalmanFilter(system, np.zeros((2, 2)), np.eye(2))
    assert (f._P_shared is not None) == shared
    out: list[np.ndarray] = []
    with pytest.raises(FilterError) as caught:
        for _ in range(100):
            f.step(np.zeros((2, 1)), np.zeros((2, 1)))
            out += [np.array(f.x), np.array(f.P), np.array(f.t_s)]
    return out, caught.value


def test_kalman_shared_p_step_ahead_failure_raises_at_its_time(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A step computed ahead that fails is not kept: the step raises at its own time."""
    shared, got = _escaping(True)
    _without_sharing(monkeypatch)
    members, expected = _escaping(False)
    assert 10 < len(shared) // 3 < 100
    assert type(got) is type(expected) is FiniteEscapeError
    assert got.time == expected.time and str(got) == str(expected)
    assert all(np.array_equal(a, b) for a, b in zip(shared, members, strict=True))


def _underflow_warnings(shared: bool) -> list[int]:
    """Warnings per step of a state decaying to zero, with ``numpy.errstate(under="warn")``."""
    system = DiscreteLinearSystem(F=np.diag([1e-30, 0.9]), B=np.ones((2, 1)),
                                  H=np.array([[0.0, 1.0]]), Q=np.diag([0.0, 0.1]), R=np.eye(1),
                                  dt_s=0.01)
    f = KalmanFilter(system, np.zeros((2, 2)), np.eye(2))
    assert (f._P_shared is not None) == shared
    counts = []
    with np.errstate(under="warn"):
        for _ in range(12):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                f.step(np.zeros((2, 1)), np.zeros((2, 1)))
            counts.append(len(caught))
    return counts


def test_kalman_shared_p_step_ahead_that_would_warn_warns_at_its_time(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A step computed ahead that sets a floating-point flag the caller does not ignore is
    dropped and computed (warning) at its own time."""
    got = _underflow_warnings(True)
    _without_sharing(monkeypatch)
    assert got == _underflow_warnings(False)
    assert got[0] == 0 and sum(got) > 1


@pytest.mark.parametrize("n", [1, 4, 7])
def test_kalman_batch_of_one_shares_its_covariance_bitwise_as_the_stack(
        n: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """A batch of one takes the shared-covariance path (its memo, its steps ahead): every
    public value bitwise the stack path's (a batch of one without sharing)."""
    rng = np.random.default_rng(60 + n)
    system = _discrete(rng, n)
    x0, P0 = rng.standard_normal((1, n)), _spd(rng, n)
    ys, us = rng.standard_normal((40, 1, 2)), rng.standard_normal((40, 1, 1))
    f = KalmanFilter(system, x0, P0)
    assert f.shared_P is not None and f.shared_P.shape == (n, n)
    shared = _kalman_run(f, ys, us)
    assert f.shared_innovation_cov is not None
    assert np.array_equal(f.shared_innovation_cov, f.innovation_cov[0])
    assert not f.shared_P.flags.writeable and not f.P.flags.writeable  # the kept arrays
    monkeypatch.setattr(KalmanFilter, "_shared", lambda self, P: None)
    g = KalmanFilter(system, x0, P0)
    assert g.shared_P is None
    stack = _kalman_run(g, ys, us)
    assert all(np.array_equal(a, b) and a.shape == b.shape
               for a, b in zip(shared, stack, strict=True))
