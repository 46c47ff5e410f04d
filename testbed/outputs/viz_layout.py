"""The layout of a run in Rerun: its entities, their styles (role colours, widths, names with
units), the views and their legends, and the blueprint's container (see
:mod:`testbed.outputs.viz` for the entity tree and the layout's rules)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from testbed.experiment.trajectory import Trajectory
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
from testbed.records import field_values

if TYPE_CHECKING:  # pragma: no cover - typing only
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
    fields = field_values(traj)
    for name in _FIELDS:
        value = fields[name]
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
