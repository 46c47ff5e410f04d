"""``testbed score`` on the command line: the list, the outputs and a user factory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main
from testbed.outputs.viz import rrd_summary
from testbed.score.report import RESULT_KEYS
from testbed.score.suite import get_suite

HERE = Path(__file__).resolve().parent


def test_list_shows_every_entry_with_both_profiles(capsys):
    assert main(["score", "--list", "--suite", "standard"]) == 0
    out = capsys.readouterr().out
    for entry in get_suite("standard"):
        assert entry.name in out
    assert "not available" not in out  # both rigs have the paper and hardware profiles
    assert any(e.profile == "hardware" for e in get_suite("standard"))
    quick = {e.name for e in get_suite("quick")}
    assert quick < {e.name for e in get_suite("standard")}


def test_score_writes_json_markdown_png_rrd(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    out = tmp_path / "runs"
    code = main(["score", "--estimator", "kalman", "--estimator", "fixed_gain:make",
                 "--suite", "quick", "--scenario", "calibration", "--runs", "3",
                 "--json", str(out / "s.json"), "--markdown", str(out / "s.md"),
                 "--plot", str(out / "s.png"), "--rrd", str(out / "s.rrd")])
    assert code == 0
    data = json.loads((out / "s.json").read_text())
    assert data["estimators"] == ["kalman", "fixed_gain:make"]
    assert [r["estimator"] for r in data["results"]] == data["estimators"]
    for res in data["results"]:
        assert tuple(res) == RESULT_KEYS
        assert res["worst_case_gain"] >= res["random_gain"] > 0
    assert data["units"]["position"] == "m"
    worst = np.load(out / "s.worst_case.npz")
    assert sorted(worst.files) == ["fixed_gain:make|calibration", "kalman|calibration"]
    assert "| kalman |" in (out / "s.md").read_text()
    assert (out / "s.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    entities = rrd_summary(out / "s.rrd")
    assert any("calibration/truth/position" in k for k in entities)
    assert any("calibration/estimate/fixed_gain_make/velocity" in k for k in entities)
    from testbed.outputs.rrd_inspect import inspect_rrd

    c = inspect_rrd(out / "s.rrd")  # every panel names its unit; errors on a round range
    assert c.views and all(v.name.endswith("]") for v in c.views)
    assert {"position [m]", "position error [m]"} <= {v.name for v in c.views}
    err = next(v for v in c.views if v.name == "position error [m]")
    assert err.y_range[0] == -err.y_range[1] and err.y_range[1] > 0
    assert err.time_range_s == pytest.approx(c.time_range_s)
    assert all(v.legend_visible is not None for v in c.views)
    assert c.styles["calibration/error/kalman/position"]["names"] == [
        "kalman: estimate − truth [m]"]
    printed = capsys.readouterr().out
    assert "calibration (3 runs)" in printed and "worst-case search" in printed


def test_score_argument_errors(capsys):
    assert main(["score"]) == 2
    assert "--estimator" in capsys.readouterr().err
    assert main(["score", "--estimator", "kalman", "--suite", "nope"]) == 2
    assert "nope" in capsys.readouterr().err
