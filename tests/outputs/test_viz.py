"""Tests of the Rerun export (testbed.outputs.viz): entity layout, sample counts, atomicity."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from testbed.experiment.trajectory import Trajectory
from testbed.outputs.viz import rrd_summary, write_rrd
from testbed.outputs.viz_rig import quat_wxyz_to_xyzw

T = 200
STATES = ["pitch", "yaw", "pitch_rate", "yaw_rate"]

TOY_XML = """
<mujoco model="toy">
  <asset><mesh name="tet" vertex="0 0 0  0.05 0 0  0 0.05 0  0 0 0.05"/></asset>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.1" rgba="0.3 0.3 0.3 1"/>
    <geom name="base" type="box" size="0.1 0.1 0.05" pos="0 0 0.05"/>
    <body name="arm" pos="0 0 0.3">
      <joint name="pitch" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="-0.2 0 0 0.2 0 0" size="0.02" rgba="0.8 0.2 0.2 1"/>
      <geom type="box" size="0.03 0.03 0.03" pos="0.2 0 0"/>
      <geom type="cylinder" size="0.02 0.05" pos="-0.2 0 0"/>
      <body name="tip" pos="0.2 0 0">
        <joint name="yaw" type="hinge" axis="0 0 1"/>
        <geom type="sphere" size="0.02"/>
        <geom type="mesh" mesh="tet"/>
        <geom type="box" size="0.01 0.01 0.01" group="3"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def make_model() -> mujoco.MjModel:
    """The toy two-joint rig used by the viz and plot tests."""
    return mujoco.MjModel.from_xml_string(TOY_XML)


def make_trajectory(model: mujoco.MjModel | None = None, *, covariance: bool = True,
                    estimate: bool = True, n_rows: int = T) -> Trajectory:
    """Synthetic run: sinusoidal pitch/yaw, noisy estimate, 2 angle measurements.

    With ``model``, body poses come from ``mj_kinematics`` over the qpos sweep.
    """
    rng = np.random.default_rng(0)
    dt = 0.01
    t = np.arange(n_rows) * dt
    pitch, yaw = 0.3 * np.sin(2.0 * t), 0.5 * np.sin(1.3 * t)
    state = np.column_stack([pitch, yaw, 0.6 * np.cos(2.0 * t), 0.65 * np.cos(1.3 * t)])
    est = state + 0.01 * rng.standard_normal(state.shape) if estimate else None
    cov = None
    if covariance and estimate:
        cov = np.tile(np.diag([1e-4, 1e-4, 4e-4, 4e-4]), (n_rows, 1, 1))
    meas = state[:, :2] + 0.005 * rng.standard_normal((n_rows, 2))
    action = np.column_stack([np.sin(t), np.cos(t)])
    action[0] = 0.0
    setpoint = np.column_stack([0.3 * np.ones(n_rows), -0.2 * np.ones(n_rows)])
    body_pos = body_quat = None
    if model is not None:
        data = mujoco.MjData(model)
        body_pos = np.empty((n_rows, model.nbody, 3))
        body_quat = np.empty((n_rows, model.nbody, 4))
        for k in range(n_rows):
            data.qpos[:] = [pitch[k], yaw[k]]
            mujoco.mj_kinematics(model, data)
            body_pos[k], body_quat[k] = data.xpos, data.xquat
    return Trajectory(
        t_s=t, state=state, state_names=list(STATES), measurement=meas,
        measurement_names=["pitch_enc", "yaw_enc"], action=action,
        action_names=["pitch_voltage [V]", "yaw_voltage [V]"], estimate=est, covariance=cov,
        measured_state_index=[0, 1], setpoint=setpoint, body_pos=body_pos,
        body_quat_wxyz=body_quat,
        meta={"rig": "toy", "units": {"pitch": "rad", "yaw": "rad", "pitch_rate": "rad/s",
                                      "yaw_rate": "rad/s", "measurement:pitch_enc": "rad",
                                      "measurement:yaw_enc": "rad"}},
    )


