"""What a simulator fixes when it is built, as small typed records the step reads.

:class:`~testbed.sim.simulator.Simulator` builds each once (its ``__init__``): the sizes,
the action limits and state envelope (arrays, Python lists for the one-member step, and one
row per member for the batch step), what a step scores (tracked states, termination), the
normals a step draws, the disturbance's inputs, the whole batch's read-only rows, and the
column layout of ``info``. The arrays in them are the simulator's own (some are written in
place, none is replaced), so the records are frozen.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True, slots=True)
class Sizes:
    """Numbers of states ``n``, actions ``nu``, joints ``j`` and signal entries ``s``."""

    states: int
    actions: int
    joints: int
    signal: int


@dataclass(frozen=True, slots=True)
class Limits:
    """The rig's action limits (nu,) and state envelope (n,) (``inf``: unbounded), as arrays
    and as lists of floats (the one-member step's)."""

    low: np.ndarray
    high: np.ndarray
    envelope: np.ndarray
    low_list: list[float]
    high_list: list[float]
    envelope_list: list[float]


@dataclass(frozen=True, slots=True)
class Scoring:
    """What a step scores: the tracked states (the reward ``-|x_tracked - reference|^2``)
    and whether the rig ends episodes.

    Attributes
    ----------
    index : ndarray of int, shape (r,)
    count : int
        ``r``.
    cols : slice or ndarray
        ``index`` as a slice when contiguous (a view instead of a gather).
    columns : list of int
        ``index`` as a list (the one-member step's).
    terminates : bool
        The rig overrides :meth:`~testbed.rigs.base.Rig.terminated`.
    terminated_row : bool
        The class defining ``terminated`` defines ``terminated_row`` too (else a one-member
        step calls ``terminated``).
    """

    index: np.ndarray
    count: int
    cols: Any
    columns: list[int]
    terminates: bool
    terminated_row: bool


@dataclass(frozen=True, slots=True)
class Draws:
    """Standard normals per member and step, in stream order: the rig's step noise, the
    disturbance's, then (when they declare a fixed number) the sensors'.

    Attributes
    ----------
    disturbance : int
    sensors : int or None
        None: the sensors draw from the streams themselves.
    step : int
        What a step draws in one call (the three above, the sensors' when declared).
    sensor_offset : int
        Where the sensors' normals start in a step's draw.
    """

    disturbance: int
    sensors: int | None
    step: int
    sensor_offset: int


@dataclass(frozen=True, slots=True)
class DisturbanceInputs:
    """What a step turns the disturbance into (fixed for the simulator's life).

    Attributes
    ----------
    has_signal, active : bool
        The disturbance has a signal ``w(t)``; it has forces (``G`` or ``b``).
    plain : bool
        No signal, no disturbance forces and no step noise: a one-member step skips their
        inputs.
    G_rows, b_rows : ndarray or None
        The velocity rows of ``G`` and ``b``.
    sqrt_dt : float
    dof_adr : ndarray of int
        The rig's dof addresses in MuJoCo's ``nv``.
    dof_cols : slice or ndarray
        ``dof_adr`` as a slice when consecutive (a basic-index write).
    """

    has_signal: bool
    active: bool
    plain: bool
    G_rows: np.ndarray | None
    b_rows: np.ndarray | None
    sqrt_dt: float
    dof_adr: np.ndarray
    dof_cols: Any


@dataclass(frozen=True, slots=True)
class WholeBatch:
    """The batch step's constants with one row per member (read-only; numpy's ufuncs between
    arrays of one shape skip the broadcasting machinery), and ``accel``, the members' joint
    accelerations in generalized coordinates (num, nv), zero but in the rig's dof columns
    (overwritten every step).

    ``whole`` is what a step of the whole batch reads for its members: their indices,
    selection, number, action limits, envelope and zero input, acceleration and signal
    rows.
    """

    all: np.ndarray
    zero_input: np.ndarray
    zero_accel: np.ndarray
    zero_w: np.ndarray
    low: np.ndarray
    high: np.ndarray
    envelope: np.ndarray
    dt: np.ndarray
    one: np.ndarray
    accel: np.ndarray
    whole: tuple[Any, ...]


@dataclass(frozen=True, slots=True)
class InfoLayout:
    """``info``'s float entries as column blocks of one array ``rows`` (N, width), so that
    one member's info is one row copy.

    Attributes
    ----------
    rows : ndarray, shape (N, width)
    columns : dict of str to slice
        Each entry's block.
    slices : tuple
        The blocks in :data:`testbed.sim.outputs._INFO_KEYS` order (``t`` its column index).
    state_t, setpoint_action : slice
        Adjacent blocks a one-member step writes at once.
    step : slice or None
        Both as one when the disturbance's columns between them are none.
    """

    rows: np.ndarray
    columns: dict[str, slice]
    slices: tuple[Any, ...]
    state_t: slice
    setpoint_action: slice
    step: slice | None


@dataclass(frozen=True, slots=True)
class RowViews:
    """Views of member 0's rows that the one-member step writes through (a list of floats
    assigned to a whole 1-D view costs less than to a slice of a 2-D array); rebuilt in
    copies.

    Attributes
    ----------
    info : ndarray, shape (width,)
    clipped : ndarray of bool, shape (nu,)
    obs : ndarray, shape (m,)
    step : tuple of ndarray
        State and t, setpoint and action_applied: one view, or two when the disturbance's
        columns lie between them.
    """

    info: np.ndarray
    clipped: np.ndarray
    obs: np.ndarray
    step: tuple[np.ndarray, ...]
