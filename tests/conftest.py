"""Shared fixtures."""

from __future__ import annotations

import numpy as np
import pytest

# testbed first, whatever module pytest collects first: its start-up sets MUJOCO_GL for a
# headless machine, which MuJoCo reads when it is imported (a test module importing mujoco
# before testbed would otherwise leave rendering without an OpenGL backend)
import testbed  # noqa: F401


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


class FigureChecks:
    """Checks of a matplotlib figure through its objects (not its pixels)."""

    @staticmethod
    def texts(fig):
        from matplotlib.text import Text

        return [t for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()]

    @staticmethod
    def readable(fig, min_pt: float = 8.0) -> None:
        """Every text at least ``min_pt``; every visible axes labelled on both axes."""
        small = [(t.get_text(), t.get_fontsize()) for t in FigureChecks.texts(fig)
                 if t.get_fontsize() < min_pt]
        assert not small
        for ax in fig.axes:
            if ax.axison:
                assert ax.get_ylabel(), ax
                assert ax.xaxis.get_label().get_text(), ax.get_ylabel()

    @staticmethod
    def legend_outside_axes(fig) -> None:
        """Every legend (figure or axes) overlaps no axes with data."""
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        legends = fig.legends + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
        assert legends
        for legend in legends:
            box = legend.get_window_extent(renderer)
            for ax in fig.axes:
                if ax.axison:
                    assert not box.overlaps(ax.get_window_extent(renderer)), ax.get_ylabel()


@pytest.fixture
def figure_checks() -> type[FigureChecks]:
    return FigureChecks
