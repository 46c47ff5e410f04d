"""Outputs of a score: the JSON results, a terminal leaderboard, Markdown, a PNG and a
comparison Rerun recording.

JSON (:func:`results`): top level ``suite``, ``seed``, ``estimators``, ``scenarios`` (the
entries' descriptions), ``units``, ``wall_s`` and ``results``, one entry per estimator and
scenario with exactly the keys of :data:`RESULT_KEYS`. Gains are in the output's unit per
unit of the scenario's ``w``; RMSE in the states' units (SI; the leaderboard, the Markdown
and the PNG show angles in degrees).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from testbed.io import atomic_path, write_json
from testbed.outputs.units import display
from testbed.score import stats
from testbed.score.harness import REFERENCE, PairResult, ScoreRun

#: Keys of every entry of ``results`` (the issue's JSON contract).
RESULT_KEYS = ("estimator", "scenario", "runs", "rmse", "rmse_ci95", "anees", "anees_bounds",
               "consistent", "anis", "anis_bounds", "worst_case_gain", "random_gain",
               "certified_gamma", "step_us", "step_vs_kalman", "mismatch_rmse_ratio",
               "skipped")


def _entry_result(pair: PairResult, reference: PairResult | None,
                  nominal: PairResult | None) -> dict[str, Any]:
    out: dict[str, Any] = dict.fromkeys(RESULT_KEYS)
    out.update(estimator=pair.estimator, scenario=pair.scenario, runs=pair.runs,
               skipped=pair.skipped)
    if pair.skipped:
        return out
    rmse, ci = {}, {}
    for name, values in pair.rmse_per_run.items():
        rmse[name], ci[name] = stats.rmse_ci(values)
    out["rmse"], out["rmse_ci95"] = rmse, {k: list(v) for k, v in ci.items()}
    if pair.nees is not None:
        anees, bounds, ok = stats.consistency(pair.nees, len(pair.state_names))
        out.update(anees=anees, anees_bounds=list(bounds), consistent=ok)
    if pair.nis is not None:
        anis, bounds, _ = stats.consistency(pair.nis, pair.nis_dim)
        out.update(anis=anis, anis_bounds=list(bounds))
    if pair.worst is not None:
        out.update(worst_case_gain=pair.worst.worst_case_gain,
                   random_gain=pair.worst.random_gain)
    out["certified_gamma"] = pair.certified_gamma
    out["step_us"] = pair.step_us
    if reference is not None and not reference.skipped and reference.step_us:
        out["step_vs_kalman"] = pair.step_us / reference.step_us
    if nominal is not None and not nominal.skipped:
        out["mismatch_rmse_ratio"] = {
            k: float(np.sqrt(np.mean(v**2)) / np.sqrt(np.mean(nominal.rmse_per_run[k] ** 2)))
            for k, v in pair.rmse_per_run.items()}
    return out


def results(run: ScoreRun) -> dict[str, Any]:
    """The JSON document of a score (see the module docstring)."""
    by_name = {e.name: pairs for e, pairs in zip(run.entries, run.pairs, strict=True)}
    entries_out, units = [], {}
    for entry, pairs in zip(run.entries, run.pairs, strict=True):
        nominal_pairs = by_name.get(entry.nominal) if entry.nominal else None
        for name in run.estimators:
            pair = pairs[name]
            units.update(pair.units)
            entries_out.append(_entry_result(
                pair, pairs.get(REFERENCE),
                None if nominal_pairs is None else nominal_pairs.get(name)))
    units.update({"rmse": "state units", "step_us": "us",
                  "worst_case_gain": "output unit per unit of w",
                  "random_gain": "output unit per unit of w",
                  "certified_gamma": "as the estimator's design states it"})
    return {"suite": run.suite, "seed": run.seed, "estimators": list(run.estimators),
            "scenarios": [e.describe() for e in run.entries], "units": units,
            "wall_s": run.wall_s, "results": entries_out}


def notes(run: ScoreRun) -> list[str]:
    """Remarks that do not fit the JSON keys (failed searches, linear predictions)."""
    out = []
    for pairs in run.pairs:
        for name in run.estimators:
            pair = pairs[name]
            prefix = f"{name} on {pair.scenario}"
            out += [f"{prefix}: {note}" for note in pair.notes]
            if pair.worst_skipped:
                out.append(f"{prefix}: {pair.worst_skipped}")
            if pair.worst is not None:
                w = pair.worst
                out.append(f"{prefix}: worst-case search over {w.horizon_s:g} s, energy "
                           f"{w.energy:g}: linearized error system predicts "
                           f"{w.linear_gain:.4g}, found {w.worst_case_gain:.4g} in "
                           f"{w.evaluations} closed-loop runs")
                out += [f"{prefix}: {note}" for note in w.notes]
    return out


# ---------------------------------------------------------------------------- tables
def _fmt(value: Any, spec: str = ".3g") -> str:
    return "-" if value is None else format(value, spec)


def _rmse_text(res: dict[str, Any], units: dict[str, str], states: list[str]) -> str:
    parts = []
    for s in states:
        factor, unit = display(units.get(s, ""))
        parts.append(f"{s} {res['rmse'][s] * factor:.3g}{(' ' + unit) if unit else ''}")
    return ", ".join(parts)


def _rows(summary: dict[str, Any]) -> list[tuple[str, list[dict[str, Any]]]]:
    groups: dict[str, list[dict[str, Any]]] = {}
    for res in summary["results"]:
        groups.setdefault(res["scenario"], []).append(res)
    return list(groups.items())


def _consistency_text(res: dict[str, Any]) -> str:
    if res["anees"] is None:
        return "-"
    lo, hi = res["anees_bounds"]
    verdict = "ok" if res["consistent"] else "INCONSISTENT"
    return f"{res['anees']:.3g} [{lo:.3g}, {hi:.3g}] {verdict}"


def _gain_text(res: dict[str, Any]) -> str:
    if res["worst_case_gain"] is None:
        return "-"
    text = f"{res['worst_case_gain']:.3g} / {res['random_gain']:.3g}"
    if res["certified_gamma"] is not None:
        text += f" (gamma {res['certified_gamma']:.3g})"
    return text


def _mismatch_text(res: dict[str, Any]) -> str:
    ratio = res["mismatch_rmse_ratio"]
    if not ratio:
        return "-"
    state = max(ratio, key=ratio.get)
    return f"{ratio[state]:.3g} ({state})"


def _sorted(group: list[dict[str, Any]]) -> list[dict[str, Any]]:
    def key(res: dict[str, Any]) -> tuple:
        if res["skipped"]:
            return (1, 0.0)
        first = next(iter(res["rmse"].values()))
        return (0, first)
    return sorted(group, key=key)


def leaderboard(summary: dict[str, Any]) -> str:
    """A plain-text leaderboard: per scenario, estimators by RMSE of the first state."""
    units = summary["units"]
    lines = [f"testbed score: suite {summary['suite']}, seed {summary['seed']}, "
             f"{summary['wall_s']:.1f} s wall"]
    header = (f"  {'estimator':<16}{'RMSE':<44}{'ANEES [95 % bounds]':<32}{'ANIS':>7}  "
              f"{'worst / random gain':<30}{'us/step (x KF)':<18}{'mismatch':<16}")
    for scenario, group in _rows(summary):
        lines.append("")
        lines.append(f"{scenario} ({group[0]['runs']} runs)")
        lines.append(header)
        for res in _sorted(group):
            if res["skipped"]:
                lines.append(f"  {res['estimator']:<16}skipped: {res['skipped']}")
                continue
            states = list(res["rmse"])[:2]
            cost = (f"{res['step_us']:.3g}" + (f" (x{res['step_vs_kalman']:.2g})"
                                                if res["step_vs_kalman"] else ""))
            lines.append(f"  {res['estimator']:<16}{_rmse_text(res, units, states):<44}"
                         f"{_consistency_text(res):<32}{_fmt(res['anis']):>7}  "
                         f"{_gain_text(res):<30}{cost:<18}{_mismatch_text(res):<16}")
    return "\n".join(lines)


def markdown(summary: dict[str, Any], remarks: list[str] | None = None) -> str:
    """The leaderboard as Markdown (one table per scenario, then the remarks)."""
    units = summary["units"]
    out = [f"# testbed score: suite `{summary['suite']}`", "",
           f"Seed {summary['seed']}, estimators {', '.join(summary['estimators'])}, "
           f"{summary['wall_s']:.1f} s wall. RMSE in display units (angles in degrees) with "
           "the 95 % interval; ANEES/ANIS against the two-sided 95 % chi-square bounds for "
           "the runs and the dimension; worst-case / random gain in the output's unit per "
           "unit of the scenario's w (a lower bound found by search, not a certificate); "
           "gamma as the estimator's design states it; cost in microseconds per "
           "trajectory-step and relative to the Kalman filter timed in the same run; mismatch "
           "= RMSE at the mismatched parameters / nominal (largest over the states). "
           "Definitions: docs/scoring.md.", ""]
    descriptions = {s["name"]: s for s in summary["scenarios"]}
    for scenario, group in _rows(summary):
        desc = descriptions.get(scenario, {})
        out += [f"## {scenario}", "", desc.get("description", ""), "",
                "| estimator | RMSE (95 % CI) | ANEES [bounds] | ANIS [bounds] | worst / random "
                "gain (gamma) | us/step (x KF) | mismatch | skipped |",
                "|---|---|---|---|---|---|---|---|"]
        for res in _sorted(group):
            if res["skipped"]:
                out.append(f"| {res['estimator']} | | | | | | | {res['skipped']} |")
                continue
            cells = []
            for s, value in res["rmse"].items():
                factor, unit = display(units.get(s, ""))
                lo, hi = res["rmse_ci95"][s]
                cells.append(f"{s} {value * factor:.3g} [{lo * factor:.3g}, {hi * factor:.3g}]"
                             f"{(' ' + unit) if unit else ''}")
            anis = "-" if res["anis"] is None else (
                f"{res['anis']:.3g} [{res['anis_bounds'][0]:.3g}, "
                f"{res['anis_bounds'][1]:.3g}]")
            cost = (f"{res['step_us']:.3g}" + (f" (x{res['step_vs_kalman']:.2g})"
                                                if res["step_vs_kalman"] else ""))
            out.append(f"| {res['estimator']} | {'<br>'.join(cells)} | "
                       f"{_consistency_text(res)} | {anis} | {_gain_text(res)} | {cost} | "
                       f"{_mismatch_text(res)} | |")
        out.append("")
    if remarks:
        out += ["## Remarks", ""] + [f"- {r}" for r in remarks] + [""]
    return "\n".join(out)


def write_markdown(path: str | os.PathLike, summary: dict[str, Any],
                   remarks: list[str] | None = None) -> Path:
    """Write :func:`markdown` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(markdown(summary, remarks))
    return Path(path)


