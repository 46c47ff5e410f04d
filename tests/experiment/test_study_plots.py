"""Monte-Carlo and sweep figures (testbed.outputs.study_plots) and the streaming error envelope."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.cli import main
from testbed.experiment.envelope import ErrorEnvelope
from testbed.experiment.runner import monte_carlo, sweep
from testbed.experiment.scenario import Scenario
from testbed.outputs.study_plots import monte_carlo_figure, plot_monte_carlo, sweep_figure

VEHICLE = Scenario(rig="vehicle-roll", sensors="imu", manoeuvre="double-lane-change",
                   duration_s=1.0, seed=2)


@pytest.fixture(scope="module")
def mc_with_npz(tmp_path_factory):
    path = tmp_path_factory.mktemp("mc") / "mc.npz"
    result = monte_carlo(VEHICLE, 11, batch_size=4, progress=False, save_npz=path,
                         envelope_points=30)
    return result, np.load(path)


def test_envelope_equals_quantiles_of_the_saved_trajectories(mc_with_npz):
    """Streamed per batch (4 + 4 + 3 runs) = computed afterwards from every trajectory."""
    result, npz = mc_with_npz
    env = result["error_envelope"]
    t = npz["t_s"]
    steps = np.array([int(np.argmin(np.abs(t - ts))) for ts in env["t_s"]])
    assert steps[0] == 0 and steps[-1] == len(t) - 1 and len(steps) == 30
    np.testing.assert_allclose(t[steps], env["t_s"], atol=1e-12)
    err = npz["estimate"][:, steps] - npz["state"][:, steps]
    std = np.sqrt(np.diagonal(npz["covariance"][:, steps], axis1=-2, axis2=-1))
    for i, name in enumerate(npz["state_names"]):
        e = env["states"][str(name)]
        q05, q50, q95 = np.quantile(err[:, :, i], [0.05, 0.5, 0.95], axis=0)
        np.testing.assert_array_equal(e["median"], q50)
        np.testing.assert_array_equal(e["q05"], q05)
        np.testing.assert_array_equal(e["q95"], q95)
        np.testing.assert_allclose(e["sigma3_mean"], 3 * std[:, :, i].mean(axis=0), rtol=1e-12)
    assert env["runs"] == [11] * 30


def test_envelope_does_not_change_the_study(mc_with_npz):
    result, _ = mc_with_npz
    plain = monte_carlo(VEHICLE, 11, batch_size=4, progress=False)
    assert plain["rmse_per_run"] == result["rmse_per_run"] and "error_envelope" not in plain


def test_envelope_validates_points():
    with pytest.raises(ValueError, match="points"):
        ErrorEnvelope(3, 10, 0.01, ["a"], points=1)
    with pytest.raises(ValueError, match="envelope_points"):
        monte_carlo(VEHICLE, 2, envelope_points=1)
    assert len(ErrorEnvelope(3, 10, 0.01, ["a"], points=500).steps) == 11


def test_monte_carlo_figure(mc_with_npz, tmp_path, figure_checks):
    result, _ = mc_with_npz
    fig = monte_carlo_figure(result)
    figure_checks.readable(fig)
    figure_checks.legend_outside_axes(fig)
    labels = [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes]
    assert ("roll RMSE [deg]", "runs [count]") in labels
    assert ("time [s]", "roll_rate error (second half) [deg/s]") in labels
    handles = fig.legends[0].get_texts()
    assert {"error (estimate − truth), median", "error (estimate − truth), 5-95 % of runs",
            "filter's ±3σ (mean over runs)"} <= {h.get_text() for h in handles}
    title = fig._suptitle.get_text()
    assert "11 runs" in title and "sensors 'imu'" in title
    assert all(len(line) <= 120 for line in title.splitlines())
    fig.canvas.draw()
    for ax in fig.axes:  # the histograms count runs: whole numbers on their y axis
        if ax.get_ylabel() == "runs [count]":
            ticks = ax.get_yticks()
            assert len(ticks) >= 2 and np.allclose(ticks, np.round(ticks)), ticks
    path = plot_monte_carlo(result, tmp_path / "mc.png")
    assert path.read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(ValueError, match="error_envelope"):
        monte_carlo_figure({k: v for k, v in result.items() if k != "error_envelope"})


@pytest.fixture(scope="module")
def sweep_result():
    return sweep(VEHICLE.replace(duration_s=0.5), {"design.a_y_std": [0.1, 0.4],
                                                   "params.roll_damping": [0.9, 1.0, 1.1]},
                 runs=2, workers=1, progress=False)


def test_sweep_figure(sweep_result, figure_checks):
    fig = sweep_figure(sweep_result, x="params.roll_damping")
    figure_checks.readable(fig)
    figure_checks.legend_outside_axes(fig)
    axes = [ax for ax in fig.axes if ax.axison]
    assert [ax.get_ylabel() for ax in axes] == ["roll RMSE [deg]", "roll_rate RMSE [deg/s]",
                                                "mean NEES [-]"]
    assert axes[0].get_xlabel() == "params.roll_damping [scale of the nominal value]"
    lines = [ln for ln in axes[0].get_lines() if not ln.get_label().startswith("_")]
    assert sorted(ln.get_label() for ln in lines) == ["design.a_y_std = 0.1",
                                                      "design.a_y_std = 0.4"]
    point = next(p for p in sweep_result["points"]
                 if p["point"] == {"design.a_y_std": 0.4, "params.roll_damping": 1.1})
    line = next(ln for ln in lines if ln.get_label() == "design.a_y_std = 0.4")
    assert list(line.get_xdata()) == [0.9, 1.0, 1.1]
    assert line.get_ydata()[-1] == pytest.approx(np.degrees(point["result"]["rmse"]["roll"]
                                                            ["mean"]))
    with pytest.raises(ValueError, match="grid parameters"):
        sweep_figure(sweep_result, x="nope")


def test_cli_mc_and_sweep_write_their_figures(tmp_path, capsys):
    assert main(["mc", "vehicle-roll", "--runs", "3", "--duration", "0.3", "--no-progress",
                 "--plot", str(tmp_path / "mc.png")]) == 0
    assert main(["sweep", "vehicle-roll", "--runs", "2", "--duration", "0.3", "--no-progress",
                 "--workers", "1", "--grid", "design.a_y_std=0.1,0.2",
                 "--plot", str(tmp_path / "sweep.png")]) == 0
    for name in ("mc.png", "sweep.png"):
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mc.png", "sweep.png"]
