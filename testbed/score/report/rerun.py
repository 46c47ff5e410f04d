"""The score as a comparison Rerun recording (:func:`write_rrd`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from testbed.io import atomic_path
from testbed.outputs.units import display
from testbed.score.harness import ScoreRun


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
    from testbed.outputs.viz import TIMELINE, panel_name, place_legend, time_axis_range

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
        start, end = time_axis_range((float(t[0]), float(t[-1])))  # + the end margin
        axis_x = rrb.TimeAxis(link="Independent", zoom_lock=False, view_range=rr.TimeRange(
            start=rrb.TimeRangeBoundary.absolute(seconds=start),
            end=rrb.TimeRangeBoundary.absolute(seconds=end)))
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

