"""The estimation-error envelope of a Monte-Carlo study, gathered while the batches run.

For a grid of at most ``points`` control steps (the first and the last included), the
error ``estimate - truth`` of every run is kept at those steps only, never the
trajectories: memory is ``runs * points * n_states * 8`` bytes (6.4 MB for 1000 runs of
a 4-state rig at 200 points). At the end, per grid step and state: the median and the
5 % / 95 % quantiles over runs, and the filter's own ``3 sqrt(P_ii)`` averaged over runs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

#: Default number of time points of the envelope.
DEFAULT_POINTS = 200


class ErrorEnvelope:
    """Per-step error quantiles over runs, filled batch by batch through ``on_step``.

    Parameters
    ----------
    runs : int
        Total number of runs of the study.
    n_steps : int
        Control steps per run (rows ``0..n_steps``).
    dt_s : float
        Control period.
    state_names : list of str
    points : int
        Maximum number of time points (>= 2).
    """

    def __init__(self, runs: int, n_steps: int, dt_s: float, state_names: list[str],
                 points: int = DEFAULT_POINTS):
        if int(points) != points or points < 2:
            raise ValueError(f"envelope points must be an integer >= 2, got {points}")
        self.state_names = list(state_names)
        self.dt_s = float(dt_s)
        self.steps = np.unique(np.round(np.linspace(0, n_steps, min(int(points), n_steps + 1)))
                               .astype(np.int64))
        self._slot = {int(k): g for g, k in enumerate(self.steps)}
        n = len(self.state_names)
        self.errors = np.full((runs, len(self.steps), n), np.nan)
        self.sigma3_sum = np.zeros((len(self.steps), n))
        self.sigma3_count = np.zeros(len(self.steps), dtype=np.int64)

    def observer(self, start: int) -> Callable[[int, dict[str, Any]], None]:
        """The ``on_step`` of :meth:`testbed.experiment.loop.ClosedLoop.run` for the batch whose
        first
        run is ``start`` (runs ``start .. start + N - 1``)."""
        def on_step(k: int, row: dict[str, Any]) -> None:
            g = self._slot.get(k)
            if g is None:
                return
            err = np.asarray(row["estimate"]) - np.asarray(row["state"])
            self.errors[start:start + len(err), g] = err
            P = row.get("covariance")
            if P is not None:
                var = np.diagonal(np.asarray(P), axis1=-2, axis2=-1)
                std = np.sqrt(np.clip(np.broadcast_to(var, err.shape), 0.0, None))
                self.sigma3_sum[g] += 3.0 * std.sum(axis=0)
                self.sigma3_count[g] += len(err)
        return on_step

    def result(self) -> dict[str, Any]:
        """JSON-ready envelope.

        Returns
        -------
        dict
            ``t_s`` (G,), ``runs`` (G,) runs that reached each time (a batch stops when one
            of its members terminates), and per state ``{"q05", "median", "q95",
            "sigma3_mean"}`` lists of length G (``sigma3_mean`` None without a
            covariance). Grid points no run reached are left out. Values in the rig's SI
            units.
        """
        reached = np.isfinite(self.errors[:, :, 0])
        keep = reached.any(axis=0)
        errors = self.errors[:, keep]
        q05, q50, q95 = np.nanquantile(errors, [0.05, 0.5, 0.95], axis=0)
        has_sigma = bool(np.all(self.sigma3_count[keep] > 0))
        sigma = (self.sigma3_sum[keep] / self.sigma3_count[keep, None]) if has_sigma else None
        states = {}
        for i, name in enumerate(self.state_names):
            states[name] = {"q05": q05[:, i].tolist(), "median": q50[:, i].tolist(),
                            "q95": q95[:, i].tolist(),
                            "sigma3_mean": None if sigma is None else sigma[:, i].tolist()}
        return {"t_s": (self.steps[keep] * self.dt_s).tolist(),
                "runs": reached.sum(axis=0)[keep].tolist(), "states": states}
