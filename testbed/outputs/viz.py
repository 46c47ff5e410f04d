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
from testbed.outputs.units import display
from testbed.outputs.viz_layout import (
    ESTIMATE_COLOR,
    ESTIMATE_WIDTH,
    MEASUREMENT_COLOR,
    MEASUREMENT_SIZE,
    SETPOINT_COLOR,
    SETPOINT_WIDTH,
    SIGMA_COLOR,
    SIGMA_WIDTH,
    TIME_AXIS_END_MARGIN,
    TIMELINE,
    TRUTH_COLOR,
    TRUTH_WIDTH,
    Layout,
    Legend,
    check_finite,
    panel_name,
    place_legend,
    time_axis_range,
)
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

__all__ = ["ESTIMATE_COLOR", "ESTIMATE_WIDTH", "MEASUREMENT_COLOR", "MEASUREMENT_SIZE",
           "SETPOINT_COLOR", "SETPOINT_WIDTH", "SIGMA_COLOR", "SIGMA_WIDTH",
           "TIME_AXIS_END_MARGIN", "TIMELINE", "TRUTH_COLOR", "TRUTH_WIDTH", "Layout", "Legend",
           "Run", "blueprint_for", "check_finite", "log_static", "new_recording", "panel_name",
           "place_legend", "release_recordings", "rrd_summary", "run_description",
           "send_rig_poses", "send_series", "time_axis_range", "write_rrd", "write_runs",
           "write_series"]


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
