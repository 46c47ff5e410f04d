"""The hardware helicopter's IMU at any control period: held below its own period, with its
per-sample noise and bias walk of its own period (closed forms)."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.rigs.helicopter.hardware import HelicopterHardware
from testbed.rigs.helicopter.rig import HelicopterRig, hardware_imu
from testbed.sensors import NoiseStreams, Sample

N = 2000  # members: statistics over members at one instant


def _gyro_series(dt_s: float, steps: int) -> np.ndarray:
    """``gyro_pitch`` (steps, N) of the hardware IMU on a rig at rest."""
    imu = hardware_imu(HelicopterHardware(), dt_s)
    streams = NoiseStreams(N)
    for i in range(N):
        streams.seed(i, i)
    imu.allocate(N)

    def sample(k: int) -> Sample:
        return Sample(np.zeros((N, 4)), np.full(N, dt_s * k), np.zeros((N, 2)),
                      np.zeros((N, 0)))

    imu.reset(sample(0), streams.view(slice(None)))
    return np.array([imu.measure(sample(k), streams.view(slice(None)))[:, 0]
                     for k in range(steps)])


@pytest.mark.parametrize("frame_skip", [1, 2, 3, 5, 7, 10, 20, 50])
def test_every_control_period_builds_sensors_for_that_period(frame_skip: int) -> None:
    dt_s = 0.001 * frame_skip
    sensors = HelicopterRig(profile="hardware").sensors(None, dt_s=dt_s)
    periods = sensors.sample_periods_s()
    assert periods and all(p == pytest.approx(dt_s, rel=1e-9) for p in periods)


def test_a_fast_loop_holds_the_imu_sample_with_the_imu_noise_per_sample() -> None:
    """At 1 kHz the 100 Hz IMU gives a new value every 10 steps; the difference of two
    successive values has the variance ``2 sigma^2 + walk^2 T`` of the IMU's own period
    ``T`` (``sigma = density / sqrt(T)``), as at a 100 Hz loop."""
    hw = HelicopterHardware()
    T = 1.0 / hw.imu_rate_hz
    expected = 2 * hw.gyro_noise_density**2 / T + hw.gyro_bias_walk**2 * T
    fast = _gyro_series(0.001, 60)
    changes = np.flatnonzero(np.any(np.diff(fast, axis=0) != 0, axis=1)) + 1
    assert np.array_equal(np.diff(changes), np.full(len(changes) - 1, 10))
    assert np.var(fast[changes[1]] - fast[changes[0]]) == pytest.approx(expected, rel=0.1)
    slow = _gyro_series(T, 6)
    assert np.var(slow[3] - slow[2]) == pytest.approx(expected, rel=0.1)
