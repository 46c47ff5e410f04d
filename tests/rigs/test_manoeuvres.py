"""Lateral-acceleration manoeuvres: registry, shapes, values, validation, use in the env."""

from __future__ import annotations

import math

import numpy as np
import pytest

from testbed.envs import RigEnv
from testbed.rigs.vehicle_roll import A_Y_LIMIT_M_S2, paper_disturbance
from testbed.rigs.vehicle_roll.manoeuvres import (
    MANOEUVRES,
    DoubleLaneChange,
    PaperDecay,
    SineSweep,
    StepSteer,
    make_manoeuvre,
)

NAMES = ["double-lane-change", "paper-decay", "sine-sweep", "step-steer"]


def test_registry_names():
    assert sorted(MANOEUVRES) == NAMES
    for name, cls in MANOEUVRES.items():
        assert cls.name == name
        assert make_manoeuvre(name).name == name


@pytest.mark.parametrize("name", NAMES)
def test_scalar_and_array_evaluation(name):
    m = make_manoeuvre(name)
    t = np.linspace(0.0, 12.0, 1201)
    a = m(t)
    assert a.shape == t.shape and np.all(np.isfinite(a))
    assert isinstance(m(0.37), float)
    assert m(0.37) == a[37] or np.isclose(m(0.37), a[37], rtol=0, atol=1e-12)
    assert np.all(np.abs(a) <= A_Y_LIMIT_M_S2)  # defaults stay inside the action limit


def test_make_manoeuvre_errors_list_valid_names():
    with pytest.raises(ValueError, match="double-lane-change.*paper-decay.*sine-sweep"):
        make_manoeuvre("slalom")
    with pytest.raises(ValueError, match="amplitude_m_s2"):
        make_manoeuvre("step-steer", amplitude=3.0)
    with pytest.raises(ValueError, match="rise_time_s must be positive"):
        make_manoeuvre("step-steer", rise_time_s=0.0)
    with pytest.raises(ValueError, match="speed_m_s must be finite"):
        make_manoeuvre("double-lane-change", speed_m_s=np.nan)
    with pytest.raises(ValueError, match="must be a number"):
        SineSweep(f0_hz="fast")


def test_step_steer_ramp():
    m = StepSteer(amplitude_m_s2=-4.0, t_start_s=1.0, rise_time_s=0.5)
    np.testing.assert_allclose(m(np.array([0.0, 1.0, 1.25, 1.5, 9.0])),
                               [0.0, 0.0, -2.0, -4.0, -4.0])


def test_sine_sweep_is_a_linear_chirp_that_starts_and_ends_at_zero():
    m = SineSweep(amplitude_m_s2=2.0, f0_hz=0.5, f1_hz=1.5, duration_s=4.0, t_start_s=1.0)
    assert m(0.5) == 0.0 and m(1.0) == 0.0 and m(6.0) == 0.0
    assert abs(m(5.0)) < 1e-12  # 4 s * (0.5 + 1.5) / 2 Hz = 4 whole cycles
    tau = 1.3
    expected = 2.0 * np.sin(2 * np.pi * (0.5 * tau + 1.0 * tau**2 / 8.0))
    assert m(1.0 + tau) == pytest.approx(expected)


def test_double_lane_change_is_v2_times_path_curvature():
    m = DoubleLaneChange()
    t = np.arange(0.0, 10.0, 1e-3)
    y = m.lateral_position(t)
    ypp_t = np.gradient(np.gradient(y, t), t)  # d2y/dt2 = v^2 d2y/dx2 at constant speed
    np.testing.assert_allclose(m(t)[5:-5], ypp_t[5:-5], atol=1e-3)
    x = m.speed_m_s * (t - m.t_start_s)
    assert y[np.argmin(np.abs(x - 56.25))] == pytest.approx(3.43, abs=0.01)  # offset lane
    assert abs(y[-1]) < 1e-6 and abs(m(t[-1])) < 1e-6  # back in the original lane
    first, second = np.abs(m(t)[x < 56.25]).max(), np.abs(m(t)[x >= 56.25]).max()
    assert first == pytest.approx(4.27, abs=0.01) and second == pytest.approx(6.16, abs=0.01)


def test_paper_decay_matches_v_k():
    m = PaperDecay()
    k = np.arange(50)
    np.testing.assert_allclose(m(k * 0.01), paper_disturbance(k), rtol=1e-12)
    assert m(0.0) == 0.01 and m(-1.0) == 0.0


