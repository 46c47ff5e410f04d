"""``testbed score`` on the command line: the list, the outputs and a user factory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main
from testbed.outputs.viz import rrd_summary
from testbed.score.report import RESULT_KEYS
from testbed.score.suite import SUITE_VERSIONS, get_suite, suite_hash, suite_identity

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
    assert f"suite standard version {SUITE_VERSIONS['standard']} sha256 " \
        f"{suite_hash('standard')}" in out


#: The definitions of each suite version (2: the scenarios carry design_profile, the
#: hardware entries design from the matched model; standard 3: the Quanser Aero entries;
#: standard 4: basin-ms-hinf out of the ranked suite). A
#: change of an entry changes the hash: bump the
#: suite's version in testbed.score.suite.SUITE_VERSIONS and record the new hash here.
PINNED = {"quick": (2, "8f051e84817fd8d8285a33a19f21d4d45c8fe020d28aa67e3e1c4cc3403c6808"),
          "standard": (4, "38f7d8bd0164eafbfe04ca96d2e73e183c1a07665b28884f4fdeb0b2e57ee58f")}


def test_suite_versions_and_hashes_are_pinned():
    for name, (version, digest) in PINNED.items():
        identity = suite_identity(name)
        assert (identity["version"], identity["hash"]) == (version, digest), (
            f"suite {name!r} changed: bump SUITE_VERSIONS[{name!r}] and record the new hash "
            f"{identity['hash']}")
    runs_changed = get_suite("quick")[0].replace(runs=33)
    assert runs_changed.describe() != get_suite("quick")[0].describe()


def test_score_writes_json_markdown_png_rrd(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    out = tmp_path / "runs"
    code = main(["score", "--estimator", "kalman", "--estimator", "fixed_gain:make",
                 "--suite", "quick", "--scenario", "calibration", "--runs", "3",
                 "--reference", "kalman-bucy", "--json", str(out / "s.json"),
                 "--markdown", str(out / "s.md"), "--plot", str(out / "s.png"),
                 "--rrd", str(out / "s.rrd")])
    assert code == 0
    data = json.loads((out / "s.json").read_text())
    assert data["estimators"] == ["kalman", "fixed_gain:make"]
    assert [r["estimator"] for r in data["results"]] == data["estimators"]
    identity = suite_identity("quick")
    assert (data["suite_version"], data["suite_hash"]) == (identity["version"],
                                                           identity["hash"])
    assert data["reference"] == "kalman-bucy"  # run for the comparison, not reported itself
    for res in data["results"]:
        assert tuple(res) == RESULT_KEYS
        assert res["worst_case_gain"] >= res["random_gain"] > 0
        versus = res["versus_reference"]
        assert versus["reference"] == "kalman-bucy"
        assert set(versus["states"]) == {"position", "velocity"}
        for comparison in versus["states"].values():
            assert comparison["verdict"] in ("better", "worse", "equivalent", "inconclusive")
            assert comparison["difference_ci"][0] <= comparison["difference_ci"][1]
    kalman = data["results"][0]
    assert len(kalman["nees_test"]["per_step"]) == kalman["nees_test"]["steps"] == 500
    assert kalman["whiteness"]["verdict"] in ("white", "correlated")
    assert data["units"]["position"] == "m"
    worst = np.load(out / "s.worst_case.npz")
    assert sorted(worst.files) == ["fixed_gain:make|calibration", "kalman|calibration"]
    markdown = (out / "s.md").read_text()
    assert "| kalman |" in markdown and identity["hash"] in markdown
    assert "kalman vs kalman-bucy (MSE ratio and difference per run" in markdown
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
    from testbed.outputs.viz import time_axis_range

    assert err.time_range_s == pytest.approx(time_axis_range(c.time_range_s))  # + margin
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
