"""The JSON results of a score (:func:`results`), its remarks (:func:`notes`) and the
results and worst-case files."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from testbed.io import atomic_path, write_json
from testbed.score import stats
from testbed.score.consistency import consistency_test, whiteness_test
from testbed.score.harness import REFERENCE, PairResult, ScoreRun

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
    reference = run.reference
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


