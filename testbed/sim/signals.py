"""The time-dependent inputs of the members: setpoint tables, open-loop input profiles
(manoeuvres) and the disturbance signal, each looked up once per distinct time.

:class:`Signals` is the part of :class:`~testbed.sim.simulator.Simulator` that holds and
reads them (the simulator's ``_tables``, ``_table_of``, ``_schedules``, ``_schedule_of``,
``_row_cache`` and ``disturbance``).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np


def _per_time(fn: Callable[[float], np.ndarray], t: np.ndarray, dim: int,
              common: bool = False) -> np.ndarray:
    """``fn(t_i)`` for every entry of ``t`` (k,), evaluated once per distinct time: (k, dim).

    ``common``: the caller knows that every entry of ``t`` is the same time (not looked at).
    """
    if len(t) and (common or t.min() == t.max()):
        return _filled(fn(float(t[0])), len(t), dim)
    values, inverse = np.unique(t, return_inverse=True)
    table = np.array([fn(float(v)) for v in values], dtype=float).reshape(len(values), dim)
    return table[inverse]


def _finite_profile(out: np.ndarray, checked: np.ndarray, t: Any) -> np.ndarray:
    """``out``, the input profiles, when ``checked`` (its rows to check) is finite; else
    ``ValueError`` naming the time(s) ``t``."""
    if np.count_nonzero(np.isfinite(checked)) != checked.size:
        times = t.tolist() if isinstance(t, np.ndarray) else [t]
        raise ValueError(f"the manoeuvre returned a non-finite input at t = {times} s")
    return out


def _filled(value: Any, k: int, dim: int) -> np.ndarray:
    """A new (k, dim) array of one time's ``value`` (a float, or what broadcasts to (dim,))
    in every row (broadcast, as np.broadcast_to)."""
    out = np.empty((k, dim))
    if type(value) is float:
        out.fill(value)
    else:
        out[...] = np.asarray(value, dtype=float)
    return out



@dataclass(slots=True)
class Schedules:
    """The members' setpoint tables and input profiles: registries (entry 0 the default)
    and each member's entry.

    Attributes
    ----------
    tables : list of ndarray
        Setpoint tables, rows ``(t_s, *tracked)``.
    table_of : ndarray of int, shape (N,)
    table_times, table_rows, table_lists
        The default table's times (floats), rows ``(1, r)`` (views) and rows as lists.
    row_cache : (float, float, int)
        The default table's row found last and the times it holds for, ``lo <= t < hi``
        (:meth:`Signals._table_row`).
    profiles : list
        Input profiles (``t_s -> (nu,)``; None: none).
    profile_of : ndarray of int, shape (N,)
    none : bool
        No member has an input profile.
    """

    tables: list[np.ndarray]
    table_of: np.ndarray
    table_times: list[float]
    table_rows: list[np.ndarray]
    table_lists: list[list[float]]
    row_cache: tuple[float, float, int]
    profiles: list[Any]
    profile_of: np.ndarray
    none: bool

    @classmethod
    def default(cls, table: np.ndarray, profile: Any, n: int) -> Schedules:
        """Every one of ``n`` members on the checked ``table`` and ``profile``."""
        return cls([table], np.zeros(n, dtype=int), table[:, 0].tolist(),
                   [row[None, 1:] for row in table], [row[1:].tolist() for row in table],
                   (math.inf, -math.inf, 0), [profile], np.zeros(n, dtype=int), profile is None)

class Signals:
    """References, input profiles and disturbance signals of the members (a part of
    :class:`~testbed.sim.simulator.Simulator`)."""

    def _resolve_manoeuvre(self, manoeuvre: Any, params: dict | None) -> Any:
        if manoeuvre is None or manoeuvre == "none":
            if params:
                raise ValueError("manoeuvre_params given without a manoeuvre")
            return None
        if isinstance(manoeuvre, str):
            if manoeuvre not in self.rig.manoeuvres:
                raise ValueError(f"unknown manoeuvre {manoeuvre!r} for rig {self.rig.name!r}; "
                                 f"expected one of {sorted(self.rig.manoeuvres) or 'none'}")
            try:
                return self.rig.manoeuvres[manoeuvre](**(params or {}))
            except TypeError as err:
                raise ValueError(f"bad manoeuvre_params for {manoeuvre!r}: {err}") from None
        if params:
            raise ValueError("manoeuvre_params is only used with a manoeuvre name")
        if not callable(manoeuvre):
            raise ValueError(f"manoeuvre must be a name, None or a callable t_s -> input, got "
                             f"{manoeuvre!r}")
        return manoeuvre

    def _index(self, registry: list, value: Any) -> int:
        for j, known in enumerate(registry):
            if known is value or (isinstance(known, np.ndarray) and isinstance(value, np.ndarray)
                                  and known.shape == value.shape and np.array_equal(known, value)):
                return j
        registry.append(value)
        return len(registry) - 1

    def _reference(self, t: np.ndarray, sel: Any, common: bool = False) -> np.ndarray:
        """References (k, r) of the members ``sel`` at their times ``t`` (k,); ``common``:
        every entry of ``t`` is the same time."""
        if len(self.schedules.tables) == 1:  # one schedule for every member
            table = self.schedules.tables[0]
            if len(t) == 1 or (common and len(t)):  # one time: the row searchsorted finds
                # below for each member, looked up once without numpy's per-call overhead
                ref = self.schedules.table_rows[self._table_row(float(t[0]))]
                return ref if len(t) == 1 else ref.repeat(len(t), axis=0)
            rows = np.searchsorted(table[:, 0], t, side="right") - 1
            return table[np.maximum(rows, 0), 1:]
        groups = self.schedules.table_of[sel]
        out = np.empty((len(t), len(self.scoring.index)))
        for g in np.unique(groups):
            table = self.schedules.tables[g]
            mask = groups == g
            rows = np.searchsorted(table[:, 0], t[mask], side="right") - 1
            out[mask] = table[np.maximum(rows, 0), 1:]
        return out

    def _table_row(self, t: float) -> int:
        """The row of the default setpoint table in force at ``t``: what ``searchsorted(times,
        t, side="right") - 1`` (at least 0) finds, looked up again only when ``t`` leaves the
        times the last row holds for (a step is then a compare, not a search)."""
        lo, hi, row = self.schedules.row_cache
        if lo <= t < hi:
            return row
        times = self.schedules.table_times
        row = max(bisect.bisect_right(times, t) - 1, 0)
        self.schedules.row_cache = (times[row] if row else -math.inf,
                           times[row + 1] if row + 1 < len(times) else math.inf, row)
        return row

    def setpoints_at(self, t_s: float | np.ndarray, members: Any = slice(None)) -> np.ndarray:
        """References of the members at time(s) ``t_s``, shape (k, r)."""
        groups = self.schedules.table_of[members]
        t = np.asarray(t_s, float)
        if t.ndim == 0:  # one time for every member
            return self._reference(np.full(groups.shape, t), members, common=True)
        return self._reference(np.broadcast_to(t, groups.shape), members)

    def _manoeuvre(self, t: np.ndarray, sel: Any, common: bool = False) -> np.ndarray:
        """The input profiles (k, nu) of the members ``sel`` at their times ``t`` (k,);
        ``common``: every entry of ``t`` is the same time."""
        if self.schedules.none:  # no profile anywhere
            return np.zeros((len(t), self.sizes.actions))
        if len(self.schedules.profiles) == 1:  # every member's profile (one, not None)
            fn = self.schedules.profiles[0]
            if common and len(t):  # one time: one call, every row the first one
                return self._common_profile(float(t[0]), len(t))
            out = _per_time(lambda s: np.atleast_1d(fn(s)), t, self.sizes.actions)
        else:
            groups = self.schedules.profile_of[sel]
            out = np.zeros((len(t), self.sizes.actions))
            for g in np.unique(groups):
                fn = self.schedules.profiles[g]
                if fn is None:
                    continue
                mask = groups == g
                out[mask] = _per_time(lambda s, fn=fn: np.atleast_1d(fn(s)), t[mask],
                                      self.sizes.actions)
        return _finite_profile(out, out, t)

    def _common_profile(self, t: float, k: int) -> np.ndarray:
        """The input profiles (k, nu) of ``k`` members at one time ``t`` when every member
        has the one default profile: one call, every row its value."""
        value = self.schedules.profiles[0](t)
        out = _filled(value, k, self.sizes.actions)
        if type(value) is float and math.isfinite(value):
            return out
        return _finite_profile(out, out[:1], t)

    def _signal(self, t: np.ndarray, index: np.ndarray, common: bool = False) -> np.ndarray:
        """The disturbance signal (k, s) of the members ``index`` at their times ``t`` (k,);
        ``common``: every entry of ``t`` is the same time."""
        if self.disturbance.per_member:  # one sequence per member (SampledDisturbance)
            return self.disturbance.member_signal(t, index)
        return _per_time(self.disturbance.signal, t, self.sizes.signal, common)
