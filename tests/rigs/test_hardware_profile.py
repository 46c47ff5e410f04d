"""The ``hardware`` profile: rotor lag, amplifier limits, deadband, IMU, sensor timing."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from testbed.envs import RigEnv, RigVectorEnv
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs.helicopter import HelicopterRig, paper_model
from testbed.rigs.helicopter.hardware import HelicopterHardware, current_limited, deadband
from testbed.rigs.helicopter.imu import HelicopterIMU
from testbed.rigs.vehicle_roll import VehicleRollRig
from testbed.sensors import NoiseStreams, Sample, ScaleFactor, StateChannel


def _spin_up(rig: HelicopterRig, volts: np.ndarray, seconds: float,
             x0: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Step the rig's model like the simulator (ctrl from the substep hook) from rest.

    Returns times (s), MuJoCo ``act`` (volt-equivalent rotor speeds) and the rotors'
    generalized forces on ``[pitch, yaw]`` (N m).
    """
    model, data = rig.model, mujoco.MjData(rig.model)
    rig.set_state(np.zeros(4) if x0 is None else x0, data)
    constants = rig.member_constants(rig.params)
    command = rig.actuation(np.asarray(volts, float)[None], constants[None])["ctrl"][0]
    steps = int(round(seconds / model.opt.timestep))
    t, act, torque = np.zeros(steps + 1), np.zeros((steps + 1, 2)), np.zeros((steps + 1, 2))
    for k in range(1, steps + 1):
        data.ctrl[:] = rig.substep_ctrl(command, data.act, constants)
        mujoco.mj_step(model, data)
        mujoco.mj_forward(model, data)
        t[k], act[k], torque[k] = data.time, data.act, data.qfrc_actuator[rig.dof_adr]
    return t, act, torque


def _time_constant(t: np.ndarray, signal: np.ndarray, horizon_s: float) -> tuple[float, float]:
    """63 % rise time (interpolated) and log-linear fit over ``horizon_s`` of a step response."""
    final = signal[-1]
    level = (1 - np.exp(-1)) * final
    k = int(np.argmax(np.abs(signal) >= abs(level)))
    t63 = t[k - 1] + (level - signal[k - 1]) / (signal[k] - signal[k - 1]) * (t[k] - t[k - 1])
    window = (t > 0) & (t < horizon_s)
    slope = np.polyfit(t[window], np.log1p(-signal[window] / final), 1)[0]
    return float(t63), float(-1 / slope)


def test_motor_step_response_time_constant_matches_the_configured_one():
    """Step each motor's voltage with the rig on its stop; time constant of the torque."""
    hw = HelicopterHardware()
    rig = HelicopterRig(profile="hardware")
    x0 = rig.default_x0()
    for i, volts in enumerate(([3.0, 0.0], [0.0, 2.0])):  # small: no current limit
        t, act, torque = _spin_up(rig, np.array(volts), 0.6, x0)
        final = deadband(np.array(volts), np.asarray(hw.deadband_v))
        np.testing.assert_allclose(act[-1], final, rtol=1e-4)
        signal = torque[:, i]  # pitch torque of the pitch rotor, yaw torque of the yaw rotor
        t63, fit = _time_constant(t, signal, 3 * hw.motor_time_constant_s[i])
        print(f"motor {i}: configured tau {hw.motor_time_constant_s[i] * 1e3:.1f} ms, "
              f"torque step response: 63 % rise {t63 * 1e3:.2f} ms, fit {fit * 1e3:.3f} ms")
        assert t63 == pytest.approx(hw.motor_time_constant_s[i], rel=5e-3)
        assert fit == pytest.approx(hw.motor_time_constant_s[i], rel=1e-3)
    # steady torque = the paper's gain times the voltage past the deadband (on the stop the
    # pitch rotor's thrust torque is K_pp, the yaw rotor's yaw torque K_yy cos(pitch))
    p = rig.params
    assert torque[-1, 1] == pytest.approx(p.K_yy * np.cos(x0[0]) * (2.0 - hw.deadband_v[1]),
                                          rel=1e-4)


