"""The recording simulation: the simulator with the recorded inputs reproduces a unit."""

from __future__ import annotations

import numpy as np
import pytest
from identify_units import HELI_FREE, TinyRig, helicopter_unit, tiny_unit, vehicle_unit

from testbed.identify import IdentificationError, simulate_recording
from testbed.identify.simulate import RecordingModel
from testbed.rigs.helicopter.rig import HelicopterRig
from testbed.rigs.vehicle_roll.rig import VehicleRollRig


def test_helicopter_hardware_unit_is_reproduced_at_its_scales():
    rec, scales = helicopter_unit(0, duration_s=2.0, noise_free=True)
    pred = simulate_recording(HelicopterRig, rec, profile="hardware", sensors="encoders+gyros",
                              params_scales=[scales, {}])
    y = rec.channel_matrix(("pitch", "yaw", "pitch_rate", "yaw_rate"))
    assert pred.shape == (2, rec.n_samples, 4)
    assert np.max(np.abs(pred[0] - y)) < 1e-9  # the same simulator, the same physics
    assert np.max(np.abs(pred[1] - y)) > 1e-2  # nominal is another rig
    # the (K, p) array over the declared identifiable fields is the same as the dicts
    names = tuple(HelicopterRig.identifiable)
    row = [scales.get(n, 1.0) for n in names]
    again = simulate_recording(HelicopterRig, rec, profile="hardware", sensors="encoders+gyros",
                               params_scales=np.array([row]))
    np.testing.assert_array_equal(again[0], pred[0])
    assert set(scales) == set(HELI_FREE)


def test_vehicle_unit_with_step_noise_is_reproduced_up_to_the_noise():
    # the unit's damping noise (D_n w_k) is held at its mean in the prediction
    rec, scales = vehicle_unit(1, duration_s=3.0, noise_free=True)
    pred = simulate_recording(VehicleRollRig, rec, profile="hardware", sensors="imu",
                              params_scales=[scales], channels=["roll_rate", "lateral_accel"])
    y = rec.channel_matrix(("roll_rate", "lateral_accel"))
    err = np.abs(pred[0] - y).max(axis=0)
    assert np.all(err < 2e-3 * np.abs(y).max(axis=0))


def test_a_period_that_is_no_multiple_of_the_physics_step():
    # 400 Hz: three physics steps of 0.833 ms per sample, not a drifting clock
    rec, scales = tiny_unit(0, duration_s=2.0, dt_s=0.0025)
    model = RecordingModel(TinyRig, rec, profile="paper")
    assert model.frame_skip == 3
    assert model.physics_dt_s == pytest.approx(0.0025 / 3)
    truth = simulate_recording(TinyRig, rec, params_scales=[scales], x0=np.zeros(2))[0]
    from testbed.identify.synthetic import simulated_recording
    clean = simulated_recording(TinyRig, rec.input_matrix(("force",)), dt_s=0.0025,
                                scales=scales, noise_free=True)
    np.testing.assert_allclose(truth[:, 0], clean.channels["position"], atol=1e-12)


def test_bad_inputs_are_one_line_errors():
    rec, _ = tiny_unit(0, duration_s=1.0)
    with pytest.raises(IdentificationError, match="no channel 'velocity'|'velocity' is not"):
        simulate_recording(TinyRig, rec, channels=["velocity"])
    with pytest.raises(IdentificationError, match="params_scales"):
        simulate_recording(TinyRig, rec, params_scales=np.ones((2, 5)))
    with pytest.raises(IdentificationError, match="unknown profile"):
        simulate_recording(TinyRig, rec, profile="hardware")
    bad = rec.segment(0, rec.n_samples)
    bad.inputs.pop("force")
    with pytest.raises(IdentificationError, match="no input 'force'"):
        simulate_recording(TinyRig, bad)