def write_results(path: str | os.PathLike, summary: dict[str, Any]) -> Path:
    """Write the JSON atomically (no NaN)."""
    return write_json(path, summary)


def write_worst_cases(path: str | os.PathLike, run: ScoreRun) -> Path | None:
    """The disturbances attaining the worst-case gains, one array per estimator and scenario
    (``<estimator>|<scenario>``, shape (K, s)), in an ``.npz``; None if there are none."""
    arrays = {}
    for pairs in run.pairs:
        for name in run.estimators:
            pair = pairs[name]
            if pair.worst is not None:
                arrays[f"{name}|{pair.scenario}"] = pair.worst.worst_case_w
    if not arrays:
        return None
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)
    return Path(path)


# ---------------------------------------------------------------------------- PNG
def write_png(path: str | os.PathLike, summary: dict[str, Any]) -> Path:
    """RMSE with 95 % intervals, ANEES against its chi-square band, worst-case against random
    gain: one column per scenario that ran."""
    from testbed.outputs.plots import new_figure, save_figure

    groups = [(s, [r for r in g if not r["skipped"]]) for s, g in _rows(summary)]
    groups = [(s, g) for s, g in groups if g]
    if not groups:
        raise ValueError("nothing to plot: every estimator was skipped on every scenario")
    units = summary["units"]
    cols = len(groups)
    fig = new_figure(3.6 * cols + 1, 9.5)
    axes = fig.subplots(3, cols, squeeze=False)
    colors = {name: f"C{i}" for i, name in enumerate(summary["estimators"])}
    for c, (scenario, group) in enumerate(groups):
        ax = axes[0, c]
        states = list(group[0]["rmse"])
        width = 0.8 / len(group)
        for j, res in enumerate(group):
            x = np.arange(len(states)) + (j - (len(group) - 1) / 2) * width
            factors = np.array([display(units.get(s, ""))[0] for s in states])
            value = np.array([res["rmse"][s] for s in states]) * factors
            lo = np.array([res["rmse_ci95"][s][0] for s in states]) * factors
            hi = np.array([res["rmse_ci95"][s][1] for s in states]) * factors
            ax.bar(x, value, width, color=colors[res["estimator"]], label=res["estimator"],
                   yerr=np.vstack([value - lo, hi - value]), capsize=2)
        ax.set_xticks(np.arange(len(states)),
                      [f"{s}\n[{display(units.get(s, ''))[1]}]" for s in states], fontsize=7)
        ax.set_yscale("log")
        ax.set_title(f"{scenario}: RMSE (95 % CI)", fontsize=9)
        ax.legend(fontsize=7)
        ax = axes[1, c]
        with_cov = [r for r in group if r["anees"] is not None]
        for j, res in enumerate(with_cov):
            ax.plot(j, res["anees"], "o", color=colors[res["estimator"]])
        if with_cov:
            lo, hi = with_cov[0]["anees_bounds"]
            ax.axhspan(lo, hi, color="0.85", label="95 % chi-square band")
        _estimator_axis(ax, with_cov, "ANEES", "no estimator reports a covariance")
        ax = axes[2, c]
        searched = [r for r in group if r["worst_case_gain"] is not None]
        for j, res in enumerate(searched):
            ax.bar(j - 0.2, res["worst_case_gain"], 0.4, color=colors[res["estimator"]],
                   label="worst case" if j == 0 else None)
            ax.bar(j + 0.2, res["random_gain"], 0.4, color=colors[res["estimator"]],
                   alpha=0.4, label="random" if j == 0 else None)
            if res["certified_gamma"] is not None:
                ax.plot([j - 0.4, j + 0.4], [res["certified_gamma"]] * 2, "k--",
                        label="design gamma")
        _estimator_axis(ax, searched, "worst-case vs random gain", "no worst-case search here")
    fig.suptitle(f"testbed score, suite {summary['suite']} (seed {summary['seed']})")
    return save_figure(fig, path)


