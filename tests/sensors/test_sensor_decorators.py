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


PRESETS = [("helicopter", p, o) for p in ("encoders", "encoders+gyros", "paper", "hardware")
           for o in ({}, {"noise_std_rad": 1e-3})] + \
          [("vehicle-roll", p, o) for p in ("imu", "paper", "hardware")
           for o in ({}, {"noise_std": 0.01} if p == "paper" else {"roll_sensor": True})]


@pytest.mark.parametrize("rig, preset, options", PRESETS,
                         ids=[f"{r}-{p}-{bool(o)}" for r, p, o in PRESETS])
def test_declared_draws_are_the_draws_a_sample_takes(rig, preset, options):
    """``draws_per_sample`` (the simulator draws that many with the step's own) equals what
    ``measure`` takes from the streams, sample after sample; None only with a hold."""
    from testbed.rigs import resolve_rig

    sensors = resolve_rig(rig)().sensors(preset, **options)
    declared = sensors.draws_per_sample()
    assert (declared is None) == ("sampleandhold" in sensors.describe())
    if declared is None:
        return
    num, n = 3, 4 if rig == "helicopter" else 2
    streams = NoiseStreams(num)
    for i in range(num):
        streams.seed(i, i)
    sensors.allocate(num)
    w = np.zeros((num, 1 if preset == "paper" and rig == "vehicle-roll" else 0))
    sample = Sample(np.full((num, n), 0.01), np.zeros(num), np.ones((num, 2 if n == 4 else 1)),
                    w, slice(None))
    sensors.reset(sample, streams.view(slice(None)))
    for _ in range(3):
        before = streams._pos.copy()
        sensors.measure(sample, streams.view(slice(None)))
        np.testing.assert_array_equal((streams._pos - before) % streams.block, declared)


@pytest.mark.parametrize("declared, message", [(0, "drew more than the 0 normals"),
                                               (2, "drew 1 normals per sample but declare 2")])
def test_a_sensor_drawing_other_than_it_declares_is_named(declared, message):
    class Liar(WhiteNoise):
        own_draws = declared  # draws one per sample all the same

    env = RigEnv("vehicle-roll", sensors=Liar(channel(), std=0.1), reset_noise_scale=0.0)
    env.reset(seed=0)
    with pytest.raises(RuntimeError, match=message):
        env.step(np.zeros(1))


def _assert_measures_alike(fused, plain, streams, smp, one: bool) -> None:
    """``fused`` (through ``measure_one`` when ``one``) measures ``smp`` bitwise as
    ``plain`` does, each from its own streams."""
    from testbed.sensors.fused import measure_one

    members = smp.members
    if one:
        a = np.asarray(measure_one(fused, smp, streams[0].view(members)),
                       dtype=float).reshape(1, -1)
    else:
        a = fused.measure(smp, streams[0].view(members))
    b = plain.measure(smp, streams[1].view(members))
    assert a.tobytes() == b.tobytes()


def _with_plain_copy(fused, num: int, seed0: int):
    """A copy of ``fused`` measured sensor by sensor (no plan), both allocated for ``num``
    members, and a set of noise streams for each (member ``i`` seeded ``seed0 + i``)."""
    import copy

    plain = copy.deepcopy(fused)
    streams = []
    for suite in (fused, plain):
        suite.allocate(num)
        streams.append(NoiseStreams(num))
        for i in range(num):
            streams[-1].seed(i, seed0 + i)
    plain._plan = None  # sensor by sensor
    return plain, streams


@pytest.mark.parametrize("rig, preset, options", PRESETS,
                         ids=[f"{r}-{p}-{bool(o)}" for r, p, o in PRESETS])
