"""The 2-DOF helicopter rig (``helicopter_2dof.xml`` beside :mod:`.rig`)."""

from testbed.rigs.helicopter.rig import (
    ACTION_NAMES,
    DEFAULT_SETPOINTS,
    GRAVITY_M_S2,
    PITCH_LIMIT_RAD,
    STATE_NAMES,
    VOLTAGE_LIMIT_V,
    HelicopterParams,
    HelicopterRig,
    LinearModel,
    gravity_voltage,
    paper_model,
)

__all__ = ["ACTION_NAMES", "DEFAULT_SETPOINTS", "GRAVITY_M_S2", "PITCH_LIMIT_RAD",
           "STATE_NAMES", "VOLTAGE_LIMIT_V", "HelicopterParams", "HelicopterRig", "LinearModel",
           "gravity_voltage", "paper_model"]
