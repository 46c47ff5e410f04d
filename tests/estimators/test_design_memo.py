"""Designs memoized by their inputs, in-process and through a run's shared directory."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.estimators import memo


def _any(value) -> bool:
    return True


def _array(value) -> bool:
    return isinstance(value, np.ndarray)


class _RaisesOnLoad:
    """Pickles to an entry whose unpickling raises ``ValueError`` (``int("x")``)."""

    def __reduce__(self):
        return (int, ("x",))


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

    first = memo.memoized("x", "k", compute, _any)
    assert memo.memoized("x", "k", compute, _any) is first and len(calls) == 1

    def fail():
        calls.append(1)
        raise ValueError("infeasible")

    for _ in range(2):
        with pytest.raises(ValueError, match="infeasible"):
            memo.memoized("x", "bad", fail, _any)
    assert len(calls) == 3


def test_shared_directory_hands_a_design_to_another_process(tmp_path):
    with memo.shared_directory(tmp_path):
        value = memo.memoized("x", "k", lambda: np.arange(3.0), _array)
    assert [p.name for p in tmp_path.iterdir()] == ["x-k.pkl"]  # no temporary file left
    memo.clear()  # another process: nothing in memory, the file on disk

    def must_not_run():
        raise AssertionError("recomputed")

    with memo.shared_directory(tmp_path):
        assert np.array_equal(memo.memoized("x", "k", must_not_run, _array), value)
    memo.clear()  # outside the context the directory is not read
    with pytest.raises(AssertionError, match="recomputed"):
        memo.memoized("x", "k", must_not_run, _array)


def test_an_unreachable_or_corrupt_directory_only_costs_a_recomputation(tmp_path):
    (tmp_path / "x-k.pkl").write_bytes(b"not a pickle")
    with memo.shared_directory(tmp_path):
        assert memo.memoized("x", "k", lambda: 7, _any) == 7
    memo.clear()
    with memo.shared_directory(tmp_path / "missing"):
        assert memo.memoized("x", "k2", lambda: 8, _any) == 8


@pytest.mark.parametrize("entry", [
    b"cbuiltins\nno_such_name\n.",              # AttributeError when unpickled
    __import__("pickle").dumps(_RaisesOnLoad()),  # ValueError when unpickled
    __import__("pickle").dumps("a string, not the design's type"),
    b"",                                           # EOFError
])
def test_a_damaged_or_wrong_entry_is_recomputed_whatever_it_raises(tmp_path, entry):
    tmp_path.chmod(0o700)
    (tmp_path / "x-k.pkl").write_bytes(entry)
    with memo.shared_directory(tmp_path):
        value = memo.memoized("x", "k", lambda: np.arange(2.0), _array)
    assert np.array_equal(value, np.arange(2.0))


def test_a_directory_others_can_write_is_neither_read_nor_written(tmp_path):
    import pickle

    (tmp_path / "x-k.pkl").write_bytes(pickle.dumps(np.arange(9.0)))  # planted
    tmp_path.chmod(0o777)
    with memo.shared_directory(tmp_path):
        assert np.array_equal(memo.memoized("x", "k", lambda: np.arange(2.0), _array),
                              np.arange(2.0))
        memo.memoized("x", "k3", lambda: np.arange(3.0), _array)
    assert not (tmp_path / "x-k3.pkl").exists()


def test_lmi_design_is_searched_once_per_design_system(monkeypatch):
    from testbed.estimators import stochastic_system as lmi
    from testbed.rigs.linear_plant.rig import LinearPlantRig

    rig = LinearPlantRig()
    design = rig.design_model(rig.sensors(dt_s=0.01), 0.01)
    first, meta = lmi.lmi_estimator(design)
    monkeypatch.setattr(lmi, "minimal_gamma", lambda *a, **k: pytest.fail("searched again"))
    again, meta_again = lmi.lmi_estimator(design)
    assert again is not first and meta_again == meta  # the same gain, gamma, status
