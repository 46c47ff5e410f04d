"""Atomic outputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from testbed.io import atomic_path, write_json


def test_write_json_roundtrip_and_numpy(tmp_path):
    path = write_json(tmp_path / "sub" / "out.json", {"a": np.float64(1.5), "b": np.arange(3)})
    assert json.loads(path.read_text()) == {"a": 1.5, "b": [0, 1, 2]}
    assert [p.name for p in path.parent.iterdir()] == ["out.json"]


def test_nan_is_refused_and_nothing_is_written(tmp_path):
    with pytest.raises(ValueError, match="non-finite"):
        write_json(tmp_path / "out.json", {"a": float("nan")})
    assert list(tmp_path.iterdir()) == []


def test_interrupted_write_leaves_previous_file(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]
