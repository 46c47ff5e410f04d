"""score.png through its objects: linear dot plots with the CIs, one unit per axis, the paired
verdicts as markers, the NEES curves against their band, legend outside, no empty panels."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.score.report import VERDICT_MARKERS, score_figure, write_png

STATES = {"pitch": "rad", "yaw": "rad", "pitch_rate": "rad/s", "yaw_rate": "rad/s"}


def _comparison(ratio: float, verdict: str) -> dict:
    return {"runs": 8, "mean_difference": 0.0, "difference_ci": [0.0, 0.0], "p_t": 0.5,
            "p_wilcoxon": 0.5, "effect_size": 0.0, "correlation": 0.9, "ratio": ratio,
            "ratio_ci": [ratio * 0.9, ratio * 1.1], "p_holm": 0.5, "verdict": verdict}


def _result(name: str, scenario: str, states: dict, scale: float, verdicts: dict | None,
            *, nees: float | None, gain: float | None, gamma: float | None = None) -> dict:
    steps = 50
    rmse = {s: scale * (i + 1) * 1e-3 for i, s in enumerate(states)}
    res = {"estimator": name, "scenario": scenario, "runs": 8, "rmse": rmse,
           "rmse_ci95": {s: [0.97 * v, 1.04 * v] for s, v in rmse.items()},
           "anees": nees, "anees_bounds": [2.5, 6.0], "consistent": None, "anis": None,
           "anis_bounds": None, "worst_case_gain": gain,
           "random_gain": None if gain is None else 0.3 * gain, "certified_gamma": gamma,
           "step_us": 5.0, "step_vs_kalman": 1.0, "mismatch_rmse_ratio": None,
           "nees_test": None, "nis_test": None, "whiteness": None,
           "versus_reference": None if verdicts is None else {
               "reference": "kalman", "loss": "per-run MSE",
               "states": {s: _comparison(r, v) for s, (r, v) in verdicts.items()}},
           "worst_case_search": None if gain is None else {
               "linear_gain": 1.2 * gain, "energy": 1.0, "horizon_s": 1.0, "evaluations": 5,
               "iterations": 3, "probe_sensors": "unquantized(pitch + yaw)",
               "quantization_removed": ["pitch", "yaw"], "quantization": "removed"},
           "skipped": None}
    if nees is not None:
        verdict = "consistent" if nees < 6 else "overconfident"
        res["nees_test"] = {"dim": len(states), "runs": 8, "steps": steps, "mean": nees,
                            "band": [2.5, 6.0], "verdict": verdict,
                            "per_step": list(np.full(steps, nees) + np.sin(np.arange(steps)))}
    return res


@pytest.fixture
def summary() -> dict:
    heli = [
        _result("kalman", "helicopter", STATES, 1.0, None, nees=4.0, gain=2e-5),
        _result("kalman-bucy", "helicopter", STATES, 1.02,
                {"pitch": (1.04, "worse"), "yaw": (0.9, "better"),
                 "pitch_rate": (1.0, "inconclusive"),
                 "yaw_rate": (1.3, "worse")}, nees=30.0, gain=8e-5),
        _result("poly-hinf", "helicopter", STATES, 3.0,
                {s: (9.0, "worse") for s in STATES}, nees=20.0, gain=6e-5, gamma=7e-5),
    ]
    cal_states = {"position": "m", "velocity": "m/s"}
    calibration = [
        _result("kalman", "calibration", cal_states, 1.0, None, nees=None, gain=None),
        _result("kalman-bucy", "calibration", cal_states, 1.1,
                {s: (1.2, "worse") for s in cal_states}, nees=None, gain=None),
        {**_result("poly-hinf", "calibration", cal_states, 1.0, None, nees=None, gain=None),
         "skipped": "the factory raised ValueError: no cubic model"},
    ]
    return {"suite": "quick", "seed": 0, "reference": "kalman",
            "estimators": ["kalman", "kalman-bucy", "poly-hinf"],
            "units": {**STATES, "position": "m", "velocity": "m/s"},
            "results": heli + calibration}


def _by_gid(fig, prefix: str) -> dict:
    return {a.get_gid(): a for a in fig.findobj(lambda a: (a.get_gid() or "").startswith(
        prefix + "|"))}


def test_score_figure_reads(summary, figure_checks):
    fig = score_figure(summary)
    figure_checks.readable(fig)
    figure_checks.legend_outside_axes(fig)
    axes = [ax for ax in fig.axes if ax.axison]
    # no empty placeholder: every axes shows data; calibration (no covariance, no search)
    # has its two RMSE axes only
    assert all(ax.lines or ax.collections for ax in axes)
    assert len(axes) == 2 + 2 + 2
    for ax in axes:
        xlabel = ax.get_xlabel()
        if xlabel.startswith("RMSE"):
            # linear, from 0, one unit per axis
            assert ax.get_xscale() == "linear" and ax.get_xlim()[0] == 0.0
            assert xlabel in ("RMSE [deg]", "RMSE [deg/s]", "RMSE [m]", "RMSE [m/s]")
            assert {t.get_text() for t in ax.get_yticklabels()} in (
                {"pitch", "yaw"}, {"pitch_rate", "yaw_rate"}, {""})
        elif xlabel.startswith("gain"):
            assert ax.get_xscale() == "linear" and ax.get_xlim()[0] == 0.0
            assert "without quantization (pitch, yaw)" in ax.get_title()
        else:
            assert xlabel == "step" and ax.get_yscale() == "log"  # the NEES curves


def test_score_figure_rmse_dots_intervals_and_verdicts(summary):
    fig = score_figure(summary)
    dots = _by_gid(fig, "rmse")
    deg = np.degrees(1.0)
    kb = dots["rmse|helicopter|kalman-bucy|pitch|worse"]
    assert kb.get_xdata()[0] == pytest.approx(1.02e-3 * deg)
    assert kb.get_marker() == VERDICT_MARKERS["worse"]
    assert dots["rmse|helicopter|kalman-bucy|yaw|better"].get_marker() == "v"
    hollow = dots["rmse|helicopter|kalman-bucy|pitch_rate|inconclusive"]
    assert hollow.get_marker() == "o" and hollow.get_markerfacecolor() in ("white", "w",
                                                                          (1, 1, 1, 1))
    assert dots["rmse|helicopter|kalman|pitch|reference"].get_marker() == "D"
    # three estimators x four states on the helicopter, two x two on calibration (the
    # skipped one left out)
    assert sum(k.startswith("rmse|helicopter|") for k in dots) == 12
    assert sum(k.startswith("rmse|calibration|") for k in dots) == 4
    # the error bar spans the 95 % interval, in display units
    bar = _by_gid(fig, "rmse-ci")["rmse-ci|helicopter|poly-hinf|yaw_rate"]
    (segment,) = bar.get_segments()
    assert sorted(segment[:, 0]) == pytest.approx([0.97 * 12e-3 * deg, 1.04 * 12e-3 * deg])
    # the MSE ratio is written beside each compared dot
    texts = {t.get_text() for t in fig.findobj(lambda a: hasattr(a, "get_text"))}
    assert {"\u00d71.04", "\u00d70.9", "\u00d79"} <= texts
    # the legend explains the marker styles
    labels = {t.get_text() for t in fig.legends[0].get_texts()}
    assert {"worse than the reference (beyond +-2 %)",
            "better than the reference (beyond +-2 %)", "inconclusive", "reference",
            "95 % per-step NEES band",
            "worst case found", "largest random", "linearized prediction",
            "design gamma", "kalman", "kalman-bucy", "poly-hinf"} <= labels


def test_score_figure_nees_against_band_and_gains(summary, tmp_path):
    fig = score_figure(summary)
    curves = _by_gid(fig, "nees")
    assert set(curves) == {"nees|helicopter|kalman|consistent",
                           "nees|helicopter|kalman-bucy|overconfident",
                           "nees|helicopter|poly-hinf|overconfident"}
    kb = summary["results"][1]["nees_test"]["per_step"]
    assert np.array_equal(curves["nees|helicopter|kalman-bucy|overconfident"].get_ydata(), kb)
    band = _by_gid(fig, "nees-band")["nees-band|helicopter"]
    assert (band.get_y(), band.get_y() + band.get_height()) == pytest.approx((2.5, 6.0))
    worst = _by_gid(fig, "gain-worst")
    assert worst["gain-worst|helicopter|kalman-bucy"].get_xdata()[0] == 8e-5
    assert _by_gid(fig, "gain-random")["gain-random|helicopter|kalman"].get_xdata()[0] == \
        pytest.approx(0.6e-5)
    assert _by_gid(fig, "gain-linear")["gain-linear|helicopter|poly-hinf"].get_xdata()[0] == \
        pytest.approx(7.2e-5)
    assert set(_by_gid(fig, "gain-gamma")) == {"gain-gamma|helicopter|poly-hinf"}
    path = write_png(tmp_path / "s.png", summary)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_score_figure_refuses_when_everything_was_skipped(summary):
    summary["results"] = [{**r, "skipped": "no"} for r in summary["results"]]
    with pytest.raises(ValueError, match="nothing to plot"):
        score_figure(summary)
