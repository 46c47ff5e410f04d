"""What a simulation raises when it leaves what the rig can physically do."""

from __future__ import annotations

from typing import Any

import numpy as np


class SimulationDiverged(RuntimeError):
    """The simulation left what the rig can physically do; its results would be meaningless.

    Raised by :meth:`Simulator.step` when, after a control step, a member's MuJoCo data
    reported an instability warning (NaN, inf or huge ``qpos``/``qvel``/``qacc``, after which
    MuJoCo silently resets the state), its state is not finite, or a state component is past
    the rig's :attr:`~testbed.rigs.base.Rig.state_envelope`. The diverged members must be
    reset before they step again.

    Parameters
    ----------
    message : str
        Human-readable description (time, member, reason, state).
    time_s : float
        Simulation time at the end of the failing step, s.
    state : ndarray, shape (k, n)
        States of the diverged members after the step.
    members : list of int
        Indices of the diverged members.
    reason : str
        ``"mujoco warning"``, ``"non-finite state"`` or ``"outside envelope"`` (of the first).
    """

    def __init__(self, message: str, *, time_s: float, state: np.ndarray, members: list[int],
                 reason: str):
        super().__init__(message)
        self.message, self.time_s, self.reason = message, float(time_s), reason
        self.state, self.members = np.asarray(state), list(members)

    def __reduce__(self) -> tuple[Any, ...]:
        # keyword-only constructor: picklable for process pools and Ray
        return (_rebuild_diverged, (self.message, self.time_s, self.state, self.members,
                                    self.reason))


def _rebuild_diverged(message: str, time_s: float, state: np.ndarray, members: list[int],
                      reason: str) -> SimulationDiverged:
    return SimulationDiverged(message, time_s=time_s, state=state, members=members,
                              reason=reason)
