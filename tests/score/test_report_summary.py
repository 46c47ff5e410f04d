"""The leaderboard's one-screen summary: the RMSE ratio from the paired MSE ratio, the
verdict abbreviations, the reference and skipped cells."""

from __future__ import annotations

from testbed.score.report.tables import summary_cell, summary_table


def _res(name: str, ratio: float | None = None, verdict: str = "consistent",
         skipped: str | None = None) -> dict:
    versus = None if ratio is None else {
        "reference": "kalman",
        "states": {"pitch": {"ratio": ratio, "ratio_ci": [ratio * 0.98, ratio * 1.02]}}}
    return {"estimator": name, "skipped": skipped, "rmse": {"pitch": 1.0, "yaw": 2.0},
            "nees_test": {"verdict": verdict}, "versus_reference": versus,
            "scenario": "helicopter"}


def test_cells() -> None:
    assert summary_cell(_res("ekf", 4.0, "overconfident"), "pitch", "kalman") == \
        "2 [1.98, 2.02], over"
    assert summary_cell(_res("kalman"), "pitch", "kalman") == "ref, ok"
    assert summary_cell(_res("x", skipped="no"), "pitch", "kalman") == "skipped"
    assert summary_cell(_res("y", verdict="no verdict"), "pitch", "kalman") == "-, -"


def test_table_has_one_row_per_entry_and_a_column_per_estimator() -> None:
    summary = {"estimators": ["kalman", "ekf"], "reference": "kalman",
               "results": [_res("kalman"), _res("ekf", 1.21, "underconfident")]}
    lines = summary_table(summary)
    assert lines[4] == "| entry (state) | kalman | ekf |"
    assert lines[6] == "| helicopter (pitch) | ref, ok | 1.1 [1.09, 1.11], under |"
