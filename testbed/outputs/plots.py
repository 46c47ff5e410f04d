"""Static PNG summary of one run (matplotlib, Agg canvas, no pyplot global state).

Layout: one row per state, left the state (truth wide and grey under the estimate in
colour, measurements of that state as dots, the setpoint dashed), right the estimation
error (estimate - truth, as everywhere) with a +-3 sigma band when a covariance exists; a
last row with the actions. One legend, outside the axes, below them; the title (short)
names the rig, the filter and the sensor preset and gives the RMSE per state and the mean
NEES (the sensor chain is in the run's JSON, ``config.sensors``).

Error axes show the steady state (:func:`testbed.outputs.axes.steady_state_limit`); samples beyond
the axis are marked with triangles at its edge. The setpoint is drawn as the reference in
force over each control interval ``[t_k, t_k+1)``: the last row, a reference no control
step used, is not drawn (it jumps when the run ends on a switching time).

States are plotted with the units the rig declares (``traj.meta["units"]``), angles in
degrees (:mod:`testbed.outputs.units`). Every text is at least :data:`MIN_FONT_PT` points.
"""

from __future__ import annotations

import os
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from testbed.experiment.metrics import nees
from testbed.experiment.trajectory import Trajectory
from testbed.io import atomic_path
from testbed.outputs.axes import held_setpoint, steady_state_limit
from testbed.outputs.units import display, label

_COLORS = [f"C{i}" for i in range(10)]
#: Smallest font size (points) used in any figure; at 100 dpi 8 pt is 11 px.
MIN_FONT_PT = 8.0
FONT_PT = 9.0
CLIP_COLOR = "crimson"


def new_figure(width_in: float, height_in: float) -> Figure:
    """A constrained-layout figure on an Agg canvas (no pyplot state)."""
    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path: str | os.PathLike, dpi: int = 100) -> Path:
    """Write ``fig`` as PNG, atomically (parent directories are created)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    return Path(path)


def set_title(fig: Figure, lines: list[str], fontsize: float = 10.0) -> None:
    """Figure title from ``lines``, each wrapped to the figure's width."""
    width_chars = max(40, int(fig.get_figwidth() * 72.0 / (0.55 * fontsize)))
    fig.suptitle("\n".join(textwrap.fill(line, width_chars) for line in lines if line),
                 fontsize=fontsize)


def figure_legend(fig: Figure, max_columns: int = 4) -> None:
    """One legend below the axes for the whole figure: the first handle of each label."""
    handles: dict[str, object] = {}
    for ax in fig.axes:
        for handle, text in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(text, handle)
    if handles:
        fitted_legend(fig, list(handles.values()), list(handles.keys()), max_columns,
                      fontsize=FONT_PT)


def shorten(text: str, width: int) -> str:
    """``text`` of at most ``width`` characters: the middle replaced by an ellipsis."""
    if len(text) <= width:
        return text
    keep = max(width - 1, 2)
    head = (keep + 1) // 2
    return f"{text[:head]}…{text[len(text) - (keep - head):]}"


def fitted_legend(fig: Figure, handles: list, labels: list[str], ncols: int,
                  margin_in: float = 0.1, **kwargs: Any) -> Any:
    """``fig.legend`` below the axes (``loc="outside lower center"``), narrower than the
    figure less ``margin_in`` each side: fewer columns, then, in one column, the longest
    entries shortened in the middle (:func:`shorten`)."""
    renderer = fig.canvas.get_renderer()
    room_px = (fig.get_figwidth() - 2 * margin_in) * fig.dpi
    labels = [str(text) for text in labels]
    ncols = max(1, min(int(ncols), len(labels)))
    while True:
        legend = fig.legend(handles, labels, loc="outside lower center", ncols=ncols,
                            **kwargs)
        if legend.get_window_extent(renderer).width <= room_px:
            return legend
        longest = max(range(len(labels)), key=lambda i: len(labels[i]))
        if ncols == 1 and len(labels[longest]) <= 8:
            return legend
        legend.remove()
        if ncols > 1:
            ncols -= 1
        else:
            labels[longest] = shorten(labels[longest], int(len(labels[longest]) * 0.85))