def test_fused_suite_equals_sensor_by_sensor(rig, preset, options):
    """A suite's decorators applied across channels (:mod:`testbed.sensors.fused`) give
    bitwise the values and the per-member state of measuring sensor by sensor, for the
    whole batch, for a subset of members and for one member (a row of Python floats, also
    through :func:`~testbed.sensors.fused.measure_one`, the one-member simulator's call),
    also in a copy made mid-episode."""
    import copy

    from testbed.rigs import resolve_rig
    from testbed.sensors import Suite

    sensors = resolve_rig(rig)().sensors(preset, **options)
    fused = sensors if isinstance(sensors, Suite) else Suite(sensors)
    num, n = 4, 4 if rig == "helicopter" else 2
    plain, streams = _with_plain_copy(fused, num, 10)
    if rig == "vehicle-roll" and preset == "imu":
        assert fused._plan is not None
    rng = np.random.default_rng(0)
    s = 1 if preset == "paper" and rig == "vehicle-roll" else 0

    def sample(members):
        k = num if isinstance(members, slice) else len(members)
        return Sample(rng.normal(0, 0.1, (k, n)), np.full(k, 0.01), rng.normal(0, 1, (k, 2 if
                      n == 4 else 1)), rng.normal(0, 0.01, (k, s)), members)

    first = sample(slice(None))
    for suite, st in zip((fused, plain), streams, strict=True):
        suite.reset(first, st.view(slice(None)))
    for step in range(9):
        if step == 4:  # a copy mid-episode measures like the original
            fused = copy.deepcopy(fused)
        members = (slice(None), np.array([1, 3]), np.array([2]))[step % 3]
        # steps 2 and 8: one member through measure_one (its row, list or array)
        _assert_measures_alike(fused, plain, streams, sample(members), step in (2, 8))
    for x, y in zip(fused.sensors, plain.sensors, strict=True):
        for name in ("bias", "last"):
            if hasattr(x, name):
                assert getattr(x, name).tobytes() == getattr(y, name).tobytes()


def test_rint_of_a_python_float_is_numpys():
    """The one-row path's rounding (:func:`testbed.sensors.fused._rint`) is ``np.rint``,
    bitwise: ties to even, the sign of a zero kept, non-finite values unchanged."""
    from testbed.sensors.fused import _rint

    values = [0.0, -0.0, 0.3, -0.3, 0.5, -0.5, 1.5, -1.5, 2.5, -2.5, 1e300, -1e300, 2.0**52 + 1,
              4503599627370495.5, np.inf, -np.inf, np.nan, 5e-324, -5e-324]
    values += np.random.default_rng(0).normal(0, 1e3, 200).tolist()
    expected = np.rint(np.array(values))
    assert np.array([_rint(v) for v in values]).tobytes() == expected.tobytes()


class Doubled(StateChannel):
    """A channel subclass that changes ``measure`` only."""

    def measure(self, sample, noise):
        return 2.0 * super().measure(sample, noise)


def test_one_member_reads_a_channel_subclass_through_its_own_measure():
    """A channel subclass that changes ``measure`` only is read through it on the fused
    one-row path (not through its parent's ``measure_row``)."""
    from testbed.sensors import Suite

    suite = Suite(WhiteNoise(Doubled(0, 2, 1, "roll", "rad"), std=0.1),
                  WhiteNoise(StateChannel(1, 2, 1, "roll_rate", "rad/s"), std=0.2))
    suite.allocate(1)
    assert suite._plan is not None
    streams = NoiseStreams(1)
    streams.seed(0, 3)
    sample = Sample(np.array([[0.25, -0.5]]), np.zeros(1), np.zeros((1, 1)), np.zeros((1, 0)))
    xi = NoiseStreams(1)
    xi.seed(0, 3)
    expected = np.array([[0.5, -0.5]]) + np.array([[0.1, 0.2]]) * xi.draw(2)
    assert suite.measure(sample, streams.view(slice(None))).tobytes() == expected.tobytes()


def test_a_channel_subclass_changing_measure_is_written_through_it():
    """The batch's fused plan writes a leaf through ``measure_into`` only where the class
    that defines ``measure`` defines it: a subclass that changes ``measure`` only is
    measured through it (not through its parent's ``measure_into``)."""
    from testbed.sensors import Suite

    suite = Suite(WhiteNoise(Doubled(0, 2, 1, "roll", "rad"), std=0.0),
                  WhiteNoise(StateChannel(1, 2, 1, "roll_rate", "rad/s"), std=0.2))
    suite.allocate(3)
    assert suite._plan is not None
    x = np.array([[0.25, -0.5], [1.0, 2.0], [-3.0, 0.5]])
    sample = Sample(x, np.zeros(3), np.zeros((3, 1)), np.zeros((3, 0)))
    streams = NoiseStreams(3)
    for i in range(3):
        streams.seed(i, i)
    y = suite.measure(sample, streams.view(slice(None)))
    assert y[:, 0].tobytes() == (2.0 * x[:, 0]).tobytes()


