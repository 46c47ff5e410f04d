"""A :class:`~testbed.sensors.Suite`'s decorators applied across channels, one kind at a time.

A suite such as the vehicle's IMU (``biasrandomwalk(whitenoise(roll_rate)) +
whitenoise(lateral_accel) + tap(quantize(whitenoise(speed)) + ...)``) measured sensor by
sensor makes one Python call and a few numpy calls per decorator and channel. A
:class:`FusedPlan` measures the suite's leaf channels into one (k, m) array, then applies
the decorators level by level (level = how many decorators lie between a decorator and its
leaves): at each level, the decorators of one kind (white noise, bias random walk,
quantization) act on all their columns in one vectorized operation; the other known kinds
(:class:`~testbed.sensors.Bias`, :class:`~testbed.sensors.ScaleFactor`,
:class:`~testbed.sensors.Delay`, :class:`~testbed.sensors.Tap`) run their own ``apply`` on
their columns.

The values are bitwise those of the sensor-by-sensor measurement: every element sees the
same floating-point operations in the same order (the decorators of a channel still apply
inner to outer), and every decorator gets the standard normals it would have drawn itself,
taken from one draw of the suite's ``draws_per_sample()`` values at the offsets of the
sequential order (:class:`~testbed.sensors.base.NoiseStreams`: a stream's values do not
depend on how its draws are split).

A suite is fused only when every sensor in it declares its draws per sample, every
decorator is one of the kinds above (exact type: a subclass may change ``apply``) and no
decorator measures its inner sensor itself (:class:`~testbed.sensors.SampleAndHold`
measures it at its own instants only); otherwise :func:`build_plan` returns None and the
suite measures sensor by sensor.

Parameters (noise levels, walks, resolutions) are read when the plan is built, at the
suite's ``allocate``; the per-member state of the fused random walks (``bias``) lives in one
array of the plan, which each decorator's ``bias`` attribute views.
"""

from __future__ import annotations

import functools
from math import copysign
from typing import Any

import numpy as np

from testbed.sensors.base import Drawn, Noise, Sample, Sensor, Suite
from testbed.sensors.decorators import (
    Bias,
    BiasRandomWalk,
    Decorator,
    Delay,
    Quantize,
    ScaleFactor,
    Tap,
    WhiteNoise,
)

#: Decorators that run their own ``apply`` on their columns inside a plan.
_OWN_APPLY = (Bias, ScaleFactor, Delay, Tap)
#: Every decorator type a plan handles (exact types).
_KNOWN = (WhiteNoise, BiasRandomWalk, Quantize, *_OWN_APPLY)


class _NotFusable(Exception):
    """The suite has a sensor a plan cannot apply across channels."""


def as_slice(index: Any) -> slice | np.ndarray:
    """Integer positions ``index`` (j,) as a basic slice when they are consecutive and
    increasing (a view, a basic-index write), else as an int array (a fancy index)."""
    cols = [int(i) for i in index]
    if cols and cols == list(range(cols[0], cols[0] + len(cols))):
        return slice(cols[0], cols[0] + len(cols))
    return np.asarray(index, dtype=int)


def _index(cols: list[int], width: int | None = None) -> Any:
    """Columns as an index: None for all ``width`` of them (the array itself), else
    :func:`as_slice` (``take`` and a fancy assignment when not consecutive)."""
    if width is not None and cols == list(range(width)):
        return None
    return as_slice(cols)


def _target(a: np.ndarray, index: Any) -> np.ndarray | None:
    """The columns ``index`` (:func:`_index`) of ``a`` as the view an operation writes in
    place: all of them (the array itself) or one (a 1-D view: numpy runs a 1-D operation
    in one loop, a (k, 1) view of a wider array through its general iterator); else None
    (a gather into a new array and back costs less than numpy's row-by-row loop over a
    view of a few columns of each row)."""
    if index is None:
        return a
    if type(index) is slice and index.stop - index.start == 1:
        return a[:, index.start]
    return None


