"""Rerun ``.rrd`` export of one run: time series, estimation errors and the rig in 3D.

One file per run, written atomically (:func:`testbed.io.atomic_path`) and never
containing NaN. Open it with ``rerun path/to/run.rrd``.

Entity layout (every temporal entity is on the ``time`` timeline, a duration in seconds)::

    state/<state>/truth            Scalars, T rows   (+ static SeriesLines style)
    state/<state>/estimate         Scalars, T rows   (only when traj.estimate exists)
    error/<state>/value            Scalars, T rows   estimate - truth
    error/<state>/plus_3sigma      Scalars, T rows   +3 sqrt(P_ii) (only with a covariance)
    error/<state>/minus_3sigma     Scalars, T rows   -3 sqrt(P_ii)
    measurement/<measurement>      Scalars, T rows   (+ static SeriesPoints style)
    action/<action>                Scalars, T rows
    setpoint/<setpoint>            Scalars, T rows   (only when traj.setpoint exists)
    rig                            static ViewCoordinates (MuJoCo is Z-up)
    rig/<body>                     Transform3D, T rows: world pose of the body
    rig/<body>/geom_<i>            static Transform3D (local geom pose) + shape

Units: every series is logged in the unit the rig declares (``traj.meta["units"]``), with
angles (rad, rad/s) converted to degrees like the PNG plots unless ``degrees=False``
(:mod:`testbed.units`). Series names carry the unit; a quantity without a declared unit is
logged unchanged and unlabelled.

Entity names come from the trajectory's names with a trailing bracketed unit dropped and
other characters than letters, digits, ``_ - .`` replaced by ``_`` (``"pitch_voltage [V]"``
-> ``action/pitch_voltage``); body names from ``mj_id2name`` (``body_<id>`` if unnamed).
Geom entities are numbered by MuJoCo geom id; geoms of group 3 and above (collision-only
by MuJoCo convention) are not drawn.

Caveat (rerun 0.41, rerun-io/rerun#2116): each :func:`write_rrd` call leaves two idle
threads behind (the recording stream Rerun builds internally for the blueprint).
"""

from __future__ import annotations

import os
import re
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from testbed.io import atomic_path
from testbed.trajectory import Trajectory
from testbed.units import display

if TYPE_CHECKING:  # pragma: no cover - typing only
    import mujoco
    import rerun as rr
    import rerun.blueprint as rrb

TIMELINE = "time"
"""Name of the Rerun timeline (durations in seconds) every temporal entity is logged on."""

# tab10, as 0-255 RGB, for per-state colors.
_PALETTE = [
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
]
_TRUTH_COLOR = (220, 220, 220)  # light grey: the viewer background is dark
_SIGMA_COLOR = (160, 160, 160)
_SETPOINT_COLOR = (255, 215, 0)
_MUJOCO_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)
_FIELDS = ("t_s", "state", "estimate", "covariance", "measurement", "action", "setpoint",
           "body_pos", "body_quat_wxyz")


def quat_wxyz_to_xyzw(quat_wxyz: np.ndarray) -> np.ndarray:
    """Reorder quaternions from MuJoCo's (w, x, y, z) to Rerun's (x, y, z, w).

    Parameters
    ----------
    quat_wxyz : ndarray, shape (..., 4)
        Quaternions, scalar first.

    Returns
    -------
    ndarray, shape (..., 4)
        The same quaternions, scalar last (a new array).
    """
    quat = np.asarray(quat_wxyz, dtype=float)
    if quat.shape[-1] != 4:
        raise ValueError(f"quaternions need a last axis of length 4, got shape {quat.shape}")
    return quat[..., [1, 2, 3, 0]].copy()


def _check_finite(traj: Trajectory) -> None:
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


def _entity_part(name: str) -> str:
    """Make ``name`` a plain entity-path part.

    A trailing unit in brackets is dropped (``"pitch_voltage [V]"`` -> ``"pitch_voltage"``)
    and every character other than letters, digits, ``_``, ``-`` and ``.`` becomes ``_``
    (Rerun would otherwise escape them, e.g. ``[`` -> ``\\[``).
    """
    stripped = re.sub(r"\s*[\[(][^\])]*[\])]\s*$", "", str(name).strip())
    part = re.sub(r"[^\w.\-]+", "_", stripped).strip("_")
    return part or "unnamed"


