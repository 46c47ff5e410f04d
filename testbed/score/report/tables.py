"""The score as text: the terminal leaderboard (:func:`leaderboard`) and Markdown
(:func:`markdown`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from testbed.io import atomic_path
from testbed.score.consistency import verdict_text
from testbed.score.paired import comparison_text
from testbed.score.report.metrics import METRICS

# ---------------------------------------------------------------------------- tables


def _rows(summary: dict[str, Any]) -> list[tuple[str, list[dict[str, Any]]]]:
    groups: dict[str, list[dict[str, Any]]] = {}
    for res in summary["results"]:
        groups.setdefault(res["scenario"], []).append(res)
    return list(groups.items())


def _squared(unit: str) -> str:
    """The unit of a mean-square error (SI): ``m`` -> ``m^2``, ``m/s`` -> ``(m/s)^2``."""
    if not unit:
        return ""
    return f"{unit}^2" if unit.isalnum() else f"({unit})^2"


def _details(group: list[dict[str, Any]], units: dict[str, str]) -> list[str]:
    """Per estimator of one scenario: the NEES and NIS tests, the whiteness of the
    innovations and the paired comparison with the reference, one line each."""
    lines = []
    for res in group:
        if res["skipped"]:
            continue
        name = res["estimator"]
        if res["nees_test"] is not None:
            lines.append(f"{name} NEES: {verdict_text(res['nees_test'])}")
        if res["nis_test"] is not None:
            lines.append(f"{name} NIS: {verdict_text(res['nis_test'])}")
        white = res["whiteness"]
        if white is not None:
            zs = ", ".join(f"{lag}: {z:+.2g}" for lag, z in zip(white["lags"], white["z"],
                                                                strict=True))
            lines.append(f"{name} innovations: {white['verdict']} (p {white['p']:.2g}; "
                         f"standardized autocorrelation at lags {zs})")
        if res["certificate"] is not None:
            sampled = res["sampled_loop_gain"]
            lines.append(f"{name} certificate: design gamma {res['certified_gamma']:.4g} "
                         f"({res['gamma_kind']}), sampled loop's H-infinity norm "
                         f"{'-' if sampled is None else f'{sampled:.4g}'}: "
                         f"{res['certificate']}")
        versus = res["versus_reference"]
        if versus is not None:
            parts = [f"{state} {comparison_text(c, _squared(units.get(state, '')))}"
                     for state, c in versus["states"].items()]
            lines.append(f"{name} vs {versus['reference']} (MSE ratio and difference per "
                         f"run, 95 % CI; p_holm over a family of {versus['family']}): "
                         f"{'; '.join(parts)}")
    return lines


def _sorted(group: list[dict[str, Any]], order: list[str] | None = None
            ) -> list[dict[str, Any]]:
    """The rows of one scenario in the order the estimators were given (the same order in
    every scenario; :func:`_ranks` gives the RMSE rank)."""
    index = {name: i for i, name in enumerate(order or [])}
    return sorted(group, key=lambda res: index.get(res["estimator"], len(index)))


#: RMSEs within this relative difference are ranked as ties (the same result up to rounding).
TIE_RTOL = 1e-9


def _ranks(group: list[dict[str, Any]]) -> dict[str, int]:
    """Rank of each estimator scored on the scenario by the RMSE of the first state; equal
    RMSEs (within :data:`TIE_RTOL` of the first of their group) share the rank ("1, 1, 3")."""
    scored = [res for res in group if not res["skipped"]]
    scored.sort(key=lambda res: next(iter(res["rmse"].values())))
    ranks: dict[str, int] = {}
    lead = None
    for i, res in enumerate(scored):
        value = next(iter(res["rmse"].values()))
        if lead is None or abs(value - lead[0]) > TIE_RTOL * abs(lead[0]):
            lead = (value, i + 1)
        ranks[res["estimator"]] = lead[1]
    return ranks


def leaderboard(summary: dict[str, Any]) -> str:
    """A plain-text leaderboard: per scenario, the estimators in the order given (the same
    in every scenario) with their rank by the RMSE of the first state; columns as wide as
    their widest cell."""
    units = summary["units"]
    lines = [f"testbed score: suite {summary['suite']} (version {summary['suite_version']}, "
             f"sha256 {summary['suite_hash'][:12]}), seed {summary['seed']}, reference "
             f"{summary['reference']}, {summary['wall_s']:.1f} s wall"]
    blocks = []
    for scenario, group in _rows(summary):
        ranks, rows = _ranks(group), []
        for res in _sorted(group, summary.get("estimators")):
            if res["skipped"]:
                rows.append((res["estimator"], f"skipped: {res['skipped']}"))
                continue
            rows.append((res["estimator"], str(ranks[res["estimator"]]),
                         *(metric.cell(res, units) for metric in METRICS)))
        blocks.append((scenario, group, rows))
    columns = ("estimator", "rank", *(metric.header for metric in METRICS))
    every = [row for _, _, rows in blocks for row in rows]
    full = [columns] + [row for row in every if len(row) == len(columns)]
    widths = [max(len(row[i]) for row in full) for i in range(len(columns))]
    widths[0] = max([widths[0], *(len(row[0]) for row in every)])

    def line(row: tuple[str, ...]) -> str:
        return "  " + "  ".join(f"{c:<{w}}" for c, w in zip(row, widths, strict=False)).rstrip()

    for scenario, group, rows in blocks:
        lines += ["", f"{scenario} ({group[0]['runs']} runs)", line(columns)]
        lines += [line(row) for row in rows]
        lines += [f"  {text}" for text in _details(group, units)]
    return "\n".join(lines)


_SHORT_VERDICT = {"consistent": "ok", "overconfident": "over", "underconfident": "under",
                  "inconclusive": "inconcl.", "no verdict": "-"}


def summary_cell(res: dict[str, Any], state: str, reference: str) -> str:
    """One cell of :func:`summary_table`: the RMSE ratio to the reference on ``state``
    (the square root of the paired MSE ratio, with its 95 % interval) and the consistency
    verdict, e.g. ``1.41 [1.38, 1.44] ok``; ``ref`` for the reference, ``skipped``."""
    if res["skipped"]:
        return "skipped"
    test = res["nees_test"]
    verdict = "-" if test is None else _SHORT_VERDICT.get(test["verdict"], test["verdict"])
    if res["estimator"] == reference:
        return f"ref, {verdict}"
    versus = res["versus_reference"]
    if versus is None or state not in versus["states"]:
        return f"-, {verdict}"
    c = versus["states"][state]
    lo, hi = (float(np.sqrt(max(v, 0.0))) for v in c["ratio_ci"])
    return f"{np.sqrt(c['ratio']):.3g} [{lo:.3g}, {hi:.3g}], {verdict}"


def summary_table(summary: dict[str, Any]) -> list[str]:
    """The one-screen summary: entries x estimators, each cell :func:`summary_cell` on the
    entry's first state (pitch, roll or position), as Markdown lines."""
    names = list(summary.get("estimators") or [])
    reference = summary["reference"]
    lines = ["## Summary", "",
             f"RMSE ratio to `{reference}` on each entry's first state (the square root of the "
             "paired MSE ratio, 95 % interval) and the consistency verdict of the mean test "
             "at 5 % (ok, over(confident), under(confident), inconcl(usive); - no NEES). "
             "Every state, and the paired verdicts, in the entries' tables below.", "",
             "| entry (state) | " + " | ".join(names) + " |",
             "|---|" + "---|" * len(names)]
    for scenario, group in _rows(summary):
        by_name = {res["estimator"]: res for res in group}
        states = next((list(r["rmse"]) for r in group if not r["skipped"] and r["rmse"]), [])
        state = states[0] if states else ""
        cells = [summary_cell(by_name[n], state, reference) if n in by_name else ""
                 for n in names]
        lines.append(f"| {scenario} ({state}) | " + " | ".join(cells) + " |")
    return lines + [""]


