"""Rerun ``.rrd`` export of runs: time series, estimation errors and the rig in 3D.

One file per call, written atomically (:func:`testbed.io.atomic_path`) and never
containing NaN. Open it with ``testbed view FILE.rrd`` (a desktop) or ``testbed view
FILE.rrd --web`` (a headless machine: prints the URL to open in a browser;
:mod:`testbed.outputs.view`). The same layout is
streamed live by :mod:`testbed.outputs.live`.

Entity layout of one run (every temporal entity is on the ``time`` timeline, a duration in
seconds; a run logged with a ``prefix`` has the same tree under ``<prefix>/``)::

    about                          static TextDocument: what the run is (when given)
    state/<state>/actual           Scalars: the truth        (+ static SeriesLines style)
    state/<state>/estimate         Scalars: the estimate     (only with traj.estimate)
    error/<state>/value            Scalars: estimate - truth
    error/<state>/plus_3sigma      Scalars: +3 sqrt(P_ii)    (only with a covariance)
    error/<state>/minus_3sigma     Scalars: -3 sqrt(P_ii)
    measurement/<measurement>      Scalars               (+ static SeriesPoints style)
    action/<action>                Scalars
    setpoint/<setpoint>            Scalars               (only with traj.setpoint)
    rig, rig/<body>, rig/<body>/<geom>   the rig in 3D (:mod:`testbed.outputs.viz_rig`)

Styles: every series has an explicit colour, width and name ending in its unit. The roles
keep one colour in every view, chosen of middle luminance so that it reads on the
viewer's light and dark themes alike: truth grey and wide, estimate vermilion and
narrow on top of it (Rerun 0.41 draws the lines of a view in entity-tree order, children
sorted by name before their parent, then all points: hence ``actual`` < ``estimate``),
measurements semi-transparent blue points named ``measured <name>`` (drawn last, so the
lines show through), setpoint green, the error in the estimate's colour between grey
+-3 sigma lines (one legend entry).

Layout (blueprint, stored in the file): the 3D rig on the left, framed by a camera
computed from the MJCF geometry (:func:`testbed.outputs.viz_rig.rig_camera`), with the
description below it; on the right a grid with, per state, a view of truth, estimate,
its measurements and its setpoint, and a view of the error (estimate - truth) whose default
range fits the steady state and its 3-sigma band, rounded up to 1, 2, 2.5 or 5 x 10^k
(:func:`testbed.outputs.axes.steady_state_limit`, :func:`~testbed.outputs.axes.nice_limit`;
zoom out for the transient); then other measurements and the actions. Every view names
its unit (``[-]``: none); every time axis spans exactly the data's time range. Each legend
sits in the corner where it covers the fewest samples (:func:`testbed.outputs.axes.legend_corner`);
where every corner would cover more than 2 % of them, a view gets headroom above its data
for a small legend (two entries, e.g. the actions), and hides a larger one or that of an
error view (fixed range) (:func:`place_legend`).

The setpoint is logged as the reference in force over each control interval: the last
row, which holds the NEXT setpoint when the run ends on a switching time, repeats the one
before (:func:`testbed.outputs.axes.held_setpoint`), so no sample lies past the run's end.

Units: every series is logged in the unit the rig declares (``traj.meta["units"]``), with
angles (rad, rad/s) converted to degrees unless ``degrees=False`` (:mod:`testbed.outputs.units`).

Entity names: the trajectory's names with a trailing bracketed unit dropped and other
characters than letters, digits, ``_ - .`` replaced by ``_`` (``"pitch_voltage [V]"`` ->
``action/pitch_voltage``); bodies and geoms by their MJCF names; an unnamed geom by its
type (``capsule``; ``box_2`` for the second unnamed box of a body; ``mesh_<mesh name>``).
Geoms of group 3 and above (collision-only by MuJoCo convention) are not drawn.

Caveat (rerun 0.41, rerun-io/rerun#2116): each :func:`write_rrd` call leaves two idle
threads behind (the recording stream Rerun builds internally for the blueprint).
"""

from __future__ import annotations

import os
import re
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from testbed.experiment.trajectory import Trajectory
from testbed.io import atomic_path
from testbed.outputs.axes import (
    CORNERS,
    ERROR_AXIS_MARGIN,
    held_setpoint,
    legend_corner,
    legend_height,
    nice_limit,
    steady_state_limit,
)
from testbed.outputs.names import entity_parts
from testbed.outputs.units import display
from testbed.outputs.viz_rig import (
    log_rig_static,
    rig_bodies,
    rig_camera,
    send_body_poses,
)

