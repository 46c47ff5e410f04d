"""Randomness by default: documented initial-state distributions and ambient disturbances."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.envs import RigVectorEnv
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs.helicopter.rig import (
    AMBIENT_NOISE_RAD_S15,
    PITCH_LIMIT_RAD,
    X0_YAW_RATE_STD_RAD_S,
    X0_YAW_STD_RAD,
)
from testbed.rigs.vehicle_roll import rig as vehicle


@pytest.mark.parametrize("rig, std", [
    ("helicopter", [0.0, X0_YAW_STD_RAD, 0.0, X0_YAW_RATE_STD_RAD_S]),
    ("vehicle-roll", list(vehicle.X0_STD)),
])
def test_initial_state_has_the_documented_distribution(rig, std):
    n = 1000
    env = RigVectorEnv(n, rig=rig, num_threads=1)
    _, info = env.reset(seed=0)
    x0 = info["state"]
    env.close()
    np.testing.assert_allclose(x0.std(axis=0), std, rtol=0.1, atol=1e-12)
    np.testing.assert_allclose(x0.mean(axis=0) - (x0.mean(axis=0) * (np.array(std) == 0)),
                               0.0, atol=4 * max(std) / np.sqrt(n))
    if rig == "helicopter":  # still, on the lower stop
        np.testing.assert_array_equal(x0[:, 0], -PITCH_LIMIT_RAD)
    # scaled spread
    env = RigVectorEnv(n, rig=rig, num_threads=1, reset_noise_scale=2.0)
    _, info = env.reset(seed=0)
    env.close()
    np.testing.assert_allclose(info["state"], 2 * x0 - (np.array(std) == 0) * x0, atol=1e-15)


@pytest.mark.parametrize("rig, b", [("helicopter", AMBIENT_NOISE_RAD_S15),
                                    ("vehicle-roll", vehicle.AMBIENT_NOISE_RAD_S15)])
def test_ambient_disturbance_intensity(rig, b):
    env = RigVectorEnv(200, rig=rig, num_threads=1)
    env.reset(seed=0)
    accel = []
    for _ in range(20):
        _, _, _, _, info = env.step(np.zeros(env.action_space.shape))
        accel.append(info["process_accel"])
    env.close()
    accel = np.concatenate(accel)
    # Euler-Maruyama: b xi / sqrt(dt) held over the control period dt
    np.testing.assert_allclose(accel.std(axis=0), b / np.sqrt(0.01), rtol=0.05)
    design = runner.build(Scenario(rig=rig)).design
    quiet = runner.build(Scenario(rig=rig, ambient_noise=0.0)).design
    dq = design.continuous.Q - quiet.continuous.Q
    j = dq.shape[0] // 2
    np.testing.assert_allclose(np.diag(dq)[j:], b**2, rtol=1e-12)


def test_reset_options_x0_draws_nothing():
    """An explicit x0 keeps the noise streams where the papers' fixed-x0 runs have them."""
    a = RigVectorEnv(2, rig="vehicle-roll", num_threads=1)
    b = RigVectorEnv(2, rig="vehicle-roll", num_threads=1, reset_noise_scale=0.0)
    obs_a, _ = a.reset(seed=3, options={"x0": np.zeros(2)})
    obs_b, _ = b.reset(seed=3, options={"x0": np.zeros(2)})
    np.testing.assert_array_equal(obs_a, obs_b)
    for _ in range(5):
        np.testing.assert_array_equal(a.step(np.zeros((2, 1)))[0], b.step(np.zeros((2, 1)))[0])
    with pytest.raises(ValueError, match="reset_noise_scale"):
        RigVectorEnv(1, rig="vehicle-roll", reset_noise_scale=-1.0)
    with pytest.raises(ValueError, match="ambient_noise"):
        RigVectorEnv(1, rig="vehicle-roll", ambient_noise=float("nan"))


@pytest.mark.parametrize("rig", ["helicopter", "vehicle-roll"])
def test_monte_carlo_on_defaults_gives_a_spread(rig):
    result = runner.monte_carlo(Scenario(rig=rig, duration_s=2.0), 8, progress=False)
    for name, stats in result["rmse"].items():
        assert stats["q05"] < stats["q95"], name
        assert len(set(result["rmse_per_run"][name])) == 8
    # the paper settings: fixed x0, no ambient disturbance, noiseless paper helicopter sensors
    if rig == "helicopter":
        fixed = runner.monte_carlo(Scenario(rig=rig, duration_s=2.0, reset_noise_scale=0.0,
                                            ambient_noise=0.0), 4, progress=False)
        assert len(set(fixed["rmse_per_run"]["pitch"])) == 1


@pytest.mark.parametrize("block, sizes", [(10, [3, 3, 3, 3, 2, 4, 1, 5]), (8, [4, 4, 4, 1, 7]),
                                          (6, [6, 6, 2, 5, 0, 4])])
def test_every_stream_draws_its_generators_values_across_refills(block, sizes):
    """``NoiseStreams.draw_all`` (all streams at one position, refilled together: the values
    left moved in one copy, overlapping or not) gives each member its own generator's
    values in order, bitwise: the same as drawing member by member."""
    from gymnasium.utils import seeding

    from testbed.sensors import NoiseStreams

    seeds = [7, 0, 12345]
    streams = NoiseStreams(len(seeds), block)
    one_by_one = NoiseStreams(len(seeds), block)
    for i, seed in enumerate(seeds):
        streams.seed(i, seed)
        one_by_one.seed(i, seed)
    together = np.concatenate([streams.draw_all(d) for d in sizes], axis=1)
    alone = np.concatenate([np.concatenate([one_by_one.draw(d, np.array([i])) for d in sizes],
                                           axis=1) for i in range(len(seeds))])
    expected = np.array([seeding.np_random(s)[0].standard_normal(sum(sizes) + 2 * block)
                         [:sum(sizes)] for s in seeds])
    assert together.tobytes() == expected.tobytes() == alone.tobytes()
