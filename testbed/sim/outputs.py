"""The members' outputs as the simulator keeps them: ``obs``, and ``info``'s float entries as
column blocks of one array (one member's info is one row copy), with the views a one-member
step writes through.

:class:`Outputs` is the part of :class:`~testbed.sim.simulator.Simulator` that lays them out
and hands them out (:meth:`Outputs.member_info`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

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
        """``info``: views of the column blocks of ``_info_rows``; and the views of member 0's
        rows the one-member step writes through (rebuilt in copies)."""
        self.info.clear()
        self.info.update({key: self._info_rows[:, cols]
                          for key, cols in self._info_columns.items()})
        self.info["t"] = self._info_rows[:, self._info_columns["t"].start]
        self.info["action_clipped"] = action_clipped
        row = self._info_row = self._info_rows[0]
        # 1-D views of member 0's columns: a list of floats assigned to a whole 1-D view
        # (``view[...] = values``) costs less than to a slice or a row of a 2-D array
        self._clipped_row = action_clipped[0]
        self._obs_row = self.obs[0]
        #: State and t, setpoint and action_applied (adjacent blocks) as one view when the
        #: disturbance's columns between them are none (:meth:`_step_single`), else two.
        self._step_views = ((row[self._step_cols],) if self._step_cols is not None
                            else (row[self._state_t_cols], row[self._setpoint_action_cols]))

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Copies (``copy.deepcopy``, pickle) step on their own arrays: ``info`` is views of
        the copy's ``_info_rows`` again (a copied view would be a detached array)."""
        self.__dict__.update(state)
        self.info = {}
        self._info_views(np.array(state["info"]["action_clipped"], copy=True))

    def member_info(self, i: int) -> dict[str, Any]:
        """A copy of member ``i``'s entries of :attr:`info` (arrays without the member axis,
        ``t`` a float): the Gymnasium ``info`` of a step."""
        row = (self._info_row if i == 0 else self._info_rows[i]).copy()
        # a dict display with the keys of _INFO_KEYS (fixed): no loop over the blocks. The
        # entries are new views of the copy, zero-width ones too (one shared empty array
        # would be visible: a user may set its shape, flags or dtype)
        state, t, w, setpoint, applied, manoeuvre, accel, step_noise = self._info_slices
        return {"state": row[state], "t": row.item(t), "disturbance": row[w],
                "setpoint": row[setpoint], "action_applied": row[applied],
                "manoeuvre": row[manoeuvre], "process_accel": row[accel],
                "step_noise": row[step_noise],
                "action_clipped": (self._clipped_row if i == 0
                                   else self.info["action_clipped"][i]).copy()}