if TYPE_CHECKING:  # pragma: no cover - typing only
    import mujoco
    import rerun as rr
    import rerun.blueprint as rrb

TIMELINE = "time"
"""Name of the Rerun timeline (durations in seconds) every temporal entity is logged on."""

# Role colours (0-255 RGB), Okabe-Ito, relative luminance 0.15-0.26: contrast >= 3.5 on
# white and on the viewer's near-black background.
TRUTH_COLOR = (128, 128, 128)
ESTIMATE_COLOR = (213, 94, 0)
MEASUREMENT_COLOR = (0, 114, 178, 120)  # RGBA: points are drawn over the lines
SETPOINT_COLOR = (0, 158, 115)
SIGMA_COLOR = (128, 128, 128)
TRUTH_WIDTH, ESTIMATE_WIDTH, SIGMA_WIDTH, SETPOINT_WIDTH = 3.0, 1.5, 1.0, 1.5
MEASUREMENT_SIZE = 1.2
# Actions and measurements of no single state: tab10 without its light members.
_PALETTE = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (140, 86, 75),
            (227, 119, 194), (255, 127, 14), (23, 190, 207)]
_FIELDS = ("t_s", "state", "estimate", "covariance", "measurement", "action", "setpoint",
           "body_pos", "body_quat_wxyz")


def check_finite(traj: Trajectory) -> None:
    """Raise ``ValueError`` naming the first field of ``traj`` holding NaN or inf."""
    for name in _FIELDS:
        value = getattr(traj, name)
        if value is None:
            continue
        arr = np.asarray(value, dtype=float)
        if not np.all(np.isfinite(arr)):
            bad = np.argwhere(~np.isfinite(arr))[0]
            raise ValueError(
                f"Trajectory.{name} contains non-finite values (first at index "
                f"{tuple(int(i) for i in bad)}); refusing to write them to an .rrd file"
            )


def _with_unit(text: str, unit: str) -> str:
    return f"{text} [{unit}]" if unit else text


def panel_name(name: str, units: Sequence[str]) -> str:
    """A view's name with the units of its series: ``"yaw [deg]"``, ``"actions [V, N]"``;
    ``[-]`` when they have none (dimensionless, or ``"1"``)."""
    shown = sorted({u for u in units if u and u != "1"})
    return f"{name} [{', '.join(shown) or '-'}]"


# ------------------------------------------------------------------------ time series
@dataclass(frozen=True)
class Legend:
    """Where a view's legend goes: a corner (None: hidden) and, when the view was given
    headroom for it, the view's value range."""

    corner: str | None
    y_range: tuple[float, float] | None = None


#: Share of the time span added after a run's end on the time axes of its Rerun views: the
#: axis' label at the last instant is then drawn inside the view, not cut by its edge.
TIME_AXIS_END_MARGIN = 0.03


def time_axis_range(time_range_s: tuple[float, float]) -> tuple[float, float]:
    """The time axis of a view showing ``time_range_s`` (s): its start, and its end plus
    :data:`TIME_AXIS_END_MARGIN` of the span."""
    start, end = float(time_range_s[0]), float(time_range_s[1])
    return start, end + TIME_AXIS_END_MARGIN * max(end - start, 0.0)


def place_legend(t_s: np.ndarray, values: Sequence[np.ndarray], entries: int,
                 y_range: tuple[float, float] | None = None, *, fixed: bool = False) -> Legend:
    """Where the legend of a view plotting ``values`` over ``t_s`` goes.

    The corner covering the fewest samples (:func:`testbed.outputs.axes.legend_corner`);
    when every corner covers data: at the top right of a value range with headroom above
    the data if the legend is small (the data keep at least half of the view's height),
    else hidden, and always hidden when the view's range is ``fixed`` (an error view).
    """
    corner = legend_corner(t_s, list(values), entries, y_range)
    h = legend_height(entries) + 0.05
    if corner is not None or fixed or not len(values) or h > 0.5:
        return Legend(corner)
    data = np.concatenate([np.asarray(v, dtype=float) for v in values])
    data = data[np.isfinite(data)]
    lo, hi = (float(data.min()), float(data.max())) if data.size else (0.0, 1.0)
    span = hi - lo if hi > lo else max(abs(hi), 1.0)
    return Legend("RightTop", (lo - 0.02 * span, hi + span * h / (1.0 - h)))