def _like(b: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``b`` (k, c) shaped as ``target`` (:func:`_target`): its one column for a 1-D one."""
    return b if target.ndim == 2 else b[:, 0]


def _get(a: np.ndarray, index: Any) -> np.ndarray:
    """The columns ``index`` (:func:`_index`) of ``a``."""
    if index is None:
        return a
    return a[:, index] if type(index) is slice else a.take(index, axis=1)


def _scaled(values: np.ndarray, xi: np.ndarray, index: Any) -> np.ndarray:
    """``values * xi[:, index]`` (k, c), a new array (the product in place of the gather
    when ``index`` gathers one)."""
    if type(index) is slice:
        if index.stop - index.start == 1:  # (1-D operands: numpy's one loop)
            return np.multiply(values[:, 0], xi[:, index.start])[:, None]
        return values * xi[:, index]
    drawn = xi.take(index, axis=1)
    return np.multiply(values, drawn, out=drawn)


class _Tiled:
    """A per-column parameter (c,) repeated for k rows, remade when k changes (numpy's
    ufuncs between arrays of one shape skip the broadcasting machinery)."""

    __slots__ = ("values", "rows")

    def __init__(self, values: np.ndarray):
        self.values = values
        self.rows = np.zeros((0, len(values)))

    def of(self, k: int) -> np.ndarray:
        """``values`` as a read-only (k, c) array."""
        rows = self.rows
        if len(rows) != k:
            rows = np.tile(self.values, (k, 1))
            rows.flags.writeable = False
            self.rows = rows
        return rows


#: At most this many scattered columns are summed into one by one (:attr:`_Group.few`).
_FEW = 3


class _Group:
    """Decorators of one kind and level applied on all their columns at once.

    Parameters
    ----------
    decorators : list of (Decorator, int, int)
        The decorators with their first column and first normal (the suite's own order).
    width : int
        The plan's columns.
    values : list of ndarray, optional
        Each decorator's per-channel parameter (std, resolution, walk step), tiled for the k
        rows of a sample (:class:`_Tiled`).
    """

    def __init__(self, decorators: list[tuple[Any, int, int]], width: int,
                 values: list[np.ndarray] | None = None):
        cols = [c for d, c0, _ in decorators for c in range(c0, c0 + d.dim)]
        xcols = [o + j for d, _, o in decorators for j in range(d.dim)]
        self.cols, self.xcols = _index(cols, width), _index(xcols)
        #: The columns one by one when they are a few scattered ones (:data:`_FEW`): a sum
        #: into each 1-D column costs less than a gather, the sum and a scatter; else None.
        self.few = (list(enumerate(cols)) if len(cols) <= _FEW and self.cols is not None
                    else None)
        self.values = None if values is None else _Tiled(np.concatenate(values))
        #: For one row (:meth:`apply_row`): (column, normal, parameter) of each column.
        self.row_terms = list(zip(cols, xcols, [0.0] * len(cols) if values is None
                                  else np.concatenate(values).tolist(), strict=True))

    def _add(self, y: np.ndarray, values: np.ndarray) -> np.ndarray:
        """``y`` with ``values`` (k, c) added to the group's columns: in place on the plan's
        own array where it can (all columns, one as a 1-D view, or a few one by one: the
        same sums), else gathered, summed and put back."""
        target = _target(y, self.cols)
        if target is not None:
            np.add(target, _like(values, target), out=target)
        elif self.few is not None:
            for j, c in self.few:
                column = y[:, c]
                np.add(column, values[:, j], out=column)
        else:
            return self._put(y, _get(y, self.cols) + values)
        return y

    def _put(self, y: np.ndarray, values: np.ndarray) -> np.ndarray:
        """``y`` with the group's columns set to ``values`` (``values`` for all of them)."""
        cols = self.cols
        if cols is None:
            return values
        y[:, cols] = values
        return y


class _NoiseGroup(_Group):
    """White noise with a per-channel std on its columns: ``y + std xi``."""

    def __init__(self, decorators: list[tuple[WhiteNoise, int, int]], width: int):
        super().__init__(decorators, width, [d._std for d, _, _ in decorators])

    def apply(self, y: np.ndarray, xi: np.ndarray, members: Any, sample: Sample,
              noise: Noise) -> np.ndarray:
        return self._add(y, _scaled(self.values.of(len(y)), xi, self.xcols))

    def apply_row(self, y: list[float], xi: list[float], members: Any) -> None:
        """:meth:`apply` on one row of Python floats, in place (the same operations)."""
        for c, o, std in self.row_terms:
            y[c] = y[c] + std * xi[o]


class _QuantizeGroup(_Group):
    """Quantization on its columns: ``round(y / step) step``."""

    def __init__(self, decorators: list[tuple[Quantize, int, int]], width: int):
        super().__init__(decorators, width, [d.step for d, _, _ in decorators])

    def apply(self, y: np.ndarray, xi: np.ndarray, members: Any, sample: Sample,
              noise: Noise) -> np.ndarray:
        step = self.values.of(len(y))
        target = _target(y, self.cols)
        if target is None:
            return self._put(y, np.rint(_get(y, self.cols) / step) * step)
        step = _like(step, target)
        q = target / step  # the same three operations, the last two in place
        np.rint(q, out=q)
        np.multiply(q, step, out=target)
        return y

    def apply_row(self, y: list[float], xi: list[float], members: Any) -> None:
        """:meth:`apply` on one row of Python floats, in place (the same operations)."""
        for c, _, step in self.row_terms:
            y[c] = _rint(y[c] / step) * step


class _WalkGroup(_Group):
    """Bias random walks on its columns: ``y + b_k``, then ``b_{k+1} = b_k + walk sqrt(dt_s)
    xi`` (walking decorators), in one (num, c) bias array the decorators view."""

    def __init__(self, decorators: list[tuple[BiasRandomWalk, int, int]], width: int,
                 walks: bool):
        super().__init__(decorators, width,
                         [d.walk * np.sqrt(d.dt_s) for d, _, _ in decorators] if walks
                         else None)
        num = len(decorators[0][0].bias)
        self.bias = np.zeros((num, sum(d.dim for d, _, _ in decorators)))
        self.views: list[tuple[BiasRandomWalk, np.ndarray]] = []
        c = 0
        for d, _, _ in decorators:  # the decorators' state moves into the shared array
            view = self.bias[:, c:c + d.dim]
            view[...] = d.bias
            d.bias = view
            self.views.append((d, view))
            c += d.dim

    def current(self) -> bool:
        """Whether every decorator still keeps its bias in this group's array (a decorator
        allocated again since, fused by another suite or copied has its own)."""
        bias = self.bias
        for d, v in self.views:
            if d.bias is not v or v.base is not bias:
                return False
        return True

    def apply(self, y: np.ndarray, xi: np.ndarray, members: Any, sample: Sample,
              noise: Noise) -> np.ndarray:
        bias = self.bias[members]
        y = self._add(y, bias)
        if self.values is not None:  # the walk: b + step xi
            scaled = _scaled(self.values.of(len(y)), xi, self.xcols)
            if type(members) is slice:  # ``bias`` is a view of the rows: in place
                np.add(bias, scaled, out=bias)
            else:
                self.bias[members] = bias + scaled
        return y

    def apply_row(self, y: list[float], xi: list[float], members: Any) -> None:
        """:meth:`apply` on one row of Python floats, in place (the same operations)."""
        bias = self.bias[members].tolist()[0]
        for (c, _, _), b in zip(self.row_terms, bias, strict=True):
            y[c] = y[c] + b
        if self.values is not None:
            self.bias[members] = [[b + step * xi[o] for (_, o, step), b
                                   in zip(self.row_terms, bias, strict=True)]]


class _TapStep:
    """A :class:`~testbed.sensors.Tap` on its columns: their values into its ``last`` (what
    ``Tap.apply`` does with the columns' view), without a decorator call."""

    def __init__(self, tap: Tap, c0: int):
        self.tap, self.cols = tap, slice(c0, c0 + tap.dim)

    def apply(self, y: np.ndarray, xi: np.ndarray, members: Any, sample: Sample,
              noise: Noise) -> np.ndarray:
        self.tap.last[members] = y[:, self.cols]
        return y

    def apply_row(self, y: list[float], xi: list[float], members: Any) -> None:
        """:meth:`apply` on one row of Python floats (the same values into ``last``)."""
        self.tap.last[members] = [y[self.cols]]


def _defining(sensor: Sensor, method: str) -> Any:
    """``sensor``'s bound ``method`` when the class defining its ``measure`` defines it
    too; else the base :class:`Sensor`'s (which goes through ``measure``: a subclass that
    changes ``measure`` only is read through it)."""
    for cls in type(sensor).__mro__:
        if "measure" in cls.__dict__:
            if method in cls.__dict__:
                return getattr(sensor, method)
            break
    return functools.partial(getattr(Sensor, method), sensor)


#: 2**52: from here on every double is an integer.
_TWO52 = 4503599627370496.0


def _rint(q: float) -> float:
    """``np.rint(q)`` of a Python float: to the nearest integer, ties to even, with the
    sign of ``q`` on a zero; an integer-valued or non-finite ``q`` is its own rint.

    For ``a = |q| < 2**52``, ``a + 2**52`` lies in ``[2**52, 2**53)``, where the doubles
    are the integers: the addition rounds ``a`` to an integer, to nearest with ties to
    even (``2**52`` is even), as ``rint`` does, and subtracting ``2**52`` is exact;
    ``copysign`` gives a zero the sign of ``q``. ``|q| >= 2**52`` (and inf) is an integer
    already; NaN fails the comparison. (The default rounding mode, as numpy's.)
    """
    return copysign((a + _TWO52) - _TWO52, q) if (a := abs(q)) < _TWO52 else q


class _OwnApply:
    """One decorator's own ``apply`` on its columns, with its normals (if any)."""

    def __init__(self, decorator: Decorator, c0: int, offset: int, draws: int):
        self.decorator, self.cols = decorator, slice(c0, c0 + decorator.dim)
        self.draws = slice(offset, offset + draws) if draws else None

    def apply(self, y: np.ndarray, xi: np.ndarray, members: Any, sample: Sample,
              noise: Noise) -> np.ndarray:
        drawn = noise if self.draws is None else Drawn(xi[:, self.draws])
        view = y[:, self.cols]
        out = self.decorator.apply(view, sample, drawn)
        if out is not view:  # (a Tap returns its input)
            y[:, self.cols] = out
        return y


class FusedPlan:
    """How to measure a suite with its decorators applied across channels (module docstring).

    Build it with :func:`build_plan`; :meth:`measure` equals ``Suite.measure`` bitwise.

    Parameters
    ----------
    suite : Suite
        The (allocated) suite.
    leaves : list of (Sensor, int, int, int)
        Leaf sensors with their first column, draw offset and draws per sample.
    decorators : list of (int, Decorator, int, int, int)
        Decorators with their level, first column, draw offset and own draws per sample.
    """

    def __init__(self, suite: Suite, leaves: list[tuple[Sensor, int, int, int]],
                 decorators: list[tuple[int, Decorator, int, int, int]]):
        self.dim = suite.dim
        self.draws = suite.draws_per_sample() or 0
        # what applies each decorator: a group of its kind and level, or its own apply
        groups: dict[tuple[int, Any], list[tuple[Any, int, int]]] = {}
        owns: list[tuple[int, Decorator, int, int, int]] = []
        for lv, dec, c0, offset, draws in decorators:
            kind = type(dec)
            if kind is Tap:
                owns.append((lv, dec, c0, offset, draws))
            elif kind is WhiteNoise and dec._std is not None:
                if draws:  # (zero noise draws nothing and changes nothing)
                    groups.setdefault((lv, "noise"), []).append((dec, c0, offset))
            elif kind is BiasRandomWalk:
                groups.setdefault((lv, ("walk", bool(draws))), []).append((dec, c0, offset))
            elif kind is Quantize:
                groups.setdefault((lv, "quantize"), []).append((dec, c0, offset))
            else:  # (correlated white noise too)
                owns.append((lv, dec, c0, offset, draws))
        self.leaves = [(s, slice(c0, c0 + s.dim), slice(o, o + d) if d else None)
                       for s, c0, o, d in leaves]
        #: The leaves' writers into the plan's columns (:meth:`Sensor.measure_into`).
        self.into_leaves = [(_defining(s, "measure_into"), cols, draws)
                            for s, cols, draws in self.leaves]
        #: The leaves' one-row readers (:meth:`Sensor.measure_row`) with their normals.
        self.row_leaves = [(_defining(s, "measure_row"), draws) for s, _, draws in self.leaves]
        #: The only leaf when it is a suite of bare state channels covering every column
        #: (whose measurement, a gather, is a new array the decorators may change in place).
        self.whole = (leaves[0][0] if len(leaves) == 1 and isinstance(leaves[0][0], Suite)
                      and leaves[0][0].dim == self.dim else None)
        #: The columns the whole suite gathers when a plain suite's slice (else None).
        self.whole_index = (self.whole._state_index if type(self.whole) is Suite
                            and type(self.whole._state_index) is slice else None)
        width = self.dim
        self.walk_groups: list[_WalkGroup] = []
        #: The steps, level by level.
        self.steps: list[Any] = []
        for level in sorted({lv for lv, *_ in decorators}):
            for lv, dec, c0, offset, draws in owns:
                if lv == level:
                    self.steps.append(_TapStep(dec, c0) if type(dec) is Tap
                                      else _OwnApply(dec, c0, offset, draws))
            for (lv, key), members in groups.items():
                if lv != level:
                    continue
                placed = sorted(members, key=lambda m: m[1])
                if key == "noise":
                    self.steps.append(_NoiseGroup(placed, width))
                elif key == "quantize":
                    self.steps.append(_QuantizeGroup(placed, width))
                else:
                    group = _WalkGroup(placed, width, walks=key[1])
                    self.walk_groups.append(group)
                    self.steps.append(group)
        #: The steps when none runs its own ``apply`` (one row then stays a list of floats
        #: through every step, :meth:`_measure_row`), else None.
        self.row_steps = (None if any(type(step) is _OwnApply for step in self.steps)
                          else tuple(self.steps))

    def current(self) -> bool:
        """Whether the plan's state arrays are still the decorators' own."""
        for group in self.walk_groups:
            if not group.current():
                return False
        return True

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """The suite's measurement of ``sample``, shape (k, m)."""
        xi = noise.normal(self.draws) if self.draws else None
        if len(sample.x) == 1:
            return self._measure_row(sample, noise, xi)
        if self.whole is not None:  # one suite of state channels: its gather is a new array
            y = self.whole.measure(sample, noise)
        else:
            y = np.empty((len(sample.x), self.dim))
            for write, cols, draws in self.into_leaves:
                write(sample, noise if draws is None else Drawn(xi[:, draws]), y[:, cols])
        members = sample.members
        for step in self.steps:
            y = step.apply(y, xi, members, sample, noise)
        return y

    def measure_state_row(self, suite: Suite, x: list[float], xi: list[float] | None,
                          members: Any) -> list[float] | None:
        """:func:`measure_one` of a plan from :func:`state_row_plan`, from one member's state
        ``x`` (n,) and the plan's normals ``xi`` (``draws``, None without) as Python floats
        (``members``: the sample's, the walks' rows):
        the same steps on the same values as :meth:`_measure_row` (which reads only
        ``sample.x`` and the normals on such a plan), without a :class:`Sample`. None
        when the plan is no longer the suite's current one (measure the sample then)."""
        if suite._plan is not self or (self.walk_groups and not self.current()):
            return None
        y = x[self.whole_index]  # (a new list: the steps change it in place)
        for step in self.row_steps:
            step.apply_row(y, xi, members)
        return y

    def _measure_row(self, sample: Sample, noise: Noise, xi: np.ndarray | None,
                     as_list: bool = False) -> Any:
        """:meth:`measure` of one member (k = 1): the leaves' values and the groups'
        operations on a row of Python floats (IEEE-754 doubles: the same operations give
        the same values, bitwise), an array only where a decorator runs its own ``apply``
        (numpy's per-call overhead on arrays of one row is most of a group's time).

        ``as_list``: the row as it ends, the list of floats (m,) when no decorator ran its
        own ``apply``, else the (1, m) array (no array made for a list)."""
        if self.whole is not None:
            index = self.whole_index
            if type(index) is slice:  # the state columns the whole suite gathers
                y: Any = sample.x.tolist()[0][index]
            else:
                y = self.whole.measure(sample, noise).tolist()[0]
        else:
            y = []
            for read, draws in self.row_leaves:
                y += read(sample, noise if draws is None else Drawn(xi[:, draws]))
        xl = None if xi is None else xi.tolist()[0]
        members = sample.members
        row_steps = self.row_steps
        if row_steps is not None:  # every step on the list (no type checks between)
            for step in row_steps:
                step.apply_row(y, xl, members)
            return y if as_list else np.array((y,), dtype=float)
        for step in self.steps:
            if type(step) is _OwnApply:
                if type(y) is list:
                    y = np.array((y,), dtype=float)
                y = step.apply(y, xi, members, sample, noise)
            else:
                if type(y) is not list:
                    y = y.tolist()[0]
                step.apply_row(y, xl, members)
        if as_list:
            return y
        return np.array((y,), dtype=float) if type(y) is list else y


def state_row_plan(suite: Sensor) -> FusedPlan | None:
    """The fused plan of ``suite`` when it measures one member from the state alone: a plain
    :class:`Suite` whose plan gathers a slice of state columns (:attr:`FusedPlan.whole`)
    and whose steps all run on a row of floats (no decorator's own ``apply``, which may
    read the sample); else None. See :meth:`FusedPlan.measure_state_row`."""
    if type(suite) is not Suite or suite._state_index is not None:
        return None
    plan = suite._plan
    if plan is None or plan.row_steps is None or type(plan.whole_index) is not slice:
        return None
    return plan


def measure_one(suite: Sensor, sample: Sample, noise: Noise) -> Any:
    """``suite.measure(sample, noise)`` of one member (k = 1), the same values: a plain
    :class:`Suite` whose fused plan is current gives its row as the plan ends it (a list of
    floats (m,), or a (1, m) array when a decorator ran its own ``apply``), without the
    (1, m) array of :meth:`Suite.measure`; any other sensor its ``measure`` (1, m)."""
    if type(suite) is Suite and suite._state_index is None:
        plan = suite._plan
        # (Suite.measure's steps on this path; current() is True without walk groups)
        if plan is not None and (not plan.walk_groups or plan.current()):
            xi = noise.normal(plan.draws) if plan.draws else None
            return plan._measure_row(sample, noise, xi, as_list=True)
    return suite.measure(sample, noise)


def build_plan(suite: Suite) -> FusedPlan | None:
    """The :class:`FusedPlan` of an allocated suite, or None when it has a sensor a plan
    cannot fuse or no decorator to fuse (module docstring)."""
    leaves: list[tuple[Sensor, int, int, int]] = []
    decorators: list[tuple[int, Decorator, int, int, int]] = []

    def visit(sensor: Sensor, c0: int, offset: int) -> tuple[int, int]:
        """Record ``sensor`` at column ``c0`` and draw offset ``offset``; its level and the
        draw offset after it."""
        if isinstance(sensor, Suite) and sensor._state_index is None:
            level, c = 0, c0
            for part in sensor.sensors:
                lv, offset = visit(part, c, offset)
                level, c = max(level, lv), c + part.dim
            return level, offset
        total = sensor.draws_per_sample()
        if total is None:
            raise _NotFusable
        if isinstance(sensor, Decorator):
            if type(sensor) not in _KNOWN:
                raise _NotFusable
            level, offset = visit(sensor.inner, c0, offset)
            own = total - sensor.inner.draws_per_sample()
            decorators.append((level + 1, sensor, c0, offset, own))
            return level + 1, offset + own
        leaves.append((sensor, c0, offset, total))  # (a suite of bare state channels: one
        return 0, offset + total                      # gather)

    try:
        visit(suite, 0, 0)
    except _NotFusable:
        return None
    if not decorators:
        return None
    return FusedPlan(suite, leaves, decorators)


#: Suites fuse their decorators through this module (the contract declares the hook,
#: :attr:`testbed.sensors.base.Suite.fuse`, and imports nothing above it).
Suite.fuse = staticmethod(build_plan)