def _entity_parts(names: list[str]) -> list[str]:
    """:func:`_entity_part` of each name, made unique with ``_2``, ``_3``... suffixes."""
    out: list[str] = []
    for name in names:
        part, base, n = _entity_part(name), _entity_part(name), 1
        while part in out:
            n += 1
            part = f"{base}_{n}"
        out.append(part)
    return out


def _geom_rgba(model: mujoco.MjModel, geom: int) -> np.ndarray:
    """RGBA (0-255, uint8) of a geom, taking its material color when it has the default."""
    rgba = np.asarray(model.geom_rgba[geom], dtype=float)
    matid = int(model.geom_matid[geom])
    if matid >= 0 and np.allclose(rgba, _MUJOCO_DEFAULT_RGBA):
        rgba = np.asarray(model.mat_rgba[matid], dtype=float)
    return np.clip(np.round(rgba * 255.0), 0, 255).astype(np.uint8)


def _geom_archetype(model: mujoco.MjModel, geom: int) -> rr.AsComponents | None:
    """Rerun archetype drawing one MuJoCo geom in its own (geom) frame, or None.

    Boxes, spheres, ellipsoids, capsules and cylinders are exact; a plane is a 2 mm thick
    box (an infinite plane, size 0, gets the model extent); meshes are drawn as
    triangle meshes; height fields and SDFs as their bounding box.
    """
    import mujoco
    import rerun as rr

    gtype = int(model.geom_type[geom])
    size = np.asarray(model.geom_size[geom], dtype=float)
    color = _geom_rgba(model, geom)
    solid = rr.components.FillMode.Solid
    g = mujoco.mjtGeom
    if gtype == g.mjGEOM_BOX:
        return rr.Boxes3D(half_sizes=[size], colors=[color], fill_mode=solid)
    if gtype == g.mjGEOM_SPHERE:
        return rr.Ellipsoids3D(radii=[size[0]], colors=[color], fill_mode=solid)
    if gtype == g.mjGEOM_ELLIPSOID:
        return rr.Ellipsoids3D(half_sizes=[size], colors=[color], fill_mode=solid)
    if gtype == g.mjGEOM_CAPSULE:
        # MuJoCo: centered on the origin along z, half-length size[1]. Rerun: one end of
        # the segment at the origin, extending along +z.
        return rr.Capsules3D(lengths=[2.0 * size[1]], radii=[size[0]],
                             translations=[[0.0, 0.0, -size[1]]], colors=[color],
                             fill_mode=solid)
    if gtype == g.mjGEOM_CYLINDER:
        return rr.Cylinders3D(lengths=[2.0 * size[1]], radii=[size[0]], colors=[color],
                              fill_mode=solid)
    if gtype == g.mjGEOM_PLANE:
        extent = float(model.stat.extent) if model.stat.extent > 0 else 1.0
        half_x = size[0] if size[0] > 0 else extent
        half_y = size[1] if size[1] > 0 else extent
        return rr.Boxes3D(half_sizes=[[half_x, half_y, 0.001]], centers=[[0.0, 0.0, -0.001]],
                          colors=[color], fill_mode=solid)
    if gtype == g.mjGEOM_MESH:
        mesh = int(model.geom_dataid[geom])
        if mesh >= 0:
            v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
            f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
            if nv > 0 and nf > 0:
                return rr.Mesh3D(vertex_positions=np.asarray(model.mesh_vert[v0:v0 + nv]),
                                 triangle_indices=np.asarray(model.mesh_face[f0:f0 + nf]),
                                 albedo_factor=color)
    if gtype in (g.mjGEOM_MESH, g.mjGEOM_HFIELD, g.mjGEOM_SDF):
        aabb = np.asarray(model.geom_aabb[geom], dtype=float)  # center (3), half-size (3)
        return rr.Boxes3D(half_sizes=[aabb[3:]], centers=[aabb[:3]], colors=[color],
                          fill_mode=rr.components.FillMode.MajorWireframe)
    return None


