"""The 2-DOF helicopter rig (``helicopter_2dof.xml`` beside :mod:`testbed.rigs.helicopter.rig`)."""

from testbed.rigs.helicopter.hardware import HelicopterHardware
from testbed.rigs.helicopter.rig import (
    ACTION_NAMES,
    DEFAULT_SETPOINTS,
    GRAVITY_M_S2,
    PAPER_GAMMA,
    PAPER_INITIAL_WEIGHT,
    PITCH_LIMIT_RAD,
    STATE_NAMES,
    VOLTAGE_LIMIT_V,
    HelicopterParams,
    HelicopterRig,
    LinearModel,
    basin_helicopter_disturbance,
    basin_helicopter_w,
    gravity_voltage,
    paper_model,
)

__all__ = ["ACTION_NAMES", "DEFAULT_SETPOINTS", "GRAVITY_M_S2", "PAPER_GAMMA",
           "PAPER_INITIAL_WEIGHT", "PITCH_LIMIT_RAD", "HelicopterHardware",
           "STATE_NAMES", "VOLTAGE_LIMIT_V", "HelicopterParams", "HelicopterRig", "LinearModel",
           "basin_helicopter_disturbance", "basin_helicopter_w", "gravity_voltage", "paper_model"]
