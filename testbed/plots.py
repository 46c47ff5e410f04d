"""Static PNG summary of one run (matplotlib, Agg canvas, no pyplot global state).

Layout: one row per state, left the state (truth in black, estimate in color,
measurements of that state as dots, setpoint dashed), right the estimation error with a
+-3 sigma band when a covariance exists; a last row with the actions. States are plotted
with the units the rig declares (``traj.meta["units"]``), angles in degrees: radians
inside, degrees at the edges (:mod:`testbed.units`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from testbed.io import atomic_path
from testbed.trajectory import Trajectory
from testbed.units import display, label

_COLORS = [f"C{i}" for i in range(10)]


def _error_ylim(error: np.ndarray, bound: np.ndarray | None) -> tuple[float, float]:
    """Symmetric y-limits showing the bulk of the error and of the 3-sigma band.

    Percentiles rather than extremes, so that a large initial covariance (or one outlier)
    does not flatten the rest of the run.

    Parameters
    ----------
    error : ndarray, shape (T,)
        Estimation error (NaN allowed).
    bound : ndarray, shape (T,) or None
        3-sigma bound.

    Returns
    -------
    tuple of float
        (lower, upper) limits.
    """
    candidates = [np.nanpercentile(np.abs(error), 99.5)] if np.any(np.isfinite(error)) else []
    if bound is not None and np.any(np.isfinite(bound)):
        candidates.append(np.nanpercentile(bound, 95.0))
    lim = 1.15 * max(candidates, default=1.0)
    if not np.isfinite(lim) or lim <= 0.0:
        lim = 1.0
    return -lim, lim


def plot_trajectory(traj: Trajectory, path: str | os.PathLike, *, title: str | None = None,
                    dpi: int = 100) -> Path:
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
        Figure title; defaults to ``rig`` / ``filter`` from ``traj.meta`` when present.
    dpi : int
        Resolution of the PNG.

    Returns
    -------
    Path
        The written path.

    Raises
    ------
    ValueError
        If a names list, ``estimate`` or ``covariance`` does not match ``state``.
    """
    t = np.asarray(traj.t_s, dtype=float)
    state = traj.state
    meas = traj.measurement
    action = traj.action
    estimate = None if traj.estimate is None else traj.estimate
    std = traj.std() if estimate is not None else None
    n_states = state.shape[1]
    msi = list(traj.measured_state_index or [])
    sp_names = traj.setpoint_names()
    setpoint = None if traj.setpoint is None else traj.setpoint

    n_cols = 2 if estimate is not None else 1  # no error column without an estimate
    fig = Figure(figsize=(6.0 * n_cols, 2.2 * (n_states + 1) + 0.8), layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(n_states + 1, n_cols)
    left0 = None
    for i, name in enumerate(traj.state_names):
        factor, unit = display(traj.unit(name))
        color = _COLORS[i % len(_COLORS)]
        ax = fig.add_subplot(grid[i, 0], sharex=left0)
        left0 = left0 or ax
        # Drawing order: measurements below, then setpoint, truth, estimate on top.
        ax.plot(t, factor * state[:, i], color="black", lw=1.2, label="truth", zorder=3)
        if estimate is not None:
            ax.plot(t, factor * estimate[:, i], color=color, lw=1.0, label="estimate",
                    zorder=4)
        for j, idx in enumerate(msi):
            if idx == i and j < meas.shape[1]:
                ax.plot(t, factor * meas[:, j], ".", color="0.55", ms=2.5, alpha=0.5,
                        label="measurement", zorder=1)
        if setpoint is not None and name in sp_names:
            ax.plot(t, factor * setpoint[:, sp_names.index(name)], "--", color="0.3", lw=1.0,
                    label="setpoint", zorder=2)
        ax.set_ylabel(label(name, unit))
        ax.grid(True, alpha=0.3)
        last = i == n_states - 1  # time tick labels on the last state row only
        ax.tick_params(labelbottom=last)

        if estimate is None:
            continue
        ax_err = fig.add_subplot(grid[i, 1], sharex=left0)
        ax_err.tick_params(labelbottom=last)
        error = factor * (estimate[:, i] - state[:, i])
        bound = None if std is None else 3.0 * factor * std[:, i]
        if bound is not None:
            ax_err.fill_between(t, -bound, bound, color=color, alpha=0.2, lw=0,
                                label="±3σ")
        ax_err.plot(t, error, color=color, lw=1.0, label="error (estimate − truth)")
        ax_err.set_ylim(*_error_ylim(error, bound))
        ax_err.axhline(0.0, color="black", lw=0.5)
        ax_err.set_ylabel(label(f"{name} error", unit))
        ax_err.grid(True, alpha=0.3)

    ax_act = fig.add_subplot(grid[n_states, :], sharex=left0)
    for k, name in enumerate(traj.action_names):
        ax_act.plot(t, action[:, k], lw=1.0, color=_COLORS[k % len(_COLORS)], label=name)
    action_units = {name.rpartition(" [")[2].rstrip("]") for name in traj.action_names
                    if name.endswith("]")}
    ax_act.set_ylabel(label("action", action_units.pop() if len(action_units) == 1 else ""))
    ax_act.set_xlabel("time [s]")
    ax_act.grid(True, alpha=0.3)
    if traj.action_names:
        ax_act.legend(loc="upper right", fontsize="small", ncols=min(4, len(traj.action_names)))

    # One legend for the state/error styles: first occurrence of each label.
    handles: dict[str, object] = {}
    for ax in fig.axes:
        if ax is ax_act:
            continue
        for handle, text in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(text, handle)
    if handles:
        fig.legend(list(handles.values()), list(handles.keys()), loc="outside lower center",
                   ncols=len(handles), fontsize="small")
    if title is None and isinstance(traj.meta, dict):
        parts = [str(traj.meta[k]) for k in ("rig", "filter") if traj.meta.get(k)]
        title = " / ".join(parts) or None
    if title:
        fig.suptitle(title)

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    return Path(path)