@dataclass
class Layout:
    """Entity paths, names and styles of one run's series (from its names and units).

    Build it with :meth:`of`; it needs no data, only the names, the units in ``meta`` and
    which state each measurement and setpoint belongs to, so the live stream uses it
    before the first sample.
    """

    prefix: str
    state_names: list[str]
    state: list[str]
    measurement: list[str]
    action: list[str]
    setpoint: list[str]
    setpoint_labels: list[str]
    meas_state: list[int | None]  # state observed by each measurement, or None
    setpoint_state: list[int | None]  # state tracked by each setpoint component, or None
    state_scale: list[tuple[float, str]]  # display factor and unit per state
    meas_scale: list[tuple[float, str]]
    action_units: list[str]
    has_estimate: bool
    has_covariance: bool
    has_setpoint: bool
    #: Legend names of the state and measurement series (``traj.meta["state_label"]``,
    #: ``["measurement_label"]``; defaults "truth" and "measured"): a run that logs
    #: something else as its state (an error, a ratio) says so in the legend.
    state_label: str = "truth"
    measurement_label: str = "measured"

    @classmethod
    def of(cls, traj: Trajectory, *, prefix: str = "", degrees: bool = True) -> Layout:
        """The layout of ``traj`` under ``prefix`` (``""`` or ``"name"``)."""
        n = len(traj.state_names)
        msi = list(traj.measured_state_index or [])
        msi += [None] * (len(traj.measurement_names) - len(msi))
        meas_state = [int(i) if i is not None and 0 <= int(i) < n else None for i in msi]
        sp_labels = traj.setpoint_names()
        sp_state = [traj.state_names.index(s) if s in traj.state_names else None
                    for s in sp_labels]
        state_parts = entity_parts(traj.state_names)
        # A setpoint of a state shares the state's entity name: setpoint/pitch.
        sp_parts = entity_parts([state_parts[i] if i is not None else s
                                  for s, i in zip(sp_labels, sp_state, strict=True)])
        return cls(
            prefix=f"{prefix.strip('/')}/" if prefix.strip("/") else "",
            state_names=list(traj.state_names), state=state_parts,
            measurement=entity_parts(traj.measurement_names),
            action=entity_parts(traj.action_names), setpoint=sp_parts,
            setpoint_labels=sp_labels, meas_state=meas_state, setpoint_state=sp_state,
            state_scale=[display(traj.unit(s), degrees) for s in traj.state_names],
            meas_scale=[display(traj.unit(m, "measurement"), degrees)
                        for m in traj.measurement_names],
            action_units=[traj.unit(a, "action") for a in traj.action_names],
            has_estimate=traj.estimate is not None, has_covariance=traj.covariance is not None,
            has_setpoint=traj.setpoint is not None,
            state_label=str(traj.meta.get("state_label", "truth")),
            measurement_label=str(traj.meta.get("measurement_label", "measured")))

    # -- styles
    def styles(self) -> list[tuple[str, rr.AsComponents]]:
        """(entity, static style) of every series: explicit colour, width, name + unit."""
        import rerun as rr

        def lines(label: str, color: tuple[int, int, int], width: float) -> rr.SeriesLines:
            return rr.SeriesLines(names=[label], colors=[color], widths=[width])

        p, out = self.prefix, []
        for i, part in enumerate(self.state):
            unit = self.state_scale[i][1]
            out.append((f"{p}state/{part}/actual", lines(_with_unit(self.state_label, unit),
                                                         TRUTH_COLOR, TRUTH_WIDTH)))
            if not self.has_estimate:
                continue
            out.append((f"{p}state/{part}/estimate",
                        lines(_with_unit("estimate", unit), ESTIMATE_COLOR, ESTIMATE_WIDTH)))
            out.append((f"{p}error/{part}/value",
                        lines(_with_unit("error = estimate − truth", unit), ESTIMATE_COLOR,
                              ESTIMATE_WIDTH)))
            if self.has_covariance:
                for side in ("plus", "minus"):  # one legend entry: same name for both
                    out.append((f"{p}error/{part}/{side}_3sigma",
                                lines(_with_unit("±3σ", unit), SIGMA_COLOR, SIGMA_WIDTH)))
        for j, part in enumerate(self.measurement):
            i = self.meas_state[j]
            color = MEASUREMENT_COLOR if i is not None else (*_PALETTE[j % len(_PALETTE)], 160)
            out.append((f"{p}measurement/{part}", rr.SeriesPoints(
                names=[_with_unit(f"{self.measurement_label} {part}".strip(),
                                  self.meas_scale[j][1])], colors=[color],
                markers=["circle"], marker_sizes=[MEASUREMENT_SIZE])))
        for k, part in enumerate(self.action):
            out.append((f"{p}action/{part}", lines(_with_unit(part, self.action_units[k]),
                                                   _PALETTE[k % len(_PALETTE)], 1.5)))
        if self.has_setpoint:
            for r, part in enumerate(self.setpoint):
                i = self.setpoint_state[r]
                unit = self.state_scale[i][1] if i is not None else ""
                name = "setpoint" if i is not None else f"{self.setpoint_labels[r]} setpoint"
                out.append((f"{p}setpoint/{part}", lines(_with_unit(name, unit),
                                                         SETPOINT_COLOR, SETPOINT_WIDTH)))
        return out

    # -- data
    def columns(self, traj: Trajectory) -> list[tuple[str, np.ndarray]]:
        """(entity, values (T,)) of every series of ``traj``, in display units."""
        p, out = self.prefix, []
        state = traj.state
        std = traj.std() if self.has_estimate else None
        for i, part in enumerate(self.state):
            factor = self.state_scale[i][0]
            out.append((f"{p}state/{part}/actual", factor * state[:, i]))
            if not self.has_estimate:
                continue
            estimate = traj.estimate[:, i]
            out.append((f"{p}state/{part}/estimate", factor * estimate))
            out.append((f"{p}error/{part}/value", factor * (estimate - state[:, i])))
            if std is not None:
                out.append((f"{p}error/{part}/plus_3sigma", 3.0 * factor * std[:, i]))
                out.append((f"{p}error/{part}/minus_3sigma", -3.0 * factor * std[:, i]))
        for j, part in enumerate(self.measurement):
            out.append((f"{p}measurement/{part}", self.meas_scale[j][0] * traj.measurement[:, j]))
        for k, part in enumerate(self.action):
            out.append((f"{p}action/{part}", traj.action[:, k]))
        if self.has_setpoint and traj.setpoint is not None:
            held = held_setpoint(traj.setpoint)  # no reference past the run's end
            for r, part in enumerate(self.setpoint):
                i = self.setpoint_state[r]
                factor = self.state_scale[i][0] if i is not None else 1.0
                out.append((f"{p}setpoint/{part}", factor * held[:, r]))
        return out

    def error_limits(self, traj: Trajectory) -> list[float | None]:
        """Per state, the half-range of its error view (display units): the steady-state
        error and 3-sigma band (:func:`testbed.outputs.axes.steady_state_limit`) rounded up
        to 1, 2, 2.5 or 5 times a power of ten (:func:`testbed.outputs.axes.nice_limit`)."""
        if not self.has_estimate:
            return [None] * len(self.state)
        std = traj.std()
        out: list[float | None] = []
        for i in range(len(self.state)):
            factor = self.state_scale[i][0]
            bound = None if std is None else 3.0 * factor * std[:, i]
            error = factor * (traj.estimate[:, i] - traj.state[:, i])
            out.append(nice_limit(steady_state_limit(traj.t_s, error, bound)))
        return out

    # -- blueprint
    def panels(self) -> list[tuple[str, list[str], list[str], int | None]]:
        """The time-series views: (name with its unit, contents, the series entities in
        it, the state of an error view or None), per state its values and its error, then
        the other signals and the actions."""
        p = self.prefix
        out: list[tuple[str, list[str], list[str], int | None]] = []
        for i, (name, part) in enumerate(zip(self.state_names, self.state, strict=True)):
            unit = self.state_scale[i][1]
            meas = [f"{p}measurement/{m}"
                    for m, s in zip(self.measurement, self.meas_state, strict=True) if s == i]
            sps = [f"{p}setpoint/{sp}"
                   for sp, s in zip(self.setpoint, self.setpoint_state, strict=True)
                   if s == i and self.has_setpoint]
            series = [f"{p}state/{part}/actual"]
            if self.has_estimate:
                series.append(f"{p}state/{part}/estimate")
            out.append((panel_name(name, [unit]), [f"{p}state/{part}/**", *meas, *sps],
                        series + meas + sps, None))
            if self.has_estimate:
                errs = [f"{p}error/{part}/value"]
                if self.has_covariance:
                    errs += [f"{p}error/{part}/plus_3sigma", f"{p}error/{part}/minus_3sigma"]
                out.append((panel_name(f"{name} error", [unit]),
                            [f"{p}error/{part}/**"], errs, i))
        other, units = [], []
        for m, s, scale in zip(self.measurement, self.meas_state, self.meas_scale, strict=True):
            if s is None:
                other.append(f"{p}measurement/{m}")
                units.append(scale[1])
        if self.has_setpoint:
            for sp, s in zip(self.setpoint, self.setpoint_state, strict=True):
                if s is None:
                    other.append(f"{p}setpoint/{sp}")
                    units.append("")
        if other:
            out.append((panel_name("other signals", units), other, other, None))
        if self.action:
            out.append((panel_name("actions", self.action_units), [f"{p}action/**"],
                        [f"{p}action/{a}" for a in self.action], None))
        return out

    def legends(self, traj: Trajectory, error_limits: Sequence[float | None] | None = None
                ) -> dict[str, Legend]:
        """Per view name, where its legend goes (:class:`Legend`), from the data of ``traj``.

        The corner that hides the fewest samples; where every corner would hide data, room
        above the data for a small legend, else none (:func:`place_legend`): an error
        view's name says what it shows (grey lines: the 3-sigma band).
        """
        columns = dict(self.columns(traj))
        t = np.asarray(traj.t_s, dtype=float)
        out: dict[str, Legend] = {}
        for name, _, series, state in self.panels():
            values = [columns[e] for e in series if e in columns]
            lim = None if (state is None or error_limits is None) else error_limits[state]
            entries = len({self._legend_name(e) for e in series})
            y_range = None if lim is None else (-ERROR_AXIS_MARGIN * lim, ERROR_AXIS_MARGIN * lim)
            out[name] = place_legend(t, values, entries, y_range, fixed=state is not None)
        return out

    @staticmethod
    def _legend_name(entity: str) -> str:
        return entity.replace("plus_3sigma", "3sigma").replace("minus_3sigma", "3sigma")

    def views(self, time_range_s: tuple[float, float] | None,
              error_limits: Sequence[float | None] | None = None,
              legends: dict[str, Legend] | None = None) -> list[rrb.View]:
        """Time-series views (:meth:`panels`): axis ranges and legends (default: bottom
        right, visible; :meth:`legends`)."""
        import rerun as rr
        import rerun.blueprint as rrb

        axis_x = None
        if time_range_s is not None:
            start, end = time_axis_range(time_range_s)
            axis_x = rrb.TimeAxis(link="Independent", zoom_lock=False, view_range=rr.TimeRange(
                start=rrb.TimeRangeBoundary.absolute(seconds=start),
                end=rrb.TimeRangeBoundary.absolute(seconds=end)))
        legends = legends or {}
        views = []
        for name, contents, _, state in self.panels():
            place = legends.get(name, Legend(CORNERS[0]))
            legend = rrb.PlotLegend(corner=place.corner or CORNERS[0],
                                    visible=place.corner is not None)
            y_range = place.y_range
            lim = None if (state is None or error_limits is None) else error_limits[state]
            if lim is not None:  # the round limit is a labelled tick inside the view
                y_range = (-ERROR_AXIS_MARGIN * lim, ERROR_AXIS_MARGIN * lim)
            axis_y = None if y_range is None else rrb.ScalarAxis(range=y_range, zoom_lock=False)
            views.append(rrb.TimeSeriesView(origin="/", contents=[f"/{c}" for c in contents],
                                            name=name, axis_x=axis_x, axis_y=axis_y,
                                            plot_legend=legend))
        return views

    def container(self, *, camera: tuple[np.ndarray, np.ndarray] | None, with_rig: bool,
                  with_about: bool, time_range_s: tuple[float, float] | None,
                  error_limits: Sequence[float | None] | None = None,
                  legends: dict[str, Legend] | None = None,
                  name: str | None = None) -> rrb.Container:
        """The run's layout: rig and description on the left, the series grid right."""
        import rerun.blueprint as rrb

        grid = rrb.Grid(*self.views(time_range_s, error_limits, legends),
                        grid_columns=2 if self.has_estimate else 1)
        left = []
        if with_rig:
            eye = None
            if camera is not None:
                eye = rrb.EyeControls3D(position=camera[0].tolist(),
                                        look_target=camera[1].tolist(), eye_up=[0.0, 0.0, 1.0])
            left.append(rrb.Spatial3DView(origin=f"/{self.prefix}rig", name="rig",
                                          eye_controls=eye))
        if with_about:
            left.append(rrb.TextDocumentView(origin=f"/{self.prefix}about", name="about"))
        if not left:
            return rrb.Horizontal(grid, name=name) if name else grid
        column = left[0] if len(left) == 1 else rrb.Vertical(*left, row_shares=[3.0, 1.0])
        return rrb.Horizontal(column, grid, column_shares=[1.0, 2.0], name=name)