def test_current_limit_slows_the_spin_up_as_the_closed_form_says():
    hw = HelicopterHardware()
    rig = HelicopterRig(profile="hardware")
    t, act, _ = _spin_up(rig, np.array([24.0, 0.0]), 1.5)
    c, tau = hw.back_emf_fraction[0], hw.motor_time_constant_s[0]
    ri = hw.resistance_ohm[0] * hw.current_limit_a[0]
    v = 24.0 - hw.deadband_v[0]
    # while limited: s' = (c s + R I - s) / tau  =>  s = R I / (1 - c) (1 - exp(-(1 - c) t / tau))
    closed = ri / (1 - c) * (1 - np.exp(-(1 - c) * t / tau))
    limited = c * closed + ri < v
    assert limited[:500].all() and not limited[-1]
    # the limit is evaluated once per physics step h (the voltage held over it, the lag
    # integrated exactly): s_k = R I / (1 - c) (1 - (1 - (1 - c) alpha)^k), alpha = 1 - e^(-h/tau)
    alpha = 1 - np.exp(-rig.model.opt.timestep / tau)
    k = np.arange(len(t))
    discrete = ri / (1 - c) * (1 - (1 - (1 - c) * alpha) ** k)
    np.testing.assert_allclose(act[limited, 0], discrete[limited], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(act[limited, 0], closed[limited], rtol=1e-2, atol=1e-9)
    current = (current_limited(np.array([v, 0.0]), act[limited], np.array([c, c]),
                               np.array([ri, ri]))[:, 0] - c * act[limited, 0]) / ri
    np.testing.assert_allclose(current, hw.current_limit_a[0] / hw.current_limit_a[0])
    # without the limit the rotor would reach 63 % in tau; limited it takes far longer
    t63 = t[np.argmax(act[:, 0] >= (1 - np.exp(-1)) * v)]
    assert t63 > 3 * tau
    assert act[-1, 0] == pytest.approx(v, rel=1e-3)


def test_deadband_and_voltage_limits():
    env = RigEnv("helicopter", profile="hardware")
    np.testing.assert_array_equal(env.action_space.high, [24.0, 15.0])
    np.testing.assert_array_equal(env.action_space.low, [-24.0, -15.0])
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([30.0, -20.0]))
    np.testing.assert_array_equal(info["action_applied"], [24.0, -15.0])
    assert info["action_clipped"].all()
    np.testing.assert_allclose(deadband(np.array([0.1, -0.1, 1.0, -1.0]), 0.2),
                               [0.0, 0.0, 0.8, -0.8])
    # inside the deadband the rotors do not move
    rig = HelicopterRig(profile="hardware")
    _, act, _ = _spin_up(rig, np.array([0.15, -0.19]), 0.2)
    np.testing.assert_array_equal(act, 0.0)
    with pytest.raises(ValueError, match="unknown profile 'lab'"):
        RigEnv("helicopter", profile="lab")
    with pytest.raises(ValueError, match="back_emf_fraction"):
        HelicopterHardware(back_emf_fraction=(1.0, 0.5))
    with pytest.raises(ValueError, match="apply to profile 'hardware'"):
        HelicopterRig(hardware=HelicopterHardware())
    slow = HelicopterRig(profile="hardware",
                         hardware=HelicopterHardware(motor_time_constant_s=(0.1, 0.1)))
    np.testing.assert_allclose(slow.model.actuator_dynprm[:, 0], [0.1, 0.1])


def test_linearize_with_and_without_motor_states():
    hw = HelicopterHardware()
    rig = HelicopterRig(profile="hardware")
    paper = paper_model()
    A, B = rig.linearize()
    np.testing.assert_allclose(A, paper.A, atol=1e-6)
    np.testing.assert_allclose(B, paper.B, rtol=1e-6, atol=1e-9)
    A6, B6 = rig.linearize(motor_states=True)
    assert A6.shape == (6, 6) and B6.shape == (6, 2)
    np.testing.assert_allclose(A6[:4, :4], paper.A, atol=1e-6)
    np.testing.assert_allclose(A6[:4, 4:], paper.B, rtol=1e-6, atol=1e-9)
    inv_tau = 1 / np.asarray(hw.motor_time_constant_s)
    np.testing.assert_allclose(A6[4:, 4:], -np.diag(inv_tau), rtol=1e-6)
    np.testing.assert_allclose(B6[4:], np.diag(inv_tau), rtol=1e-6)
    np.testing.assert_allclose(B6[:4], 0.0, atol=1e-9)
    # the paper profile has no motor states
    assert HelicopterRig().linearize(motor_states=True)[0].shape == (4, 4)