def markdown(summary: dict[str, Any], remarks: list[str] | None = None) -> str:
    """The leaderboard as Markdown (one table per scenario, then the remarks)."""
    units = summary["units"]
    out = [f"# testbed score: suite `{summary['suite']}`", "",
           f"Suite version {summary['suite_version']}, sha256 `{summary['suite_hash']}`. "
           f"Seed {summary['seed']}, estimators {', '.join(summary['estimators'])}, "
           f"reference {summary['reference']}, "
           f"{summary['wall_s']:.1f} s wall. RMSE in display units (angles in degrees) with "
           "the 95 % interval; ANEES with the 95 % t interval of the per-run time averages "
           "and its p-value, and the verdict: the mean test at 5 % (OVERCONFIDENT / "
           "UNDERCONFIDENT when it rejects; ok when it and the per-step chi-square band "
           "diagnostic both accept, INCONCLUSIVE when only the band rejects; no verdict "
           "below 6 runs), ANIS with the per-step band; "
           "worst-case / random gain in the output's unit per "
           "unit of the scenario's w (a lower bound found by search, not a certificate; "
           "measured on probe runs whose sensors have their quantization removed, so that "
           "the change of quantization error does not floor it: the remarks name the "
           "channels); "
           "gamma as the estimator's design states it; cost in microseconds per "
           "trajectory-step and relative to the Kalman filter timed in the same run; mismatch "
           "= RMSE at the mismatched parameters / nominal (largest over the states). "
           "Definitions: docs/scoring.md.", ""]
    out += summary_table(summary)
    descriptions = {s["name"]: s for s in summary["scenarios"]}
    for scenario, group in _rows(summary):
        desc = descriptions.get(scenario, {})
        headers = ["estimator", *(metric.markdown_header for metric in METRICS), "skipped"]
        out += [f"## {scenario}", "", desc.get("description", ""), "",
                "| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
        for res in _sorted(group, summary.get("estimators")):
            if res["skipped"]:
                out.append(f"| {res['estimator']} |" + " |" * len(METRICS)
                           + f" {res['skipped']} |")
                continue
            cells = [metric.markdown_cell(res, units) for metric in METRICS]
            out.append(f"| {res['estimator']} | " + " | ".join(cells) + " | |")
        out.append("")
        details = _details(group, units)
        if details:
            out += [f"- {line}" for line in details] + [""]
    if remarks:
        out += ["## Remarks", ""] + [f"- {r}" for r in remarks] + [""]
    return "\n".join(out)


def write_markdown(path: str | os.PathLike, summary: dict[str, Any],
                   remarks: list[str] | None = None) -> Path:
    """Write :func:`markdown` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(markdown(summary, remarks))
    return Path(path)