# ------------------------------------------------------------------------ writing
@dataclass
class Run:
    """One run of a recording: its trajectory, entity prefix and description.

    Attributes
    ----------
    traj : Trajectory
    prefix : str
        Entity path the run is logged under (``""``: the root).
    description : str, optional
        Markdown saying what the run is, logged as ``<prefix>/about``.
    model : mujoco.MjModel, optional
        Enables the 3D rig (needs ``traj.body_pos`` and ``traj.body_quat_wxyz``).
    """

    traj: Trajectory
    prefix: str = ""
    description: str | None = None
    model: Any = None


def _check_bodies(run: Run) -> bool:
    """Whether the run has a 3D rig; ``ValueError`` if its body arrays do not fit."""
    traj, model = run.traj, run.model
    if model is None or traj.body_pos is None or traj.body_quat_wxyz is None:
        return False
    n_rows = len(traj.t_s)
    shape_p, shape_q = np.shape(traj.body_pos), np.shape(traj.body_quat_wxyz)
    if shape_p != (n_rows, model.nbody, 3) or shape_q != (n_rows, model.nbody, 4):
        raise ValueError(f"body_pos {shape_p} / body_quat_wxyz {shape_q} do not match "
                         f"(T={n_rows}, nbody={model.nbody}, 3 / 4)")
    return True


