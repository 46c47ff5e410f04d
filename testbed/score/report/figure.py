"""The score as a figure (:func:`score_figure`, :func:`write_png`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from testbed.outputs.units import display
from testbed.score.harness import REFERENCE
from testbed.score.report.tables import _rows

# ---------------------------------------------------------------------------- PNG
#: Marker of each paired verdict against the reference in the RMSE panels (the reference
#: itself: a diamond; an estimator without a comparison: a plus).
VERDICT_MARKERS = {"reference": "D", "better": "v", "worse": "^", "equivalent": "X",
                   "inconclusive": "o", None: "P"}
#: Filled or hollow (inconclusive is hollow: it is not "equal").
_HOLLOW = {"inconclusive"}


def _verdict(res: dict[str, Any], state: str, reference: str) -> str | None:
    if res["estimator"] == reference:
        return "reference"
    versus = res["versus_reference"]
    if versus is None or state not in versus["states"]:
        return None
    return versus["states"][state]["verdict"]


def _unit_groups(states: list[str], units: dict[str, str]) -> list[tuple[str, list[str]]]:
    """States grouped by display unit, in the order of first appearance."""
    groups: dict[str, list[str]] = {}
    for s in states:
        groups.setdefault(display(units.get(s, ""))[1], []).append(s)
    return list(groups.items())


def _rmse_panel(ax: Any, scenario: str, group: list[dict[str, Any]], unit: str,
                states: list[str], units: dict[str, str], colors: dict[str, str],
                reference: str) -> None:
    """A dot plot on a linear axis from 0: per state (y groups) one row per estimator, the
    RMSE with its 95 % interval as an error bar, the marker the paired verdict against the
    reference, the MSE ratio written beside it."""
    from testbed.outputs.plots import FONT_PT, MIN_FONT_PT

    rows = len(group)
    spacing = 0.8 / max(rows, 1)
    right = 0.0
    for i, state in enumerate(states):
        factor = display(units.get(state, ""))[0]
        for j, res in enumerate(group):
            y = i + (j - (rows - 1) / 2) * spacing
            value = res["rmse"][state] * factor
            lo, hi = (v * factor for v in res["rmse_ci95"][state])
            verdict = _verdict(res, state, reference)
            color = colors[res["estimator"]]
            bars = ax.errorbar([value], [y], xerr=[[value - lo], [hi - value]], fmt="none",
                               ecolor=color, elinewidth=1.2, capsize=3)
            bars.lines[2][0].set_gid(f"rmse-ci|{scenario}|{res['estimator']}|{state}")
            (dot,) = ax.plot([value], [y], VERDICT_MARKERS[verdict], ms=7, color=color,
                             mfc="white" if verdict in _HOLLOW else color, mec=color,
                             mew=1.5, linestyle="none")
            dot.set_gid(f"rmse|{scenario}|{res['estimator']}|{state}|{verdict}")
            if verdict not in ("reference", None):
                ratio = res["versus_reference"]["states"][state]["ratio"]
                ax.annotate(f"\u00d7{ratio:.3g}", (hi, y), xytext=(5, 0),
                            textcoords="offset points", va="center", ha="left",
                            fontsize=MIN_FONT_PT, color=color)
            right = max(right, hi)
    ax.set_xlim(0.0, right * 1.35 if right > 0 else 1.0)
    ax.set_ylim(len(states) - 0.5, -0.5)
    names = [short_name(r["estimator"]) for r in group]
    ax.set_yticks([i + (j - (rows - 1) / 2) * spacing for i in range(len(states))
                   for j in range(rows)], names * len(states), minor=True)
    ax.set_yticks(range(len(states)), states if len(states) > 1 else [""])
    pad = 0.62 * MIN_FONT_PT * max(len(n) for n in names) + 8
    ax.yaxis.remove_overlapping_locs = False  # a row at a state's centre keeps its name
    ax.tick_params(axis="y", which="major", length=0, pad=pad, labelsize=FONT_PT,
                   labelrotation=90)
    ax.tick_params(axis="y", which="minor", length=2, labelsize=MIN_FONT_PT)
    for label in ax.get_yticklabels():
        label.set_verticalalignment("center")
    for i in range(1, len(states)):
        ax.axhline(i - 0.5, color="0.7", lw=0.8)
    ax.set_xlabel(f"RMSE [{unit}]" if unit else "RMSE", fontsize=FONT_PT)
    ax.set_ylabel("state" if len(states) > 1 else states[0], fontsize=FONT_PT)
    ax.set_title(f"RMSE [{unit}] with 95 % CI; \u00d7 MSE / reference's" if unit
                 else "RMSE with 95 % CI; \u00d7 MSE / reference's", fontsize=FONT_PT)
    ax.tick_params(axis="x", labelsize=MIN_FONT_PT)
    ax.grid(axis="x", color="0.9")


def _nees_panel(ax: Any, scenario: str, with_cov: list[dict[str, Any]],
                colors: dict[str, str]) -> None:
    """The per-step N-run average NEES of each estimator against the per-step band (log)."""
    from testbed.outputs.plots import FONT_PT, MIN_FONT_PT

    lo, hi = with_cov[0]["nees_test"]["band"]
    band = ax.axhspan(lo, hi, color="0.85", zorder=0)
    band.set_gid(f"nees-band|{scenario}")
    for res in with_cov:
        test = res["nees_test"]
        (line,) = ax.plot(np.arange(1, test["steps"] + 1), test["per_step"], lw=0.9,
                          color=colors[res["estimator"]])
        line.set_gid(f"nees|{scenario}|{res['estimator']}|{test['verdict']}")
    ax.set_yscale("log")
    ax.set_xlabel("step", fontsize=FONT_PT)
    ax.set_ylabel(f"NEES (dim {with_cov[0]['nees_test']['dim']})", fontsize=FONT_PT)
    verdicts = "; ".join(f"{short_name(r['estimator'])} {r['nees_test']['verdict']}"
                         for r in with_cov)
    ax.set_title(f"{with_cov[0]['runs']}-run average NEES per step vs 95 % band: {verdicts}",
                 fontsize=FONT_PT, wrap=True)
    ax.tick_params(labelsize=MIN_FONT_PT)


def _gain_panel(ax: Any, scenario: str, searched: list[dict[str, Any]],
                colors: dict[str, str]) -> None:
    """Worst-case (found) and random gain, the linearized prediction and the design gamma,
    one row per estimator, on a linear axis from 0."""
    from testbed.outputs.plots import FONT_PT, MIN_FONT_PT

    right = 0.0
    removed: set[str] = set()
    for j, res in enumerate(searched):
        color = colors[res["estimator"]]
        search = res.get("worst_case_search") or {}
        removed.update(search.get("quantization_removed") or [])
        name = res["estimator"]
        values = {"worst": res["worst_case_gain"], "random": res["random_gain"],
                  "linear": search.get("linear_gain"), "gamma": res["certified_gamma"]}
        ax.plot([values["random"], values["worst"]], [j, j], color=color, lw=1.0)
        (dot,) = ax.plot([values["worst"]], [j], "o", ms=7, color=color, linestyle="none")
        dot.set_gid(f"gain-worst|{scenario}|{name}")
        (dot,) = ax.plot([values["random"]], [j], "o", ms=7, mfc="white", mec=color,
                         mew=1.5, linestyle="none")
        dot.set_gid(f"gain-random|{scenario}|{name}")
        if values["linear"] is not None:
            (mark,) = ax.plot([values["linear"]], [j], "|", ms=14, mew=2, color="k",
                              linestyle="none")
            mark.set_gid(f"gain-linear|{scenario}|{name}")
        if values["gamma"] is not None:
            (mark,) = ax.plot([values["gamma"]], [j], "x", ms=8, mew=2, color="k",
                              linestyle="none")
            mark.set_gid(f"gain-gamma|{scenario}|{name}")
        right = max([right] + [v for v in values.values() if v is not None])
    ax.set_xlim(0.0, right * 1.1 if right > 0 else 1.0)
    ax.set_ylim(len(searched) - 0.5, -0.5)
    ax.set_yticks(range(len(searched)), [short_name(r["estimator"]) for r in searched],
                  fontsize=FONT_PT)
    ax.set_xlabel("gain [output unit / unit of w]", fontsize=FONT_PT)
    ax.set_ylabel("estimator", fontsize=FONT_PT)
    probe = (f"sensors without quantization ({', '.join(sorted(removed))})" if removed
             else "the scenario's sensors")
    ax.set_title(f"worst-case gain, probe runs on {probe}", fontsize=FONT_PT, wrap=True)
    ax.tick_params(labelsize=MIN_FONT_PT)
    ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4))
    ax.xaxis.get_offset_text().set_fontsize(MIN_FONT_PT)
    ax.grid(axis="x", color="0.9")


#: Characters of an estimator's name on the figure's axes (longer names are shortened in the
#: middle; the legend, the key, keeps them whole where they fit).
AXIS_NAME_CHARS = 20


def short_name(name: str) -> str:
    """An estimator's name on the figure's axes (:data:`AXIS_NAME_CHARS` at most)."""
    from testbed.outputs.plots import shorten

    return shorten(str(name), AXIS_NAME_CHARS)


def _legend_handles(estimators: list[str], colors: dict[str, str], verdicts: set,
                    nees: bool, gains: dict[str, bool]) -> tuple[list, list[str]]:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles, labels = [], []
    for name in estimators:
        handles.append(Line2D([], [], color=colors[name], marker="s", ms=7, lw=1.5))
        labels.append(name)
    from testbed.score.paired import MARGIN

    margin_pct = 100 * MARGIN
    for verdict in ("reference", "better", "worse", "equivalent", "inconclusive", None):
        if verdict in verdicts:
            handles.append(Line2D([], [], color="k", marker=VERDICT_MARKERS[verdict], ms=7,
                                  mfc="white" if verdict in _HOLLOW else "k",
                                  linestyle="none"))
            labels.append({"reference": "reference", None: "not compared",
                           "equivalent": f"equivalent (MSE ratio within +-{margin_pct:g} %)"}
                          .get(verdict, f"{verdict} than the reference (beyond +-"
                                        f"{margin_pct:g} %)" if verdict in ("better", "worse")
                               else verdict))
    if nees:
        handles.append(Patch(color="0.85"))
        labels.append("95 % per-step NEES band")
    if gains.get("any"):
        handles += [Line2D([], [], color="k", marker="o", ms=7, linestyle="none"),
                    Line2D([], [], color="k", marker="o", ms=7, mfc="white",
                           linestyle="none")]
        labels += ["worst case found", "largest random"]
        if gains.get("linear"):
            handles.append(Line2D([], [], color="k", marker="|", ms=12, mew=2,
                                  linestyle="none"))
            labels.append("linearized prediction")
        if gains.get("gamma"):
            handles.append(Line2D([], [], color="k", marker="x", ms=8, mew=2,
                                  linestyle="none"))
            labels.append("design gamma")
    return handles, labels


def score_figure(summary: dict[str, Any]) -> Any:
    """The score as a figure: one block per scenario that ran (estimators skipped there left
    out), with

    - RMSE dot plots, one axes per display unit (deg and deg/s never share one): per state one
      row per estimator, the 95 % interval as an error bar on a linear axis from 0, the
      marker the paired verdict against the reference (better, worse, equivalent,
      inconclusive; the reference a diamond) and the MSE ratio to the reference beside it;
    - the per-step N-run average NEES of every estimator with a covariance against the 95 %
      per-step band (when one has a covariance);
    - the worst-case gain found, the largest random gain, the linearized prediction and the
      design gamma per estimator (when the scenario has a search), linear axis from 0.

    One legend below everything. Artists carry gids (``rmse|scenario|estimator|state|
    verdict``, ``rmse-ci|...``, ``nees|scenario|estimator|verdict``, ``nees-band|scenario``,
    ``gain-worst|...``, ``gain-random|...``, ``gain-linear|...``, ``gain-gamma|...``) for
    tests.
    """
    from testbed.outputs.plots import FONT_PT, fitted_legend, new_figure, set_title

    groups = [(s, [r for r in g if not r["skipped"]]) for s, g in _rows(summary)]
    groups = [(s, g) for s, g in groups if g]
    if not groups:
        raise ValueError("nothing to plot: every estimator was skipped on every scenario")
    units = summary["units"]
    reference = summary.get("reference", REFERENCE)
    colors = {name: f"C{i}" for i, name in enumerate(summary["estimators"])}
    layouts = []
    for scenario, group in groups:
        rmse_axes = _unit_groups(list(group[0]["rmse"]), units)
        with_cov = [r for r in group if r["nees_test"] is not None]
        searched = [r for r in group if r["worst_case_gain"] is not None]
        layouts.append((scenario, group, rmse_axes, with_cov, searched))
    width = max(11.0, 3.6 * max(len(lay[2]) for lay in layouts))
    upper = [1.5 + 0.28 * len(group) * max(len(states) for _, states in rmse_axes)
             for _, group, rmse_axes, _, _ in layouts]
    heights = [top + (2.8 if with_cov or searched else 0.0)
               for top, (_, _, _, with_cov, searched) in zip(upper, layouts, strict=True)]
    fig = new_figure(width, sum(heights) + 1.6)
    subfigs = np.atleast_1d(fig.subfigures(len(layouts), 1, height_ratios=heights))
    verdicts: set = set()
    gains = {"any": False, "linear": False, "gamma": False}
    for sub, top, (scenario, group, rmse_axes, with_cov, searched) in zip(
            subfigs, upper, layouts, strict=True):
        sub.suptitle(f"{scenario} ({group[0]['runs']} runs)", fontsize=FONT_PT + 1,
                     fontweight="bold")
        lower = bool(with_cov or searched)
        parts = sub.subfigures(2, 1, height_ratios=[top, 2.8]) if lower else [sub]
        axes = parts[0].subplots(1, len(rmse_axes), squeeze=False)[0]
        for ax, (unit, states) in zip(axes, rmse_axes, strict=True):
            _rmse_panel(ax, scenario, group, unit, states, units, colors, reference)
            verdicts.update(_verdict(r, s, reference) for r in group for s in states)
        if lower:
            n_lower = int(bool(with_cov)) + int(bool(searched))
            ratios = [2, 1] if n_lower == 2 else [1]
            lower_axes = parts[1].subplots(1, n_lower, squeeze=False,
                                           width_ratios=ratios)[0]
            k = 0
            if with_cov:
                _nees_panel(lower_axes[k], scenario, with_cov, colors)
                k += 1
            if searched:
                _gain_panel(lower_axes[k], scenario, searched, colors)
                gains["any"] = True
                gains["linear"] |= any((r.get("worst_case_search") or {}).get("linear_gain")
                                       is not None for r in searched)
                gains["gamma"] |= any(r["certified_gamma"] is not None for r in searched)
    shown = [n for n in summary["estimators"]
             if any(r["estimator"] == n for _, g in groups for r in g)]
    handles, labels = _legend_handles(shown, colors, verdicts,
                                      any(lay[3] for lay in layouts), gains)
    fitted_legend(fig, handles, labels, 5, fontsize=FONT_PT)
    set_title(fig, [f"testbed score, suite {summary['suite']} (seed {summary['seed']}), "
                    f"reference {reference}"], fontsize=FONT_PT + 2)
    return fig


def write_png(path: str | os.PathLike, summary: dict[str, Any]) -> Path:
    """Write :func:`score_figure` as a PNG (atomically)."""
    from testbed.outputs.plots import save_figure

    return save_figure(score_figure(summary), path)

