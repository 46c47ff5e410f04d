"""Sensor decorators against closed forms and sample statistics, and the period check."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.envs import RigEnv
from testbed.sensors import (
    BiasRandomWalk,
    Delay,
    NoiseStreams,
    Quantize,
    Sample,
    SampleAndHold,
    StateChannel,
    WhiteNoise,
)

N = 2000  # members: sample statistics over members at one instant


def channel() -> StateChannel:
    return StateChannel(0, n_states=2, n_inputs=1, name="angle", unit="rad")


def series(sensor, x_of_k, steps: int, num: int = N, seed0: int = 0) -> np.ndarray:
    """Measurements (steps, num) of ``sensor`` for states ``x_of_k(k) -> (num, 2)``."""
    streams = NoiseStreams(num)
    for i in range(num):
        streams.seed(i, seed0 + i)
    sensor.allocate(num)

    def sample(k):
        return Sample(x_of_k(k), np.full(num, 0.01 * k), np.zeros((num, 1)), np.zeros((num, 0)))

    sensor.reset(sample(0), streams.view(slice(None)))
    return np.array([sensor.measure(sample(k), streams.view(slice(None)))[:, 0]
                     for k in range(steps)])


def test_white_noise_density_gives_the_per_sample_std_and_its_model():
    dt = 0.01
    sensor = WhiteNoise(channel(), density=0.02, dt_s=dt)
    y = series(sensor, lambda k: np.zeros((N, 2)), 3)
    expected = 0.02 / np.sqrt(dt)
    assert np.std(y) == pytest.approx(expected, rel=0.03)
    assert sensor.linear_model().R[0, 0] == pytest.approx(expected**2, rel=1e-12)


def test_quantization_error_is_uniform_with_variance_q2_over_12():
    q = 0.01
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.uniform(-1, 1, N), np.zeros(N)])
    sensor = Quantize(channel(), q)
    y = series(sensor, lambda k: x, 1)[0]
    err = y - x[:, 0]
    assert np.max(np.abs(err)) <= q / 2 + 1e-15
    assert np.var(err) == pytest.approx(q**2 / 12, rel=0.1)
    assert sensor.linear_model().R[0, 0] == pytest.approx(q**2 / 12, rel=1e-12)


def test_bias_random_walk_variance_grows_linearly():
    walk, dt, steps = 0.3, 0.01, 100
    sensor = BiasRandomWalk(channel(), walk=walk, dt_s=dt)
    y = series(sensor, lambda k: np.zeros((N, 2)), steps)
    # b_k is the sum of k increments of variance walk^2 dt
    for k in (25, 99):
        assert np.var(y[k]) == pytest.approx(walk**2 * dt * k, rel=0.1)


def test_delay_and_sample_and_hold_on_a_ramp():
    def ramp(k):
        return np.column_stack([np.full(3, float(k)), np.zeros(3)])

    delayed = series(Delay(channel(), 2), ramp, 6, num=3)[:, 0]
    np.testing.assert_array_equal(delayed, [0, 0, 0, 1, 2, 3])
    held = series(SampleAndHold(channel(), 3), ramp, 7, num=3)[:, 0]
    np.testing.assert_array_equal(held, [0, 0, 0, 3, 3, 3, 6])


def test_sensors_built_for_another_period_are_rejected():
    env = RigEnv("helicopter")
    dt = env.dt_s

    def encoders():
        return env.rig.sensors("encoders", dt_s=dt)

    RigEnv("helicopter", sensors=WhiteNoise(encoders(), density=0.01, dt_s=dt))
    with pytest.raises(ValueError, match="sampling period of 0.02 s but the control period"):
        RigEnv("helicopter", sensors=WhiteNoise(encoders(), density=0.01, dt_s=2 * dt))
    # a sensor behind sample-and-hold samples every 4 periods: built for 4 dt
    RigEnv("helicopter", sensors=SampleAndHold(WhiteNoise(encoders(), density=0.01,
                                                          dt_s=4 * dt), 4))
    with pytest.raises(ValueError, match="sampling period"):
        RigEnv("helicopter", sensors=SampleAndHold(WhiteNoise(encoders(), density=0.01,
                                                              dt_s=dt), 4))