def send_series(rec: rr.RecordingStream, layout: Layout, traj: Trajectory) -> None:
    """Send the rows of ``traj`` (one chunk per entity) with ``send_columns``."""
    import rerun as rr

    index = [rr.TimeColumn(TIMELINE, duration=np.asarray(traj.t_s, dtype=float))]
    for entity, values in layout.columns(traj):
        rec.send_columns(entity, indexes=index, columns=rr.Scalars.columns(scalars=values))


def send_rig_poses(rec: rr.RecordingStream, model: mujoco.MjModel, prefix: str,
                   t_s: np.ndarray, body_pos: np.ndarray, body_quat_wxyz: np.ndarray) -> None:
    """Send per-row body poses (T, nbody, 3) / (T, nbody, 4) of the rig under ``prefix``."""
    import rerun as rr

    index = [rr.TimeColumn(TIMELINE, duration=np.asarray(t_s, dtype=float))]
    send_body_poses(rec, rig_bodies(model), index, np.asarray(body_pos, dtype=float),
                    np.asarray(body_quat_wxyz, dtype=float), prefix)


def log_static(rec: rr.RecordingStream, layout: Layout, *, model: Any = None,
               description: str | None = None) -> None:
    """Styles, the description and the rig's geometry (all static)."""
    import rerun as rr

    for entity, style in layout.styles():
        rec.log(entity, style, static=True)
    if description:
        rec.log(f"{layout.prefix}about", rr.TextDocument(description,
                                                         media_type=rr.MediaType.MARKDOWN),
                static=True)
    if model is not None:
        log_rig_static(rec, model, rig_bodies(model), layout.prefix)


