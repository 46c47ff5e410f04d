"""The rig in 3D for Rerun: MuJoCo geoms as Rerun shapes, MJCF names, a framing camera.

Used by :mod:`testbed.outputs.viz` (files) and :mod:`testbed.outputs.live` (streams). Entities::

    <prefix>rig                    static ViewCoordinates (MuJoCo is Z-up)
    <prefix>rig/<body>             Transform3D per row: world pose of the body
    <prefix>rig/<body>/<geom>      static Transform3D (local geom pose) + shape

Bodies and geoms are named by their MJCF names; an unnamed geom by its type
(``capsule``; ``box_2`` for the second unnamed box of a body; ``mesh_<mesh name>``).
Geoms of group 3 and above (collision-only by MuJoCo convention) are not drawn.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from testbed.outputs.names import entity_parts

if TYPE_CHECKING:  # pragma: no cover - typing only
    import mujoco
    import rerun as rr

#: Half-angle (deg) of the cone the default camera fits the rig's bounding sphere in.
CAMERA_HALF_ANGLE_DEG = 12.0
#: Direction (world, Z up) from the rig towards the default camera: front-right, above.
CAMERA_DIRECTION = (1.0, -1.0, 0.7)
_MUJOCO_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)


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


def _geom_names(model: mujoco.MjModel, geoms: list[int]) -> list[str]:
    """Entity names of one body's geoms: the MJCF name, else the type (``capsule``,
    ``box_2`` for the second unnamed box, ``mesh_<mesh name>``), unique within the body."""
    import mujoco

    names = []
    for gi in geoms:
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, gi)
        if not name:
            gtype = mujoco.mjtGeom(int(model.geom_type[gi])).name.removeprefix("mjGEOM_")
            name = gtype.lower()
            mesh = int(model.geom_dataid[gi])
            if name == "mesh" and mesh >= 0:
                name = f"mesh_{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_MESH, mesh) or mesh}"
        names.append(name)
    return entity_parts(names)


def rig_bodies(model: mujoco.MjModel) -> list[tuple[int, str, list[tuple[int, str]]]]:
    """Bodies with at least one visible geom (MuJoCo groups 0-2).

    Returns
    -------
    list of (int, str, list of (int, str))
        Body id, entity name (``mj_id2name``, sanitized and unique; ``body_<id>`` when
        unnamed) and its visible geoms as (geom id, entity name).
    """
    import mujoco

    names = entity_parts([mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b)
                           or f"body_{b}" for b in range(model.nbody)])
    geom_body = np.asarray(model.geom_bodyid)
    out = []
    for body in range(model.nbody):
        geoms = [int(gi) for gi in np.flatnonzero(geom_body == body)
                 if int(model.geom_group[gi]) <= 2]
        if geoms:
            out.append((body, names[body], list(zip(geoms, _geom_names(model, geoms),
                                                    strict=True))))
    return out


def rig_camera(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """A camera framing the rig: its position and look target (world, metres).

    The target is the centre of the axis-aligned box around the visible geoms other
    than planes (the floor or road would dominate), at the model's initial pose
    (``qpos0``); the camera sits along :data:`CAMERA_DIRECTION` at the distance where
    the box's bounding sphere fills a cone of half-angle :data:`CAMERA_HALF_ANGLE_DEG`.

    Parameters
    ----------
    model : mujoco.MjModel

    Returns
    -------
    position, look_target : ndarray, shape (3,)
    """
    import mujoco

    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T  # (8, 3)
    corners = []
    for gi in range(model.ngeom):
        if int(model.geom_group[gi]) > 2 or int(model.geom_type[gi]) == mujoco.mjtGeom.mjGEOM_PLANE:
            continue
        aabb = np.asarray(model.geom_aabb[gi], dtype=float)
        local = aabb[:3] + signs * aabb[3:]
        corners.append(data.geom_xpos[gi] + local @ data.geom_xmat[gi].reshape(3, 3).T)
    if not corners:
        center, radius = np.asarray(model.stat.center, float), max(float(model.stat.extent), 1.0)
    else:
        pts = np.concatenate(corners)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        center, radius = 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
    direction = np.asarray(CAMERA_DIRECTION, dtype=float)
    direction /= np.linalg.norm(direction)
    distance = radius / np.sin(np.radians(CAMERA_HALF_ANGLE_DEG))
    return center + distance * direction, center


def log_rig_static(rec: rr.RecordingStream, model: mujoco.MjModel,
                    bodies: list[tuple[int, str, list[tuple[int, str]]]], prefix: str) -> None:
    """View coordinates and the static geometry under ``<prefix>rig/<body>/<geom>``."""
    import rerun as rr

    rec.log(f"{prefix}rig", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for _, name, geoms in bodies:
        for gi, gname in geoms:
            shape = _geom_archetype(model, gi)
            if shape is None:
                continue
            rec.log(f"{prefix}rig/{name}/{gname}",
                    rr.Transform3D(translation=np.asarray(model.geom_pos[gi], dtype=float),
                                   quaternion=quat_wxyz_to_xyzw(model.geom_quat[gi])),
                    shape, static=True)


def send_body_poses(rec: rr.RecordingStream, bodies: list[tuple[int, str, list]],
                    index: list[rr.TimeColumn], body_pos: np.ndarray,
                    body_quat_wxyz: np.ndarray, prefix: str) -> None:
    """Per-row world poses of the bodies, ``body_pos`` (T, nbody, 3), quats (T, nbody, 4)."""
    import rerun as rr

    for body, name, _ in bodies:
        rec.send_columns(
            f"{prefix}rig/{name}", indexes=index,
            columns=rr.Transform3D.columns(
                translation=body_pos[:, body, :],
                quaternion=quat_wxyz_to_xyzw(body_quat_wxyz[:, body, :])))
