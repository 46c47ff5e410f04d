"""Sensors drawing their noise from streams of their own, derived from the members' seeds.

Every sensor of a suite draws from its member's one stream, in order
(:class:`~testbed.sensors.base.NoiseStreams`): a channel added to a suite that draws noise
moves every later draw, and so changes the numbers of the channels already there.
:class:`OwnStream` gives the sensor it wraps a stream of its own per member instead: a child
of the member's seed (:class:`numpy.random.SeedSequence` with the member's entropy and spawn
key, extended by the wrapper's ``key``; O'Neill 2014, numpy's independent streams). The
member's stream draws nothing for it (``draws_per_sample() == 0``), so the other channels'
numbers stay what they were, bitwise; the wrapped sensor's noise is as reproducible as
theirs (same seed, same values) and independent of them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from testbed.sensors.base import Members, Noise, Sample, Sensor, SensorModel


class _Streams:
    """One generator per member, drawn one member at a time."""

    __slots__ = ("generators",)

    def __init__(self, num: int):
        self.generators: list[np.random.Generator | None] = [None] * num

    def normal(self, d: int, members: Members) -> np.ndarray:
        index = np.arange(len(self.generators))[members]
        out = np.empty((len(index), d))
        for row, i in enumerate(index.tolist()):
            out[row] = self.generators[i].standard_normal(d)
        return out


class _View:
    """The streams of some members as a noise source (``normal(d) -> (k, d)``)."""

    __slots__ = ("streams", "members")

    def __init__(self, streams: _Streams, members: Members):
        self.streams, self.members = streams, members

    def normal(self, d: int) -> np.ndarray:
        return self.streams.normal(d, self.members)


def child_generator(parent: np.random.Generator | None, key: int, member: int
                    ) -> np.random.Generator:
    """A generator independent of ``parent``, derived from its seed sequence.

    Parameters
    ----------
    parent : numpy.random.Generator or None
        The member's own generator (None: the member has none; the child then derives from
        the member index alone).
    key : int
        Appended to the parent's spawn key (distinct keys: distinct streams).
    member : int
        The member's index (used only without a parent).
    """
    seq = None if parent is None else parent.bit_generator.seed_seq
    if isinstance(seq, np.random.SeedSequence):
        child = np.random.SeedSequence(seq.entropy, spawn_key=(*seq.spawn_key, int(key)))
    else:
        child = np.random.SeedSequence(int(member), spawn_key=(int(key),))
    return np.random.Generator(np.random.PCG64(child))


class OwnStream(Sensor):
    """``inner`` measured with noise from a stream of its own per member (module docstring).

    A member's stream is made at its first reset from the generator its parent stream has
    then; a later reset that keeps that generator (``reset(seed=None)``) keeps the child's
    stream going, one that replaces it (a new seed) starts the child anew.

    Parameters
    ----------
    inner : Sensor
    key : int
        Distinguishes this wrapper's streams from those of other ``OwnStream`` wrappers of
        the same suite (default 1).
    """

    def __init__(self, inner: Sensor, key: int = 1):
        if not isinstance(inner, Sensor):
            raise ValueError(f"inner must be a Sensor, got {inner!r}")
        if isinstance(key, bool) or not isinstance(key, int | np.integer) or key < 0:
            raise ValueError(f"key must be an integer >= 0, got {key!r}")
        self.inner, self.key = inner, int(key)
        self.names, self.units = inner.names, inner.units
        self.measured_state = inner.measured_state
        self._streams = _Streams(0)
        self._parents: list[Any] = []

    def allocate(self, num: int) -> None:
        """Allocate the inner sensor and one stream per member."""
        self.inner.allocate(num)
        self._streams = _Streams(num)
        self._parents = [None] * num

    def _members(self, sample: Sample) -> np.ndarray:
        return np.arange(len(self._parents))[sample.members]

    def reset(self, sample: Sample, noise: Noise) -> None:
        """(Re)derive the members' streams from their parents' generators, then reset the
        inner sensor with them."""
        # a simulator's streams (Noise) or a stream decorator's (_View): the members' own
        parents = noise.streams.generators if isinstance(noise, Noise | _View) else None
        for i in self._members(sample).tolist():
            parent = parents[i] if parents is not None else None
            if self._streams.generators[i] is None or parent is not self._parents[i]:
                self._streams.generators[i] = child_generator(parent, self.key, i)
                self._parents[i] = parent
        self.inner.reset(sample, _View(self._streams, sample.members))

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """The inner sensor's measurement with its own streams: (k, m)."""
        return self.inner.measure(sample, _View(self._streams, sample.members))

    def draws_per_sample(self) -> int:
        """0: the members' own streams draw nothing for it."""
        return 0

    def sample_periods_s(self) -> set[float]:
        """The inner sensor's."""
        return self.inner.sample_periods_s()

    def linear_model(self) -> SensorModel:
        """The inner sensor's."""
        return self.inner.linear_model()

    def describe(self) -> str:
        """``own-stream(<inner>)``."""
        return f"own-stream({self.inner.describe()})"
