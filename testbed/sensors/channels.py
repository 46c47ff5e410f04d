"""Measurement channels a rig declares: a state read directly, or a linear combination."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from testbed.sensors.base import Noise, Sample, Sensor, SensorModel


class StateChannel(Sensor):
    """One state component, exactly (decorate it with noise, quantization...).

    Parameters
    ----------
    index : int
        State index.
    n_states, n_inputs : int
        Dimensions of the rig's state and action (for the linear model).
    name, unit : str
        Channel name (usually the state's) and unit.
    """

    def __init__(self, index: int, n_states: int, n_inputs: int, name: str, unit: str):
        self.index = int(index)
        self.n_states, self.n_inputs = int(n_states), int(n_inputs)
        self.names, self.units, self.measured_state = (name,), (unit,), (self.index,)

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``x[:, index]``, shape (k, 1)."""
        return sample.x[:, self.index:self.index + 1]

    def measure_into(self, sample: Sample, noise: Noise, out: np.ndarray) -> None:
        """``x[:, index]`` into ``out`` (k, 1)."""
        out[...] = sample.x[:, self.index:self.index + 1]

    def measure_row(self, sample: Sample, noise: Noise) -> list[float]:
        """``[x[0, index]]``."""
        return [sample.x.item(0, self.index)]

    def direct_state(self) -> int:
        """This channel's state index."""
        return self.index

    def draws_per_sample(self) -> int:
        """0: noise comes from decorators."""
        return 0

    def linear_model(self) -> SensorModel:
        """A unit row of ``C``, no noise."""
        C = np.zeros((1, self.n_states))
        C[0, self.index] = 1.0
        return SensorModel(C=C, D=np.zeros((1, self.n_inputs)), R=np.zeros((1, 1)),
                           Hw=np.zeros((1, 0)), stochastic=np.ones(1, bool))

    def describe(self) -> str:
        """The channel name."""
        return self.names[0]


class LinearChannel(Sensor):
    """``y = C x (+ Hw w)``: the papers' output channels.

    With ``Hw`` and no noise decorator the channels are deterministic (an H-infinity
    filter's ``y2 = C2 x + H w``): a stochastic design leaves them out.

    Parameters
    ----------
    C : ndarray, shape (m, n)
    names, units : sequence of str, length m
    Hw : ndarray, shape (m, s), optional
        Input of the deterministic disturbance ``w``.
    n_inputs : int
        Action dimension (``D = 0``).
    """

    def __init__(self, C: np.ndarray, names: Sequence[str], units: Sequence[str],
                 Hw: np.ndarray | None = None, n_inputs: int = 0):
        self.C = np.atleast_2d(np.asarray(C, dtype=float))
        m = self.C.shape[0]
        if len(names) != m or len(units) != m:
            raise ValueError(f"LinearChannel needs {m} names and units for C of shape "
                             f"{self.C.shape}")
        self.Hw = None if Hw is None else np.atleast_2d(np.asarray(Hw, dtype=float))
        if self.Hw is not None and self.Hw.shape[0] != m:
            raise ValueError(f"Hw must have {m} rows like C, got shape {self.Hw.shape}")
        self.n_inputs = int(n_inputs)
        self.names, self.units = tuple(names), tuple(units)
        self.measured_state = tuple(_unit_row(row) for row in self.C)

    def measure(self, sample: Sample, noise: Noise) -> np.ndarray:
        """``C x (+ Hw w)``, shape (k, m); ``w`` must match ``Hw``."""
        y = np.matvec(self.C, sample.x)
        if self.Hw is None:
            return y
        w = sample.w
        if w.shape[1:] != (self.Hw.shape[1],):
            raise ValueError(f"channels {list(self.names)} need the disturbance w of size "
                             f"{self.Hw.shape[1]}; this scenario's has size {w.shape[1]}")
        return y + np.matvec(self.Hw, w)

    def draws_per_sample(self) -> int:
        """0: noise comes from decorators."""
        return 0

    def linear_model(self) -> SensorModel:
        """``C``, ``Hw``; no noise; deterministic when ``Hw`` is given."""
        m = self.C.shape[0]
        Hw = np.zeros((m, 0)) if self.Hw is None else self.Hw
        return SensorModel(C=self.C.copy(), D=np.zeros((m, self.n_inputs)), R=np.zeros((m, m)),
                           Hw=Hw, stochastic=np.full(m, self.Hw is None))


def _unit_row(row: np.ndarray) -> int | None:
    nz = np.flatnonzero(row)
    return int(nz[0]) if len(nz) == 1 and row[nz[0]] == 1 else None