def mark_clipped(ax: Any, t: np.ndarray, values: np.ndarray, lim: float) -> int:
    """Mark the samples of ``values`` beyond ``+-lim`` with triangles at the axis edge.

    Returns
    -------
    int
        Number of marked samples.
    """
    values = np.asarray(values, dtype=float)
    above, below = values > lim, values < -lim
    if above.any():
        ax.plot(t[above], np.full(above.sum(), lim), "^", color=CLIP_COLOR, ms=4,
                clip_on=False, zorder=6, label="beyond the axis")
    if below.any():
        ax.plot(t[below], np.full(below.sum(), -lim), "v", color=CLIP_COLOR, ms=4,
                clip_on=False, zorder=6, label="beyond the axis")
    return int(above.sum() + below.sum())


def trajectory_metrics(traj: Trajectory) -> dict[str, Any]:
    """RMSE per state and mean NEES of a trajectory, over rows ``1..T`` (as
    :class:`testbed.experiment.metrics.EpisodeMetrics`: row 0 is the prior)."""
    if traj.estimate is None or len(traj.t_s) < 2:
        return {}
    err = traj.estimate[1:] - traj.state[1:]
    out: dict[str, Any] = {"rmse": dict(zip(traj.state_names,
                                            np.sqrt(np.nanmean(err**2, axis=0)).tolist(),
                                            strict=True))}
    if traj.covariance is not None:
        P = np.asarray(traj.covariance[1:], dtype=float)
        out["nees_mean"] = float(np.nanmean(nees(err, P)))
    return out


def _title(traj: Trajectory, title: str | None, summary: dict[str, Any] | None
           ) -> list[str]:
    meta = traj.meta if isinstance(traj.meta, dict) else {}
    if title is None:
        title = " / ".join(str(meta[k]) for k in ("rig", "filter") if meta.get(k)) or "run"
    preset = (meta.get("scenario") or {}).get("sensors")
    if isinstance(preset, str) and len(preset) <= 30:  # the chain itself is in the JSON
        title += f", sensors {preset!r}"
    lines = [title]
    metrics = summary if summary is not None else trajectory_metrics(traj)
    parts = []
    for name, value in (metrics.get("rmse") or {}).items():
        factor, unit = display(traj.unit(name))
        parts.append(f"{name} {value * factor:.3g}{' ' + unit if unit else ''}")
    if parts:
        text = "RMSE " + ", ".join(parts)
        if metrics.get("nees_mean") is not None:
            text += f"; mean NEES {metrics['nees_mean']:.2f} (n = {len(traj.state_names)})"
        lines.append(text)
    return lines


def _action_units(traj: Trajectory) -> str:
    units = sorted({u for u in (traj.unit(a, "action") for a in traj.action_names) if u})
    return ", ".join(units)


