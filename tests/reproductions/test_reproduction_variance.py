"""Reproductions of Wang & Fang (2006) (continuous) and Liu, Deng & Wang (n.d.) (discrete):
keys, claims, the searched designs checked by an independent computation, CLI."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from scipy.linalg import solve_continuous_lyapunov, solve_discrete_lyapunov

from testbed.cli import main
from testbed.reproductions import load
from testbed.reproductions.outputs import agree_text
from testbed.reproductions.variance_constrained import family
from testbed.reproductions.variance_constrained import liu_discrete as vd
from testbed.reproductions.variance_constrained import wang_parabolic as vc
from testbed.reproductions.variance_constrained.family import SEARCHED
from testbed.reproductions.variance_constrained.scenario import (
    VarianceConstrainedContinuousScenario,
    VarianceConstrainedDiscreteScenario,
)

DESIGN_KEYS = {"solved", "Q1", "Q2", "K", "G"}
PUBLISHED_KEYS = {"name", "K", "G", "hinf_worst", "variance_worst", "poles_in_region",
                  "worst_F", "covariance"}
#: A short design search for the default suite (the full one is 8 starts x 300 evaluations).
SHORT_SEARCH = {"search_starts": 2, "search_evaluations": 60}


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
    assert {"design", "design_search", "published", "searched", "paper", "monte_carlo",
            "claims", "env"} <= set(data)
    assert set(data["design"]) == {"U=1", "U=-1"}
    for d in data["design"].values():
        assert DESIGN_KEYS | {f"residual_{eqs[0]}", f"residual_{eqs[1]}"} <= set(d)
    assert len(data["published"]) == n_published
    for pub in data["published"]:
        assert PUBLISHED_KEYS <= set(pub)
        assert set(pub["covariance"]) == {"1", "0", "-1"}
        assert len(pub["variance_worst"]) == 2
        assert np.array(pub["covariance"]["0"]).shape == (2, 2)
    search = data["design_search"]
    assert {"found", "design", "candidates", "summary", "evaluations"} <= set(search)
    # candidate 0 is the printed parameters, evaluated as they are
    assert search["candidates"][0]["start"] == 0
    # the claims are computed from the JSON's numbers alone
    module = vc if data["scenario"] == vc.NAME else vd
    assert [c.__dict__ for c in module.claims(json.loads(json.dumps(data)))] == data["claims"]
    assert all(c["paper"] and c["ours"] and c["verdict"] in ("agrees", "differs")
               for c in data["claims"])
    # Monte Carlo: every filter (printed, then the searched one) at F = 1, 0, -1
    names = [pub["name"] for pub in data["published"]] + (
        [SEARCHED] if data["searched"] else [])
    assert [m["filter"] for m in data["monte_carlo"]] == [n for n in names for _ in range(3)]
    assert data["env"]["id"] == "testbed/UncertainLinear-v0"
    assert _finite(data)


def _sweep_hinf(Af: np.ndarray, Df: np.ndarray, Cf: np.ndarray, points: np.ndarray) -> float:
    """max over the points s of ||Cf (s I - Af)^-1 Df||_2 (dense frequency sweep)."""
    eye = np.eye(Af.shape[0])
    return max(float(np.linalg.norm(Cf @ np.linalg.solve(s * eye - Af, Df), 2)) for s in points)


def _independent_check(plant, G, K, *, discrete: bool, a: float = 0.0, b: float = 1.0):
    """Pole margin, worst H-infinity norm and worst variances over 41 values of F, written
    here from the augmented system without the analysis toolkit.

    Continuous: margin ``min -(2/b)(Re + a) - Im^2`` (parabola), Lyapunov variances, sweep
    over ``j w``; discrete: margin ``1 - max |lambda|``, discrete Lyapunov, sweep over the unit
    circle.
    """
    n = plant.n
    worst_h, worst_var, margin = 0.0, np.zeros(n), math.inf
    if discrete:
        points = np.exp(1j * np.linspace(0.0, np.pi, 1501))
    else:
        points = 1j * np.concatenate([[0.0], np.geomspace(1e-3, 1e3, 1500)])
    for F in np.linspace(-1.0, 1.0, 41):
        A = plant.A + plant.M1 @ [[F]] @ plant.N
        C = plant.C + plant.M2 @ [[F]] @ plant.N
        Af = np.block([[A, np.zeros((n, n))], [A - G - K @ C, G]])
        Df = np.vstack([plant.D1, plant.D1 - K @ plant.D2])
        Cf = np.hstack([np.zeros((1, n)), plant.L])
        lam = np.linalg.eigvals(Af)
        if discrete:
            margin = min(margin, float(1.0 - np.abs(lam).max()))
            X = solve_discrete_lyapunov(Af, Df @ Df.T)
        else:
            margin = min(margin, float(np.min(-(2 / b) * (lam.real + a) - lam.imag**2)))
            X = solve_continuous_lyapunov(Af, -Df @ Df.T)
        worst_var = np.maximum(worst_var, np.diag(X[n:, n:]))
        worst_h = max(worst_h, _sweep_hinf(Af, Df, Cf, points))
    return margin, worst_h, worst_var


def _check_searched(data: dict, plant, *, discrete: bool, a: float = 0.0, b: float = 1.0):
    """The searched design meets the specification by the independent computation, which
    agrees with the reproduction's verification."""
    summary = data["design_search"]["summary"]
    assert data["design_search"]["found"] and summary is not None
    K, G = np.array(summary["K"]), np.array(summary["G"])
    margin, h, var = _independent_check(plant, G, K, discrete=discrete, a=a, b=b)
    sigma2 = np.array(data["parameters"]["sigma2"])
    gamma = data["parameters"]["gamma"]
    assert margin > 0 and h <= gamma and np.all(var <= sigma2)
    assert h == pytest.approx(summary["hinf_worst"], rel=2e-3)
    np.testing.assert_allclose(var, summary["variance_worst"], rtol=1e-6)
    assert margin == pytest.approx(summary["pole_margin_worst"], rel=1e-6, abs=1e-9)
    # the searched design's JSON agrees with the summary
    assert data["searched"]["meets"] == {"poles_in_region": True, "hinf": True,
                                         "variance": True}


