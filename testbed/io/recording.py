"""A recording: time plus a rig's inputs and sensor channels, no truth.

What a real unit's log holds (and what ``testbed run --save-log`` writes for a simulated one):
the time stamps, the inputs the rig received (named as the rig's ``action_names``) and the
channels its sensors gave (named as the sensor suite's ``names``). A recording may hold a
subset of the channels. Readers and writers of files are in :mod:`testbed.io.formats`.

Row ``k`` holds the time ``t_k``, the channels the sensors gave at ``t_k`` and the inputs
applied from ``t_k`` to ``t_{k+1}`` (a real rig's data logger: the command computed after
reading row ``k``, held over the next step).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np


class RecordingError(ValueError):
    """A recording that cannot be used: one line naming the file, the column and the row."""


@dataclasses.dataclass(frozen=True)
class Recording:
    """Time, inputs and sensor channels of one recorded run.

    Attributes
    ----------
    time_s : ndarray, shape (N,)
        Sample times, s, strictly increasing at a uniform rate.
    inputs : dict of str to ndarray, shape (N,)
        The rig's inputs by action name (e.g. ``V_pitch``), SI units.
    channels : dict of str to ndarray, shape (N,)
        Sensor channels by name (e.g. ``pitch``, ``gyro_pitch``), SI units (rad, rad/s).
    source : str
        Where it came from (a file name), for messages.
    sha256 : str
        sha256 (hex) of the file's bytes ("" when not read from a file).
    meta : dict
        Anything else the file said (rig, profile, seed of a simulated unit); never truth.
    """

    time_s: np.ndarray
    inputs: dict[str, np.ndarray]
    channels: dict[str, np.ndarray]
    source: str = "<memory>"
    sha256: str = ""
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        """Number of samples ``N``."""
        return int(self.time_s.shape[0])

    @property
    def dt_s(self) -> float:
        """The sample period, s (the median step; uniform by construction)."""
        return float(np.median(np.diff(self.time_s))) if self.n_samples > 1 else 0.0

    def input_matrix(self, names: tuple[str, ...]) -> np.ndarray:
        """The inputs in the order ``names``, shape (N, len(names))."""
        return np.column_stack([self.inputs[n] for n in names]) if names else \
            np.zeros((self.n_samples, 0))

    def channel_matrix(self, names: tuple[str, ...]) -> np.ndarray:
        """The channels in the order ``names``, shape (N, len(names))."""
        return np.column_stack([self.channels[n] for n in names]) if names else \
            np.zeros((self.n_samples, 0))

    def segment(self, start: int, stop: int) -> Recording:
        """Samples ``start:stop`` as a recording (same source and sha256)."""
        cut = slice(start, stop)
        return dataclasses.replace(
            self, time_s=self.time_s[cut], inputs={k: v[cut] for k, v in self.inputs.items()},
            channels={k: v[cut] for k, v in self.channels.items()})
