"""Reproductions of Wang & Fang (2006) (continuous) and Liu, Deng & Wang (n.d.) (discrete):
keys, numbers, CLI."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

from testbed.cli import main
from testbed.reproductions import liu_variance_constrained_discrete as vd
from testbed.reproductions import load
from testbed.reproductions import wang_variance_constrained_parabolic as vc

DESIGN_KEYS = {"solved", "Q1", "Q2", "K", "G"}
PUBLISHED_KEYS = {"name", "K", "G", "hinf_worst", "variance_worst", "poles_in_region",
                  "worst_F", "covariance"}


def _finite(obj) -> bool:
    """No NaN or inf anywhere (None allowed)."""
    if isinstance(obj, dict):
        return all(_finite(v) for v in obj.values())
    if isinstance(obj, list):
        return all(_finite(v) for v in obj)
    if isinstance(obj, float):
        return math.isfinite(obj)
    return True


def _check_common(data: dict, n_published: int, eqs: tuple[str, str]) -> None:
    assert {"design", "design_search", "published", "paper", "monte_carlo"} <= set(data)
    assert set(data["design"]) == {"U=1", "U=-1"}
    for d in data["design"].values():
        assert DESIGN_KEYS | {f"residual_{eqs[0]}", f"residual_{eqs[1]}"} <= set(d)
    assert len(data["published"]) == n_published
    for pub in data["published"]:
        assert PUBLISHED_KEYS <= set(pub)
        assert set(pub["covariance"]) == {"1", "0", "-1"}
        assert len(pub["variance_worst"]) == 2
        assert np.array(pub["covariance"]["0"]).shape == (2, 2)
    assert {"found", "design", "tried"} <= set(data["design_search"])
    assert _finite(data)


def test_discrete_cli_writes_outputs(tmp_path, capsys):
    out = tmp_path / "d"
    code = main(["reproduce", "liu-variance-constrained-discrete", "--horizon", "80", "--seed",
                 "1", "--json", f"{out}.json", "--plot", f"{out}.png", "--rrd", f"{out}.rrd"])
    assert code == 0
    data = json.loads((tmp_path / "d.json").read_text())
    _check_common(data, 1, ("11", "12r"))
    assert set(data["paper_covariance"]) == {"1", "0"}
    assert data["paper"]["K"] == [[0.9764], [-0.0882]]
    # the printed delta1 = 0.31 leaves (11) without solution: a result, not a crash
    assert data["design"]["U=1"]["solved"] is False
    assert 0.29 < data["design_diagnostics"]["delta1_threshold_at_printed_eps"] < 0.31
    pub = data["published"][0]
    assert pub["poles_in_region"] and pub["hinf_worst"] < data["paper"]["gamma"]
    # our Lyapunov covariances of the printed filter are within 4 % of the printed ones
    for comp in data["covariance_comparison"].values():
        assert np.max(np.abs(comp["relative_difference"])) < 0.04
    assert data["design_search"]["found"]
    assert (tmp_path / "d.png").stat().st_size > 10_000
    assert (tmp_path / "d.rrd").stat().st_size > 10_000
    row = load("liu-variance-constrained-discrete").row(data)
    assert set(row) == {"paper", "claim", "ours", "agree", "why"}
    assert "0.3022" in row["why"] and "ours:" in capsys.readouterr().out


def test_continuous_short_run_keys_and_findings(tmp_path):
    r = vc.reproduce(horizon_s=1.0, n_runs=20, search_points=2, json_path=tmp_path / "c.json")
    data = json.loads((tmp_path / "c.json").read_text())
    _check_common(data, 2, ("16", "17"))
    assert set(data["paper"]) == {"Q1", "Q2", "K1", "G1", "K2", "G2"}
    d = data["design"]["U=1"]
    assert d["solved"] is False and d["K"] is None
    assert d["residual_16"] < 1e-10 and 0.4 < d["residual_17"] < 0.5
    diag = data["design_diagnostics"]
    assert len(diag["equation17_margin"]) == 2  # (16) has two admissible solutions
    assert all(m["min_lambda_max"] > 0.4 for m in diag["equation17_margin"])
    assert 0.2 < diag["gamma_threshold"] < 0.25
    for pub in data["published"]:  # the printed filters meet all three requirements
        assert pub["meets"] == {"poles_in_region": True, "hinf": True, "variance": True}
    assert data["published"][0]["hinf_worst"] == pytest.approx(0.02488, abs=2e-4)
    checks = data["paper_checks"]
    assert checks["residual_16_at_printed_Q1"] > 1.0
    row = vc.row(r)
    assert row["agree"] == "partly" and "0.228" in row["why"]


@pytest.mark.slow
def test_continuous_cli_full_run(tmp_path):
    start = time.perf_counter()
    code = main(["reproduce", "wang-variance-constrained-parabolic", "--json",
                 str(tmp_path / "c.json"), "--plot", str(tmp_path / "c.png"), "--rrd",
                 str(tmp_path / "c.rrd")])
    wall = time.perf_counter() - start
    assert code == 0 and wall < 120.0
    data = json.loads((tmp_path / "c.json").read_text())
    _check_common(data, 2, ("16", "17"))
    for mc in data["monte_carlo"]:
        assert max(abs(z) for z in mc["z_vs_sampled"]) < 4.0
        assert max(abs(v) for v in mc["relative_to_lyapunov"]) < 0.03


@pytest.mark.slow
def test_discrete_full_monte_carlo():
    r = vd.reproduce()
    for mc in r["monte_carlo"]:
        assert max(abs(z) for z in mc["z_vs_sampled"]) < 4.0