def _capture_figures(monkeypatch) -> list:
    import testbed.outputs.plots

    figures = []
    save = testbed.outputs.plots.save_figure
    monkeypatch.setattr(testbed.outputs.plots, "save_figure",
                        lambda fig, path, **kw: (figures.append(fig), save(fig, path, **kw))[1])
    return figures


def _check_outputs(rrd_path, figures, checks, claims) -> None:
    """The figure shows the claims, readable, legends outside the data; the .rrd holds the
    episode under its own path with a text saying what it is."""
    from testbed.outputs.rrd_inspect import inspect_rrd

    (fig,) = figures
    shown = " ".join(" ".join(t.get_text() for t in checks.texts(fig)).split())
    for c in claims:
        assert f"[{c['verdict']}]" in shown and c["claim"] in shown
    checks.readable(fig)
    checks.legend_outside_axes(fig)
    rrd = inspect_rrd(rrd_path)
    assert list(rrd.texts) == ["episode/about"] and "F = 1" in rrd.texts["episode/about"]
    assert {e.split("/")[0] for e in rrd.rows} == {"episode"}


def test_discrete_cli_writes_outputs(tmp_path, capsys, monkeypatch, figure_checks):
    figures = _capture_figures(monkeypatch)
    monkeypatch.setattr(family, "SEARCH_STARTS", SHORT_SEARCH["search_starts"])
    monkeypatch.setattr(family, "SEARCH_EVALUATIONS", SHORT_SEARCH["search_evaluations"])
    out = tmp_path / "d"
    code = main(["reproduce", "liu-variance-constrained-discrete", "--horizon", "80", "--seed",
                 "1", "--json", f"{out}.json", "--plot", f"{out}.png", "--rrd", f"{out}.rrd"])
    assert code == 0
    data = json.loads((tmp_path / "d.json").read_text())
    _check_common(data, 1, ("11", "12r"))
    assert len(data["design_search"]["candidates"]) == SHORT_SEARCH["search_starts"] + 1
    assert set(data["paper_covariance"]) == {"1", "0"}
    assert data["paper"]["K"] == [[0.9764], [-0.0882]]
    # the printed delta1 = 0.31 leaves (11) without solution: a result, not a crash
    assert data["design"]["U=1"]["solved"] is False
    assert not data["design_search"]["candidates"][0]["solved"]
    assert 0.29 < data["design_diagnostics"]["delta1_threshold_at_printed_eps"] < 0.31
    pub = data["published"][0]
    assert pub["poles_in_region"] and pub["hinf_worst"] < data["paper"]["gamma"]
    # our Lyapunov covariances of the printed filter are within 4 % of the printed ones
    for comp in data["covariance_comparison"].values():
        assert np.max(np.abs(comp["relative_difference"])) < 0.04
    agree = {c["claim"]: c["verdict"] == "agrees" for c in data["claims"]}
    assert agree == {"printed filter meets the requirements": True,
                     "printed covariances for F = 1, 0": False,
                     "design solvable at the printed eps, delta1": False,
                     "a design meeting the specification exists": True}
    _check_searched(data, VarianceConstrainedDiscreteScenario().plant, discrete=True)
    assert (tmp_path / "d.png").stat().st_size > 10_000
    assert (tmp_path / "d.rrd").stat().st_size > 10_000
    why = load("liu-variance-constrained-discrete").why(data)
    assert agree_text(data["claims"]) == (
        "2 of 4 claims agree; differs: printed covariances for F = 1, 0; "
        "design solvable at the printed eps, delta1")
    # verdicts follow the numbers: a printed covariance within the tolerance flips one
    changed = json.loads(json.dumps(data))
    for comp in changed["covariance_comparison"].values():
        comp["relative_difference"] = [[0.0, 0.0], [0.0, 0.0]]
    assert vd.claims(changed)[1].verdict == "agrees"
    _check_outputs(tmp_path / "d.rrd", figures, figure_checks, data["claims"])
    out = capsys.readouterr().out
    assert "0.3022" in data["claims"][2]["ours"] and "0.3022" not in why
    assert "| ours " in out and "Liu, Deng & Wang (n.d.)" in out