def test_env_options_select_and_parameterize_the_manoeuvre():
    env = RigEnv("vehicle-roll", manoeuvre="step-steer")

    def profile(n: int = 200) -> list[float]:
        """The manoeuvre's part of the applied input over ``n`` steps of zero action."""
        out = []
        for _ in range(n):
            _, _, _, _, info = env.step(np.zeros(1))
            assert info["action_applied"][0] == info["manoeuvre"][0]  # zero action added
            out.append(info["manoeuvre"][0])
        return out

    env.reset(seed=0, options={"manoeuvre": "double-lane-change",
                               "manoeuvre_params": {"speed_m_s": 15.0}})
    expected = DoubleLaneChange(speed_m_s=15.0)
    assert profile() == [expected(k * env.dt_s) for k in range(200)]
    assert expected != DoubleLaneChange()  # the parameter was used
    env.reset(seed=0)  # back to the constructor's step steer
    assert profile() == [StepSteer()(k * env.dt_s) for k in range(200)]
    assert any(StepSteer()(k * env.dt_s) != 0.0 for k in range(200))
    env.reset(seed=0, options={"manoeuvre_params": {"amplitude_m_s2": 2.0}})
    assert profile() == [StepSteer(amplitude_m_s2=2.0)(k * env.dt_s) for k in range(200)]
    env.reset(seed=0, options={"manoeuvre": None})
    _, _, _, _, info = env.step(np.array([1.5]))
    assert info["action_applied"][0] == 1.5 and info["manoeuvre"][0] == 0.0
    with pytest.raises(ValueError, match="expected one of"):
        env.reset(options={"manoeuvre": "slalom"})
    with pytest.raises(ValueError, match="manoeuvre_params"):
        env.reset(options={"manoeuvre": "step-steer", "manoeuvre_params": {"sharpness": 1.0}})


@pytest.mark.parametrize("name", NAMES)
def test_common_time_profile_matches_per_member_times(name):
    """The one-time path of Simulator._manoeuvre (common=True) gives, bitwise, the rows the
    general path gives for members at different times (each time's value, per member)."""
    from testbed.sim import build_simulator

    sim = build_simulator("vehicle-roll", 3, num_threads=1, manoeuvre=name)
    sim.reset(None, [0, 1, 2])
    fn = sim.schedules.profiles[0]
    for t0 in (0.0, 0.37, 1.25, 2.5, 4.0, 9.9):
        common = sim._manoeuvre(np.full(3, t0), sim.rows.all, common=True)
        mixed = sim._manoeuvre(np.array([t0, t0 + 0.5, t0]), sim.rows.all)
        assert common.shape == (3, 1) and common.dtype == np.float64
        assert common.tobytes() == np.repeat(mixed[:1], 3, axis=0).tobytes()
        assert mixed[0].tobytes() == mixed[2].tobytes() == np.float64(fn(t0)).tobytes()
        assert mixed[1].tobytes() == np.float64(fn(t0 + 0.5)).tobytes()


def test_common_time_profile_rejects_a_non_finite_value():
    from testbed.sim import build_simulator

    sim = build_simulator("vehicle-roll", 2, num_threads=1, manoeuvre=lambda t: math.nan)
    sim.reset(None, [0, 1])
    with pytest.raises(ValueError, match="non-finite input"):
        sim._manoeuvre(np.full(2, 0.5), sim.rows.all, common=True)


@pytest.mark.parametrize("kind", ["numpy scalar", "array", "nan array"])
def test_common_time_profile_calls_a_non_float_manoeuvre_once(kind):
    """A manoeuvre returning a numpy scalar or array at a common time is called once per
    step (not once for the float test and again for the rows); the rows are its value."""
    from testbed.sim import build_simulator

    calls = []

    def fn(t):
        calls.append(t)
        value = np.float64(0.25 * t) if kind == "numpy scalar" else np.array([0.25 * t])
        return value * np.nan if kind == "nan array" else value

    sim = build_simulator("vehicle-roll", 3, num_threads=1, manoeuvre=fn)
    sim.reset(None, [0, 1, 2])
    calls.clear()
    if kind == "nan array":
        with pytest.raises(ValueError, match="non-finite input"):
            sim._manoeuvre(np.full(3, 0.5), sim.rows.all, common=True)
    else:
        rows = sim._manoeuvre(np.full(3, 0.5), sim.rows.all, common=True)
        assert rows.shape == (3, 1) and np.all(rows == 0.125)
    assert calls == [0.5]


def test_members_with_other_manoeuvres_at_one_time_keep_their_own_profiles():
    """A whole-batch step with every member at one time, but members reset to different
    manoeuvres (or none), gives each member its own profile: the values of stepping the
    same members by index (the general path)."""
    from testbed.sim import build_simulator

    options = [None, {"manoeuvre": None}, {"manoeuvre": "step-steer"}]
    sims = []
    for _ in range(2):
        sim = build_simulator("vehicle-roll", 3, num_threads=1, manoeuvre="double-lane-change")
        sim.reset(None, [0, 1, 2], options)
        sims.append(sim)
    whole, by_index = sims
    u = np.zeros((3, 1))
    for _ in range(150):
        whole.step(u)
        by_index.step(u, np.arange(3))
        assert whole.info["manoeuvre"].tobytes() == by_index.info["manoeuvre"].tobytes()
        assert whole.info["state"].tobytes() == by_index.info["state"].tobytes()
    assert whole.info["manoeuvre"][1, 0] == 0.0 != whole.info["manoeuvre"][0, 0]
    assert whole.info["manoeuvre"][2, 0] != whole.info["manoeuvre"][0, 0]