def _component(path, entity: str, component: str) -> tuple[np.ndarray, np.ndarray]:
    """(time in ns, values) of one temporal component read back from an .rrd file."""
    from rerun.chunk import RrdReader

    times, values = [], []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        times.append(batch.column("time").cast("int64").to_numpy())
        values.append(np.array([row[0] for row in batch.column(component).to_pylist()]))
    assert times, f"no temporal chunk for {entity}"
    time_ns, vals = np.concatenate(times), np.concatenate(values)
    order = np.argsort(time_ns, kind="stable")
    return time_ns[order], vals[order]


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return make_model()


@pytest.fixture(scope="module")
def rrd_file(tmp_path_factory, model):
    out_dir = tmp_path_factory.mktemp("rrd")
    traj = make_trajectory(model)
    path = write_rrd(traj, out_dir / "run.rrd", model=model)
    return path, traj


def test_state_error_measurement_entities_have_t_samples(rrd_file):
    path, _ = rrd_file
    summary = rrd_summary(path)
    for name in STATES:
        for entity in (f"state/{name}/actual", f"state/{name}/estimate",
                       f"error/{name}/value", f"error/{name}/plus_3sigma",
                       f"error/{name}/minus_3sigma"):
            assert summary.get(entity) == T, entity
    for entity in ("measurement/pitch_enc", "measurement/yaw_enc",
                   "action/pitch_voltage", "action/yaw_voltage",
                   "setpoint/pitch", "setpoint/yaw"):
        assert summary.get(entity) == T, entity
    assert not any(e.startswith("__") for e in summary)


def test_rig_transforms_and_geometry(rrd_file):
    path, _ = rrd_file
    summary = rrd_summary(path)
    for body in ("world", "arm", "tip"):
        assert summary.get(f"rig/{body}") == T, body
    geoms = sorted(e for e in summary if e.count("/") == 2 and e.startswith("rig/"))
    # floor + base on world (MJCF names), capsule/box/cylinder on arm, sphere + mesh on tip
    # (unnamed: by type); the group-3 (collision-only) box is not drawn.
    assert geoms == ["rig/arm/box", "rig/arm/capsule", "rig/arm/cylinder", "rig/tip/mesh_tet",
                     "rig/tip/sphere", "rig/world/base", "rig/world/floor"]
    assert all(summary[g] == 0 for g in geoms)  # static


def test_rig_quaternion_matches_mujoco(rrd_file, model):
    path, traj = rrd_file
    k = 137
    data = mujoco.MjData(model)
    data.qpos[:] = traj.state[k, :2]
    mujoco.mj_kinematics(model, data)
    tip = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "tip")
    time_ns, quats = _component(path, "/rig/tip", "Transform3D:quaternion")
    assert len(time_ns) == T
    row = int(np.argmin(np.abs(time_ns - round(traj.t_s[k] * 1e9))))
    expected = data.xquat[tip][[1, 2, 3, 0]]
    np.testing.assert_allclose(quats[row], expected, atol=1e-6)
    _, trans = _component(path, "/rig/tip", "Transform3D:translation")
    np.testing.assert_allclose(trans[row], data.xpos[tip], atol=1e-6)


def test_without_declared_units_values_are_logged_unchanged(tmp_path):
    traj = make_trajectory()
    traj.meta = {"rig": "toy"}
    path = write_rrd(traj, tmp_path / "plain.rrd")
    _, values = _component(path, "/state/pitch_rate/actual", "Scalars:scalars")
    np.testing.assert_allclose(values, traj.state[:, 2])


def test_scalar_values_in_degrees(rrd_file):
    path, traj = rrd_file
    time_ns, values = _component(path, "/state/pitch_rate/actual", "Scalars:scalars")
    np.testing.assert_allclose(time_ns, np.round(traj.t_s * 1e9))
    np.testing.assert_allclose(values, np.degrees(traj.state[:, 2]))
    _, sigma = _component(path, "/error/yaw/plus_3sigma", "Scalars:scalars")
    np.testing.assert_allclose(sigma, 3.0 * math.degrees(0.01))


