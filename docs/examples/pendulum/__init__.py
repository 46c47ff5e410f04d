"""A user's rig from outside the package: a damped pendulum with a torque motor."""

from dataclasses import dataclass

from testbed.rigs import register_rig
from testbed.rigs.base import Params, Rig
from testbed.sensors import Quantize, StateChannel, Suite, WhiteNoise


@dataclass(frozen=True)
class PendulumParams(Params):
    """Physical parameters (SI)."""

    mass_kg: float = 1.0
    damping: float = 0.05


class PendulumRig(Rig):
    """A pendulum hanging from a hinge; the action is the motor torque in N m."""

    name = "pendulum"
    xml_path = "pendulum.xml"          # beside this file
    params_type = PendulumParams
    joints = ("hinge",)
    state_names = ("angle", "angle_rate")
    state_units = ("rad", "rad/s")
    action_names = ("torque",)
    action_units = ("N m",)
    action_low, action_high = (-5.0,), (5.0,)
    tracked_states = ("angle",)
    state_envelope = (float("inf"), 200.0)  # it may swing over; 200 rad/s means divergence

    def apply_params(self, model, params):
        body = self.body_id("arm")
        model.body_mass[body] = params.mass_kg
        model.dof_damping[self.dof_adr[0]] = params.damping

    def sensors(self, preset=None, *, dt_s=0.01, noise_std_rad=0.001):
        """One noisy, quantized angle encoder."""
        angle = StateChannel(0, 2, 1, "angle", "rad")
        return Suite(WhiteNoise(Quantize(angle, 2e-3), std=noise_std_rad))


register_rig(PendulumRig)   # the one registration line
