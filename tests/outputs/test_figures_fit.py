"""Figures that fit: no artist of the run, Monte-Carlo and score figures leaves the canvas
(matplotlib's tight bounding box inside the figure, every legend inside it), at short and
long labels and few and many entries."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.lines import Line2D

from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.outputs.plots import fitted_legend, new_figure, shorten, trajectory_figure
from testbed.outputs.study_plots import monte_carlo_figure

EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples"
LONG = "a-plug-in-label-of-sixty-characters-" + "x" * 24  # 60 characters


def outside(fig) -> list[str]:
    """What leaves the canvas: the figure's tight bounding box and each legend, against the
    figure's box (1 px tolerance)."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = fig.bbox
    found = []
    tight = fig.get_tightbbox(renderer)  # inches
    W, H = fig.get_size_inches()
    tol = 1.0 / fig.dpi
    if tight.x0 < -tol or tight.y0 < -tol or tight.x1 > W + tol or tight.y1 > H + tol:
        found.append(f"tight bbox {tight.bounds} outside ({W}, {H}) in")
    for legend in fig.legends + [ax.get_legend() for ax in fig.axes if ax.get_legend()]:
        ext = legend.get_window_extent(renderer)
        if ext.x0 < box.x0 - 1 or ext.x1 > box.x1 + 1 or ext.y0 < box.y0 - 1 \
                or ext.y1 > box.y1 + 1:
            found.append(f"legend {ext.bounds} outside {box.bounds}")
    return found


def test_the_check_sees_a_legend_wider_than_the_figure():
    fig = new_figure(4.0, 3.0)
    ax = fig.add_subplot()
    handles = [ax.plot([0, 1], [i, i])[0] for i in range(6)]
    fig.legend(handles, [f"{LONG}{i}" for i in range(6)], loc="outside lower center",
               ncols=6)
    assert outside(fig)  # the check can fail


@pytest.mark.parametrize("entries,width_in,height_in", [(1, 3.0, 3.0), (6, 4.0, 4.0),
                                                        (14, 8.0, 6.0)])
def test_a_fitted_legend_fits_at_any_number_of_long_entries(entries, width_in, height_in):
    fig = new_figure(width_in, height_in)
    ax = fig.add_subplot()
    handles = [Line2D([], [], color=f"C{i % 10}") for i in range(entries)]
    labels = [f"{LONG}{i}" for i in range(entries)]
    legend = fitted_legend(fig, handles, labels, 6)
    assert outside(fig) == []
    texts = [t.get_text() for t in legend.get_texts()]
    assert len(set(texts)) == entries  # shortened in the middle: still told apart
    ax.plot([0, 1], [0, 1])


def test_shorten_keeps_both_ends():
    assert shorten("abcdefghij", 20) == "abcdefghij"
    short = shorten(LONG, 20)
    assert len(short) == 20 and short.startswith("a-plug") and short.endswith("xxxx")


def test_the_monte_carlo_figure_keeps_its_legend_inside():
    """testbed mc vehicle-roll --plot: the legend was wider than the figure (0.57 in each
    side)."""
    mc = runner.monte_carlo(Scenario(rig="vehicle-roll", duration_s=1.0), runs=4,
                            progress=False, envelope_points=50)
    assert outside(monte_carlo_figure(mc)) == []


def test_the_run_figure_fits_and_labels_the_state_panels_time():
    traj, summary = runner.run(Scenario(rig="helicopter", duration_s=1.0), progress=False)
    fig = trajectory_figure(traj, summary=summary)
    assert outside(fig) == []
    fig.canvas.draw()
    n = traj.state.shape[1]
    last_left = fig.axes[2 * (n - 1)]  # state panels and error panels alternate
    assert last_left.get_ylabel().startswith(traj.state_names[-1])
    assert any(t.get_visible() and t.get_text() for t in last_left.get_xticklabels())
    assert last_left.xaxis.label.get_visible()


def test_the_score_figure_fits_with_sixty_character_labels():
    from testbed.estimators import labelled
    from testbed.score import harness, report

    plug = labelled(f"{LONG}={EXAMPLES / 'userkf.py'}:make")
    run = harness.score(["kalman", plug], "quick", scenarios=["calibration"], runs=3,
                        worst_case=False)
    summary = report.results(run)
    assert summary["estimators"] == ["kalman", LONG]
    fig = report.score_figure(summary)
    assert outside(fig) == []
    ticks = [t.get_text() for ax in fig.axes for t in ax.get_yticklabels(minor=True)]
    assert LONG not in ticks and report.short_name(LONG) in ticks
    legend_texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert LONG in legend_texts  # the key keeps the whole name
    assert np.isfinite(fig.get_size_inches()).all()