def blueprint_for(runs: Sequence[Run], layouts: Sequence[Layout],
                  with_rig: Sequence[bool]) -> rrb.Blueprint:
    """One run: its layout; several: a tab per run."""
    import rerun.blueprint as rrb

    containers = []
    for run, layout, rig in zip(runs, layouts, with_rig, strict=True):
        t = run.traj.t_s
        limits = layout.error_limits(run.traj)
        containers.append(layout.container(
            camera=rig_camera(run.model) if rig else None, with_rig=rig,
            with_about=bool(run.description), time_range_s=(float(t[0]), float(t[-1])),
            error_limits=limits, legends=layout.legends(run.traj, limits),
            name=(run.prefix.strip("/") or None) if len(runs) > 1 else None))
    root = containers[0] if len(containers) == 1 else rrb.Tabs(*containers, active_tab=0)
    return rrb.Blueprint(root, rrb.TimePanel(timeline=TIMELINE), collapse_panels=False)


def new_recording(application_id: str) -> rr.RecordingStream:
    """A fresh recording stream; ``/`` and ``.`` in the id become ``-`` (Rerun 0.41 would
    otherwise rename the id with a hash suffix and warn)."""
    import rerun as rr

    rec = rr.RecordingStream(re.sub(r"[/\\.]", "-", application_id), recording_id=uuid.uuid4())
    if not rec.is_enabled():
        raise RuntimeError("Rerun logging is disabled (RERUN env var?); cannot record")
    return rec


