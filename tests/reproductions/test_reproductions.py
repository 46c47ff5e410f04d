"""Paper reproductions: short-horizon smoke tests and the full runs (marked slow)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from testbed.cli import main
from testbed.reproductions import REPRODUCTIONS, load, render_doc
from testbed.reproductions.basin_ms_hinf import helicopter as ms
from testbed.reproductions.basin_ms_hinf.scenario import MsHinfHelicopterScenario

KEYS = {"T_final", "T_max", "T_final_noisy", "T_max_noisy", "gamma", "final_error",
        "paper_T_max", "kalman_T_final"}


def test_ms_hinf_short_horizon_writes_outputs(tmp_path):
    code = main(["reproduce", "basin-ms-hinf-helicopter", "--horizon", "5", "--json",
                 str(tmp_path / "o.json"), "--plot", str(tmp_path / "o.png"), "--rrd",
                 str(tmp_path / "o.rrd")])
    assert code == 0
    data = json.loads((tmp_path / "o.json").read_text())
    assert KEYS <= set(data)
    assert data["paper_T_max"] == 0.208 and data["gamma"] == 1.1
    assert set(data["final_error"]) == {"pitch", "yaw"}
    # the bound (6) concerns the mean trajectory: it must hold there
    assert data["T_max"] < data["gamma"]
    # the H-infinity channel helps: Kalman-Bucy on y1 alone does worse on the mean run
    assert data["kalman_T_final"] > data["T_final"]
    assert (tmp_path / "o.png").stat().st_size > 10_000
    assert (tmp_path / "o.rrd").stat().st_size > 10_000
    # the final yaw error splits into the parts of w2, w4 and the rest (error affine in w)
    parts = data["yaw_bias_contributions"]
    assert abs(parts["closure"]) < 1e-12
    assert data["final_error_without"]["w"] == data["final_error"]
    assert parts["rest"] == data["final_error_without"]["w2 = w4 = 0"]["yaw"]


def test_ms_hinf_recording_shows_errors_not_the_gravity_free_model():
    s = MsHinfHelicopterScenario()
    run = ms._run(s, 0.01, 500, None, kalman=False)
    result = {"model_pitch_final_rad": float(run["x"][-1, 0])}
    traj = ms._trajectory(run, s, result)
    # the figure's and the paper's convention e = x - m, and the legend says so
    np.testing.assert_array_equal(traj.state, run["x"] - run["est"])
    assert traj.meta["state_label"] == "error (truth - estimate, the paper's x - m)"
    assert traj.state_names[0] == "pitch_error" and traj.estimate is None
    np.testing.assert_array_equal(traj.measurement[:, 0], run["T"])
    assert "gravity-free" in traj.meta["note"]
    # the model's pitch runs away under the constant u; the logged error does not
    assert abs(run["x"][-1, 0]) > 10 * np.abs(traj.state[-50:, 0]).max()


@pytest.mark.slow
def test_ms_hinf_full_horizon_numbers():
    r = ms.reproduce()
    assert r["horizon_s"] == 80.0
    assert r["T_max"] < r["gamma"]
    assert 0.15 < r["T_final"] < 0.3  # measured 0.2097; the paper prints max T = 0.208
    assert abs(r["final_error"]["pitch"]) < 0.01
    assert r["T_final_noisy"] > r["T_final"]
    # measured: yaw -0.0321 = +0.0294 (w2) - 0.0616 (w4) + 1.7e-4 (rest); the two
    # non-decaying disturbances leave biases of opposite signs
    parts = r["yaw_bias_contributions"]
    assert r["final_error"]["yaw"] == pytest.approx(-0.0321, abs=5e-4)
    assert parts["w2"] > 0.02 and parts["w4"] < -0.05 and abs(parts["rest"]) < 1e-3
    # the gravity-free model's pitch runs away under the constant u (not rig motion)
    assert r["model_pitch_final_rad"] > 200 and r["model_pitch_final_u_only_rad"] > 200


def test_registry_and_doc_sections_from_claims(monkeypatch):
    assert "basin-ms-hinf-helicopter" in REPRODUCTIONS
    with pytest.raises(ValueError, match="unknown reproduction"):
        load("nope")
    from testbed.reproductions.outputs import Claim, claims_json, format_claims

    claims = claims_json([Claim("c|d", "p", "o", "agrees"),
                          Claim("e", "1", "2", "differs", "because " + "x" * 300)])
    monkeypatch.setattr(ms, "why", lambda result: "a long cause " * 80)
    text = render_doc({"basin-ms-hinf-helicopter": {"claims": claims}},
                      {"basin-ms-hinf-helicopter": "figures/h.png"})
    lines = text.splitlines()
    assert max(map(len, lines)) <= 400
    assert "**Why.** a long cause" in text and max(len(li) for li in lines if "cause" in li) <= 100
    assert lines.count("## " + ms.PAPER.example) == 1
    # one table row per claim, the same content `testbed reproduce NAME` prints
    assert "| c\\|d | p | o | agrees |" in lines
    assert "| e | 1 | 2 | **differs** (1) |" in lines
    assert "Notes: (1) because" in text and "x" * 300 in text
    printed = format_claims(claims).splitlines()
    assert printed[0] == "  [agrees] c|d: paper p | ours o"
    assert "![" in text and "(figures/h.png)" in text
    assert f"[`basin-ms-hinf-helicopter`](#{ms.PAPER.example.lower().replace(' ', '-')})" in text


DOC = Path(__file__).resolve().parents[2] / "docs" / "reproductions.md"


def test_committed_doc_is_for_readers():
    """docs/reproductions.md: one section per reproduction with its paper, claims table, why
    paragraph and a small figure; no line longer than 400 characters."""
    import re

    text = DOC.read_text()
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 400
    # wrapped prose never starts a line that Markdown would read as a list or a quote
    bullets = ("- Paper: ", "- Run: ", "- Verdict: ")
    assert not [line for line in lines if re.match(r"([-+*>=]|\d+[.)])(\s|$)", line)
                and not line.startswith(bullets)]
    sections = [line for line in lines if line.startswith("## ")]
    assert len(sections) == len(REPRODUCTIONS)
    for name in REPRODUCTIONS:
        module = load(name)
        body = text.split("## " + module.PAPER.example + "\n", 1)[1].split("\n## ", 1)[0]
        assert f"`testbed reproduce {name}`" in body and module.PAPER.citation in body
        assert "| claim | paper | ours | verdict |" in body and "**Why.**" in body
        (figure,) = re.findall(r"!\[[^]]*\]\(([^)]+)\)", body)
        path = DOC.parent / figure
        assert figure == f"figures/{name}.png" and path.stat().st_size < 150_000


def test_names_follow_the_papers_and_are_documented():
    references = (Path(__file__).resolve().parents[2] / "docs" / "references.md").read_text()
    for name, module in REPRODUCTIONS.items():
        assert name.split("-")[0] in {"basin", "zhang", "wang", "liu"}  # first author
        family = module.split(".")[2]  # one folder per filter family
        assert module.startswith("testbed.reproductions.") and len(module.split(".")) == 4
        assert set(family.split("_")) & set(name.split("-")), (name, family)
        assert f"`{name}`" in references


# ------------------------------------------------------------------ claims, figure, .rrd
def _helicopter_expected(r: dict) -> list[bool]:
    paper, err = r["paper_T_max"], r["final_error"]
    return [r["T_max"] < r["gamma"], abs(r["T_final"] - paper) <= 0.05 * paper,
            abs(r["T_max"] - paper) <= 0.05 * paper,
            max(abs(err["pitch"]), abs(err["yaw"])) < 1e-3]


def _polynomial_expected(r: dict) -> list[bool]:
    paper, esc, c = r["paper"], r["escaped"], r["curve"]
    exists = esc["poly"] is None and esc["linearized"] is None and r["horizon"] >= 1.4
    pairs = [(p, q) for p, q in zip(c["poly"], c["linearized"], strict=True)
             if p is not None and q is not None]
    lin_end = r["T_at_paper_horizon"]["linearized"]
    return [exists,
            exists and abs(r["T_poly"] / paper["T_poly"] - 1) <= 0.05
            and abs(r["T_linearized"] / paper["T_linearized"] - 1) <= 0.05,
            r["T_poly"] < min(r["T_linearized"], r["gamma"]) and all(p < q for p, q in pairs),
            lin_end is not None and lin_end > r["gamma"]]


def _nonlinear_expected(r: dict) -> list[bool]:
    return [r["inequality_holds"], r["corollary3"]["max_violation"] <= 0,
            r["condition_26"]["possible"] and r["hji_27"]["max_violation"] <= 0
            and r["hji_27_wide"]["max_violation"] <= 0]


def _flip_helicopter(r: dict) -> int:
    r["T_max"] = 2.0 * r["gamma"]
    return 0


def _flip_polynomial(r: dict) -> int:
    r["T_at_paper_horizon"] = {**r["T_at_paper_horizon"], "linearized": 2.0 * r["gamma"]}
    return 3


def _flip_nonlinear(r: dict) -> int:
    r["inequality_holds"] = not r["inequality_holds"]
    return 0


#: name -> (reproduce kwargs, independent verdicts, a change of one number -> claim it flips,
#: the .rrd's runs)
CASES = {
    "basin-ms-hinf-helicopter": ({"horizon_s": 5.0}, _helicopter_expected, _flip_helicopter,
                                 {"noise_free", "noisy"}),
    "basin-polynomial-hinf": ({"horizon_s": 0.3}, _polynomial_expected, _flip_polynomial,
                              {"polynomial_filter", "linearized_filter"}),
    "zhang-nonlinear-discrete": ({"horizon_s": 50, "runs": 50}, _nonlinear_expected,
                                 _flip_nonlinear, {"filter_in_loop"}),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_claims_follow_the_numbers_figure_and_runs(name, tmp_path, monkeypatch, figure_checks):
    import testbed.outputs.plots
    from testbed.outputs.rrd_inspect import inspect_rrd
    from testbed.reproductions.outputs import agree_text

    kwargs, expected, flip, runs = CASES[name]
    figures = []
    save = testbed.outputs.plots.save_figure
    monkeypatch.setattr(testbed.outputs.plots, "save_figure",
                        lambda fig, path, **kw: (figures.append(fig), save(fig, path, **kw))[1])
    module = load(name)
    module.reproduce(json_path=tmp_path / "r.json", plot_path=tmp_path / "r.png",
                     rrd_path=tmp_path / "r.rrd", **kwargs)
    r = json.loads((tmp_path / "r.json").read_text())
    # verdicts: computed from the JSON's numbers, and as an independent reading of them says
    claims = [c.__dict__ for c in module.claims(r)]
    assert claims == r["claims"]
    verdicts = [c["verdict"] for c in claims]
    assert verdicts == ["agrees" if ok else "differs" for ok in expected(r)]
    assert all(c["paper"] and c["ours"] for c in claims)
    assert 100 < len(module.why(r)) < 1200  # a short paragraph
    changed = json.loads(json.dumps(r))
    i = flip(changed)
    assert module.claims(changed)[i].verdict != verdicts[i]
    # the figure: the claims with their verdicts, readable, legends outside the data
    (fig,) = figures
    shown = " ".join(" ".join(t.get_text() for t in figure_checks.texts(fig)).split())
    for c in claims:
        assert f"[{c['verdict']}]" in shown and c["claim"][:30] in shown
    assert " ".join(agree_text(claims).split()) in shown  # the title's summary
    figure_checks.readable(fig)
    figure_checks.legend_outside_axes(fig)
    # the .rrd: each run under its own path with a text saying what it is
    c = inspect_rrd(tmp_path / "r.rrd")
    assert set(c.texts) == {f"{run}/about" for run in runs}
    assert all(text.startswith("# ") and len(text) > 100 for text in c.texts.values())
    assert {e.split("/")[0] for e in c.rows} == runs
    if name == "basin-ms-hinf-helicopter":  # errors in rad, shown in degrees
        assert c.styles["noisy/state/yaw_error/actual"]["names"][0].endswith("[deg]")
        assert "noise-free" in c.texts["noise_free/about"].lower()


def test_reproduce_all_writes_outputs_figures_and_the_doc(tmp_path, monkeypatch):
    """`testbed reproduce all` under the CLI's all-or-nothing outputs: each reproduction's
    outputs, its docs figure (made from its PNG) and the document (one fast reproduction)."""
    import testbed.reproductions as reproductions

    name = "zhang-nonlinear-discrete"
    monkeypatch.setattr(reproductions, "REPRODUCTIONS", {name: REPRODUCTIONS[name]})
    doc = tmp_path / "docs" / "reproductions.md"
    assert main(["reproduce", "all", "--out-dir", str(tmp_path / "out"), "--doc",
                 str(doc)]) == 0
    assert {p.name for p in (tmp_path / "out").iterdir()} == {f"{name}.{e}" for e in
                                                             ("json", "png", "rrd")}
    assert (doc.parent / "figures" / f"{name}.png").stat().st_size > 10_000
    assert f"(figures/{name}.png)" in doc.read_text()


def test_every_reproduction_is_a_reproduction_and_a_module_without_why_is_refused(monkeypatch):
    import sys
    import types

    from testbed import reproductions

    for name in REPRODUCTIONS:
        assert isinstance(load(name), reproductions.Reproduction)
    fake = types.ModuleType("fake_reproduction")
    fake.PAPER, fake.reproduce, fake.claims = object(), lambda **_: {}, lambda r: []
    monkeypatch.setitem(sys.modules, "fake_reproduction", fake)
    monkeypatch.setitem(REPRODUCTIONS, "fake", "fake_reproduction")
    with pytest.raises(TypeError, match=r"lacks \['why'\]"):
        load("fake")