def test_imu_channels_equal_mujoco_gyro_and_accelerometer():
    spec = mujoco.MjSpec.from_file(str(HelicopterRig.resolved_xml_path()))
    spec.add_sensor(name="gyro", type=mujoco.mjtSensor.mjSENS_GYRO,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu")
    spec.add_sensor(name="acc", type=mujoco.mjtSensor.mjSENS_ACCELEROMETER,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu")
    model = spec.compile()
    data = mujoco.MjData(model)
    rig = HelicopterRig()
    imu = HelicopterIMU()
    rng = np.random.default_rng(1)
    for _ in range(20):
        x = np.concatenate([rng.uniform(-0.7, 0.7, 1), rng.uniform(-3, 3, 1),
                            rng.normal(0, 2, 2)])
        rig.set_state(x, data, model)
        ours = imu.measure(Sample(x[None], np.zeros(1), np.zeros((1, 2)), np.zeros((1, 0))),
                           None)[0]
        gyro, acc = data.sensordata[:3], data.sensordata[3:6]
        np.testing.assert_allclose(ours, [-gyro[1], gyro[2], acc[0]], rtol=1e-9, atol=1e-9)
        assert gyro[0] == pytest.approx(x[3] * np.sin(x[0]))
        assert acc[2] == pytest.approx(9.81 * np.cos(x[0]), rel=1e-9)
    model_lin = imu.linear_model()
    np.testing.assert_allclose(model_lin.C[:, [0, 2, 3]], [[0, 1, 0], [0, 0, 1], [9.81, 0, 0]])


def test_hardware_sensor_noise_levels_and_delay():
    hw = HelicopterHardware()
    env = RigEnv("helicopter", profile="hardware", ambient_noise=0.0, reset_noise_scale=0.0)
    assert env.sensors.names == ("pitch", "yaw", "gyro_pitch", "gyro_yaw", "accel_x")
    # at rest on the stop: the gyros read bias + noise, the accelerometer g sin(pitch)
    obs = []
    env.reset(seed=4)
    for _ in range(400):
        obs.append(env.step(np.zeros(2))[0])
    obs = np.array(obs[10:])
    sigma = np.sqrt(1 / env.dt_s) * np.array([hw.gyro_noise_density, hw.gyro_noise_density,
                                              hw.accel_noise_density])
    std = np.std(np.diff(obs[:, 2:], axis=0), axis=0) / np.sqrt(2)
    np.testing.assert_allclose(std, sigma, rtol=0.15)
    pitch = float(env.sim.info["state"][0, 0])
    # offset: calibration residual and sensitivity error (4 sigma)
    spread = np.hypot(hw.accel_bias0_std, hw.scale_factor_std * 9.81 * np.sin(pitch))
    assert np.mean(obs[:, 4]) == pytest.approx(9.81 * np.sin(pitch), abs=4 * spread)
    # one sample of delay on the IMU (the encoders have none): the gyro reads the rate of the
    # previous sample
    env.reset(seed=0, options={"x0": [0.3, 0.0, 0.0, 0.0]})
    states, obs = [env.sim.info["state"][0].copy()], [env.sim.obs[0].copy()]
    rng = np.random.default_rng(0)
    for _ in range(100):
        y, _, _, _, info = env.step(rng.uniform(-10, 24, 2))
        states.append(info["state"])
        obs.append(y)
    states, obs = np.array(states), np.array(obs)
    late = np.abs(obs[1:, 2] - states[:-1, 2]).mean()
    now = np.abs(obs[1:, 2] - states[1:, 2]).mean()
    assert late < 0.1 * now
    q = 2 * np.pi / np.array([4096, 8192])
    assert np.all(np.abs(obs[:, :2] - states[:, :2]) <= q / 2 + 1e-12)


def test_scale_factor_decorator():
    channel = StateChannel(0, 1, 0, "x", "m")
    fixed = ScaleFactor(channel, error=0.02)
    drawn = ScaleFactor(channel, initial_std=0.01)
    n = 4000
    streams = NoiseStreams(n, 8)
    for i in range(n):
        streams.seed(i, i)
    sample = Sample(np.ones((n, 1)) * 2.0, np.zeros(n), np.zeros((n, 0)), np.zeros((n, 0)))
    for sensor in (fixed, drawn):
        sensor.allocate(n)
        sensor.reset(sample, streams.view(slice(None)))
    np.testing.assert_allclose(fixed.measure(sample, None), 2.04)
    y = drawn.measure(sample, streams.view(slice(None)))
    assert np.mean(y / 2 - 1) == pytest.approx(0.0, abs=5e-4)
    assert np.std(y / 2 - 1) == pytest.approx(0.01, rel=0.05)
    with pytest.raises(ValueError, match="error must be > -1"):
        ScaleFactor(channel, error=-1.0)


@pytest.mark.parametrize("rig", ["helicopter", "vehicle-roll", "aero"])
def test_hardware_vector_env_equals_single_envs_bitwise(rig):
    seeds = [5, 9, 2]
    kwargs = {"profile": "hardware"}
    vec = RigVectorEnv(len(seeds), rig=rig, num_threads=2, **kwargs)
    singles = [RigEnv(rig, **kwargs) for _ in seeds]
    obs_v, _ = vec.reset(seed=seeds)
    for i, (env, seed) in enumerate(zip(singles, seeds, strict=True)):
        np.testing.assert_array_equal(env.reset(seed=seed)[0], obs_v[i])
    rng = np.random.default_rng(0)
    high = vec.single_action_space.high
    for _ in range(60):
        actions = rng.uniform(-1, 1, (len(seeds), len(high))) * high
        obs_v, _, _, _, info_v = vec.step(actions)
        for i, env in enumerate(singles):
            obs, _, _, _, info = env.step(actions[i])
            np.testing.assert_array_equal(obs, obs_v[i])
            np.testing.assert_array_equal(info["state"], info_v["state"][i])
    vec.close()


def test_design_model_stays_the_papers_under_hardware_with_design_profile_paper():
    paper = runner.build(Scenario(rig="helicopter", sensors="encoders"))
    hard = runner.build(Scenario(rig="helicopter", profile="hardware", sensors="encoders",
                                 design_profile="paper"))
    matched = runner.build(Scenario(rig="helicopter", profile="hardware", sensors="encoders"))
    for name in ("A", "B", "C", "Q", "R"):
        np.testing.assert_array_equal(getattr(hard.design.continuous, name),
                                      getattr(paper.design.continuous, name))
    assert hard.loop.sim.rig.profile == "hardware" and hard.loop.sim.rig.model.na == 2
    # matched: the rotor states augment the paper model (encoders: no IMU states)
    assert matched.design.state_names[4:] == ("dact_pitch", "dact_yaw")
    np.testing.assert_allclose(matched.design.continuous.A[:4, :4],
                               paper.design.continuous.A, atol=1e-6)
    for experiment in (paper, hard, matched):
        experiment.close()
    with pytest.raises(ValueError, match="profile must be one of"):
        Scenario(rig="helicopter", profile="lab").check()


def test_vehicle_hardware_profile_changes_only_the_default_sensors():
    paper, hard = VehicleRollRig(), VehicleRollRig(profile="hardware")
    assert hard.sensors(dt_s=0.01).describe().startswith("delay(")
    assert paper.sensors(dt_s=0.01).describe() == paper.sensors("imu", dt_s=0.01).describe()
    # same physics: with the same sensors the runs are equal bitwise
    a = runner.run(Scenario(rig="vehicle-roll", sensors="imu", duration_s=1.0), record=True,
                   progress=False)[0]
    b = runner.run(Scenario(rig="vehicle-roll", profile="hardware", sensors="imu",
                            duration_s=1.0), record=True, progress=False)[0]
    np.testing.assert_array_equal(a.state, b.state)
    np.testing.assert_array_equal(a.measurement, b.measurement)


@pytest.mark.parametrize("rig", ["helicopter", "vehicle-roll", "aero"])
def test_mc_of_one_hardware_run_equals_run(rig):
    scenario = Scenario(rig=rig, profile="hardware", duration_s=1.0, seed=7)
    mc = runner.monte_carlo(scenario, 1, progress=False)
    _, single = runner.run(scenario.replace(seed=mc["seeds"][0]), record=False, progress=False)
    for name, value in single["rmse"].items():
        assert mc["rmse_per_run"][name][0] == value


def test_cli_profile_flag(tmp_path, capsys):
    from testbed.cli import main

    path = tmp_path / "h.json"
    assert main(["run", "helicopter", "--profile", "hardware", "--duration", "0.5",
                 "--json", str(path), "--no-progress"]) == 0
    import json

    data = json.loads(path.read_text())
    assert data["scenario"]["profile"] == "hardware"
    assert "gyro_pitch" in data["meta"]["sensors"]
    with pytest.raises(SystemExit):
        main(["run", "helicopter", "--profile", "lab"])
