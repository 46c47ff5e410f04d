"""The members' outputs as the simulator keeps them: ``obs``, and ``info``'s float entries as
column blocks of one array (one member's info is one row copy), with the views a one-member
step writes through.

:class:`Outputs` is the part of :class:`~testbed.sim.simulator.Simulator` that lays them out
and hands them out (:meth:`Outputs.member_info`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from testbed.sim.layout import RowViews

#: The float entries of :attr:`Simulator.info`, in its order (``action_clipped`` follows).
_INFO_KEYS = ("state", "t", "disturbance", "setpoint", "action_applied", "manoeuvre",
              "process_accel", "step_noise")


def _joined(columns: dict[str, slice], first: str, second: str) -> slice:
    """The columns of two adjacent blocks of ``columns`` as one slice."""
    a, b = columns[first], columns[second]
    assert a.stop == b.start
    return slice(a.start, b.stop)


class Outputs:
    """``info`` as views of one array, and one member's copy of it (a part of
    :class:`~testbed.sim.simulator.Simulator`)."""

    def _info_views(self, action_clipped: np.ndarray) -> None:
        """``info``: views of the column blocks of ``layout.rows``; and ``views``, member 0's
        rows the one-member step writes through (rebuilt in copies)."""
        layout = self.layout
        self.info.clear()
        self.info.update({key: layout.rows[:, cols] for key, cols in layout.columns.items()})
        self.info["t"] = layout.rows[:, layout.columns["t"].start]
        self.info["action_clipped"] = action_clipped
        row = layout.rows[0]
        step = ((row[layout.step],) if layout.step is not None
                else (row[layout.state_t], row[layout.setpoint_action]))
        self.views = RowViews(row, action_clipped[0], self.obs[0], step)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Copies (``copy.deepcopy``, pickle) step on their own arrays: ``info`` is views of
        the copy's ``_info_rows`` again (a copied view would be a detached array)."""
        self.__dict__.update(state)
        self.info = {}
        self._info_views(np.array(state["info"]["action_clipped"], copy=True))

    def member_info(self, i: int) -> dict[str, Any]:
        """A copy of member ``i``'s entries of :attr:`info` (arrays without the member axis,
        ``t`` a float): the Gymnasium ``info`` of a step."""
        row = (self.views.info if i == 0 else self.layout.rows[i]).copy()
        # a dict display with the keys of _INFO_KEYS (fixed): no loop over the blocks. The
        # entries are new views of the copy, zero-width ones too (one shared empty array
        # would be visible: a user may set its shape, flags or dtype)
        state, t, w, setpoint, applied, manoeuvre, accel, step_noise = self.layout.slices
        return {"state": row[state], "t": row.item(t), "disturbance": row[w],
                "setpoint": row[setpoint], "action_applied": row[applied],
                "manoeuvre": row[manoeuvre], "process_accel": row[accel],
                "step_noise": row[step_noise],
                "action_clipped": (self.views.clipped if i == 0
                                   else self.info["action_clipped"][i]).copy()}
