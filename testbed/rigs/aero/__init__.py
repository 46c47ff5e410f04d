"""The Quanser Aero 2-DOF helicopter rig (``models/aero.xml``)."""

from testbed.rigs.aero.hardware import AeroHardware
from testbed.rigs.aero.imu import AeroIMU
from testbed.rigs.aero.motors import MOTOR_CHANNELS, AeroMotor, AeroMotors, hardware_motors
from testbed.rigs.aero.rig import (
    ACTION_NAMES,
    DEFAULT_SETPOINTS,
    ENCODER_COUNTS,
    LOCKED_SETPOINTS,
    LOCKED_STATE_NAMES,
    STATE_NAMES,
    VOLTAGE_LIMIT_V,
    AeroParams,
    AeroRig,
    hardware_imu,
    quanser_model,
)

__all__ = ["ACTION_NAMES", "DEFAULT_SETPOINTS", "ENCODER_COUNTS", "LOCKED_SETPOINTS",
           "LOCKED_STATE_NAMES", "MOTOR_CHANNELS", "STATE_NAMES", "VOLTAGE_LIMIT_V",
           "AeroHardware", "AeroIMU", "AeroMotor", "AeroMotors", "AeroParams", "AeroRig",
           "hardware_imu", "hardware_motors", "quanser_model"]
