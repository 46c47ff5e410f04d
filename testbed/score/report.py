"""Outputs of a score: the JSON results, a terminal leaderboard, Markdown, a PNG and a
comparison Rerun recording.

JSON (:func:`results`): top level ``suite``, ``suite_version``, ``suite_hash``, ``seed``,
``level``, ``reference``, ``estimators``, ``scenarios`` (the entries' descriptions),
``units``, ``wall_s`` and ``results``, one entry per estimator and scenario with exactly the
keys of :data:`RESULT_KEYS`. ``nees_test``/``nis_test`` are
:func:`testbed.score.consistency.consistency_test` (with the per-step curve),
``whiteness`` :func:`~testbed.score.consistency.whiteness_test` and ``versus_reference``
the paired comparison of each state's per-run MSE with the reference's
(:mod:`testbed.score.paired`: the ratio interval, the +-2 % margin, Holm over the lineup).
``worst_case_search`` is
:meth:`testbed.score.worst_case.SearchResult.describe` (the linear prediction, the probe
sensors and the channels measured without quantization). ``cpu_s`` is the pair's CPU seconds
per stage (:attr:`~testbed.score.harness.PairResult.cpu_s`: where the time goes; not
deterministic). Gains are in the output's unit per
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
from testbed.score.consistency import consistency_test, verdict_text, whiteness_test
from testbed.score.harness import REFERENCE, PairResult, ScoreRun
from testbed.score.paired import comparison_text

#: Keys of every entry of ``results`` (the issue's JSON contract).
RESULT_KEYS = ("estimator", "scenario", "runs", "rmse", "rmse_ci95", "anees", "anees_bounds",
               "consistent", "anis", "anis_bounds", "worst_case_gain", "random_gain",
               "certified_gamma", "gamma_kind", "sampled_loop_gain", "certificate",
               "step_us", "step_vs_kalman", "mismatch_rmse_ratio",
               "nees_test", "nis_test", "whiteness", "versus_reference", "worst_case_search",
               "cpu_s", "skipped")


def _entry_result(pair: PairResult, reference: PairResult | None,
                  nominal: PairResult | None) -> dict[str, Any]:
    out: dict[str, Any] = dict.fromkeys(RESULT_KEYS)
    out.update(estimator=pair.estimator, scenario=pair.scenario, runs=pair.runs,
               skipped=pair.skipped, cpu_s={k: round(v, 3) for k, v in pair.cpu_s.items()})
    if pair.skipped:
        return out
    rmse, ci = {}, {}
    for name, values in pair.rmse_per_run.items():
        rmse[name], ci[name] = stats.rmse_ci(values)
    out["rmse"], out["rmse_ci95"] = rmse, {k: list(v) for k, v in ci.items()}
    if pair.nees is not None:
        test = consistency_test(pair.nees, len(pair.state_names))
        out.update(anees=test["mean"], anees_bounds=test["band"],
                   consistent=test["verdict"] == "consistent", nees_test=test)
    if pair.nis is not None:
        test = consistency_test(pair.nis, pair.nis_dim)
        out.update(anis=test["mean"], anis_bounds=test["band"], nis_test=test)
    if pair.innovations is not None:
        out["whiteness"] = whiteness_test(pair.innovations)
    if pair.worst is not None:
        out.update(worst_case_gain=pair.worst.worst_case_gain,
                   random_gain=pair.worst.random_gain,
                   worst_case_search=pair.worst.describe())
    out["certified_gamma"] = pair.certified_gamma
    out["gamma_kind"] = pair.gamma_kind
    norm = None if pair.worst is None else pair.worst.hinf
    if norm is not None:
        out["sampled_loop_gain"] = norm.value
    out["certificate"] = certificate(
        pair.certified_gamma, pair.gamma_kind, out["sampled_loop_gain"],
        finite_horizon=None if pair.worst is None else max(pair.worst.linear_gain,
                                                           pair.worst.worst_case_gain),
        truncation=None if norm is None or norm.method == "realization" else norm.truncation)
    out["step_us"] = pair.step_us
    if reference is not None and not reference.skipped and reference.step_us:
        out["step_vs_kalman"] = pair.step_us / reference.step_us
    if nominal is not None and not nominal.skipped:
        out["mismatch_rmse_ratio"] = {
            k: float(np.sqrt(np.mean(v**2)) / np.sqrt(np.mean(nominal.rmse_per_run[k] ** 2)))
            for k, v in pair.rmse_per_run.items()}
    return out


def certificate(gamma: float | None, kind: str | None, sampled_gain: float | None, *,
                finite_horizon: float | None = None, truncation: float | None = None
                ) -> str | None:
    """What a design's ``gamma`` says about the loop as it runs, sampled at the control
    period.

    ``sampled_gain`` is the infinite-horizon H-infinity norm of the linearized error system
    of the filter as it runs (discrete, ``w`` held over each period; the worst-case search's
    ``hinf``: the realized LTI system's norm, or the truncated response's, which is then
    within ``truncation`` of it). ``finite_horizon`` is a measured lower bound (the larger of
    the linearized gain over the search horizon and the gain found on the nonlinear loop):
    it can show a violation, never that ``gamma`` holds. A discrete
    design's gamma is checked: ``"violated"`` when the lower bound or ``sampled_gain -
    truncation`` exceeds it, ``"holds"`` when ``sampled_gain + truncation`` does not, else
    ``"undecided"``. A continuous-observation gamma (Basin et al.'s filters integrated over
    each period with the sample held) certifies no sampled loop: ``"not a sampled-loop
    certificate"``, whatever the numbers.

    Returns
    -------
    str or None
        None when no gamma is stated for the scenario's channel.
    """
    if gamma is None:
        return None
    if sampled_gain is None:
        return "sampled-loop gain not computed (no worst-case search)"
    if kind != "discrete":
        return "not a sampled-loop certificate (continuous-observation gamma)"
    tail = 0.0 if truncation is None else truncation
    bound = gamma * (1 + 1e-9)
    if (finite_horizon is not None and finite_horizon > bound) or sampled_gain - tail > bound:
        return "violated"
    if sampled_gain + tail <= bound:
        return "holds"
    return "undecided (gamma within the truncation error of the norm)"


def comparisons(pairs: dict[str, PairResult], estimators: list[str], reference: str,
                level: float = stats.LEVEL,
                lineup: tuple[str, ...] | None = None) -> dict[str, dict[str, Any]]:
    """Paired comparisons of one entry: estimator name to ``{"reference", "loss", "family",
    "states"}`` with, per state, :func:`testbed.score.paired.paired_comparison` of the
    per-run MSE, Holm-adjusted over a fixed family (:func:`testbed.score.paired.adjust`):
    every state x every estimator of ``lineup`` (default
    :data:`testbed.score.suite.LINEUP`) but the reference, plus the estimator itself when it
    is not in the lineup; members of the family the run did not score (or that were
    skipped) enter with p = 1. Estimators skipped, the reference itself, and all when the
    reference was skipped, are left out."""
    from testbed.score.paired import adjust, paired_comparison
    from testbed.score.suite import LINEUP

    ref = pairs.get(reference)
    if ref is None or ref.skipped:
        return {}
    lineup = LINEUP if lineup is None else tuple(lineup)
    names = [n for n in estimators if n != reference and not pairs[n].skipped]
    states = list(ref.rmse_per_run)
    raw = {(n, state): paired_comparison(pairs[n].rmse_per_run[state] ** 2,
                                         ref.rmse_per_run[state] ** 2, level)
           for n in names for state in states if state in pairs[n].rmse_per_run}
    declared = [n for n in lineup if n != reference]
    out: dict[str, dict[str, Any]] = {}
    for n in names:
        family = declared if n in declared else [*declared, n]
        members = {key: dict(c) for key, c in raw.items() if key[0] in family}
        adjust(members, len(family) * len(states), level)
        out[n] = {"reference": reference, "loss": "per-run MSE",
                  "family": f"{len(family)} estimators x {len(states)} states",
                  "states": {state: members[(n, state)] for state in states
                             if (n, state) in members}}
    return out


def results(run: ScoreRun) -> dict[str, Any]:
    """The JSON document of a score (see the module docstring)."""
    from testbed.score.suite import suite_identity

    by_name = {e.name: pairs for e, pairs in zip(run.entries, run.pairs, strict=True)}
    reference = getattr(run, "reference", REFERENCE)
    entries_out, units = [], {}
    for entry, pairs in zip(run.entries, run.pairs, strict=True):
        nominal_pairs = by_name.get(entry.nominal) if entry.nominal else None
        versus = comparisons(pairs, run.estimators, reference)
        for name in run.estimators:
            pair = pairs[name]
            units.update(pair.units)
            res = _entry_result(pair, pairs.get(REFERENCE),
                                None if nominal_pairs is None else nominal_pairs.get(name))
            res["versus_reference"] = versus.get(name)
            entries_out.append(res)
    units.update({"rmse": "state units", "step_us": "us", "cpu_s": "s (CPU, per stage)",
                  "worst_case_gain": "output unit per unit of w",
                  "random_gain": "output unit per unit of w",
                  "linear_gain": "output unit per unit of w",
                  "certified_gamma": "as the estimator's design states it",
                  "sampled_loop_gain": "output unit per unit of w (held over each period; "
                                       "infinite-horizon H-infinity norm)"})
    identity = suite_identity(run.suite)
    return {"suite": run.suite, "suite_version": identity["version"],
            "suite_hash": identity["hash"], "seed": run.seed, "level": stats.LEVEL,
            "reference": reference, "estimators": list(run.estimators),
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
                probe = (f"sensors without quantization ({', '.join(w.quantization_removed)})"
                         if w.quantization_removed else "the scenario's sensors")
                spread = (f" (restarts {min(w.restart_gains):.2g} to "
                          f"{max(w.restart_gains):.2g})" if len(w.restart_gains) > 1 else "")
                out.append(f"{prefix}: worst-case search over {w.horizon_s:g} s, energy "
                           f"{w.energy:g}, probe runs on {probe}: linearized error system "
                           f"predicts {w.linear_gain:.3g} over the horizon, found "
                           f"{w.worst_case_gain:.2g}{spread} in {w.evaluations} closed-loop "
                           "runs")
                if w.hinf is not None:
                    out.append(f"{prefix}: {_norm_text(w.hinf, w.linear_gain)}")
                out += [f"{prefix}: {note}" for note in w.notes]
    return out


def _norm_text(norm: Any, finite_horizon: float) -> str:
    """The sampled loop's H-infinity norm, how it was obtained, and its lower bound."""
    fft = (f"truncated response's FFT {norm.fft_value:.4g}, tail "
           + ("not decaying" if not np.isfinite(norm.truncation)
              else f"<= {norm.truncation:.2g} (estimated)"))
    how = (f"realized LTI system of order {norm.order} (fit {norm.fit:.1g} over the "
           f"{norm.horizon_s:g} s measured)" if norm.method == "realization"
           else f"no realization fits the {norm.horizon_s:g} s measured")
    return (f"sampled loop's H-infinity norm {norm.value:.4g}: {how}; {fft}; finite-horizon "
            f"gain {finite_horizon:.4g} (a lower bound)")


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
    """``ANEES [t interval of the per-run time averages] p <mean test's p> verdict``: ``ok``
    only for ``consistent`` (the mean test and the band diagnostic both accept),
    ``no verdict`` below the minimum number of runs, else the verdict in capitals."""
    test = res["nees_test"]
    if test is None:
        return "-"
    lo, hi = test["mean_ci"]
    verdict = {"consistent": "ok", "no verdict": "no verdict"}.get(test["verdict"],
                                                                   test["verdict"].upper())
    return f"{test['mean']:.3g} [{lo:.3g}, {hi:.3g}] p {test['mean_p']:.2g} {verdict}"


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


