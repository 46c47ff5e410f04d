"""The one-member step's state-only sensor path (``fused.state_row_plan``): bitwise the
batch's measurement, with the plan's normals after step-noise and disturbance draws, and
back on the sample path when the suite is fused again."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.sensors import BiasRandomWalk, Quantize, StateChannel, Suite, WhiteNoise
from testbed.sim import build_simulator


def _suite(n: int, nu: int) -> Suite:
    """Walk, white noise and quantization across every state channel (a fused plan of row
    steps only, with normals)."""
    channels = [StateChannel(i, n, nu, f"x{i}", "u") for i in range(n)]
    return Suite(Quantize(WhiteNoise(BiasRandomWalk(Suite(*channels), walk=0.05, dt_s=0.01,
                                                    initial_std=0.01), std=0.003), 1e-3))


@pytest.mark.parametrize("rig", ["helicopter", "vehicle-roll"])
def test_state_row_path_equals_a_member_of_a_batch(rig):
    """Observations and infos of the one-member path equal member 1 of a batch, bitwise,
    before and after a walk's state is replaced (the suite fused again)."""
    probe = build_simulator(rig, 1, num_threads=1)
    n, nu = probe.rig.n_states, probe.rig.n_actions
    probe.close()
    one = build_simulator(rig, 1, num_threads=1, sensors=_suite(n, nu))
    many = build_simulator(rig, 3, num_threads=2, sensors=_suite(n, nu))
    assert one._row_plan is not None and one._row_plan is one.sensors._plan
    one.reset(None, [7], None)
    many.reset(None, [5, 7, 9], None)
    rng = np.random.default_rng(2)
    high = np.asarray(one.rig.action_high)
    for k in range(30):
        if k == 10:  # a walk's state replaced: the plan is not current, the suite refuses
            for sim in (one, many):
                walk = sim.sensors.sensors[0].inner.inner
                walk.bias = walk.bias + 0.25
        u = rng.uniform(-1.2, 1.2, (3, nu)) * high
        one.step(u[1:2])
        many.step(u)
        assert one.obs.tobytes() == many.obs[1:2].tobytes()
        got, expected = one.member_info(0), many.member_info(1)
        for key, value in got.items():
            assert np.asarray(value).tobytes() == np.asarray(expected[key]).tobytes(), key
    assert one._row_plan is one.sensors._plan  # (looked up again after the refusion)
    one.close()
    many.close()


def test_rint_near_the_integer_range_is_numpys():
    """``fused._rint`` (``(|q| + 2**52) - 2**52`` with q's sign below 2**52) is ``np.rint``
    bitwise: ties to even up to 2**52, half-ulp neighbours of ties, signed zeros,
    subnormals, huge and non-finite values."""
    from testbed.sensors.fused import _rint

    rng = np.random.default_rng(3)
    k = rng.integers(-2**53, 2**53, 20000)
    ties = np.arange(-2000, 2000) + 0.5
    values = np.concatenate([
        k / 2.0, k + 0.5, ties, np.nextafter(ties, np.inf), np.nextafter(ties, -np.inf),
        rng.uniform(-2.0**53, 2.0**53, 20000), rng.normal(0, 1e3, 20000),
        [2.0**51 + 0.5, 2.0**52 - 1.5, 2.0**52 - 0.5, -2.0**52 + 0.5, 2.0**52, 2.0**53,
         np.nextafter(2.0**52, 0), 0.49999999999999994, -0.49999999999999994, 0.0, -0.0,
         5e-324, -5e-324, 1e300, -1e300, np.inf, -np.inf, np.nan]])
    got = np.array([_rint(v) for v in values.tolist()])
    assert got.tobytes() == np.rint(values).tobytes()
