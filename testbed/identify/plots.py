"""Figures of an identification and of a comparison (matplotlib, Agg canvas, no pyplot).

One PNG: per channel a pair of panels, the measured channel (wide, grey) under the
prediction (colour) and below it the residual (measured - predicted); the held-out part is
shaded. Angles in degrees (:mod:`testbed.outputs.units`), the project's figure helpers
(:func:`testbed.outputs.plots.new_figure`, ``save_figure``, ``set_title``,
``figure_legend``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from testbed.outputs.plots import FONT_PT, figure_legend, new_figure, save_figure, set_title
from testbed.outputs.units import display, label


def _plot_channels(path: str | os.PathLike, t: np.ndarray, measured: np.ndarray,
                   predicted: np.ndarray, names: list[str], units: list[str], n_fit: int,
                   fits: dict[str, float], holds: dict[str, float], title: list[str]) -> Path:
    m = len(names)
    fig = new_figure(9.0, 1.0 + 2.6 * m)
    axes = fig.subplots(2 * m, 1, sharex=True, squeeze=False,
                        gridspec_kw={"height_ratios": [2.0, 1.0] * m})[:, 0]
    for c, name in enumerate(names):
        factor, unit = display(units[c])
        ax, ax_r = axes[2 * c], axes[2 * c + 1]
        y, y_hat = measured[:, c] * factor, predicted[:, c] * factor
        ax.plot(t, y, color="0.6", lw=2.5, label="measured")
        ax.plot(t, y_hat, color="C0", lw=1.0, label="predicted")
        ax_r.plot(t, y - y_hat, color="C3", lw=0.8, label="residual")
        ax_r.axhline(0.0, color="0.3", lw=0.5)
        fit = f"fit {fits.get(name, float('nan')):.1f} %"
        if name in holds:
            fit += f", held out {holds[name]:.1f} %"
        ax.set_title(f"{name}: {fit}", fontsize=FONT_PT, loc="left")
        ax.set_ylabel(label(name, unit), fontsize=FONT_PT)
        ax_r.set_ylabel(label("residual", unit), fontsize=FONT_PT)
        if n_fit < len(t):
            for a in (ax, ax_r):
                a.axvspan(t[n_fit], t[-1], color="0.92", zorder=0,
                          label="held out" if a is ax else None)
        for a in (ax, ax_r):
            a.tick_params(labelsize=FONT_PT)
            a.grid(True, lw=0.3)
    axes[-1].set_xlabel("time [s]", fontsize=FONT_PT)
    set_title(fig, title)
    figure_legend(fig)
    return save_figure(fig, path)


def plot_identification(result: Any, path: str | os.PathLike) -> Path:
    """Measured vs predicted channels and residuals of an
    :class:`~testbed.identify.fit.Identification` as one PNG.

    Returns
    -------
    Path
    """
    fitted = [n for n, p in result.parameters.items() if p.identifiable]
    held = [n for n, p in result.parameters.items() if not p.identifiable]
    title = [f"{result.rig} ({result.profile}) identified by {result.method} from "
             f"{result.recording_source}",
             f"fitted: {', '.join(f'{n} x{result.parameters[n].scale:.3g}' for n in fitted)}"
             + (f"; held at nominal: {', '.join(held)}" if held else "")]
    return _plot_channels(path, result.time_s, result.measured, result.predicted,
                          list(result.channels), list(result.units), result.n_fit,
                          result.fit_percent, result.holdout_fit_percent, title)


def plot_compare(result: dict[str, Any], path: str | os.PathLike) -> Path:
    """Overlays of :func:`~testbed.identify.comparison.compare`'s prediction on the recording,
    with residuals, as one PNG."""
    series = result["series"]
    what = f"twin {result['twin']}" if result["source"] == "twin" else "nominal parameters"
    title = [f"{result['rig']} ({result['profile']}), {what}, {result['method']}, against "
             f"{result['recording_source']}"]
    return _plot_channels(path, series["time_s"], series["measured"], series["predicted"],
                          result["channels"], result["units"], series["n_fit"],
                          result["fit_percent"], result["holdout_fit_percent"], title)