def _gain_text(res: dict[str, Any]) -> str:
    if res["worst_case_gain"] is None:
        return "-"
    text = f"{res['worst_case_gain']:.2g} / {res['random_gain']:.2g}"
    if res["certified_gamma"] is not None:
        sampled = res["sampled_loop_gain"]
        text += f" (gamma {res['certified_gamma']:.3g}"
        if sampled is not None:
            text += f", sampled loop {sampled:.3g}"
        text += ")"
    return text


def _mismatch_text(res: dict[str, Any]) -> str:
    ratio = res["mismatch_rmse_ratio"]
    if not ratio:
        return "-"
    state = max(ratio, key=ratio.get)
    return f"{ratio[state]:.3g} ({state})"


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


#: Columns of :func:`leaderboard`.
_COLUMNS = ("estimator", "rank", "RMSE", "ANEES [95 % CI] p verdict", "ANIS",
            "worst / random gain (gamma, sampled loop)", "us/step (x KF)", "mismatch")


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
            states = list(res["rmse"])[:2]
            cost = (f"{res['step_us']:.3g}" + (f" (x{res['step_vs_kalman']:.2g})"
                                                if res["step_vs_kalman"] else ""))
            rows.append((res["estimator"], str(ranks[res["estimator"]]),
                         _rmse_text(res, units, states), _consistency_text(res),
                         _fmt(res["anis"]), _gain_text(res), cost, _mismatch_text(res)))
        blocks.append((scenario, group, rows))
    every = [row for _, _, rows in blocks for row in rows]
    full = [_COLUMNS] + [row for row in every if len(row) == len(_COLUMNS)]
    widths = [max(len(row[i]) for row in full) for i in range(len(_COLUMNS))]
    widths[0] = max([widths[0], *(len(row[0]) for row in every)])

    def line(row: tuple[str, ...]) -> str:
        return "  " + "  ".join(f"{c:<{w}}" for c, w in zip(row, widths, strict=False)).rstrip()

    for scenario, group, rows in blocks:
        lines += ["", f"{scenario} ({group[0]['runs']} runs)", line(_COLUMNS)]
        lines += [line(row) for row in rows]
        lines += [f"  {text}" for text in _details(group, units)]
    return "\n".join(lines)


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
    descriptions = {s["name"]: s for s in summary["scenarios"]}
    for scenario, group in _rows(summary):
        desc = descriptions.get(scenario, {})
        out += [f"## {scenario}", "", desc.get("description", ""), "",
                "| estimator | RMSE (95 % CI) | ANEES [95 % CI] p verdict | ANIS [band] | worst / "
                "random gain (gamma) | us/step (x KF) | mismatch | skipped |",
                "|---|---|---|---|---|---|---|---|"]
        for res in _sorted(group, summary.get("estimators")):
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
