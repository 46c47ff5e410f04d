"""Figures of Monte-Carlo studies and sweeps (PNG; matplotlib without pyplot state).

- :func:`monte_carlo_figure`: per state (a column each), the distribution of the per-run
  RMSE, and the error envelope over time (median and 5 % / 95 % quantiles over runs) with
  the filter's mean +-3 sigma, over the whole run and over its second half (steady state).
  Needs the ``error_envelope`` of :func:`testbed.experiment.runner.monte_carlo`
  (``envelope_points``).
- :func:`sweep_figure`: per state, the RMSE (mean over runs, 5-95 % band) against one grid
  parameter, one line per combination of the other parameters.

Units are the rig's (``result["units"]``), angles in degrees; legends sit outside the axes;
no text is smaller than :data:`testbed.outputs.plots.MIN_FONT_PT`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from testbed.outputs.axes import TRANSIENT_FRACTION, steady_state_limit
from testbed.outputs.plots import figure_legend, new_figure, save_figure, set_title
from testbed.outputs.units import display, label


def _study_title(fig: Figure, result: dict[str, Any], what: str, *extra: str) -> None:
    """Figure title, short: rig, filter, the sensor preset, what; extra lines. The sensor
    chain itself is in the JSON (``meta["sensors"]``); the preset is the study's
    ``scenario["sensors"]``."""
    meta = result.get("meta") or {}
    scenario = result.get("scenario") or meta.get("scenario") or {}
    preset = scenario.get("sensors")
    sensors = f", sensors {preset!r}" if isinstance(preset, str) and len(preset) <= 30 else ""
    lines = [f"{meta.get('rig', '?')}: {result.get('filter', scenario.get('estimator', '?'))} "
             f"filter{sensors}, {what}", *extra]
    set_title(fig, lines)


def monte_carlo_figure(result: dict[str, Any]) -> Figure:
    """The figure of :func:`plot_monte_carlo` (not saved).

    Parameters
    ----------
    result : dict
        Of :func:`testbed.experiment.runner.monte_carlo` with ``rmse_per_run``, ``units`` and
        ``error_envelope``.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        If ``result`` has no ``error_envelope`` (run it with ``envelope_points``).
    """
    envelope = result.get("error_envelope")
    if not envelope:
        raise ValueError("the Monte-Carlo result has no error_envelope; run monte_carlo with "
                         "envelope_points (testbed mc --plot does)")
    states = list(result["rmse_per_run"])
    units = result.get("units", {})
    fig = new_figure(max(3.6 * len(states), 8.0), 9.5)
    grid = fig.add_gridspec(3, len(states))
    t = np.asarray(envelope["t_s"], dtype=float)
    late = t >= t[0] + TRANSIENT_FRACTION * (t[-1] - t[0])
    for i, name in enumerate(states):
        factor, unit = display(units.get(name, ""))
        rmse = factor * np.asarray(result["rmse_per_run"][name], dtype=float)
        ax = fig.add_subplot(grid[0, i])
        ax.hist(rmse, bins=max(5, min(40, len(rmse) // 5)), color="C0", alpha=0.7,
                label="runs")
        stats = result["rmse"][name]
        ax.axvline(factor * stats["mean"], color="black", lw=1.2, label="mean")
        for q in ("q05", "q95"):
            ax.axvline(factor * stats[q], color="black", lw=0.8, ls=":",
                       label="5 % / 95 % quantiles")
        ax.set_xlabel(label(f"{name} RMSE", unit))
        ax.set_ylabel("runs [count]")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts: whole runs
        ax.grid(True, alpha=0.3)

        env = envelope["states"][name]
        q05, q50, q95 = (factor * np.asarray(env[k], dtype=float)
                         for k in ("q05", "median", "q95"))
        sigma = None if env.get("sigma3_mean") is None else \
            factor * np.asarray(env["sigma3_mean"], dtype=float)
        for row, (mask, what) in enumerate(((slice(None), "whole run"),
                                            (late, "second half"))):
            ax = fig.add_subplot(grid[1 + row, i])
            ax.fill_between(t[mask], q05[mask], q95[mask], color="C1", alpha=0.3, lw=0,
                            label="error (estimate − truth), 5-95 % of runs")
            ax.plot(t[mask], q50[mask], color="C1", lw=1.2,
                    label="error (estimate − truth), median")
            if sigma is not None:
                ax.plot(t[mask], sigma[mask], color="0.25", lw=1.0, ls="--",
                        label="filter's ±3σ (mean over runs)")
                ax.plot(t[mask], -sigma[mask], color="0.25", lw=1.0, ls="--")
            ax.axhline(0.0, color="black", lw=0.5)
            if row == 1:
                spread = np.maximum(np.abs(q05), np.abs(q95))
                lim = steady_state_limit(t, spread, sigma)
                ax.set_ylim(-lim, lim)
            ax.set_xlabel("time [s]")
            ax.set_ylabel(label(f"{name} error ({what})", unit))
            ax.grid(True, alpha=0.3)
    nees = result.get("nees_mean")
    _study_title(fig, result, f"{result['runs']} runs of {result['duration_s']:g} s",
                 *([] if nees is None else [f"mean NEES {nees:.2f} (n = {len(states)})"]))
    figure_legend(fig)
    return fig


def plot_monte_carlo(result: dict[str, Any], path: str | os.PathLike, *,
                     dpi: int = 100) -> Path:
    """Write :func:`monte_carlo_figure` of ``result`` to a PNG, atomically."""
    return save_figure(monte_carlo_figure(result), path, dpi=dpi)


def _axis_label(name: str) -> str:
    """x label of a grid parameter: ``params.*`` are scales of the nominal value; other
    names are shown as given (their unit is the option's, not known here)."""
    if name.startswith("params."):
        return f"{name} [scale of the nominal value]"
    return f"{name} [as given to --grid]"


def sweep_figure(result: dict[str, Any], x: str | None = None) -> Figure:
    """The figure of :func:`plot_sweep` (not saved).

    Parameters
    ----------
    result : dict
        Of :func:`testbed.experiment.runner.sweep`.
    x : str, optional
        Grid parameter on the horizontal axis (default: the first one); the other
        parameters' combinations are the lines.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        If ``x`` is not a grid parameter.
    """
    points = result["points"]
    names = list(points[0]["point"])
    x = names[0] if x is None else x
    if x not in names:
        raise ValueError(f"x must be one of the grid parameters {names}, got {x!r}")
    others = [n for n in names if n != x]
    first = points[0]["result"]
    states = list(first["rmse"])
    units = first.get("units", {})
    has_nees = all(p["result"].get("nees_mean") is not None for p in points)
    panels = states + (["NEES"] if has_nees else [])
    cols = min(len(panels), 3)
    rows = int(np.ceil(len(panels) / cols))
    fig = new_figure(4.2 * cols, 3.0 * rows + 1.6)
    grid = fig.add_gridspec(rows, cols)
    combos = sorted({tuple(p["point"][n] for n in others) for p in points})
    xs_all = np.array(sorted({float(p["point"][x]) for p in points}))
    log_x = bool(np.all(xs_all > 0) and xs_all.max() / xs_all.min() >= 100)
    for k, panel in enumerate(panels):
        ax = fig.add_subplot(grid[k // cols, k % cols])
        for c, combo in enumerate(combos):
            sel = sorted((p for p in points if tuple(p["point"][n] for n in others) == combo),
                         key=lambda p: float(p["point"][x]))
            xs = np.array([float(p["point"][x]) for p in sel])
            text = ", ".join(f"{n} = {v:g}" for n, v in zip(others, combo, strict=True))
            color = f"C{c % 10}"
            if panel == "NEES":
                ax.plot(xs, [p["result"]["nees_mean"] for p in sel], "o-", color=color,
                        lw=1.2, ms=4, label=text or "mean")
                continue
            factor = display(units.get(panel, ""))[0]
            stats = [p["result"]["rmse"][panel] for p in sel]
            mean = factor * np.array([s["mean"] for s in stats])
            lo = factor * np.array([s["q05"] for s in stats])
            hi = factor * np.array([s["q95"] for s in stats])
            ax.fill_between(xs, lo, hi, color=color, alpha=0.15, lw=0)
            ax.plot(xs, mean, "o-", color=color, lw=1.2, ms=4, label=text or "mean")
        if panel == "NEES":
            ax.axhline(len(states), color="black", lw=0.8, ls=":", label="consistent filter")
            ax.set_ylabel("mean NEES [-]")
            values = np.array([p["result"]["nees_mean"] for p in points], dtype=float)
            if np.all(values > 0) and values.max() / values.min() >= 100:
                ax.set_yscale("log")
        else:
            ax.set_ylabel(label(f"{panel} RMSE", display(units.get(panel, ""))[1]))
        ax.set_xlabel(_axis_label(x))
        if log_x:
            ax.set_xscale("log")
        ax.grid(True, alpha=0.3)
    runs = first.get("runs", "?")
    _study_title(fig, first, f"sweep over {', '.join(names)}",
                 f"{runs} runs per point; lines: mean, bands: 5-95 % of runs")
    figure_legend(fig)
    return fig


def plot_sweep(result: dict[str, Any], path: str | os.PathLike, *, x: str | None = None,
               dpi: int = 100) -> Path:
    """Write :func:`sweep_figure` of ``result`` to a PNG, atomically."""
    return save_figure(sweep_figure(result, x), path, dpi=dpi)
