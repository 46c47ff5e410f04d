"""Figures and Rerun files of a replay (:class:`testbed.experiment.replay.ReplayResult`).

No truth in a replay: the state panels show the estimate with its +-3 sigma band over the
measurements of that state (and the held-out reference channel, when there is one); the
innovation panels show each innovation channel between +-3 sqrt(S_ii), on an axis that fits
the steady state (samples beyond it marked at its edge). Units as everywhere:
the declared ones, angles in degrees (:mod:`testbed.outputs.units`).

Rerun entities (every temporal one on the ``time`` timeline, a duration in seconds)::

    about                                 static TextDocument: what was replayed
    state/<state>/estimate                Scalars (+ static SeriesLines style)
    state/<state>/plus_3sigma, minus_3sigma   estimate +- 3 sqrt(P_ii)
    measurement/<channel>                 Scalars (+ static SeriesPoints style)
    innovation/<channel>/value            Scalars
    innovation/<channel>/plus_3sigma, minus_3sigma   +- 3 sqrt(S_ii)
    nis                                   Scalars: nu^T S^-1 nu per step
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from testbed.experiment.replay import ReplayResult
from testbed.outputs.axes import steady_state_limit
from testbed.outputs.names import entity_parts
from testbed.outputs.plots import figure_legend, mark_clipped, new_figure, save_figure, set_title
from testbed.outputs.units import display, label
from testbed.outputs.viz import (
    ESTIMATE_COLOR,
    ESTIMATE_WIDTH,
    MEASUREMENT_COLOR,
    MEASUREMENT_SIZE,
    SIGMA_COLOR,
    SIGMA_WIDTH,
    TIMELINE,
    write_series,
)

_COLORS = [f"C{i}" for i in range(10)]


def _measured_state(result: ReplayResult) -> list[int | None]:
    """The state each channel measures directly (None: no single state)."""
    out = list(result.measured_state)
    return out + [None] * (len(result.measurement_names) - len(out))


def _title(result: ReplayResult) -> list[str]:
    lines = [f"replay: {result.rig} ({result.profile}) / {result.estimator}, "
             f"{Path(result.source).name}, {result.steps} steps at {result.period_s:g} s"]
    c = result.consistency
    if c is not None:
        lo, hi = c["band"]
        text = (f"ANIS {c['anis']:.3g} [{lo:.3g}, {hi:.3g}] vs {c['dim']}: {c['verdict']}; "
                f"{100 * c['band_fraction']:.1f} % of steps outside the chi2({c['dim']}) band")
        if c["whiteness"] is not None:
            text += f"; whiteness p {c['whiteness']['p']:.2g}"
        lines.append(text)
    ref = result.reference
    if ref is not None:
        factor, unit = display(ref["unit"])
        lines.append(f"reference {ref['channel']} (held out): RMSE "
                     f"{factor * ref['rmse']:.3g} {unit}")
    return lines


def replay_figure(result: ReplayResult) -> Any:
    """The figure of :func:`plot_replay` (not saved): states left, innovations right."""
    t = np.asarray(result.time_s, float)
    n = len(result.state_names)
    p = 0 if result.innovations is None else result.innovations.shape[1]
    rows = max(n, p, 1)
    cols = 2 if p else 1
    fig = new_figure(6.0 * cols, 2.0 * rows + 1.6)
    grid = fig.add_gridspec(rows, cols)
    msi = _measured_state(result)
    ref = None if result.reference is None else result.reference["channel"]
    first = None
    for i, name in enumerate(result.state_names):
        factor, unit = display(result.state_units[i])
        color = _COLORS[i % len(_COLORS)]
        ax = fig.add_subplot(grid[i, 0], sharex=first)
        first = first or ax
        for j, idx in enumerate(msi):
            if idx != i:
                continue
            held = result.measurement_names[j] == ref
            ax.plot(t, factor * result.measurement[:, j], ".", ms=2.5, alpha=0.5, zorder=1,
                    color="black" if held else "0.55",
                    label="reference (held out)" if held else "measurement")
        x = factor * result.x_hat[:, i]
        if result.P_diag is not None:
            bound = 3.0 * factor * np.sqrt(result.P_diag[:, i])
            ax.fill_between(t, x - bound, x + bound, color=color, alpha=0.2, lw=0,
                            label="±3σ", zorder=2)
        ax.plot(t, x, color=color, lw=1.0, label="estimate", zorder=3)
        ax.set_ylabel(label(name, unit))
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelbottom=i == n - 1)
        if i == n - 1:
            ax.set_xlabel("time [s]")
    for k in range(p):
        name = result.innovation_names[k]
        j = result.measurement_names.index(name) if name in result.measurement_names else None
        factor, unit = display(result.measurement_units[j] if j is not None else "")
        ax = fig.add_subplot(grid[k, 1], sharex=first)
        bound = 3.0 * factor * np.sqrt(result.innovation_var[:, k])
        values = factor * result.innovations[:, k]
        lim = steady_state_limit(t[1:], values, bound)
        ax.fill_between(t[1:], -bound, bound, color="0.5", alpha=0.25, lw=0, label="±3√S")
        ax.plot(t[1:], values, color=_COLORS[k % len(_COLORS)], lw=0.8, label="innovation")
        mark_clipped(ax, t[1:], values, lim)
        ax.set_ylim(-lim, lim)
        ax.axhline(0.0, color="black", lw=0.5)
        ax.set_ylabel(label(f"{name} innovation", unit))
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelbottom=k == p - 1)
        if k == p - 1:
            ax.set_xlabel("time [s]")
    if first is not None and len(t) > 1:
        first.set_xlim(t[0], t[-1])
    figure_legend(fig, max_columns=5)
    set_title(fig, _title(result))
    return fig


def plot_replay(result: ReplayResult, path: str | os.PathLike) -> Path:
    """Write the replay's PNG: per state the estimate +-3 sigma over its measurements (the
    reference channel in black), per innovation channel the innovation between +-3 sqrt(S).

    Parameters
    ----------
    result : ReplayResult
    path : str or PathLike
        Destination ``.png`` (written atomically).

    Returns
    -------
    Path
    """
    return save_figure(replay_figure(result), path)


def _description(result: ReplayResult) -> str:
    return "\n\n".join(["# " + _title(result)[0], *_title(result)[1:],
                        f"sensors: {result.sensors}",
                        f"recording sha256: {result.sha256 or '-'}"])


def log_replay_rerun(result: ReplayResult, path: str | os.PathLike, *,
                     degrees: bool = True, application_id: str = "testbed-replay") -> Path:
    """Write the replay as a Rerun ``.rrd`` (entities in the module docstring), atomically.

    Parameters
    ----------
    result : ReplayResult
    path : str or PathLike
        Destination ``.rrd``.
    degrees : bool
        Angles in degrees.
    application_id : str

    Returns
    -------
    Path

    Raises
    ------
    RuntimeError
        Rerun logging is disabled (``RERUN=off``).
    """
    import rerun as rr
    import rerun.blueprint as rrb

    t = np.asarray(result.time_s, float)
    states = entity_parts(result.state_names)
    channels = entity_parts(result.measurement_names)
    innov = entity_parts(result.innovation_names)
    msi = _measured_state(result)
    series: list[tuple[str, np.ndarray, np.ndarray]] = []
    styles: list[tuple[str, Any]] = []

    def lines(name: str, unit: str, color: Any, width: float) -> Any:
        return rr.SeriesLines(names=[f"{name} [{unit}]" if unit else name], colors=[color],
                              widths=[width])

    views = []
    for i, part in enumerate(states):
        factor, unit = display(result.state_units[i], degrees)
        x = factor * result.x_hat[:, i]
        series.append((f"state/{part}/estimate", t, x))
        styles.append((f"state/{part}/estimate", lines("estimate", unit, ESTIMATE_COLOR,
                                                      ESTIMATE_WIDTH)))
        contents = [f"/state/{part}/**"]
        if result.P_diag is not None:
            bound = 3.0 * factor * np.sqrt(result.P_diag[:, i])
            for side, sign in (("plus", 1.0), ("minus", -1.0)):
                series.append((f"state/{part}/{side}_3sigma", t, x + sign * bound))
                styles.append((f"state/{part}/{side}_3sigma",
                               lines("estimate ±3σ", unit, SIGMA_COLOR, SIGMA_WIDTH)))
        contents += [f"/measurement/{channels[j]}" for j, s in enumerate(msi) if s == i]
        views.append(rrb.TimeSeriesView(origin="/", contents=contents, name=part))
    for j, part in enumerate(channels):
        factor, unit = display(result.measurement_units[j], degrees)
        values = result.measurement[:, j]
        keep = np.isfinite(values)
        series.append((f"measurement/{part}", t[keep], factor * values[keep]))
        styles.append((f"measurement/{part}", rr.SeriesPoints(
            names=[f"measured {part} [{unit}]" if unit else f"measured {part}"],
            colors=[MEASUREMENT_COLOR], markers=["circle"], marker_sizes=[MEASUREMENT_SIZE])))
        if msi[j] is None:
            views.append(rrb.TimeSeriesView(origin="/", contents=[f"/measurement/{part}"],
                                            name=part))
    for k, part in enumerate(innov):
        name = result.innovation_names[k]
        j = result.measurement_names.index(name) if name in result.measurement_names else None
        factor, unit = display(result.measurement_units[j] if j is not None else "", degrees)
        series.append((f"innovation/{part}/value", t[1:], factor * result.innovations[:, k]))
        styles.append((f"innovation/{part}/value", lines("innovation", unit, ESTIMATE_COLOR,
                                                         ESTIMATE_WIDTH)))
        bound = 3.0 * factor * np.sqrt(result.innovation_var[:, k])
        for side, sign in (("plus", 1.0), ("minus", -1.0)):
            series.append((f"innovation/{part}/{side}_3sigma", t[1:], sign * bound))
            styles.append((f"innovation/{part}/{side}_3sigma",
                           lines("±3√S", unit, SIGMA_COLOR, SIGMA_WIDTH)))
        views.append(rrb.TimeSeriesView(origin="/", contents=[f"/innovation/{part}/**"],
                                        name=f"{part} innovation"))
    if result.nis is not None:
        series.append(("nis", t[1:], np.asarray(result.nis, float)))
        styles.append(("nis", lines("NIS", "", ESTIMATE_COLOR, 1.0)))
        views.append(rrb.TimeSeriesView(origin="/", contents=["/nis"], name="NIS"))
    blueprint = rrb.Blueprint(
        rrb.Horizontal(rrb.TextDocumentView(origin="/about", name="about"),
                       rrb.Grid(*views, grid_columns=2), column_shares=[1.0, 3.0]),
        rrb.TimePanel(timeline=TIMELINE), collapse_panels=False)
    return write_series(path, application_id, blueprint, _description(result), styles,
                        series)