def trajectory_figure(traj: Trajectory, *, title: str | None = None,
                      summary: dict[str, Any] | None = None) -> Figure:
    """The figure of :func:`plot_trajectory` (not saved).

    Parameters
    ----------
    traj : Trajectory
    title : str, optional
        First title line; defaults to ``rig / filter`` from ``traj.meta``.
    summary : dict, optional
        ``rmse`` ({state: SI value}) and ``nees_mean`` for the title (e.g. the runner's
        summary); computed from ``traj`` (:func:`trajectory_metrics`) when omitted.

    Returns
    -------
    matplotlib.figure.Figure
    """
    t = np.asarray(traj.t_s, dtype=float)
    state, meas, action = traj.state, traj.measurement, traj.action
    estimate = traj.estimate
    std = traj.std() if estimate is not None else None
    n_states = state.shape[1]
    msi = list(traj.measured_state_index or [])
    sp_names = traj.setpoint_names()
    setpoint = None if traj.setpoint is None else held_setpoint(traj.setpoint)

    n_cols = 2 if estimate is not None else 1  # no error column without an estimate
    fig = new_figure(6.0 * n_cols, 2.2 * (n_states + 1) + 1.6)
    grid = fig.add_gridspec(n_states + 1, n_cols)
    left0 = None
    for i, name in enumerate(traj.state_names):
        factor, unit = display(traj.unit(name))
        color = _COLORS[i % len(_COLORS)]
        ax = fig.add_subplot(grid[i, 0], sharex=left0)
        left0 = left0 or ax
        # Drawing order: measurements below, then setpoint, the wide truth, the estimate.
        for j, idx in enumerate(msi):
            if idx == i and j < meas.shape[1]:
                ax.plot(t, factor * meas[:, j], ".", color="0.55", ms=2.5, alpha=0.5,
                        label="measurement", zorder=1)
        if setpoint is not None and name in sp_names:
            ax.plot(t, factor * setpoint[:, sp_names.index(name)], "--", color="0.3", lw=1.0,
                    drawstyle="steps-post", label="setpoint", zorder=2)
        ax.plot(t, factor * state[:, i], color="black", lw=2.6, alpha=0.4, label="truth",
                zorder=3)
        if estimate is not None:
            ax.plot(t, factor * estimate[:, i], color=color, lw=1.0, label="estimate",
                    zorder=4)
        ax.set_ylabel(label(name, unit))
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("time [s]")
        # time ticks under the last state row (beside the error column's), and on the
        # full-width action row below, whose time scale is wider
        ax.xaxis.label.set_visible(i == n_states - 1)
        ax.tick_params(labelbottom=i == n_states - 1)

        if estimate is None:
            continue
        ax_err = fig.add_subplot(grid[i, 1], sharex=left0)
        ax_err.tick_params(labelbottom=i == n_states - 1)
        error = factor * (estimate[:, i] - state[:, i])
        bound = None if std is None else 3.0 * factor * std[:, i]
        lim = steady_state_limit(t, error, bound)
        if bound is not None:
            ax_err.fill_between(t, -bound, bound, color=color, alpha=0.2, lw=0, label="±3σ")
        ax_err.plot(t, error, color=color, lw=1.0, label="error (estimate − truth)")
        mark_clipped(ax_err, t, error, lim)
        ax_err.set_ylim(-lim, lim)
        ax_err.axhline(0.0, color="black", lw=0.5)
        ax_err.set_ylabel(label(f"{name} error", unit))
        ax_err.set_xlabel("time [s]")
        ax_err.xaxis.label.set_visible(i == n_states - 1)
        ax_err.grid(True, alpha=0.3)

    ax_act = fig.add_subplot(grid[n_states, :], sharex=left0)
    for k, name in enumerate(traj.action_names):
        ax_act.plot(t, action[:, k], lw=1.0, color=_COLORS[k % len(_COLORS)], label=name)
    ax_act.set_ylabel(label("action", _action_units(traj)))
    ax_act.set_xlabel("time [s]")
    ax_act.grid(True, alpha=0.3)
    if left0 is not None and len(t):
        left0.set_xlim(t[0], t[-1])

    figure_legend(fig, max_columns=6)
    lines = _title(traj, title, summary)
    if estimate is not None:
        lines.append("error axes: the second half of the run (steady state); "
                     "triangles mark samples beyond them")
    set_title(fig, lines)
    return fig


def plot_trajectory(traj: Trajectory, path: str | os.PathLike, *, title: str | None = None,
                    dpi: int = 100, summary: dict[str, Any] | None = None) -> Path:
    """Plot a run to a PNG file, atomically.

    Parameters
    ----------
    traj : Trajectory
        The run: ``t_s`` (T,), ``state`` (T, n), optional ``estimate`` (T, n) and
        ``covariance`` (T, n, n), ``measurement`` (T, m) with ``measured_state_index``,
        ``action`` (T, k), optional ``setpoint`` (T, n_ref). NaN samples (e.g. sensor
        dropouts) show as gaps.
    path : str or PathLike
        Destination ``.png`` (parent directories are created).
    title : str, optional
        First title line; defaults to ``rig`` / ``filter`` from ``traj.meta``.
    dpi : int
        Resolution of the PNG.
    summary : dict, optional
        Metrics for the title (see :func:`trajectory_figure`).

    Returns
    -------
    Path
        The written path.

    Raises
    ------
    ValueError
        If a names list, ``estimate`` or ``covariance`` does not match ``state``.
    """
    return save_figure(trajectory_figure(traj, title=title, summary=summary), path, dpi=dpi)