def test_blueprint_is_stored(rrd_file):
    from rerun.chunk import RrdReader

    reader = RrdReader(rrd_file[0])
    assert len(reader.recordings()) == 1
    assert len(reader.blueprints()) == 1
    names, queries = set(), []
    for chunk in reader.stream(store=reader.blueprints()[0]):
        batch = chunk.to_record_batch()
        if "ViewBlueprint:display_name" in batch.schema.names:
            names.update(v[0] for v in batch.column("ViewBlueprint:display_name").to_pylist())
        if "ViewContents:query" in batch.schema.names:
            queries += batch.column("ViewContents:query").to_pylist()[0]
    assert {"rig", "actions [V]", "pitch [deg]", "pitch_rate [deg/s]", "yaw error [deg]",
            "yaw_rate error [deg/s]"} <= names
    assert "/measurement/pitch_enc" in queries and "/setpoint/yaw" in queries


def test_quat_conversion_helper():
    q = np.array([[0.1, 0.2, 0.3, 0.4], [1.0, 0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(quat_wxyz_to_xyzw(q), [[0.2, 0.3, 0.4, 0.1],
                                                          [0.0, 0.0, 0.0, 1.0]])
    with pytest.raises(ValueError):
        quat_wxyz_to_xyzw(np.zeros(3))


def test_no_temp_files_left(rrd_file):
    path, _ = rrd_file
    assert sorted(p.name for p in path.parent.iterdir()) == ["run.rrd"]


def test_without_model_or_covariance(tmp_path):
    traj = make_trajectory(None, covariance=False)
    path = write_rrd(traj, tmp_path / "sub" / "plain.rrd")
    summary = rrd_summary(path)
    assert not any(e.startswith("rig") for e in summary)
    assert summary["state/yaw/estimate"] == T
    assert summary["error/yaw/value"] == T
    assert "error/yaw/plus_3sigma" not in summary
    assert sorted(p.name for p in path.parent.iterdir()) == ["plain.rrd"]


def test_without_estimate(tmp_path):
    from rerun.chunk import RrdReader

    traj = make_trajectory(None, estimate=False)
    path = write_rrd(traj, tmp_path / "truth_only.rrd", application_id="testbed/toy.v1")
    assert RrdReader(path).recordings()[0].application_id == "testbed-toy-v1"
    summary = rrd_summary(path)
    assert summary["state/pitch/actual"] == T
    assert not any(e.startswith(("error", "state/pitch/estimate")) for e in summary)


def test_model_without_body_arrays_skips_rig(tmp_path, model):
    traj = make_trajectory(None)
    summary = rrd_summary(write_rrd(traj, tmp_path / "r.rrd", model=model))
    assert not any(e.startswith("rig") for e in summary)


@pytest.mark.parametrize("field", ["state", "estimate", "covariance", "body_quat_wxyz"])
def test_nan_raises_and_writes_nothing(tmp_path, model, field):
    traj = make_trajectory(model)
    arr = getattr(traj, field).copy()
    arr.flat[5] = np.nan
    setattr(traj, field, arr)
    with pytest.raises(ValueError, match=field):
        write_rrd(traj, tmp_path / "bad.rrd", model=model)
    assert list(tmp_path.iterdir()) == []


def test_body_arrays_must_match_model(tmp_path, model):
    traj = make_trajectory(model)
    traj.body_pos = traj.body_pos[:, :2]
    with pytest.raises(ValueError, match="nbody"):
        write_rrd(traj, tmp_path / "bad.rrd", model=model)
    assert list(tmp_path.iterdir()) == []


def test_failure_while_logging_leaves_no_file(tmp_path, model, monkeypatch):
    import rerun as rr

    def broken(self, entity_path, *args, **kwargs):
        if entity_path.startswith("rig/"):
            raise RuntimeError("boom")
        return original(self, entity_path, *args, **kwargs)

    original = rr.RecordingStream.send_columns
    monkeypatch.setattr(rr.RecordingStream, "send_columns", broken)
    with pytest.raises(RuntimeError, match="boom"):
        write_rrd(make_trajectory(model), tmp_path / "run.rrd", model=model)
    assert list(tmp_path.iterdir()) == []


def test_mismatched_estimate_is_refused_at_construction():
    import dataclasses

    traj = make_trajectory(None)
    with pytest.raises(ValueError, match="estimate"):
        dataclasses.replace(traj, estimate=traj.estimate[:, :2])


def test_no_actions_no_measurements(tmp_path):
    traj = make_trajectory(None)
    traj.action, traj.action_names = np.zeros((T, 0)), []
    traj.measurement, traj.measurement_names = np.zeros((T, 0)), []
    traj.measured_state_index = []
    summary = rrd_summary(write_rrd(traj, tmp_path / "r.rrd"))
    assert summary["state/pitch/actual"] == T
    assert not any(e.startswith(("action", "measurement")) for e in summary)


# ------------------------------------------------------------------ read back: styles, ranges
def _with_transient(model=None) -> Trajectory:
    """A run whose covariance starts 100x wider than its steady state (a transient)."""
    traj = make_trajectory(model)
    decay = 1.0 + 99.0 * np.exp(-traj.t_s / 0.1)
    traj.covariance = traj.covariance * (decay**2)[:, None, None]
    return traj


@pytest.fixture(scope="module")
def contents(tmp_path_factory, model):
    from testbed.outputs.rrd_inspect import inspect_rrd

    traj = _with_transient(model)
    path = write_rrd(traj, tmp_path_factory.mktemp("inspect") / "run.rrd", model=model,
                     description="# toy\n\nwhat this run is")
    return inspect_rrd(path), traj


def test_every_series_has_an_explicit_style_with_its_unit(contents):
    c, _ = contents
    series = [e for e, n in c.rows.items() if n and not e.startswith("rig")]
    assert series and set(series) <= set(c.styles)
    for entity in series:
        style = c.styles[entity]
        assert len(style["colors"]) == 1 and style["sizes"], entity
        assert style["names"][0].endswith("]"), (entity, style["names"])  # a unit
    assert c.styles["state/pitch/actual"]["names"] == ["truth [deg]"]
    assert c.styles["state/pitch_rate/estimate"]["names"] == ["estimate [deg/s]"]
    assert c.styles["action/pitch_voltage"]["names"] == ["pitch_voltage [V]"]
    meas = c.styles["measurement/pitch_enc"]
    assert meas["kind"] == "points" and meas["names"] == ["measured pitch_enc [deg]"]
    assert c.styles["error/yaw/plus_3sigma"]["names"] == c.styles["error/yaw/minus_3sigma"][
        "names"] == ["±3σ [deg]"]


def test_roles_are_distinct_and_readable_on_light_and_dark(contents):
    c, _ = contents

    def luminance(rgb):
        lin = [(v / 255) / 12.92 if v / 255 <= 0.04045 else ((v / 255 + 0.055) / 1.055) ** 2.4
               for v in rgb[:3]]
        return 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]

    roles = {"truth": "state/pitch/actual", "estimate": "state/pitch/estimate",
             "measurement": "measurement/pitch_enc", "setpoint": "setpoint/pitch",
             "sigma": "error/pitch/plus_3sigma"}
    colors = {r: c.styles[e]["colors"][0] for r, e in roles.items()}
    assert len({colors[r][:3] for r in ("truth", "estimate", "measurement", "setpoint")}) == 4
    for role, rgba in colors.items():
        lum = luminance(rgba)
        on_white, on_black = 1.05 / (lum + 0.05), (lum + 0.05) / 0.05
        assert min(on_white, on_black) >= 3.0, (role, rgba, on_white, on_black)
    # truth wide under a narrow estimate; points translucent (drawn after the lines)
    assert c.styles[roles["truth"]]["sizes"][0] > c.styles[roles["estimate"]]["sizes"][0]
    assert colors["measurement"][3] < 255
    # Rerun 0.41 draws a view's lines in sorted entity order: the truth must sort first
    assert sorted(["actual", "estimate"]) == ["actual", "estimate"]


def test_time_range_is_the_data_and_error_views_show_the_steady_state(contents):
    from testbed.outputs.axes import ERROR_AXIS_MARGIN, nice_limit, steady_state_limit

    c, traj = contents
    from testbed.outputs.viz import TIME_AXIS_END_MARGIN, time_axis_range

    t0, t1 = float(traj.t_s[0]), float(traj.t_s[-1])
    # the run's span, and a margin after its end for the axis' last label
    shown = (t0, t1 + TIME_AXIS_END_MARGIN * (t1 - t0))
    assert time_axis_range((t0, t1)) == pytest.approx(shown) and shown[1] > t1
    assert c.time_range_s == pytest.approx((t0, t1))  # the data's
    series_views = [v for v in c.views if v.name not in ("rig", "about")]
    assert series_views and all(v.time_range_s == pytest.approx(shown) for v in series_views)
    view = c.view("pitch error [deg]")
    lo, hi = view.y_range
    error = np.degrees(traj.estimate[:, 0] - traj.state[:, 0])
    bound = 3.0 * np.degrees(traj.std()[:, 0])
    late = traj.t_s >= t1 / 2
    assert lo == -hi
    assert hi >= np.abs(error[late]).max() and hi >= bound[late].max()  # steady state in view
    assert hi < 0.1 * bound[0]  # the transient (zoom out for it) does not set the range
    # a readable scale: the steady-state range rounded up to 1, 2, 2.5 or 5 x 10^k, a
    # labelled tick inside the view
    nice = nice_limit(steady_state_limit(traj.t_s, error, bound))
    assert hi == pytest.approx(ERROR_AXIS_MARGIN * nice)
    mantissa = nice / 10.0 ** np.floor(np.log10(nice))
    assert min(abs(mantissa - m) for m in (1.0, 2.0, 2.5, 5.0)) < 1e-9
    assert c.view("pitch [deg]").y_range is None  # values: auto range


def test_description_and_camera(contents, model):
    c, _ = contents
    assert c.texts["about"].startswith("# toy")
    rig = c.view("rig")
    assert rig.eye_position is not None and rig.eye_target is not None


@pytest.mark.parametrize("rig_name", ["helicopter", "vehicle-roll"])
def test_camera_frames_every_visible_geom_of_the_rig(rig_name):
    """All corners of the visible, non-plane geoms (world, initial pose, computed here from
    MuJoCo) lie inside the camera's cone: nothing of the rig is cut off."""
    from testbed.outputs.viz_rig import CAMERA_HALF_ANGLE_DEG, rig_camera
    from testbed.rigs import resolve_rig

    model = resolve_rig(rig_name)().model
    eye, target = rig_camera(model)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    axis = (target - eye) / np.linalg.norm(target - eye)
    worst = 0.0
    for g in range(model.ngeom):
        if model.geom_group[g] > 2 or model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            continue
        center, half = model.geom_aabb[g][:3], model.geom_aabb[g][3:]
        for signs in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T:
            p = data.geom_xpos[g] + data.geom_xmat[g].reshape(3, 3) @ (center + signs * half)
            v = p - eye
            worst = max(worst, np.degrees(np.arccos(v @ axis / np.linalg.norm(v))))
    assert worst <= CAMERA_HALF_ANGLE_DEG
    assert worst >= 0.4 * CAMERA_HALF_ANGLE_DEG  # and the rig fills a good part of the view


def test_several_runs_each_under_its_prefix_with_a_text(tmp_path, model):
    from testbed.outputs.rrd_inspect import inspect_rrd
    from testbed.outputs.viz import Run, write_runs

    runs = [Run(make_trajectory(model), "noise_free", "# noise-free run", model),
            Run(make_trajectory(None, covariance=False), "noisy", "# noisy run")]
    c = inspect_rrd(write_runs(runs, tmp_path / "two.rrd"))
    assert c.texts == {"noise_free/about": "# noise-free run", "noisy/about": "# noisy run"}
    assert c.rows["noise_free/state/pitch/actual"] == T == c.rows["noisy/state/pitch/actual"]
    assert c.rows["noise_free/rig/arm"] == T and not any(e.startswith("noisy/rig") for e in
                                                          c.rows)
    assert "noisy/error/pitch/plus_3sigma" not in c.rows
    names = [v.name for v in c.views]
    assert names.count("pitch error [deg]") == 2 and names.count("about") == 2
    with pytest.raises(ValueError, match="prefixes"):
        write_runs([runs[0], Run(make_trajectory(), "noise_free")], tmp_path / "bad.rrd")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["two.rrd"]


def test_no_setpoint_past_the_run_end(tmp_path):
    """A run ending on a switching time (helicopter, 5 s): its last row holds the NEXT
    setpoint (yaw 30 deg); the recording logs the one in force, so the yaw view keeps the
    scale of the run (yaw stays within about 1 deg)."""
    from testbed.cli import main
    from testbed.outputs.rrd_inspect import inspect_rrd, series

    path = tmp_path / "run.rrd"
    assert main(["run", "helicopter", "--duration", "5", "--no-progress", "--rrd",
                 str(path)]) == 0
    c = inspect_rrd(path)
    from testbed.outputs.viz import time_axis_range

    assert c.time_range_s == pytest.approx((0.0, 5.0))
    t, sp = series(path, "setpoint/yaw")
    _, yaw = series(path, "state/yaw/actual")
    assert t[-1] == pytest.approx(5.0) and np.abs(sp).max() < 1.0 and np.abs(yaw).max() < 2.0
    assert all(v.time_range_s[1] == pytest.approx(time_axis_range((0.0, 5.0))[1])
               for v in c.views if v.time_range_s)


def test_panels_have_units_and_legends_hide_no_data(tmp_path, model):
    """Every time-series view names its unit; a shown legend sits in a corner that covers
    at most 2 % of the view's samples, read back from the file (else it is hidden)."""
    from testbed.outputs import axes
    from testbed.outputs.rrd_inspect import inspect_rrd, series

    path = write_rrd(_with_transient(model), tmp_path / "run.rrd", model=model)
    c = inspect_rrd(path)
    views = [v for v in c.views if v.name not in ("rig", "about")]
    assert views and all(v.name.endswith("]") for v in views)
    assert {v.name for v in views} >= {"pitch [deg]", "pitch error [deg]", "actions [V]"}
    assert all(v.legend_visible is not None and v.legend_corner in axes.CORNERS
               for v in views)
    shown = [v for v in views if v.legend_visible]
    # a small legend gets room above the data when every corner is taken (the actions)
    actions = c.view("actions [V]")
    assert actions.legend_visible and actions.y_range is not None
    for v in shown:
        entities = [e for e, n in c.rows.items() if n and any(
            e == q.strip("/").removesuffix("/**") or e.startswith(q.strip("/")[:-2])
            for q in v.contents if q.strip("/"))]
        data = [series(path, e) for e in entities]
        t0, t1 = c.time_range_s
        x = np.concatenate([(t - t0) / (t1 - t0) for t, _ in data])
        y = np.concatenate([y for _, y in data])
        lo, hi = v.y_range or (y.min(), y.max())
        u = (y - lo) / (hi - lo)
        names = {c.styles[e]["names"][0] for e in entities}
        h = min(0.85, axes.LEGEND_BASE_HEIGHT + axes.LEGEND_ENTRY_HEIGHT * len(names))
        w = axes.LEGEND_WIDTH
        right = x >= 1 - w if v.legend_corner.startswith("Right") else x <= w
        band = u <= h if v.legend_corner.endswith("Bottom") else u >= 1 - h
        assert np.mean(right & band & (u >= 0) & (u <= 1)) <= 0.02, v.name


def test_legend_corner_avoids_the_data():
    from testbed.outputs.axes import legend_corner, nice_limit

    t = np.linspace(0.0, 10.0, 1001)
    rising = np.clip(t - 5.0, 0.0, None)  # 0 until 5 s, then up: bottom-left and top-right
    assert legend_corner(t, [rising], 2) in ("RightBottom", "LeftTop")
    assert legend_corner(t, [rising], 2) != "RightTop"
    assert legend_corner(t, [np.full_like(t, 1.0)], 1, y_range=(-1, 1)) == "RightBottom"
    noise = np.random.default_rng(0).uniform(-1, 1, t.size)  # fills the view: hidden
    assert legend_corner(t, [noise], 2, y_range=(-1, 1)) is None
    assert [nice_limit(x) for x in (0.0382, 0.07, 0.21, 4.6, 1.0)] == [0.05, 0.1, 0.25, 5.0, 1.0]