def _rig_bodies(model: mujoco.MjModel) -> list[tuple[int, str, list[int]]]:
    """Bodies with at least one visible geom (MuJoCo groups 0-2).

    Returns
    -------
    list of (int, str, list of int)
        Body id, entity name (``mj_id2name``, sanitized and unique; ``body_<id>`` when
        unnamed) and the ids of its visible geoms.
    """
    import mujoco

    names = _entity_parts([mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b)
                           or f"body_{b}" for b in range(model.nbody)])
    geom_body = np.asarray(model.geom_bodyid)
    out = []
    for body in range(model.nbody):
        geoms = [int(gi) for gi in np.flatnonzero(geom_body == body)
                 if int(model.geom_group[gi]) <= 2]
        if geoms:
            out.append((body, names[body], geoms))
    return out


@dataclass
class _Layout:
    """Entity-path parts of one trajectory and how its series relate to the states."""

    state: list[str]
    measurement: list[str]
    action: list[str]
    setpoint: list[str]
    setpoint_labels: list[str]
    meas_state: list[int | None]  # state observed by each measurement, or None
    setpoint_state: list[int | None]  # state tracked by each setpoint component, or None

    @classmethod
    def of(cls, traj: Trajectory) -> _Layout:
        n = len(traj.state_names)
        msi = list(traj.measured_state_index or [])
        msi += [None] * (len(traj.measurement_names) - len(msi))
        meas_state = [int(i) if i is not None and 0 <= int(i) < n else None for i in msi]
        sp_labels = traj.setpoint_names()
        sp_state = [traj.state_names.index(s) if s in traj.state_names else None
                    for s in sp_labels]
        state_parts = _entity_parts(traj.state_names)
        # A setpoint of a state shares the state's entity name: setpoint/pitch.
        sp_parts = _entity_parts([state_parts[i] if i is not None else s
                                  for s, i in zip(sp_labels, sp_state, strict=True)])
        return cls(state=state_parts, measurement=_entity_parts(traj.measurement_names),
                   action=_entity_parts(traj.action_names), setpoint=sp_parts,
                   setpoint_labels=sp_labels, meas_state=meas_state, setpoint_state=sp_state)


def _blueprint(traj: Trajectory, layout: _Layout, *, with_rig: bool) -> rrb.Blueprint:
    """Default layout: the 3D rig on the left; on the right a grid with, per state, a view
    of truth + estimate + its measurements + its setpoint and a view of the error with the
    +-3 sigma series; then other measurements and the actions."""
    import rerun.blueprint as rrb

    views = []
    for i, (name, part) in enumerate(zip(traj.state_names, layout.state, strict=True)):
        contents = [f"/state/{part}/**"]
        contents += [f"/measurement/{m}"
                     for m, s in zip(layout.measurement, layout.meas_state, strict=True) if s == i]
        contents += [f"/setpoint/{p}"
                     for p, s in zip(layout.setpoint, layout.setpoint_state, strict=True) if s == i]
        views.append(rrb.TimeSeriesView(origin="/", contents=contents, name=name))
        if traj.estimate is not None:
            views.append(rrb.TimeSeriesView(origin=f"/error/{part}", name=f"{name} error"))
    other = [f"/measurement/{m}"
             for m, s in zip(layout.measurement, layout.meas_state, strict=True) if s is None]
    other += [f"/setpoint/{p}"
              for p, s in zip(layout.setpoint, layout.setpoint_state, strict=True) if s is None]
    if other:
        views.append(rrb.TimeSeriesView(origin="/", contents=other, name="other signals"))
    if layout.action:
        views.append(rrb.TimeSeriesView(origin="/action", name="actions"))
    grid = rrb.Grid(*views, grid_columns=2 if traj.estimate is not None else 1)
    if not with_rig:
        return rrb.Blueprint(grid)
    return rrb.Blueprint(rrb.Horizontal(rrb.Spatial3DView(origin="/rig", name="rig"), grid,
                                        column_shares=[1.0, 2.0]))


