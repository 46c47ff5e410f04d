"""A recording laid over its simulation (``testbed compare --rrd``): per channel the measured
samples and the simulated channel, as a Rerun ``.rrd``, written atomically.

Entities: ``channel/<name>/measured`` (points), ``channel/<name>/simulated`` (a line), and
``about`` (the fit per channel).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from testbed.outputs.names import entity_parts
from testbed.outputs.units import display
from testbed.outputs.viz import (
    ESTIMATE_COLOR,
    ESTIMATE_WIDTH,
    MEASUREMENT_COLOR,
    MEASUREMENT_SIZE,
    TIMELINE,
    write_series,
)


def write_overlay_rrd(result: dict[str, Any], path: str | os.PathLike, *,
                      degrees: bool = True, application_id: str = "testbed-compare") -> Path:
    """Write :func:`testbed.identify.comparison.compare`'s result as a Rerun ``.rrd``.

    Parameters
    ----------
    result : dict
        With ``series`` (``time_s`` (N,), ``measured`` and ``predicted`` (N, m)),
        ``channels``, ``units`` and ``fit_percent``.
    path : str or PathLike
        Destination ``.rrd``.
    degrees : bool
        Angles in degrees.
    application_id : str

    Returns
    -------
    Path
    """
    import rerun as rr
    import rerun.blueprint as rrb

    series = result["series"]
    t = np.asarray(series["time_s"], float)
    names, units = list(result["channels"]), list(result["units"])
    parts = entity_parts(names)
    views, columns, styles = [], [], []
    for j, part in enumerate(parts):
        factor, unit = display(units[j], degrees)
        suffix = f" [{unit}]" if unit else ""
        for kind, values in (("measured", series["measured"][:, j]),
                             ("simulated", series["predicted"][:, j])):
            keep = np.isfinite(values)
            columns.append((f"channel/{part}/{kind}", t[keep], factor * values[keep]))
        styles.append((f"channel/{part}/measured", rr.SeriesPoints(
            names=[f"measured {names[j]}{suffix}"], colors=[MEASUREMENT_COLOR],
            markers=["circle"], marker_sizes=[MEASUREMENT_SIZE])))
        styles.append((f"channel/{part}/simulated", rr.SeriesLines(
            names=[f"simulated {names[j]}{suffix}"], colors=[ESTIMATE_COLOR],
            widths=[ESTIMATE_WIDTH])))
        fit = result["fit_percent"].get(names[j], float("nan"))
        views.append(rrb.TimeSeriesView(origin="/", contents=[f"/channel/{part}/**"],
                                        name=f"{names[j]}: fit {fit:.1f} %"))
    what = result.get("twin") or f"the nominal {result['rig']}"
    about = (f"# {result['recording_source']} vs {what}\n\n"
             f"rig {result['rig']} ({result['profile']}), method {result['method']}\n\n"
             + "\n".join(f"- {ch}: fit {v:.2f} %" for ch, v in result["fit_percent"].items()))
    blueprint = rrb.Blueprint(
        rrb.Horizontal(rrb.TextDocumentView(origin="/about", name="about"),
                       rrb.Grid(*views, grid_columns=1), column_shares=[1.0, 3.0]),
        rrb.TimePanel(timeline=TIMELINE), collapse_panels=False)
    return write_series(path, application_id, blueprint, about, styles, columns)