def write_runs(runs: Sequence[Run], path: str | os.PathLike, *,
               application_id: str = "testbed", degrees: bool = True) -> Path:
    """Write several runs into one ``.rrd`` file, atomically, each under its prefix.

    Parameters
    ----------
    runs : sequence of Run
        Distinct prefixes (``""`` allowed for a single run).
    path : str or PathLike
        Destination ``.rrd`` file (parent directories are created).
    application_id : str
        Rerun application id (the viewer keeps one active layout per id).
    degrees : bool
        Log angles in deg and deg/s instead of rad and rad/s.

    Returns
    -------
    Path
        The written path.

    Raises
    ------
    ValueError
        Non-finite values (naming the field), body arrays not matching the model, or
        duplicate prefixes; no file is written then.
    RuntimeError
        If Rerun logging is disabled (e.g. ``RERUN=off`` in the environment).
    """
    prefixes = [r.prefix.strip("/") for r in runs]
    if not runs or len(set(prefixes)) != len(prefixes) or (len(runs) > 1 and "" in prefixes):
        raise ValueError(f"runs need distinct, non-empty prefixes, got {prefixes}")
    for run in runs:
        check_finite(run.traj)
    rigs = [_check_bodies(run) for run in runs]
    layouts = [Layout.of(run.traj, prefix=run.prefix, degrees=degrees) for run in runs]
    blueprint = blueprint_for(runs, layouts, rigs)
    rec = new_recording(application_id)
    try:
        with atomic_path(path) as tmp:
            rec.save(tmp, default_blueprint=blueprint)
            try:
                for run, layout, rig in zip(runs, layouts, rigs, strict=True):
                    log_static(rec, layout, model=run.model if rig else None,
                               description=run.description)
                    send_series(rec, layout, run.traj)
                    if rig:
                        send_rig_poses(rec, run.model, layout.prefix, run.traj.t_s,
                                       run.traj.body_pos, run.traj.body_quat_wxyz)
                rec.flush()
            finally:
                rec.disconnect()  # closes the file before it is renamed (or removed)
    finally:
        del rec
        release_recordings()
    return Path(path)


def write_rrd(traj: Trajectory, path: str | os.PathLike, *,
              model: mujoco.MjModel | None = None, application_id: str = "testbed",
              degrees: bool = True, description: str | None = None) -> Path:
    """Write one run to a Rerun ``.rrd`` file, atomically.

    See the module docstring for the entity layout and the styles. Whole series are sent
    with ``send_columns`` (one chunk per entity); styles and geometry are static. The
    default blueprint (layout) is stored in the same file.

    Parameters
    ----------
    traj : Trajectory
        The run; arrays of shape (T, ...). ``body_pos`` (T, nbody, 3) and
        ``body_quat_wxyz`` (T, nbody, 4) are used for the 3D rig when ``model`` is given.
    path : str or PathLike
        Destination ``.rrd`` file (parent directories are created).
    model : mujoco.MjModel, optional
        The model the run was simulated with; enables the ``rig/...`` entities (needs
        ``traj.body_pos`` and ``traj.body_quat_wxyz``, with ``nbody`` matching the model).
    application_id : str
        Rerun application id; ``/`` and ``.`` become ``-``.
    degrees : bool
        Log angles (states, errors, sigma bounds, setpoints of a state, measurements in
        rad) in deg and deg/s instead of rad and rad/s.
    description : str, optional
        Markdown logged as ``about`` (what the run is).

    Returns
    -------
    Path
        The written path.

    Raises
    ------
    ValueError
        If any array of ``traj`` holds NaN or inf (the message names the field), a names
        list does not match its array, or the body arrays do not match ``model``. No file
        is written then.
    RuntimeError
        If Rerun logging is disabled (e.g. ``RERUN=off`` in the environment).
    """
    return write_runs([Run(traj, "", description, model)], path,
                      application_id=application_id, degrees=degrees)