def write_rrd(traj: Trajectory, path: str | os.PathLike, *,
              model: mujoco.MjModel | None = None, application_id: str = "testbed",
              degrees: bool = True) -> Path:
    """Write one run to a Rerun ``.rrd`` file, atomically.

    See the module docstring for the entity layout. Whole series are sent with
    ``send_columns`` (one chunk per entity); styles and geometry are static. The default
    blueprint (layout) is stored in the same file.

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
        Rerun application id; the viewer keeps one active layout per application id.
        ``/`` and ``.`` become ``-`` (``"testbed/helicopter"`` -> ``"testbed-helicopter"``):
        Rerun 0.41 would otherwise rename the id with a hash suffix and warn.
    degrees : bool
        Log angles (states, errors, sigma bounds, setpoints of a state, direct
        measurements of a state) in deg and deg/s instead of rad and rad/s.

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
    import rerun as rr

    _check_finite(traj)
    n_rows = len(traj.t_s)
    with_rig = (model is not None and traj.body_pos is not None
                and traj.body_quat_wxyz is not None)
    if with_rig:
        shape_p, shape_q = np.shape(traj.body_pos), np.shape(traj.body_quat_wxyz)
        if shape_p != (n_rows, model.nbody, 3) or shape_q != (n_rows, model.nbody, 4):
            raise ValueError(
                f"body_pos {shape_p} / body_quat_wxyz {shape_q} do not match "
                f"(T={n_rows}, nbody={model.nbody}, 3 / 4)")

    layout = _Layout.of(traj)
    bodies = _rig_bodies(model) if with_rig else []
    blueprint = _blueprint(traj, layout, with_rig=bool(bodies))

    rec = rr.RecordingStream(re.sub(r"[/\\.]", "-", application_id),
                             recording_id=uuid.uuid4())
    try:
        if not rec.is_enabled():
            raise RuntimeError("Rerun logging is disabled (RERUN env var?); cannot write .rrd")
        with atomic_path(path) as tmp:
            rec.save(tmp, default_blueprint=blueprint)
            try:
                index = [rr.TimeColumn(TIMELINE, duration=np.asarray(traj.t_s, dtype=float))]
                _log_series(rec, traj, layout, index, degrees=degrees)
                if bodies:
                    _log_rig(rec, model, bodies, index, np.asarray(traj.body_pos, dtype=float),
                             np.asarray(traj.body_quat_wxyz, dtype=float))
                rec.flush()
            finally:
                rec.disconnect()  # closes the file before it is renamed (or removed)
    finally:
        del rec
        _release_recordings()
    return Path(path)


def _release_recordings() -> None:
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


def _log_series(rec: rr.RecordingStream, traj: Trajectory, layout: _Layout,
                index: list[rr.TimeColumn], *, degrees: bool) -> None:
    """Log the state, estimate, error, measurement, action and setpoint series.

    Parameters
    ----------
    rec : rerun.RecordingStream
        Open recording.
    traj : Trajectory
        The run, already checked (finite, consistent shapes).
    layout : _Layout
        Entity names and state associations of ``traj``.
    index : list of rerun.TimeColumn
        The ``time`` column, length T.
    degrees : bool
        Convert angles to deg (deg/s).
    """
    import rerun as rr

    def series(entity: str, values: np.ndarray, style: rr.AsComponents) -> None:
        rec.log(entity, style, static=True)
        rec.send_columns(entity, indexes=index, columns=rr.Scalars.columns(scalars=values))

    def lines(label: str, color: tuple[int, int, int], width: float = 1.5) -> rr.SeriesLines:
        return rr.SeriesLines(names=[label], colors=[color], widths=[width])

    state, meas, action = traj.state, traj.measurement, traj.action
    estimate = None if traj.estimate is None else traj.estimate
    std = traj.std() if estimate is not None else None
    scales = [display(traj.unit(n), degrees) for n in traj.state_names]
    for i, (name, part) in enumerate(zip(traj.state_names, layout.state, strict=True)):
        factor, unit = scales[i]
        color = _PALETTE[i % len(_PALETTE)]
        series(f"state/{part}/truth", factor * state[:, i],
               lines(f"{name} truth [{unit}]", _TRUTH_COLOR))
        if estimate is None:
            continue
        series(f"state/{part}/estimate", factor * estimate[:, i],
               lines(f"{name} estimate [{unit}]", color))
        series(f"error/{part}/value", factor * (estimate[:, i] - state[:, i]),
               lines(f"{name} error [{unit}]", color))
        if std is not None:
            bound = 3.0 * factor * std[:, i]
            series(f"error/{part}/plus_3sigma", bound,
                   lines(f"+3 sigma [{unit}]", _SIGMA_COLOR, 1.0))
            series(f"error/{part}/minus_3sigma", -bound,
                   lines(f"-3 sigma [{unit}]", _SIGMA_COLOR, 1.0))
    for j, (name, part) in enumerate(zip(traj.measurement_names, layout.measurement,
                                         strict=True)):
        i = layout.meas_state[j]
        factor, unit = display(traj.unit(name, "measurement"), degrees)
        color = _PALETTE[(i if i is not None else len(layout.state) + j) % len(_PALETTE)]
        style = rr.SeriesPoints(names=[f"{name} [{unit}]" if unit else name],
                                colors=[color], markers=["circle"], marker_sizes=[1.5])
        series(f"measurement/{part}", factor * meas[:, j], style)
    for k, (name, part) in enumerate(zip(traj.action_names, layout.action, strict=True)):
        series(f"action/{part}", action[:, k], lines(name, _PALETTE[k % len(_PALETTE)]))
    if traj.setpoint is not None:
        setpoint = traj.setpoint
        for r, (name, part) in enumerate(zip(layout.setpoint_labels, layout.setpoint,
                                             strict=True)):
            i = layout.setpoint_state[r]
            factor, unit = scales[i] if i is not None else (1.0, "")
            label = f"{name} setpoint [{unit}]" if unit else f"{name} setpoint"
            series(f"setpoint/{part}", factor * setpoint[:, r],
                   lines(label, _SETPOINT_COLOR, 1.0))


def _log_rig(rec: rr.RecordingStream, model: mujoco.MjModel,
             bodies: list[tuple[int, str, list[int]]], index: list[rr.TimeColumn],
             body_pos: np.ndarray, body_quat_wxyz: np.ndarray) -> None:
    """Log the rig: static geometry under ``rig/<body>/geom_<i>``, per-step body poses.

    Parameters
    ----------
    rec : rerun.RecordingStream
        Open recording.
    model : mujoco.MjModel
        Source of the geometry.
    bodies : list of (int, str, list of int)
        Body id, entity name and visible geom ids (from :func:`_rig_bodies`).
    index : list of rerun.TimeColumn
        The ``time`` column, length T.
    body_pos : ndarray, shape (T, nbody, 3)
        World body positions.
    body_quat_wxyz : ndarray, shape (T, nbody, 4)
        World body orientations, MuJoCo order.
    """
    import rerun as rr

    rec.log("rig", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for body, name, geoms in bodies:
        for gi in geoms:
            shape = _geom_archetype(model, gi)
            if shape is None:
                continue
            rec.log(f"rig/{name}/geom_{gi}",
                    rr.Transform3D(translation=np.asarray(model.geom_pos[gi], dtype=float),
                                   quaternion=quat_wxyz_to_xyzw(model.geom_quat[gi])),
                    shape, static=True)
        rec.send_columns(
            f"rig/{name}", indexes=index,
            columns=rr.Transform3D.columns(
                translation=body_pos[:, body, :],
                quaternion=quat_wxyz_to_xyzw(body_quat_wxyz[:, body, :])))


def rrd_summary(path: str | os.PathLike) -> dict[str, int]:
    """Count, per entity, the rows logged on the ``time`` timeline of an ``.rrd`` file.

    Parameters
    ----------
    path : str or PathLike
        An ``.rrd`` file (e.g. from :func:`write_rrd`).

    Returns
    -------
    dict of str to int
        Entity path without the leading slash (``"state/pitch/truth"``) -> number of rows
        on the ``time`` timeline, summed over chunks. Entities holding only static data
        (styles aside, e.g. ``rig`` or ``rig/<body>/geom_<i>``) are included with 0.
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
