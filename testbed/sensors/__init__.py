"""Sensors: one batched contract, channels a rig declares, decorators for any rig.

See :mod:`testbed.sensors.base` for the contract, :mod:`testbed.sensors.channels` for the
generic channels and :mod:`testbed.sensors.decorators` for quantization, noise, biases,
delay and sample-and-hold.
"""

from testbed.sensors import fused as _fused  # noqa: F401  (sets Suite.fuse: the fused plans)
from testbed.sensors.base import (
    ChannelFunctions,
    Drawn,
    Noise,
    NoiseStreams,
    Sample,
    Sensor,
    SensorModel,
    Suite,
    no_input_gradient,
    reads_actuators,
)
from testbed.sensors.channels import LinearChannel, StateChannel
from testbed.sensors.decorators import (
    Bias,
    BiasRandomWalk,
    Decorator,
    Delay,
    Quantize,
    SampleAndHold,
    ScaleFactor,
    Tap,
    WhiteNoise,
)

__all__ = ["Bias", "BiasRandomWalk", "ChannelFunctions", "Decorator", "Delay", "Drawn",
           "LinearChannel", "Noise", "NoiseStreams", "Quantize", "Sample", "SampleAndHold",
           "ScaleFactor", "Sensor", "SensorModel", "StateChannel", "Suite", "Tap", "WhiteNoise",
           "no_input_gradient", "reads_actuators"]