def test_continuous_short_run_keys_and_claims(tmp_path, monkeypatch, figure_checks):
    figures = _capture_figures(monkeypatch)
    r = vc.reproduce(horizon_s=1.0, n_runs=20, json_path=tmp_path / "c.json",
                     plot_path=tmp_path / "c.png", rrd_path=tmp_path / "c.rrd", **SHORT_SEARCH)
    data = json.loads((tmp_path / "c.json").read_text())
    _check_common(data, 2, ("16", "17"))
    assert set(data["paper"]) == {"Q1", "Q2", "K1", "G1", "K2", "G2"}
    d = data["design"]["U=1"]
    assert d["solved"] is False and d["K"] is None
    assert d["residual_16"] < 1e-10
    diag = data["design_diagnostics"]
    assert len(diag["equation16_solutions"]) == 2  # (16) has two admissible solutions
    # the printed eps: (17)'s stabilizing branch folds before gamma = 0.1, also with H = 0
    branch, branch0 = diag["equation17_branch"], diag["equation17_branch_H0"]
    assert branch["status"] == branch0["status"] == "branch_ended"
    assert 0.22 < branch0["gamma_reached"] < branch["gamma_reached"] < 0.24
    assert 0.4 < diag["multistart_residual_17"] < 0.5
    assert not data["design_search"]["candidates"][0]["solved"]
    for pub in data["published"]:  # the printed filters meet all three requirements
        assert pub["meets"] == {"poles_in_region": True, "hinf": True, "variance": True}
    assert data["published"][0]["hinf_worst"] == pytest.approx(0.02488, abs=2e-4)
    checks = data["paper_checks"]
    assert checks["residual_16_at_printed_Q1"] > 1.0
    agree = {c["claim"]: c["verdict"] == "agrees" for c in data["claims"]}
    assert agree == {"printed filters meet the three requirements": True,
                     "(17) solvable with the printed eps, delta, H": False,
                     "printed Q1, Q2, gains follow from (16)-(18)": False,
                     "a Theorem 1 design meeting the specification exists": True}
    s = VarianceConstrainedContinuousScenario()
    _check_searched(data, s.plant, discrete=False, a=s.a, b=s.b)
    assert agree_text(r["claims"]) == (
        "2 of 4 claims agree; differs: (17) solvable with the printed eps, "
        "delta, H; printed Q1, Q2, gains follow from (16)-(18)")
    _check_outputs(tmp_path / "c.rrd", figures, figure_checks, data["claims"])
    ours = " ".join(c["ours"] for c in r["claims"])
    assert f"{branch['gamma_reached']:.3g}" in ours and "196" not in ours + vc.why(r)


def test_reproduce_rejects_bad_search_settings():
    with pytest.raises(ValueError, match="search_starts"):
        vc.reproduce(horizon_s=1.0, n_runs=2, search_starts=0)
    with pytest.raises(ValueError, match="n_runs"):
        vd.reproduce(horizon_s=10, n_runs=0)


@pytest.mark.slow
def test_continuous_cli_full_run(tmp_path):
    start = time.perf_counter()
    code = main(["reproduce", "wang-variance-constrained-parabolic", "--json",
                 str(tmp_path / "c.json"), "--plot", str(tmp_path / "c.png"), "--rrd",
                 str(tmp_path / "c.rrd")])
    wall = time.perf_counter() - start
    assert code == 0 and wall < 180.0
    data = json.loads((tmp_path / "c.json").read_text())
    _check_common(data, 2, ("16", "17"))
    summary = data["design_search"]["summary"]
    assert summary["n_candidates"] == family.SEARCH_STARTS + 1 and summary["n_verified"] >= 2
    assert summary["certified"]
    s = VarianceConstrainedContinuousScenario()
    _check_searched(data, s.plant, discrete=False, a=s.a, b=s.b)
    for mc in data["monte_carlo"]:
        assert max(abs(z) for z in mc["z_vs_sampled"]) < 4.0
        assert max(abs(v) for v in mc["relative_to_lyapunov"]) < 0.03


@pytest.mark.slow
def test_discrete_full_monte_carlo():
    r = vd.reproduce()
    assert r["design_search"]["summary"]["n_verified"] >= 2
    _check_searched(r, VarianceConstrainedDiscreteScenario().plant, discrete=True)
    for mc in r["monte_carlo"]:
        assert max(abs(z) for z in mc["z_vs_sampled"]) < 4.0
