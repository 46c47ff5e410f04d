"""Tests of the PNG summary (testbed.outputs.plots)."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.experiment.trajectory import Trajectory
from testbed.outputs.plots import plot_trajectory

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
T = 200


def make_trajectory(*, covariance: bool = True, estimate: bool = True,
                    setpoint: bool = True) -> Trajectory:
    """Synthetic 4-state run (pitch, yaw and their rates, in rad and rad/s)."""
    rng = np.random.default_rng(1)
    t = np.arange(T) * 0.01
    state = np.column_stack([0.3 * np.sin(2.0 * t), 0.5 * np.sin(1.3 * t),
                             0.6 * np.cos(2.0 * t), 0.65 * np.cos(1.3 * t)])
    action = np.column_stack([np.sin(t), np.cos(t)])
    action[0] = 0.0
    return Trajectory(
        t_s=t, state=state, state_names=["pitch", "yaw", "pitch_rate", "yaw_rate"],
        measurement=state[:, :2] + 0.005 * rng.standard_normal((T, 2)),
        measurement_names=["pitch_enc", "yaw_enc"], action=action,
        action_names=["pitch_voltage [V]", "yaw_voltage [V]"],
        estimate=state + 0.01 * rng.standard_normal(state.shape) if estimate else None,
        covariance=(np.tile(np.diag([1e-4, 1e-4, 4e-4, 4e-4]), (T, 1, 1))
                    if covariance and estimate else None),
        measured_state_index=[0, 1],
        setpoint=np.tile([0.3, -0.2], (T, 1)) if setpoint else None,
        meta={"rig": "toy", "filter": "ekf"},
    )


def _check_png(path, min_bytes: int = 10_000) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > min_bytes
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]  # no temp files


def test_full_trajectory_png(tmp_path):
    path = plot_trajectory(make_trajectory(), tmp_path / "out" / "run.png", title="toy")
    assert path == tmp_path / "out" / "run.png"
    _check_png(path, min_bytes=50_000)


@pytest.mark.parametrize(("covariance", "estimate"), [(False, True), (False, False)])
def test_png_without_covariance_or_estimate(tmp_path, covariance, estimate):
    traj = make_trajectory(covariance=covariance, estimate=estimate, setpoint=False)
    _check_png(plot_trajectory(traj, tmp_path / "run.png", dpi=50))


def test_nan_dropouts_are_gaps(tmp_path):
    traj = make_trajectory()
    traj.measurement[10:20, 0] = np.nan
    _check_png(plot_trajectory(traj, tmp_path / "run.png", dpi=50))


def test_overwrite_replaces_existing_file(tmp_path):
    path = tmp_path / "run.png"
    path.write_bytes(b"old")
    plot_trajectory(make_trajectory(), path, dpi=50)
    _check_png(path)


def test_mismatched_names_are_refused_at_construction():
    import dataclasses

    traj = make_trajectory()
    with pytest.raises(ValueError, match="state_names"):
        dataclasses.replace(traj, state_names=["pitch", "yaw"])


def test_failed_save_leaves_no_file(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    def broken_savefig(self, fname, **kwargs):
        with open(fname, "wb") as fh:
            fh.write(PNG_SIGNATURE)  # a truncated file...
        raise OSError("disk full")  # ...then a failure

    monkeypatch.setattr(Figure, "savefig", broken_savefig)
    with pytest.raises(OSError, match="disk full"):
        plot_trajectory(make_trajectory(), tmp_path / "run.png")
    assert list(tmp_path.iterdir()) == []


def test_no_actions_no_measurements(tmp_path):
    traj = make_trajectory(setpoint=False)
    traj.action, traj.action_names = np.zeros((T, 0)), []
    traj.measurement, traj.measurement_names = np.zeros((T, 0)), []
    traj.measured_state_index = None
    _check_png(plot_trajectory(traj, tmp_path / "run.png", dpi=50))


# ------------------------------------------------------------------ what the figure shows
def with_units(traj):
    traj.meta.update(units={"pitch": "rad", "yaw": "rad", "pitch_rate": "rad/s",
                            "yaw_rate": "rad/s", "pitch_voltage": "V", "yaw_voltage": "V"},
                     sensors="quantize(pitch + yaw)")
    return traj


def test_figure_labels_units_fonts_and_legend_outside(figure_checks):
    from testbed.outputs.plots import trajectory_figure

    fig = trajectory_figure(with_units(make_trajectory()))
    figure_checks.readable(fig)
    figure_checks.legend_outside_axes(fig)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert {"pitch [deg]", "yaw_rate [deg/s]", "pitch error [deg]", "action [V]"} <= set(labels)
    assert fig.axes[-1].get_xlabel() == "time [s]"
    title = fig._suptitle.get_text()
    # short: the sensor chain is in the run's JSON, not in the title
    assert "quantize(pitch + yaw)" not in title
    assert all(len(line) <= 120 for line in title.splitlines())
    assert any("estimate − truth" in t.get_text() for t in fig.legends[0].get_texts())
    assert "RMSE pitch" in title and "deg" in title and "mean NEES" in title


def test_title_metrics_come_from_the_summary_when_given():
    from testbed.outputs.plots import trajectory_figure

    summary = {"rmse": {"pitch": np.radians(0.5), "yaw": 0.0, "pitch_rate": 0.0,
                        "yaw_rate": 0.0}, "nees_mean": 4.25}
    title = trajectory_figure(with_units(make_trajectory()), summary=summary)._suptitle
    assert "pitch 0.5 deg" in title.get_text() and "mean NEES 4.25" in title.get_text()


def test_trajectory_metrics_match_the_definition():
    from testbed.outputs.plots import trajectory_metrics

    traj = make_trajectory()
    err = traj.estimate[1:] - traj.state[1:]
    m = trajectory_metrics(traj)
    assert m["rmse"]["yaw"] == pytest.approx(np.sqrt(np.mean(err[:, 1] ** 2)))
    P = traj.covariance[1]  # constant
    assert m["nees_mean"] == pytest.approx(np.mean(np.sum(err**2 / np.diag(P), axis=1)))


def test_clipped_error_spikes_are_marked():
    from testbed.outputs.plots import trajectory_figure

    traj = make_trajectory()
    traj.estimate[20, 0] += 0.5  # a spike in the first half: outside the steady-state axis
    fig = trajectory_figure(traj)
    ax = next(a for a in fig.axes if a.get_ylabel().startswith("pitch error"))
    marks = [ln for ln in ax.get_lines() if ln.get_label() == "beyond the axis"]
    assert len(marks) == 1
    lo, hi = ax.get_ylim()
    assert marks[0].get_ydata()[0] == pytest.approx(hi)
    assert marks[0].get_xdata()[0] == pytest.approx(traj.t_s[20])
    other = next(a for a in fig.axes if a.get_ylabel().startswith("yaw error"))
    assert not [ln for ln in other.get_lines() if ln.get_label() == "beyond the axis"]


def test_setpoint_does_not_jump_on_the_last_sample():
    from testbed.outputs.plots import trajectory_figure

    traj = make_trajectory()
    traj.setpoint[-1] = [1.0, 1.0]  # the schedule switches exactly at the end
    fig = trajectory_figure(traj)
    line = next(ln for ln in fig.axes[0].get_lines() if ln.get_label() == "setpoint")
    y = line.get_ydata()
    assert line.get_drawstyle() == "steps-post"
    assert y[-1] == y[-2] == pytest.approx(0.3)  # no declared units: shown as given
