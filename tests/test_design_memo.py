"""Designs memoized by their inputs, in-process and through a run's shared directory."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.estimators import memo


@pytest.fixture(autouse=True)
def _fresh():
    memo.clear()
    yield
    memo.clear()


def test_key_tells_arrays_apart_by_dtype_shape_and_bytes():
    a = np.arange(6.0)
    assert memo.key(a, 1) == memo.key(a.copy(), 1)
    assert memo.key(a, 1) != memo.key(a.reshape(2, 3), 1)
    assert memo.key(a, 1) != memo.key(a.astype(np.float32), 1)
    assert memo.key(a, 1) != memo.key(a, 2)
    assert memo.key(None) != memo.key("None", None)


def test_memoized_computes_once_and_keeps_no_failure():
    calls = []

    def compute():
        calls.append(1)
        return {"gain": np.ones(2)}

    first = memo.memoized("x", "k", compute)
    assert memo.memoized("x", "k", compute) is first and len(calls) == 1

    def fail():
        calls.append(1)
        raise ValueError("infeasible")

    for _ in range(2):
        with pytest.raises(ValueError, match="infeasible"):
            memo.memoized("x", "bad", fail)
    assert len(calls) == 3


def test_shared_directory_hands_a_design_to_another_process(tmp_path):
    with memo.shared_directory(tmp_path):
        value = memo.memoized("x", "k", lambda: np.arange(3.0))
    assert [p.name for p in tmp_path.iterdir()] == ["x-k.pkl"]  # no temporary file left
    memo.clear()  # another process: nothing in memory, the file on disk

    def must_not_run():
        raise AssertionError("recomputed")

    with memo.shared_directory(tmp_path):
        assert np.array_equal(memo.memoized("x", "k", must_not_run), value)
    memo.clear()  # outside the context the directory is not read
    with pytest.raises(AssertionError, match="recomputed"):
        memo.memoized("x", "k", must_not_run)


def test_an_unreachable_or_corrupt_directory_only_costs_a_recomputation(tmp_path):
    (tmp_path / "x-k.pkl").write_bytes(b"not a pickle")
    with memo.shared_directory(tmp_path):
        assert memo.memoized("x", "k", lambda: 7) == 7
    memo.clear()
    with memo.shared_directory(tmp_path / "missing"):
        assert memo.memoized("x", "k2", lambda: 8) == 8


def test_lmi_design_is_searched_once_per_design_system(monkeypatch):
    from testbed.estimators import lmi
    from testbed.rigs.linear_plant.rig import LinearPlantRig

    rig = LinearPlantRig()
    design = rig.design_model(rig.sensors(dt_s=0.01), 0.01)
    first, meta = lmi.lmi_estimator(design)
    monkeypatch.setattr(lmi, "minimal_gamma", lambda *a, **k: pytest.fail("searched again"))
    again, meta_again = lmi.lmi_estimator(design)
    assert again is not first and meta_again == meta  # the same gain, gamma, status
