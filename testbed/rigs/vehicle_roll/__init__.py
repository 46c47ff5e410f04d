"""The vehicle roll rig (``vehicle_roll.xml`` beside :mod:`testbed.rigs.vehicle_roll.rig`)."""

from testbed.rigs.vehicle_roll.model import (
    A_Y_LIMIT_M_S2,
    ACTION_NAMES,
    PAPER_PERIOD_S,
    STATE_NAMES,
    PaperModel,
    VehicleRollParams,
    paper_disturbance,
    paper_model,
    physical_model,
)
from testbed.rigs.vehicle_roll.rig import ROLLOVER_RAD, VehicleRollRig, process_noise_intensity

__all__ = ["A_Y_LIMIT_M_S2", "ACTION_NAMES", "PAPER_PERIOD_S", "ROLLOVER_RAD", "STATE_NAMES",
           "PaperModel", "VehicleRollParams", "VehicleRollRig", "paper_disturbance",
           "paper_model", "physical_model", "process_noise_intensity"]