def _vehicle_leaves():
    from testbed.rigs.vehicle_roll.sensors import (
        LateralAccelerometer,
        SpeedChannel,
        SpeedYawRate,
        YawRateChannel,
    )

    return [StateChannel(1, 2, 1, "roll_rate", "rad/s"), LateralAccelerometer(), SpeedChannel(),
            YawRateChannel(), SpeedYawRate()]


@pytest.mark.parametrize("leaf", _vehicle_leaves(), ids=lambda s: type(s).__name__)
def test_measure_into_writes_what_measure_returns(leaf):
    """A channel's ``measure_into`` (the fused plan's write into its columns of a wider
    array) gives bitwise ``measure``'s values."""
    rng = np.random.default_rng(1)
    k = 37
    sample = Sample(rng.normal(0, 0.3, (k, 2)), np.zeros(k), rng.normal(0, 4, (k, 1)),
                    np.zeros((k, 0)))
    wide = np.full((k, leaf.dim + 3), np.nan)
    leaf.measure_into(sample, None, wide[:, 2:2 + leaf.dim])
    assert wide[:, 2:2 + leaf.dim].tobytes() == np.ascontiguousarray(
        leaf.measure(sample, None)).tobytes()
    assert np.isnan(wide[:, :2]).all() and np.isnan(wide[:, 2 + leaf.dim:]).all()


def _column_suites():
    from testbed.rigs.vehicle_roll.sensors import LateralAccelerometer, SpeedYawRate
    from testbed.sensors import Suite

    def roll():
        return StateChannel(0, 2, 1, "roll", "rad")

    def rate():
        return StateChannel(1, 2, 1, "roll_rate", "rad/s")

    return {
        # quantization and a walk on one column each, a walk on three scattered columns,
        # noise on four (a gather)
        "one-and-few": Suite(Quantize(WhiteNoise(roll(), std=0.05), 0.01),
                             BiasRandomWalk(rate(), walk=0.3, dt_s=0.01, initial_std=0.1),
                             WhiteNoise(LateralAccelerometer(), std=0.2),
                             BiasRandomWalk(WhiteNoise(SpeedYawRate(), std=[0.1, 0.01]),
                                            walk=[0.2, 0.1], dt_s=0.01)),
        # noise on two scattered columns and on two adjacent ones, one column by one
        "scattered": Suite(WhiteNoise(roll(), std=0.05), rate(),
                           WhiteNoise(LateralAccelerometer(), std=0.2)),
        "adjacent": Suite(rate(), WhiteNoise(SpeedYawRate(), std=[0.1, 0.01]),
                          BiasRandomWalk(roll(), walk=0.1, dt_s=0.01)),
    }


@pytest.mark.parametrize("name", list(_column_suites()))
def test_fused_groups_on_one_column_equal_sensor_by_sensor(name):
    """Groups that act on one column of the plan (noise, quantization, a walk: their
    in-place 1-D operations), on a few (column by one) and on many (a gather), beside
    leaves written in place, give bitwise the sensor-by-sensor values and walks, for the
    whole batch (a slice), a subset and one member."""


    fused = _column_suites()[name]
    num = 5
    plain, streams = _with_plain_copy(fused, num, 20)
    assert fused._plan is not None
    rng = np.random.default_rng(2)

    def sample(members):
        k = num if isinstance(members, slice) else len(members)
        return Sample(rng.normal(0, 0.2, (k, 2)), np.zeros(k), rng.normal(0, 3, (k, 1)),
                      np.zeros((k, 0)), members)

    first = sample(slice(None))
    for suite, st in zip((fused, plain), streams, strict=True):
        suite.reset(first, st.view(slice(None)))
    for step in range(12):
        members = (slice(None), np.array([0, 2, 4]), np.array([3]))[step % 3]
        _assert_measures_alike(fused, plain, streams, sample(members), step % 6 == 5)
    walks = [(x, y) for x, y in zip(fused.sensors, plain.sensors, strict=True)
             if isinstance(x, BiasRandomWalk)]
    for x, y in walks:
        assert x.bias.tobytes() == y.bias.tobytes()
