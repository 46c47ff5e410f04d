"""Identification from the Aero's rotor speeds and motor currents: channels read from MuJoCo's
actuator states, fitted when named, which determine the rotor time constants."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.identify import IdentificationError, identify
from testbed.identify.synthetic import random_steps, simulated_recording
from testbed.rigs.aero import MOTOR_CHANNELS, AeroRig

LOCKED = {"yaw_locked": True}
SCALES = {"K_pp": 1.2, "rotor_time_constant_pitch_s": 1.5, "rotor_time_constant_yaw_s": 0.7}


@pytest.fixture(scope="module")
def unit():
    """A yaw-locked Aero (hardware profile, its default sensors) at hidden scales, 1.5 s of
    random voltage steps at 500 Hz."""
    dt = 0.002
    n = int(round(1.5 / dt))
    u = random_steps(np.random.default_rng(0), n, dt, [-10, -10], [14, 10], hold_s=(0.1, 0.4),
                     still_s=0.3)
    return simulated_recording(AeroRig, u, dt_s=dt, profile="hardware", options=LOCKED,
                               scales=SCALES, seed=1)


def _half_widths(res) -> dict:
    return {k: (res.parameters[k].ci95[1] - res.parameters[k].ci95[0]) / 2
            / res.parameters[k].nominal for k in SCALES}


def test_rotor_channels_determine_the_rotor_time_constants(unit):
    assert set(MOTOR_CHANNELS) <= set(unit.channels)
    plain = identify(AeroRig, unit, options=LOCKED, free=list(SCALES), method="output-error")
    assert not set(MOTOR_CHANNELS) & set(plain.channels)  # not fitted by default
    named = ["pitch", "gyro_pitch", "accel_x", "rotor_speed_pitch", "rotor_speed_yaw",
             "current_pitch"]
    motors = identify(AeroRig, unit, options=LOCKED, free=list(SCALES), channels=named,
                      method="output-error")
    assert motors.channels == tuple(named)
    for name, truth in SCALES.items():
        p = motors.parameters[name]
        assert p.identifiable and p.scale == pytest.approx(truth, rel=0.01), name
        lo, hi = np.asarray(p.ci95) / p.nominal
        assert lo <= truth <= hi, (name, lo, hi)
    wide, narrow = _half_widths(plain), _half_widths(motors)
    for name in ("rotor_time_constant_pitch_s", "rotor_time_constant_yaw_s"):
        assert narrow[name] < wide[name] / 3, (name, narrow[name], wide[name])
    assert min(motors.fit_percent[c] for c in named[3:]) > 95.0


def test_an_input_channel_that_reads_no_actuator_is_still_refused():
    from identify_units import vehicle_unit

    from testbed.rigs.vehicle_roll.rig import VehicleRollRig

    rec, _ = vehicle_unit(0, duration_s=1.0)
    inputs = [n for n in rec.channels if n not in ("roll_rate", "lateral_accel")]
    if not inputs:
        pytest.skip("the vehicle's hardware recording has no input channel")
    with pytest.raises(IdentificationError, match="is an input channel"):
        identify(VehicleRollRig, rec, free=["roll_stiffness"], channels=[inputs[0]])
