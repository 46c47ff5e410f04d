"""The one NEES formula (:func:`testbed.experiment.metrics.nees`): its value, and the same
bits alone, in a batch and against a shared covariance."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.experiment.metrics import NEES_ELEMENTWISE_MAX, EpisodeMetrics, nees
from testbed.score import stats


def _covariances(rng: np.random.Generator, batch: int, n: int) -> np.ndarray:
    A = rng.normal(size=(batch, n, n))
    return A @ A.mT + 0.1 * np.eye(n)


def _lu(error: np.ndarray, P: np.ndarray) -> np.ndarray:
    """An independent value: e^T P^-1 e through LAPACK's LU solve."""
    return np.vecdot(error, np.linalg.solve(P, error[..., None])[..., 0])


@pytest.mark.parametrize("n", range(1, NEES_ELEMENTWISE_MAX + 3))
def test_value_and_bits_alone_batched_and_shared(n):
    rng = np.random.default_rng(n)
    P = _covariances(rng, 32, n)
    e = rng.normal(size=(32, n))
    batched = nees(e, P)
    np.testing.assert_allclose(batched, _lu(e, P), rtol=1e-12)
    alone = np.array([nees(e[i], P[i]) for i in range(32)])
    assert all(isinstance(nees(e[i], P[i]), float) for i in range(2))
    np.testing.assert_array_equal(batched, alone)
    # one covariance shared by the batch: factored once, the same bits as each row's own
    shared = nees(e, P[0])
    np.testing.assert_array_equal(shared, nees(e, np.repeat(P[:1], 32, axis=0)))
    np.testing.assert_array_equal(shared, [nees(e[i], P[0]) for i in range(32)])
    # leading axes beyond one
    np.testing.assert_array_equal(nees(e.reshape(4, 8, n), P.reshape(4, 8, n, n)),
                                  batched.reshape(4, 8))


def test_closed_forms():
    assert nees(np.array([3.0]), np.array([[4.0]])) == 9.0 / 4.0
    P = np.diag([4.0, 0.25])
    assert nees(np.array([2.0, 1.0]), P) == 1.0 + 4.0
    e = np.array([[2.0, 1.0], [0.0, 0.5]])
    np.testing.assert_array_equal(nees(e, P), [5.0, 1.0])


def test_a_matrix_that_is_not_positive_definite_gets_the_lu_value_row_by_row():
    indefinite = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and -1
    e = np.array([[1.0, 0.5], [0.3, 0.2]])
    np.testing.assert_allclose(nees(e, indefinite), _lu(e, indefinite), rtol=1e-15)
    stack = np.stack([np.eye(2), indefinite])
    mixed = nees(e, stack)
    assert mixed[0] == nees(e[0], np.eye(2)) == 1.25
    assert mixed[1] == nees(e[1], indefinite)
    with pytest.raises(np.linalg.LinAlgError):
        nees(np.ones(2), np.ones((2, 2)))  # singular: LAPACK's error, as before


def test_non_finite_covariance_is_not_factored_elementwise():
    P = np.array([[np.inf, 0.0], [0.0, 1.0]])
    e = np.ones((3, 2))
    assert nees(e[0], P) == nees(e, np.repeat(P[None], 3, axis=0))[0]


def test_metrics_and_score_use_the_same_formula():
    rng = np.random.default_rng(7)
    P = _covariances(rng, 6, 3).reshape(2, 3, 3, 3)
    err = rng.normal(size=(2, 3, 3))
    np.testing.assert_array_equal(stats.nees(err, P), nees(err, P))
    m = EpisodeMetrics(["a", "b", "c"], 0.1, [0, None, None])
    m.reset(np.zeros((2, 3)))
    for k in range(3):
        m.update(err[:, k], np.zeros((2, 3)), P[:, k], np.zeros((2, 3)), None)
    np.testing.assert_array_equal(m.nees_mean(), (nees(-err, P)).sum(axis=1) / 3)