def _estimator_axis(ax: Any, rows: list[dict[str, Any]], title: str, empty: str) -> None:
    """Ticks named after the estimators of ``rows``, log scale and legend; ``empty`` written
    in the axes when there are none."""
    if rows:
        ax.set_xticks(range(len(rows)), [r["estimator"] for r in rows], fontsize=7)
        ax.set_yscale("log")
        ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, empty, ha="center", transform=ax.transAxes, fontsize=8)
    ax.set_title(title, fontsize=9)


# ---------------------------------------------------------------------------- Rerun
def _part(name: str) -> str:
    import re

    return re.sub(r"[^\w.\-]+", "_", str(name)).strip("_") or "unnamed"


def _unit_name(name: str, unit: str) -> str:
    return f"{name} [{unit}]" if unit else name


def write_rrd(path: str | os.PathLike, run: ScoreRun) -> Path:
    """Run 0 of every scenario: the truth once and every estimator under its own path.

    Entities (angles in degrees, on the ``time`` timeline)::

        <scenario>/truth/<state>                 the true state
        <scenario>/estimate/<estimator>/<state>  each estimator's estimate
        <scenario>/error/<estimator>/<state>     estimate - truth

    The blueprint has one tab per scenario with, per state, a view overlaying the truth and
    every estimate, and a view of every estimator's error (estimate - truth) on a round
    symmetric range fitted to the steady state; every view names its unit, spans the run's
    time and puts its legend where it hides no data (else hides it), as the run recordings
    do (:mod:`testbed.outputs.viz`).
    """
    import rerun as rr
    import rerun.blueprint as rrb

    from testbed.outputs.axes import (
        CORNERS,
        ERROR_AXIS_MARGIN,
        nice_limit,
        steady_state_limit,
    )
    from testbed.outputs.viz import TIMELINE, panel_name, place_legend

    rec = rr.RecordingStream("testbed-score")
    if not rec.is_enabled():
        raise RuntimeError("Rerun logging is disabled (RERUN env var?); cannot write .rrd")
    tabs = []
    palette = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40),
               (148, 103, 189), (140, 86, 75), (227, 119, 194), (188, 189, 34)]
    payload = []
    for entry, pairs in zip(run.entries, run.pairs, strict=True):
        done = [(n, pairs[n]) for n in run.estimators if pairs[n].trajectory is not None]
        if not done:
            continue
        scen = _part(entry.name)
        first = done[0][1]
        t = np.asarray(first.trajectory["t_s"], dtype=float)
        axis_x = rrb.TimeAxis(link="Independent", zoom_lock=False, view_range=rr.TimeRange(
            start=rrb.TimeRangeBoundary.absolute(seconds=float(t[0])),
            end=rrb.TimeRangeBoundary.absolute(seconds=float(t[-1]))))
        views = []
        for i, state in enumerate(first.state_names):
            factor, unit = display(first.units.get(state, ""))
            truth = factor * first.trajectory["state"][:, i]
            values = [(f"{scen}/truth/{_part(state)}", truth,
                       rr.SeriesLines(names=[_unit_name(f"{state} truth", unit)],
                                      colors=[(128, 128, 128)], widths=[2.5]))]
            errors = []
            for j, (n, pair) in enumerate(done):
                color = palette[j % len(palette)]
                est = factor * pair.trajectory["estimate"][:, i]
                values.append((f"{scen}/estimate/{_part(n)}/{_part(state)}", est,
                               rr.SeriesLines(names=[_unit_name(n, unit)], colors=[color],
                                              widths=[1.5])))
                errors.append((f"{scen}/error/{_part(n)}/{_part(state)}",
                               est - factor * pair.trajectory["state"][:, i],
                               rr.SeriesLines(names=[_unit_name(f"{n}: estimate − truth", unit)],
                                              colors=[color], widths=[1.5])))
            lim = ERROR_AXIS_MARGIN * nice_limit(max(steady_state_limit(t, e)
                                                     for _, e, _ in errors))
            for contents, y_range, name in ((values, None, state),
                                            (errors, (-lim, lim), f"{state} error")):
                place = place_legend(t, [v for _, v, _ in contents], len(contents), y_range,
                                     fixed=y_range is not None)
                y_range = y_range or place.y_range
                views.append(rrb.TimeSeriesView(
                    origin=f"/{scen}", name=panel_name(name, [unit]),
                    contents=[f"/{e}" for e, _, _ in contents], axis_x=axis_x,
                    axis_y=None if y_range is None else rrb.ScalarAxis(range=y_range,
                                                                       zoom_lock=False),
                    plot_legend=rrb.PlotLegend(corner=place.corner or CORNERS[0],
                                               visible=place.corner is not None)))
            payload += [(e, t, v, style) for e, v, style in values + errors]
        tabs.append(rrb.Grid(*views, grid_columns=2, name=entry.name))
    if not payload:
        raise ValueError("nothing to record: every estimator was skipped on every scenario")
    blueprint = rrb.Blueprint(rrb.Tabs(*tabs))
    for _, _, values, _ in payload:
        if not np.all(np.isfinite(values)):
            raise ValueError("refusing to write non-finite values to the .rrd")
    with atomic_path(path) as tmp:
        rec.save(tmp, default_blueprint=blueprint)
        try:
            for entity, t, values, style in payload:
                rec.log(entity, style, static=True)
                rec.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=t)],
                                 columns=rr.Scalars.columns(scalars=values))
            rec.flush()
        finally:
            rec.disconnect()
    return Path(path)