def release_recordings() -> None:
    """Stop the threads of dropped recording streams.

    Rerun keeps the batcher and forwarding threads of a Python ``RecordingStream`` alive
    after it is dropped (rerun-io/rerun#2116). ``rr.init`` clears them with this internal
    binding; calling it after each file frees the data stream's two threads. The stream
    Rerun creates internally for the blueprint is not released by it (rerun 0.41), so each
    :func:`write_rrd` call still leaves two idle threads behind. Only recordings nothing
    references any more are touched.
    """
    try:
        import rerun_bindings
    except ImportError:  # pragma: no cover - layout of the rerun package changed
        return
    cleanup = getattr(rerun_bindings, "flush_and_cleanup_orphaned_recordings", None)
    if cleanup is not None:
        cleanup()


def run_description(meta: dict[str, Any], summary: dict[str, Any] | None = None) -> str:
    """Markdown describing a run of the runner: rig, filter, controller, sensors, seed and,
    with ``summary``, the RMSE per state and the mean NEES."""
    scenario = meta.get("scenario", {})
    lines = [f"# {meta.get('rig', 'run')}", "",
             f"- filter: `{scenario.get('estimator', '?')}`",
             f"- controller: `{scenario.get('controller', '?')}`",
             f"- sensors: {meta.get('sensors', '?')}",
             f"- seed {scenario.get('seed', '?')}, {scenario.get('duration_s', '?')} s, "
             f"control period {meta.get('control_dt_s', '?')} s"]
    if summary:
        units = summary.get("units", meta.get("units", {}))
        lines += ["", "| state | RMSE |", "|---|---|"]
        for name, value in summary.get("rmse", {}).items():
            factor, unit = display(units.get(name, ""))
            lines.append(f"| {name} | {value * factor:.4g} {unit} |")
        if summary.get("nees_mean") is not None:
            lines += ["", f"mean NEES {summary['nees_mean']:.3f} "
                          f"({len(summary.get('rmse', {}))} for a consistent filter)"]
    return "\n".join(lines)


def rrd_summary(path: str | os.PathLike) -> dict[str, int]:
    """Count, per entity, the rows logged on the ``time`` timeline of an ``.rrd`` file.

    Parameters
    ----------
    path : str or PathLike
        An ``.rrd`` file (e.g. from :func:`write_rrd`).

    Returns
    -------
    dict of str to int
        Entity path without the leading slash (``"state/pitch/actual"``) -> number of rows on
        the ``time`` timeline, summed over chunks. Entities holding only static data
        (styles aside, e.g. ``rig`` or ``rig/<body>/<geom>``) are included with 0.
        Rerun-internal entities (``__properties``...) are left out. Only the first
        recording store of the file is read (blueprints are ignored).
    """
    from rerun.chunk import RrdReader

    counts: dict[str, int] = {}
    for chunk in RrdReader(Path(path)).stream():
        entity = chunk.entity_path.lstrip("/")
        if entity.startswith("__"):
            continue
        rows = chunk.num_rows if (not chunk.is_static and TIMELINE in chunk.timeline_names) \
            else 0
        counts[entity] = counts.get(entity, 0) + rows
    return dict(sorted(counts.items()))


def write_series(path: str | os.PathLike, application_id: str, blueprint: Any, about: str,
                 styles: Sequence[tuple[str, Any]],
                 series: Sequence[tuple[str, np.ndarray, np.ndarray]]) -> Path:
    """Time series as a Rerun ``.rrd``, written atomically: an ``about`` text (Markdown),
    each entity's static style, then each ``(entity, times_s (K,), values (K,))`` in one
    column on :data:`TIMELINE` (``testbed replay`` and ``testbed compare`` write so).

    Returns
    -------
    Path
    """
    import rerun as rr

    rec = new_recording(application_id)
    try:
        with atomic_path(path) as tmp:
            rec.save(tmp, default_blueprint=blueprint)
            try:
                rec.log("about", rr.TextDocument(about, media_type=rr.MediaType.MARKDOWN),
                        static=True)
                for entity, style in styles:
                    rec.log(entity, style, static=True)
                for entity, times, values in series:
                    rec.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=times)],
                                     columns=rr.Scalars.columns(scalars=values))
                rec.flush()
            finally:
                rec.disconnect()
    finally:
        del rec
        release_recordings()
    return Path(path)
