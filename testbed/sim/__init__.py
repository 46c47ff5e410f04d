"""The simulator and its factory: the only MuJoCo reset/step of the rigs."""

from testbed.sim.factory import build_simulator
from testbed.sim.simulator import Simulator

__all__ = ["Simulator", "build_simulator"]
