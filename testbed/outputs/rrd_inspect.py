"""Read a Rerun ``.rrd`` file back: what a viewer will show, without a viewer.

:func:`inspect_rrd` summarises the first recording of a file (rows per entity, the data's
time range, the series styles, text documents) and its stored blueprint (the views with
their names, time and value ranges and the 3D camera). The tests read every kind of file
the testbed writes with it; it is also handy to check a recording on a headless machine.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

TIMELINE = "time"


def rgba(packed: int) -> tuple[int, int, int, int]:
    """Rerun's packed ``0xRRGGBBAA`` colour as an (r, g, b, a) tuple of 0-255 ints."""
    packed = int(packed)
    return ((packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255, packed & 255)


@dataclass
class View:
    """One view of a stored blueprint."""

    name: str
    time_range_s: tuple[float, float] | None = None
    y_range: tuple[float, float] | None = None
    eye_position: tuple[float, ...] | None = None
    eye_target: tuple[float, ...] | None = None
    contents: list[str] = field(default_factory=list)
    #: ``"RightBottom"``, ``"LeftTop"``... and whether the legend is shown (None: not set).
    legend_corner: str | None = None
    legend_visible: bool | None = None


@dataclass
class RrdContents:
    """What :func:`inspect_rrd` found.

    Attributes
    ----------
    rows : dict of str to int
        Entity (no leading ``/``) -> rows on the ``time`` timeline (0: static only).
    chunks : dict of str to int
        Entity -> number of temporal chunks (a streamed run sends several).
    time_range_s : (float, float) or None
        First and last time of any temporal row.
    styles : dict of str to dict
        Entity -> ``{"kind": "lines" | "points", "names", "colors" (RGBA tuples),
        "widths" or "sizes"}``.
    texts : dict of str to str
        Entity -> text of its ``TextDocument``.
    views : list of View
        The blueprint's views (empty without a blueprint).
    application_id : str or None
    """

    rows: dict[str, int] = field(default_factory=dict)
    chunks: dict[str, int] = field(default_factory=dict)
    time_range_s: tuple[float, float] | None = None
    styles: dict[str, dict[str, Any]] = field(default_factory=dict)
    texts: dict[str, str] = field(default_factory=dict)
    views: list[View] = field(default_factory=list)
    application_id: str | None = None

    def view(self, name: str) -> View:
        """The view called ``name`` (``KeyError`` listing the names otherwise)."""
        for v in self.views:
            if v.name == name:
                return v
        raise KeyError(f"no view {name!r}; views: {[v.name for v in self.views]}")


def _column(batch: Any, name: str) -> list | None:
    return batch.column(name).to_pylist() if name in batch.schema.names else None


def _reader(path: str | os.PathLike) -> Any:
    import warnings

    from rerun.chunk import RrdReader

    with warnings.catch_warnings():  # a streamed file has no footer: Rerun warns, reads all
        warnings.simplefilter("ignore")
        return RrdReader(Path(path))


def series(path: str | os.PathLike, entity: str, component: str = "Scalars:scalars"
           ) -> tuple[np.ndarray, np.ndarray]:
    """(time in s, values) of one temporal component, sorted by time.

    Parameters
    ----------
    path : str or PathLike
    entity : str
        With or without the leading ``/``.
    component : str
        Column name, e.g. ``"Scalars:scalars"`` or ``"Transform3D:quaternion"``.
    """
    entity = "/" + entity.lstrip("/")
    times, values = [], []
    for chunk in _reader(path).stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        times.append(batch.column(TIMELINE).cast("int64").to_numpy())
        values.append(np.array([row[0] for row in batch.column(component).to_pylist()]))
    if not times:
        raise KeyError(f"no temporal {component} for {entity} in {path}")
    t_ns, vals = np.concatenate(times), np.concatenate(values)
    order = np.argsort(t_ns, kind="stable")
    return t_ns[order] * 1e-9, vals[order]


def inspect_rrd(path: str | os.PathLike) -> RrdContents:
    """Summarise an ``.rrd`` file (see :class:`RrdContents`).

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    RrdContents
    """
    out = RrdContents()
    reader = _reader(path)
    recordings = reader.recordings()
    if recordings:
        out.application_id = recordings[0].application_id
    lo, hi = np.inf, -np.inf
    for chunk in reader.stream():
        entity = chunk.entity_path.lstrip("/")
        if entity.startswith("__"):
            continue
        temporal = not chunk.is_static and TIMELINE in chunk.timeline_names
        out.rows[entity] = out.rows.get(entity, 0) + (chunk.num_rows if temporal else 0)
        batch = chunk.to_record_batch()
        if temporal:
            out.chunks[entity] = out.chunks.get(entity, 0) + 1
            t = batch.column(TIMELINE).cast("int64").to_numpy()
            if len(t):
                lo, hi = min(lo, t.min() * 1e-9), max(hi, t.max() * 1e-9)
            continue
        for kind, arch, size in (("lines", "SeriesLines", "widths"),
                                 ("points", "SeriesPoints", "marker_sizes")):
            colors = _column(batch, f"{arch}:colors")
            if colors is not None:
                out.styles[entity] = {
                    "kind": kind, "names": (_column(batch, f"{arch}:names") or [None])[-1],
                    "colors": [rgba(c) for c in colors[-1]],
                    "sizes": (_column(batch, f"{arch}:{size}") or [None])[-1]}
        text = _column(batch, "TextDocument:text")
        if text is not None:
            out.texts[entity] = text[-1][0] if isinstance(text[-1], list) else text[-1]
    if np.isfinite(lo):
        out.time_range_s = (float(lo), float(hi))
    out.rows = dict(sorted(out.rows.items()))
    # a live run sends its blueprint twice (auto ranges, then fitted): the stores are merged
    # by (view name, occurrence), a property set in any store kept (the reader's store order
    # is not fixed)
    merged: dict[tuple[str, int], View] = {}
    for store in reader.blueprints():
        seen: dict[str, int] = {}
        for v in _views(reader, store):
            key = (v.name, seen.setdefault(v.name, 0))
            seen[v.name] += 1
            if key not in merged:
                merged[key] = v
                continue
            kept = merged[key]
            for key, value in vars(v).items():
                if value is not None and getattr(kept, key) is None:
                    setattr(kept, key, value)
    out.views = list(merged.values())
    return out


#: Rerun's ``Corner2D`` values.
_CORNERS = {1: "LeftTop", 2: "RightTop", 3: "LeftBottom", 4: "RightBottom"}


def _views(reader: Any, store: Any) -> list[View]:
    """Views of a blueprint store, with their properties."""
    views: dict[str, View] = {}

    def view(path: str) -> View:
        key = path.split("/")[2] if path.count("/") >= 2 else path
        return views.setdefault(key, View(name=""))

    for chunk in reader.stream(store=store):
        path = chunk.entity_path
        if not path.startswith("/view/"):
            continue
        batch = chunk.to_record_batch()
        v = view(path)
        name = _column(batch, "ViewBlueprint:display_name")
        if name:
            v.name = name[-1][0]
        query = _column(batch, "ViewContents:query")
        if query:
            v.contents = list(query[-1])
        time_range = _column(batch, "TimeAxis:view_range")
        if time_range:
            r = time_range[-1][0]
            v.time_range_s = (r["start"] * 1e-9, r["end"] * 1e-9)
        y_range = _column(batch, "ScalarAxis:range")
        if y_range:
            v.y_range = tuple(float(x) for x in y_range[-1][0])
        corner = _column(batch, "PlotLegend:corner")
        if corner:
            v.legend_corner = _CORNERS.get(int(corner[-1][0]))
        visible = _column(batch, "PlotLegend:visible")
        if visible:
            v.legend_visible = bool(visible[-1][0])
        position = _column(batch, "EyeControls3D:position")
        if position:
            v.eye_position = tuple(float(x) for x in position[-1][0])
            v.eye_target = tuple(float(x) for x in
                                 _column(batch, "EyeControls3D:look_target")[-1][0])
    return [v for v in views.values() if v.name]
