"""The score's tables iterate over testbed.score.report.metrics.METRICS: a metric added there
is a column of the terminal and the Markdown leaderboard, with nothing else changed."""

from __future__ import annotations

import dataclasses

from testbed.score.report import leaderboard, markdown, tables
from testbed.score.report import metrics as metrics_module


def _result(name: str, rmse: float, skipped: str | None = None) -> dict:
    return {"scenario": "calibration", "estimator": name, "skipped": skipped, "runs": 8,
            "rmse": {"position": rmse}, "rmse_ci95": {"position": [rmse * 0.9, rmse * 1.1]},
            "nees_test": None, "nis_test": None, "whiteness": None, "certificate": None,
            "versus_reference": None, "anis": None, "anis_bounds": None,
            "worst_case_gain": None, "random_gain": None, "certified_gamma": None,
            "sampled_loop_gain": None, "step_us": 1.5, "step_vs_kalman": None,
            "mismatch_rmse_ratio": {}, "settling_s": 0.25 * rmse}


SUMMARY = {"suite": "quick", "suite_version": 1, "suite_hash": "0" * 64, "seed": 0,
           "reference": "kalman", "wall_s": 1.0, "units": {"position": "m"},
           "estimators": ["kalman", "other", "gone"],
           "scenarios": [{"name": "calibration", "description": "a plant"}],
           "results": [_result("kalman", 0.01), _result("other", 0.02),
                       _result("gone", 0.0, skipped="not applicable")]}


def test_a_new_metric_is_a_column_of_both_tables(monkeypatch):
    settling = metrics_module.Metric(
        "settling_s", "settling", "settling time (s)",
        lambda res, units: f"{res['settling_s']:.3g} s",
        lambda res, units: f"{res['settling_s']:.3g} s")
    before_md = markdown(SUMMARY)
    monkeypatch.setattr(tables, "METRICS", (*metrics_module.METRICS, settling))
    text, md = leaderboard(SUMMARY), markdown(SUMMARY)
    assert "settling" in text.splitlines()[3] and "0.0025 s" in text
    header = next(line for line in md.splitlines() if line.startswith("| estimator |"))
    assert header.endswith("| settling time (s) | skipped |")
    assert "| 0.005 s | |" in md  # the other estimator's new cell, then an empty skipped
    assert "| gone | | | | | | | | not applicable |" in md  # one more empty cell
    assert "settling" not in before_md


def test_every_metric_reads_a_result_key_and_has_both_headers():
    for metric in metrics_module.METRICS:
        assert dataclasses.is_dataclass(metric) and metric.name in _result("x", 1.0)
        assert metric.header and metric.markdown_header
        assert isinstance(metric.cell(_result("x", 1.0), {"position": "m"}), str)
        assert isinstance(metric.markdown_cell(_result("x", 1.0), {"position": "m"}), str)
