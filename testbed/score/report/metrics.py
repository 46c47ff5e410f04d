"""The score's reported quantities as :class:`Metric` objects: the tables iterate over them.

A :class:`Metric` is one column of the leaderboard: its name (the result's key it reads),
its headers in the terminal table and in Markdown, and how one scored pair's result is
written in each. :data:`METRICS` lists them in column order; :mod:`.tables` prints the
estimator's name and rank, then each metric's cell. A new reported quantity is one
:class:`Metric` here (and the harness's key it reads); the tables follow.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from testbed.outputs.units import display

#: A cell writer: ``(result of one pair, units by state) -> text``.
Cell = Callable[[dict[str, Any], dict[str, str]], str]


@dataclass(frozen=True)
class Metric:
    """One reported quantity of a scored (entry, estimator) pair.

    Attributes
    ----------
    name : str
        The key of the pair's result it reads (``"rmse"``, ``"nees_test"``...).
    header : str
        Its column header in the terminal table.
    markdown_header : str
        Its column header in the Markdown table.
    cell : callable ``(res, units) -> str``
        The terminal cell.
    markdown_cell : callable ``(res, units) -> str``
        The Markdown cell.
    """

    name: str
    header: str
    markdown_header: str
    cell: Cell
    markdown_cell: Cell


def fmt(value: Any, spec: str = ".3g") -> str:
    """``value`` formatted, ``-`` for None."""
    return "-" if value is None else format(value, spec)


def rmse_text(res: dict[str, Any], units: dict[str, str], states: list[str]) -> str:
    """``state value unit`` of the given states, in display units, comma-separated."""
    parts = []
    for s in states:
        factor, unit = display(units.get(s, ""))
        parts.append(f"{s} {res['rmse'][s] * factor:.3g}{(' ' + unit) if unit else ''}")
    return ", ".join(parts)


def _rmse_cell(res: dict[str, Any], units: dict[str, str]) -> str:
    return rmse_text(res, units, list(res["rmse"])[:2])


def _rmse_markdown(res: dict[str, Any], units: dict[str, str]) -> str:
    cells = []
    for s, value in res["rmse"].items():
        factor, unit = display(units.get(s, ""))
        lo, hi = res["rmse_ci95"][s]
        cells.append(f"{s} {value * factor:.3g} [{lo * factor:.3g}, {hi * factor:.3g}]"
                     f"{(' ' + unit) if unit else ''}")
    return "<br>".join(cells)


def consistency_text(res: dict[str, Any], units: dict[str, str] | None = None) -> str:
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


def _anis_cell(res: dict[str, Any], units: dict[str, str]) -> str:
    return fmt(res["anis"])


def _anis_markdown(res: dict[str, Any], units: dict[str, str]) -> str:
    if res["anis"] is None:
        return "-"
    return f"{res['anis']:.3g} [{res['anis_bounds'][0]:.3g}, {res['anis_bounds'][1]:.3g}]"


def gain_text(res: dict[str, Any], units: dict[str, str] | None = None) -> str:
    """``worst / random`` gain, with the design's gamma and the sampled loop's norm."""
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


def _cost_cell(res: dict[str, Any], units: dict[str, str]) -> str:
    return f"{res['step_us']:.3g}" + (f" (x{res['step_vs_kalman']:.2g})"
                                      if res["step_vs_kalman"] else "")


def mismatch_text(res: dict[str, Any], units: dict[str, str] | None = None) -> str:
    """The largest RMSE ratio at the mismatched parameters over nominal, and its state."""
    ratio = res["mismatch_rmse_ratio"]
    if not ratio:
        return "-"
    state = max(ratio, key=ratio.get)
    return f"{ratio[state]:.3g} ({state})"


#: The reported quantities, in column order.
METRICS: tuple[Metric, ...] = (
    Metric("rmse", "RMSE", "RMSE (95 % CI)", _rmse_cell, _rmse_markdown),
    Metric("nees_test", "ANEES [95 % CI] p verdict", "ANEES [95 % CI] p verdict",
           consistency_text, consistency_text),
    Metric("anis", "ANIS", "ANIS [band]", _anis_cell, _anis_markdown),
    Metric("worst_case_gain", "worst / random gain (gamma, sampled loop)",
           "worst / random gain (gamma)", gain_text, gain_text),
    Metric("step_us", "us/step (x KF)", "us/step (x KF)", _cost_cell, _cost_cell),
    Metric("mismatch_rmse_ratio", "mismatch", "mismatch", mismatch_text, mismatch_text),
)
