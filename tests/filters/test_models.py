"""Validation and discretization of :mod:`filters.models`."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.signal import cont2discrete

from filters.models import DiscreteLinearSystem, LinearSystem


def _valid(n: int = 4, m: int = 2, k: int = 1) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {
        "A": rng.standard_normal((n, n)),
        "B": rng.standard_normal((n, k)),
        "C": rng.standard_normal((m, n)),
        "Q": np.eye(n),
        "R": np.eye(m),
    }


@pytest.mark.parametrize(
    ("name", "value", "fragment"),
    [
        ("Q", np.eye(3), "Q must be symmetric positive semidefinite with shape (4, 4), got shape"),
        ("Q", np.triu(np.ones((4, 4))), "got a non-symmetric matrix"),
        ("Q", np.diag([1.0, 1.0, -1.0, 1.0]), "minimum eigenvalue -1"),
        ("Q", np.full((4, 4), np.nan), "non-finite"),
        ("R", np.eye(3), "R must be symmetric positive definite with shape (2, 2), got shape"),
        ("R", np.array([[1.0, 0.5], [0.0, 1.0]]), "non-symmetric"),
        ("R", np.diag([1.0, 0.0]), "R must be symmetric positive definite"),
        ("R", np.diag([1.0, -2.0]), "minimum eigenvalue -2"),
        ("A", np.ones((4, 3)), "A must be a finite square matrix"),
        ("A", np.ones(4), "got shape (4,)"),
        ("B", np.ones((3, 1)), "B must be a finite matrix with shape (4, k), got shape (3, 1)"),
        ("C", np.ones((2, 3)), "C must be a finite matrix with shape (m, 4)"),
        ("C", "abc", "C must be a real numeric array"),
    ],
)
def test_bad_continuous_arguments_raise_naming_argument(
    name: str, value: object, fragment: str
) -> None:
    kwargs: dict[str, object] = dict(_valid())
    kwargs[name] = value
    with pytest.raises(ValueError, match=rf"^{name} ") as info:
        LinearSystem(**kwargs)  # type: ignore[arg-type]
    assert fragment in str(info.value)


def test_bad_discrete_arguments_and_dt() -> None:
    v = _valid()
    with pytest.raises(ValueError, match=r"^F must be a finite square matrix"):
        DiscreteLinearSystem(F=np.ones((4, 2)), B=v["B"], H=v["C"], Q=v["Q"], R=v["R"])
    with pytest.raises(ValueError, match=r"^H must be a finite matrix with shape \(m, 4\)"):
        DiscreteLinearSystem(F=v["A"], B=v["B"], H=np.ones((2, 5)), Q=v["Q"], R=v["R"])
    with pytest.raises(ValueError, match=r"^dt_s must be a positive finite float"):
        DiscreteLinearSystem(F=v["A"], B=v["B"], H=v["C"], Q=v["Q"], R=v["R"], dt_s=0.0)
    with pytest.raises(ValueError, match=r"^D must be a finite matrix with shape \(2, 1\)"):
        LinearSystem(**v, D=np.ones((2, 2)))
    with pytest.raises(ValueError, match=r"^dt_s must be a positive finite float"):
        LinearSystem(**v).discretize(-1.0)


def test_storage_is_float64_readonly_copy_and_dimensions() -> None:
    v = _valid()
    A = v["A"].copy()
    sys_ = LinearSystem(A=A, B=None, C=v["C"].astype(np.float32), Q=v["Q"], R=v["R"])
    A[0, 0] = 123.0
    assert sys_.A[0, 0] != 123.0
    assert sys_.C.dtype == np.float64
    assert sys_.B.shape == (4, 0)
    assert sys_.D.shape == (2, 0)
    assert (sys_.n, sys_.m, sys_.k) == (4, 2, 0)
    with pytest.raises(ValueError, match="read-only"):
        sys_.Q[0, 0] = 2.0
    # tiny asymmetry from rounding is accepted and removed
    Q = np.eye(4)
    Q[0, 1] = 1e-14
    assert np.array_equal(LinearSystem(**{**v, "Q": Q}).Q, LinearSystem(**{**v, "Q": Q}).Q.T)


def test_double_integrator_closed_form() -> None:
    dt, q, r = 0.1, 2.5, 0.3
    sys_ = LinearSystem(
        A=[[0.0, 1.0], [0.0, 0.0]],
        B=[[0.0], [1.0]],
        C=[[1.0, 0.0]],
        Q=[[0.0, 0.0], [0.0, q]],
        R=[[r]],
    )
    d = sys_.discretize(dt)
    np.testing.assert_allclose(d.F, [[1.0, dt], [0.0, 1.0]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(d.B, [[dt**2 / 2], [dt]], rtol=1e-14, atol=1e-17)
    Qd = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    np.testing.assert_allclose(d.Q, Qd, rtol=1e-12, atol=0)
    np.testing.assert_allclose(d.R, [[r / dt]], rtol=1e-15)
    np.testing.assert_array_equal(d.H, sys_.C)
    assert d.dt_s == dt


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_zoh_matches_scipy_cont2discrete(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, m, k, dt = 3 + seed, 2, 2, 0.05 * seed
    A = rng.standard_normal((n, n))
    B = rng.standard_normal((n, k))
    C = rng.standard_normal((m, n))
    G = rng.standard_normal((n, n))
    sys_ = LinearSystem(A=A, B=B, C=C, Q=G @ G.T, R=np.eye(m))
    d = sys_.discretize(dt)
    Fd, Bd, _, _, _ = cont2discrete((A, B, C, np.zeros((m, k))), dt, method="zoh")
    np.testing.assert_allclose(d.F, Fd, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(d.B, Bd, rtol=1e-12, atol=1e-13)
    # Van Loan against a fine trapezoid quadrature of int_0^dt e^{As} Q e^{A^T s} ds
    s = np.linspace(0.0, dt, 2001)
    integrand = np.stack([expm(A * si) @ sys_.Q @ expm(A * si).T for si in s])
    np.testing.assert_allclose(d.Q, np.trapezoid(integrand, s, axis=0), rtol=1e-6, atol=1e-10)
    np.testing.assert_array_equal(d.Q, d.Q.T)
