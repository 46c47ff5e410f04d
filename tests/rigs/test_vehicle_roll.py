"""Vehicle roll rig (Zhang et al. Example 5.2): physics, paper model, sensors, env, experiment."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from scipy.integrate import solve_ivp

import testbed  # noqa: F401  (registers the environments)
from testbed.envs import RigEnv
from testbed.experiment.runner import run
from testbed.experiment.scenario import Scenario
from testbed.rigs.helicopter import GRAVITY_M_S2
from testbed.rigs.vehicle_roll import (
    ROLLOVER_RAD,
    VehicleRollParams,
    VehicleRollRig,
    paper_disturbance,
    paper_model,
    physical_model,
    process_noise_intensity,
)
from testbed.rigs.vehicle_roll.sensors import PaperRollChannel, imu
from testbed.sensors import NoiseStreams, Sample, Suite

G = GRAVITY_M_S2


def VehicleRollEnv(**kwargs) -> RigEnv:  # noqa: N802  (the old class name, kept for reading)
    return RigEnv("vehicle-roll", **kwargs)


def _member_model(env: RigEnv):
    """The MuJoCo model member 0 is simulated with (its per-step damping included)."""
    return env.sim.physics.models[0]


def _measure(sensor, x: np.ndarray, a_y: float, seed: int = 0, num: int = 1) -> np.ndarray:
    """Reset ``sensor`` for ``num`` members at state ``x`` and take one sample: (num, m)."""
    sensor.allocate(num)
    streams = NoiseStreams(num)
    for i in range(num):
        streams.seed(i, seed + i)
    members = np.arange(num)
    sample = Sample(np.tile(x, (num, 1)), np.zeros(num), np.full((num, 1), a_y),
                    np.zeros((num, 0)), members)
    noise = streams.view(members)
    sensor.reset(sample, noise)
    return sensor.measure(sample, noise)


# ---------------------------------------------------------------- paper model vs physics
def test_paper_model_verbatim():
    pm = paper_model()
    assert pm.T == 0.01
    np.testing.assert_allclose(pm.A, [[1.0, 0.01],
                                      [(1700 * 0.25 - 55314) * 0.01 / 1700,
                                       1 - 53071 * 0.01 / 1700]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(pm.A[1], [-0.32287647, 0.68781765], atol=1e-8)
    np.testing.assert_allclose(pm.C, [[0.0, 0.0], [0.0, -20 * 0.01 / 1700]], rtol=0, atol=1e-18)
    np.testing.assert_array_equal(pm.H, [[0.4048, 0.6405], [1.1213, 1.4616]])
    np.testing.assert_array_equal(pm.B, [[-0.7916], [0.3652]])
    np.testing.assert_array_equal(pm.L, [[0.8248], [-1.3774]])
    np.testing.assert_array_equal(pm.M, [[1.0, 0.0]])
    assert paper_disturbance(0) == 0.01 and paper_disturbance(2) == pytest.approx(0.0081)


def test_paper_A_lacks_g_physical_has_it():
    p = VehicleRollParams()
    pm = paper_model()
    A_phys, _ = VehicleRollRig().linearize()
    # A[1, 0] = (gravity term - K_R) / I_xx (times T in the discrete paper model)
    paper_gravity = pm.A[1, 0] * p.roll_inertia / pm.T + p.roll_stiffness
    physical_gravity = A_phys[1, 0] * p.roll_inertia + p.roll_stiffness
    print(f"gravity stiffness: paper {paper_gravity:.2f}, physical {physical_gravity:.2f} "
          "N m/rad")
    assert paper_gravity == pytest.approx(425.0, abs=1e-9)  # m_s h_cr
    assert physical_gravity == pytest.approx(4169.25, abs=1e-3)  # m_s g h_cr
    # The paper's A is the forward-Euler discretization of the model without g:
    A_no_g = np.array([[0.0, 1.0], [(425.0 - p.roll_stiffness) / p.roll_inertia,
                                    -p.roll_damping / p.roll_inertia]])
    np.testing.assert_allclose(pm.A, np.eye(2) + pm.T * A_no_g, atol=1e-14)


def test_linearization_matches_analytic():
    rig = VehicleRollRig()
    A, B = rig.linearize()
    A_an, B_an = physical_model()
    np.testing.assert_allclose(A, A_an, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(B, B_an, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(A_an, [[0, 1], [(4169.25 - 55314) / 1700, -53071 / 1700]])
    np.testing.assert_allclose(B_an, [[0], [0.25]])
    # Away from upright: cos(eta) on the input, the slopes of the nonlinear torques.
    p = rig.params
    eta, a_y = 0.1, 4.0
    A, B = rig.linearize(np.array([eta, 0.3]), u_op=np.array([a_y]))
    mh = p.sprung_mass_kg * p.com_height_m
    d_eta = (mh * G * np.cos(eta) - mh * a_y * np.sin(eta) - p.roll_stiffness) / p.roll_inertia
    np.testing.assert_allclose(A[1], [d_eta, -p.roll_damping / p.roll_inertia], rtol=1e-6)
    np.testing.assert_allclose(B[1, 0], mh * np.cos(eta) / p.roll_inertia, rtol=1e-6)


def test_rig_inertia_is_about_the_roll_axis():
    rig = VehicleRollRig()
    M = np.zeros((1, 1))
    mujoco.mj_fullM(rig.model, rig.data, M)
    assert M[0, 0] == pytest.approx(1700.0, rel=1e-12)
    assert rig.params.inertia_com == pytest.approx(1700 - 1700 * 0.25**2)


# ---------------------------------------------------------------- rig vs eq. (51)
def _eq51(p: VehicleRollParams, a_seq, w_seq, dt_s, with_cos: bool) -> np.ndarray:
    """Integrate eq. (51) with scipy, a_y and w_k held over each control step."""
    mh = p.sprung_mass_kg * p.com_height_m

    def f(t, x, a, w):
        lever = np.cos(x[0]) if with_cos else 1.0
        torque = (mh * a * lever + mh * G * np.sin(x[0]) - p.roll_stiffness * x[0]
                  - (p.roll_damping + p.damping_noise * w) * x[1])
        return [x[1], torque / p.roll_inertia]

    x = np.zeros(2)
    out = []
    for a, w in zip(a_seq, w_seq, strict=True):
        x = solve_ivp(f, (0.0, dt_s), x, args=(a, w), method="DOP853", rtol=1e-10,
                      atol=1e-12).y[:, -1]
        out.append(x)
    return np.array(out)


def test_mujoco_rig_reproduces_eq51():
    # A hard step steer plus random perturbations, and D_n x 500 so the multiplicative
    # damping noise matters: the replay uses the a_y and w_k the env reports.
    env = VehicleRollEnv(manoeuvre="step-steer", manoeuvre_params={"amplitude_m_s2": 7.0},
                         params={"damping_noise": 500.0}, ambient_noise=0.0,
                         reset_noise_scale=0.0)
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    states, a_seq, w_seq = [], [], []
    for _ in range(1000):  # 10 s
        _, _, _, _, info = env.step(rng.uniform(-1.0, 1.0, 1))
        states.append(info["state"])
        a_seq.append(info["action_applied"][0])
        w_seq.append(info["step_noise"][0])
    states = np.array(states)
    assert np.abs(states[:, 0]).max() > 0.05  # about 3.4 deg of roll
    verbatim = _eq51(env.nominal_params, a_seq, w_seq, env.dt_s, with_cos=False)
    with_cos = _eq51(env.nominal_params, a_seq, w_seq, env.dt_s, with_cos=True)
    err = np.abs(states[:, 0] - verbatim[:, 0]).max()
    err_cos = np.abs(states[:, 0] - with_cos[:, 0]).max()
    print(f"roll error vs eq. (51): {err:.2e} rad; vs eq. (51) with cos(eta): {err_cos:.2e}")
    assert err < 1e-3
    assert err_cos < 1e-4  # what is left is MuJoCo's 1 ms integration error


def test_gravity_input_is_the_xfrc_actuation_up_to_rounding():
    # the simulator carries a_y as each member's opt.gravity (Rig.physics_inputs); the same
    # episode with actuation()'s xfrc_applied written instead (the definition) gives the
    # same states up to rounding, and a reset restores the model's gravity
    kwargs = {"manoeuvre": "step-steer", "manoeuvre_params": {"amplitude_m_s2": 7.0},
              "params": {"damping_noise": 500.0}}
    env, by_xfrc = VehicleRollEnv(**kwargs), VehicleRollEnv(**kwargs)
    rig = by_xfrc.sim.rig
    rig.physics_inputs = rig.actuation  # (this instance only)
    env.reset(seed=4)
    by_xfrc.reset(seed=4)
    rng = np.random.default_rng(3)
    states, replayed = [], []
    for _ in range(600):
        action = rng.uniform(-1.0, 1.0, 1)
        _, _, _, _, info = env.step(action)
        a_y = float(np.ravel(info["action_applied"])[0])
        assert _member_model(env).opt.gravity.tolist() == [0.0, -a_y, -G]
        assert not env.sim.physics.state[0, env.sim.physics._xfrc].any()
        states.append(info["state"])
        replayed.append(by_xfrc.step(action)[4]["state"])
        assert _member_model(by_xfrc).opt.gravity.tolist() == [0.0, 0.0, -G]
    states, replayed = np.array(states), np.array(replayed)
    assert np.abs(states[:, 0]).max() > 0.05
    assert not np.array_equal(states, replayed)  # (the two paths round differently)
    np.testing.assert_allclose(states, replayed, rtol=0, atol=1e-12 * np.abs(states).max())
    env.reset(seed=4)
    assert _member_model(env).opt.gravity.tolist() == [0.0, 0.0, -G]


def test_damping_noise_is_drawn_per_step_and_applied():
    env = VehicleRollEnv()
    env.reset(seed=3)
    w = []
    for _ in range(400):
        _, _, _, _, info = env.step(np.array([2.0]))
        w.append(info["step_noise"][0])
        assert _member_model(env).dof_damping[0] == pytest.approx(53071.0 + 20.0 * w[-1])
    w = np.array(w)
    assert abs(w.mean()) < 0.2 and 0.85 < w.std() < 1.15
    env.reset(seed=3)
    assert _member_model(env).dof_damping[0] == 53071.0


def test_damping_noise_of_each_member_in_a_threaded_batch_equals_single_envs():
    # the physics threads apply member i's damping noise to member i's model: with the
    # noise amplified and a manoeuvre rolling the body, a mix-up would change the states
    from testbed.envs import RigVectorEnv

    kwargs = {"manoeuvre": "double-lane-change", "params": {"damping_noise": 500.0}}
    seeds = [5, 1, 9, 2, 7]
    vec = RigVectorEnv(len(seeds), rig="vehicle-roll", num_threads=2, **kwargs)
    singles = [VehicleRollEnv(**kwargs) for _ in seeds]
    vec.reset(seed=seeds)
    for env, seed in zip(singles, seeds, strict=True):
        env.reset(seed=seed)
    rng = np.random.default_rng(2)
    for _ in range(150):
        actions = rng.uniform(-1.0, 1.0, (len(seeds), 1))
        _, _, _, _, info_v = vec.step(actions)
        for i, env in enumerate(singles):
            _, _, _, _, info = env.step(actions[i])
            np.testing.assert_array_equal(info_v["state"][i], info["state"])
            np.testing.assert_array_equal(info_v["step_noise"][i], info["step_noise"])
            assert vec.sim.physics.models[i].dof_damping[0] == \
                _member_model(env).dof_damping[0]
    assert len({float(m.dof_damping[0]) for m in vec.sim.physics.models}) == len(seeds)
    vec.close()


# ---------------------------------------------------------------- sensors
def test_imu_formula_and_noise_levels():
    suite = imu(dt_s=0.01, roll_sensor=True, gyro_bias_walk=0.0, speed_yaw_rate=False)
    quiet = imu(dt_s=0.01, roll_sensor=True, gyro_noise_density=0.0, gyro_bias_walk=0.0,
                accel_noise_density=0.0, roll_noise_std=0.0, accel_bias=0.02,
                speed_yaw_rate=False)
    x = np.array([0.05, -0.2])
    np.testing.assert_allclose(_measure(quiet, x, 4.0)[0],
                               [-0.2, 4.0 * np.cos(0.05) + G * np.sin(0.05) + 0.02, 0.05])
    samples = _measure(suite, x, 4.0, num=4000)  # 4000 members, one sample each
    std = samples.std(axis=0)
    expected = [np.deg2rad(0.01) * 10.0, 150e-6 * G * 10.0, np.deg2rad(0.1)]
    np.testing.assert_allclose(std, expected, rtol=0.05)
    model = suite.linear_model()
    np.testing.assert_allclose(np.sqrt(np.diag(model.R)), expected)
    np.testing.assert_allclose(model.C, [[0, 1], [G, 0], [1, 0]])
    np.testing.assert_allclose(model.R, np.diag(np.square(expected)))
    np.testing.assert_array_equal(model.D, [[0], [1], [0]])
    assert model.Hw.shape == (3, 0) and model.stochastic.all()
    assert suite.names == ("roll_rate", "lateral_accel", "roll")
    assert suite.units == ("rad/s", "m/s^2", "rad")
    assert suite.measured_state == (1, None, 0)
    # roll sensor optional; the input channels (speed, yaw rate) by default
    assert imu(dt_s=0.01).names == ("roll_rate", "lateral_accel", "speed", "yaw_rate")


def test_imu_gyro_bias_random_walk():
    suite = imu(dt_s=0.01, gyro_noise_density=0.0, gyro_bias_walk=0.01, gyro_bias0_std=0.0,
                accel_noise_density=0.0)
    suite.allocate(1)
    streams = NoiseStreams(1)
    streams.seed(0, 1)
    members = np.arange(1)
    sample = Sample(np.zeros((1, 2)), np.zeros(1), np.zeros((1, 1)), np.zeros((1, 0)),
                    members)
    noise = streams.view(members)
    suite.reset(sample, noise)
    biases = [suite.measure(sample, noise)[0, 0] for _ in range(1000)]
    assert biases[0] == 0.0  # calibrated at reset: b_0 = 0
    increments = np.diff(biases)
    assert increments.std() == pytest.approx(0.01 * np.sqrt(0.01), rel=0.1)
    suite.reset(sample, noise)
    assert suite.measure(sample, noise)[0, 0] == 0.0  # the bias restarts at zero
    # with an initial bias spread, b_0 is drawn at reset
    spread = imu(dt_s=0.01, gyro_noise_density=0.0, gyro_bias_walk=0.0, gyro_bias0_std=0.01)
    b0 = _measure(spread, np.zeros(2), 0.0, num=4000)[:, 0]
    assert b0.std() == pytest.approx(0.01, rel=0.05)


@pytest.mark.parametrize("disturbance", [None, "zhang-decay"])
def test_paper_suite_is_H_x_plus_L_v(disturbance):
    env = VehicleRollEnv(sensors="paper", manoeuvre="paper-decay", disturbance=disturbance)
    assert isinstance(env.sensors, PaperRollChannel)
    obs, info = env.reset(seed=0, options={"x0": [0.1, 1.0]})
    pm = paper_model()
    np.testing.assert_allclose(obs, pm.H @ [0.1, 1.0] + pm.L[:, 0] * 0.01, rtol=1e-14)
    for k in range(1, 30):
        obs, _, _, _, info = env.step(np.zeros(1))
        v = paper_disturbance(k)
        np.testing.assert_allclose(obs, pm.H @ info["state"] + pm.L[:, 0] * v, rtol=1e-12)
        # the manoeuvre v_{k-1} is held over the step that ends at sample k
        assert info["action_applied"][0] == pytest.approx(paper_disturbance(k - 1))
        assert info["manoeuvre"][0] == info["action_applied"][0]
        if disturbance is None:
            assert info["disturbance"].shape == (0,)
        else:  # the scenario's w, like the input, is the value held over the step
            np.testing.assert_allclose(info["disturbance"], [paper_disturbance(k - 1)],
                                       rtol=1e-12)
    model = env.sensors.linear_model()
    np.testing.assert_array_equal(model.C, pm.H)
    assert np.all(np.linalg.eigvalsh(model.R) > 0)


def test_accelerometer_on_the_rig_sees_a_y_and_gravity():
    env = VehicleRollEnv(sensor_kwargs={"gyro_noise_density": 0.0, "gyro_bias_walk": 0.0,
                                        "accel_noise_density": 0.0})
    env.reset(seed=0)
    for _ in range(300):
        obs, _, _, _, info = env.step(np.array([6.0]))
    eta = info["state"][0]
    assert obs[1] == pytest.approx(6.0 * np.cos(eta) + G * np.sin(eta), rel=1e-12)
    assert obs[0] == info["state"][1]


def test_sensor_presets_and_errors():
    rig = VehicleRollRig()
    suite = rig.sensors("imu", dt_s=0.01)
    assert isinstance(suite, Suite) and suite.names == ("roll_rate", "lateral_accel", "speed",
                                                        "yaw_rate")
    assert isinstance(rig.sensors("paper", dt_s=0.01), PaperRollChannel)
    assert rig.sensors(None, dt_s=0.01).names == suite.names  # default preset: imu
    assert rig.sensors("imu", dt_s=0.01, roll_sensor=True).dim == 5
    with pytest.raises(ValueError, match=r"expected one of \('imu', 'paper', 'hardware'\)"):
        rig.sensors("encoders", dt_s=0.01)
    with pytest.raises(ValueError, match="density must be finite and non-negative"):
        rig.sensors("imu", dt_s=0.01, gyro_noise_density=-1.0)
    with pytest.raises(ValueError, match="bad option for sensor preset 'imu'"):
        rig.sensors("imu", dt_s=0.01, sonar=True)
    with pytest.raises(ValueError, match="noise_std must be finite"):
        rig.sensors("paper", dt_s=0.01, noise_std=-1.0)
    with pytest.raises(ValueError, match="sensor_kwargs is only used with a sensor preset"):
        VehicleRollEnv(sensors=imu(), sensor_kwargs={"roll_sensor": True})


# ---------------------------------------------------------------- environment contract
@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("sensors, manoeuvre", [("imu", None), ("imu", "double-lane-change"),
                                                ("paper", "paper-decay")])
def test_check_env(sensors, manoeuvre):
    env = gym.make("testbed/VehicleRoll-v0", sensors=sensors, manoeuvre=manoeuvre,
                   sensor_kwargs={"roll_sensor": True} if sensors == "imu" else None)
    check_env(env.unwrapped, skip_render_check=True)


def test_registered_with_time_limit():
    env = gym.make("testbed/VehicleRoll-v0")
    assert env.spec.max_episode_steps == 1000
    env.reset(seed=0)
    truncated, steps = False, 0
    while not truncated:
        _, _, _, truncated, _ = env.step(np.zeros(1))
        steps += 1
    assert steps == 1000


def _rollout(seed: int, n: int = 200) -> list:
    env = VehicleRollEnv(manoeuvre="sine-sweep", sensor_kwargs={"roll_sensor": True,
                                                                "gyro_bias0_std": 0.01})
    obs, info = env.reset(seed=seed)
    out = [obs, info["state"]]
    rng = np.random.default_rng(seed)
    for _ in range(n):
        obs, reward, _, _, info = env.step(rng.uniform(-1, 1, 1))
        out += [obs, info["state"], np.array([reward, info["t"], info["manoeuvre"][0],
                                              info["step_noise"][0]]),
                info["action_applied"], info["action_clipped"]]
    return out


def test_same_seed_is_bitwise_identical_and_other_seed_differs():
    a, b, c = _rollout(3), _rollout(3), _rollout(4)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(a, c, strict=True))


def test_info_contents_and_reset_defaults():
    env = VehicleRollEnv(reset_noise_scale=0.0)
    obs, info = env.reset(seed=0)
    assert obs.shape == (4,) and env.observation_space.contains(obs)
    np.testing.assert_array_equal(info["state"], [0.0, 0.0])
    assert info["t"] == 0.0 and info["action_applied"][0] == 0.0
    # the roll angle is the tracked state (zero reference); no disturbance signal
    np.testing.assert_array_equal(info["setpoint"], [0.0])
    assert info["disturbance"].shape == (0,)
    _, reward, terminated, truncated, info = env.step(np.array([3.0]))
    assert info["t"] == pytest.approx(0.01)
    assert reward == pytest.approx(-info["state"][0] ** 2)
    assert not terminated and not truncated
    np.testing.assert_array_equal(info["action_applied"], [3.0])
    np.testing.assert_array_equal(info["action_clipped"], [False])
    np.testing.assert_array_equal(info["manoeuvre"], [0.0])
    assert info["step_noise"].shape == (1,) and info["step_noise"][0] != 0.0
    assert info["state"][0] > 0  # a left turn (a_y > 0) rolls the body outwards (+)
    assert set(info) >= {"state", "t", "disturbance", "setpoint", "action_applied",
                         "action_clipped", "manoeuvre", "step_noise", "process_accel"}
    assert env.state_names == ["roll", "roll_rate"]
    assert env.action_names == ["a_y"]
    assert env.units()["a_y"] == "m/s^2" and env.units()["roll"] == "rad"
    pos, quat = env.body_poses()
    assert pos.shape == (env.rig.model.nbody, 3) and quat.shape == (env.rig.model.nbody, 4)


def test_rollover_terminates():
    env = VehicleRollEnv(params={"roll_stiffness": 0.0, "roll_damping": 0.0})
    env.reset(seed=0, options={"x0": [ROLLOVER_RAD - 0.01, 1.0]})
    terminated = False
    for _ in range(10):
        _, _, terminated, _, info = env.step(np.zeros(1))
        if terminated:
            break
    assert terminated and abs(info["state"][0]) > ROLLOVER_RAD


def test_actions_beyond_the_limit_are_clipped_and_flagged():
    env = VehicleRollEnv()
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([9.5]))
    assert info["action_applied"][0] == 8.0 and info["action_clipped"].tolist() == [True]
    env = VehicleRollEnv(manoeuvre="step-steer", manoeuvre_params={"amplitude_m_s2": 7.0,
                                                                    "t_start_s": 0.0,
                                                                    "rise_time_s": 0.01})
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.5]))  # manoeuvre(0) = 0: no clipping
    assert info["action_applied"][0] == 0.5 and not info["action_clipped"][0]
    _, _, _, _, info = env.step(np.array([2.0]))  # 7 + 2 > 8
    assert info["action_applied"][0] == 8.0 and info["manoeuvre"][0] == 7.0
    assert info["action_clipped"][0]


@pytest.mark.parametrize("action", [[np.nan], [np.inf], [1.0, 2.0], [[1.0]], 1.0, "abc", None])
def test_bad_action_raises_and_leaves_state_unchanged(action):
    env = VehicleRollEnv(manoeuvre="step-steer")
    env.reset(seed=0)
    for _ in range(120):
        env.step(np.array([1.0]))
    noise = env.sim.noise

    def snapshot():  # physics (qpos, qvel, xfrc_applied...), model, time, noise, sensors
        return (env.sim.physics.state.copy(), _member_model(env).dof_damping.copy(), env.t_s,
                noise.generators[0].bit_generator.state, noise._pos.copy(),
                env.sim.obs.copy(), env.sim.info["step_noise"].copy())

    before = snapshot()
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    after = snapshot()
    for x, y in zip(before, after, strict=True):
        if isinstance(x, dict):
            assert x == y
        else:
            np.testing.assert_array_equal(x, y)


def test_bad_names_and_unphysical_parameters():
    with pytest.raises(ValueError, match=r"expected one of \['double-lane-change'"):
        VehicleRollEnv(manoeuvre="slalom")
    with pytest.raises(ValueError, match=r"expected one of \('imu', 'paper', 'hardware'\)"):
        VehicleRollEnv(sensors="lidar")
    with pytest.raises(ValueError, match="unknown disturbance 'basin-helicopter'"):
        VehicleRollEnv(disturbance="basin-helicopter")
    with pytest.raises(ValueError, match="no process-noise model"):
        VehicleRollEnv(process_noise=1.0)
    for name in ("sprung_mass_kg", "roll_stiffness", "roll_damping"):
        with pytest.raises(ValueError, match=name):
            VehicleRollEnv(params={name: -1.0})
        with pytest.raises(ValueError, match=f"VehicleRollParams.{name} must be"):
            VehicleRollParams(**{name: -5.0}).validate()
    with pytest.raises(ValueError, match="sprung_mass_kg must be positive"):
        VehicleRollParams(sprung_mass_kg=0.0).validate()
    with pytest.raises(ValueError, match="roll_inertia"):
        VehicleRollParams(com_height_m=2.0).validate()  # I_xx < m h^2
    env = VehicleRollEnv()
    with pytest.raises(ValueError, match="roll_damping"):
        env.reset(options={"params": {"roll_damping": -2.0}})
    with pytest.raises(ValueError, match="unknown params key 'mass'"):
        env.reset(options={"params": {"mass": 1.1}})
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"bogus": 1})
    with pytest.raises(ValueError, match="setpoints"):  # a valid key, but an empty table
        env.reset(options={"setpoints": []})
    with pytest.raises(ValueError, match="x0"):
        env.reset(options={"x0": [0.0, 0.0, 0.0]})
    with pytest.raises(ValueError, match="x0"):
        env.reset(options={"x0": [np.nan, 0.0]})
    with pytest.raises(ValueError, match="beyond rollover"):
        env.reset(options={"x0": [2.0, 0.0]})


def test_model_mismatch_params_scale_the_rig():
    env = VehicleRollEnv()
    env.reset(seed=0, options={"params": {"roll_stiffness": 0.5, "damping_noise": 0.0}})
    assert _member_model(env).jnt_stiffness[0] == pytest.approx(55314 / 2)
    env.step(np.zeros(1))
    assert _member_model(env).dof_damping[0] == 53071.0  # D_n = 0: no damping noise
    env.reset(seed=0)
    assert _member_model(env).jnt_stiffness[0] == 55314.0
    env.step(np.zeros(1))
    assert _member_model(env).dof_damping[0] != 53071.0  # damping noise back
    assert env.nominal_params == VehicleRollParams()


# ---------------------------------------------------------------- experiment
def vehicle_scenario(estimator: str = "kalman", **kwargs) -> Scenario:
    return Scenario(rig="vehicle-roll", estimator=estimator, **kwargs)


def test_kalman_filter_on_imu_during_double_lane_change():
    traj, summary = run(vehicle_scenario(manoeuvre="double-lane-change", sensors="imu",
                                         duration_s=10.0, seed=0), progress=False)
    rmse_deg = {k: np.rad2deg(v) for k, v in summary["rmse"].items()}
    meas_deg = {k: np.rad2deg(v) for k, v in summary["measurement_rmse"].items()}
    print(f"Kalman/imu/double-lane-change RMSE: roll {rmse_deg['roll']:.4f} deg, roll_rate "
          f"{rmse_deg['roll_rate']:.4f} deg/s; gyro measurement RMSE "
          f"{meas_deg['roll_rate']:.4f} deg/s; NEES {summary['nees_mean']:.2f}; peak roll "
          f"{np.rad2deg(np.abs(traj.state[:, 0]).max()):.2f} deg")
    assert rmse_deg["roll"] < 0.5
    assert rmse_deg["roll_rate"] < meas_deg["roll_rate"]  # better than the raw gyro
    assert summary["steps"] == 1000 and summary["clipped_fraction"] == 0.0
    # the roll angle is tracked against a zero reference
    assert traj.setpoint.shape == (1001, 1) and traj.setpoint_names() == ["roll"]
    assert not traj.setpoint.any()
    assert traj.action_names == ["a_y [m/s^2]"]
    assert np.abs(traj.action[:, 0]).max() == pytest.approx(6.16, abs=0.01)


def test_process_noise_derivation():
    p = VehicleRollParams()
    Q = process_noise_intensity(p, 0.01, a_y_std=0.1, design_roll_rate=0.2)
    q_damp = (p.damping_noise * 0.01 / p.roll_inertia * 0.2) ** 2 / 0.01  # paper's C x w
    q_ay = (0.25 * 0.01 * 0.1) ** 2 / 0.01
    np.testing.assert_allclose(Q, np.diag([0.0, q_damp + q_ay]), rtol=1e-12)
    design = VehicleRollRig().design_model(imu(dt_s=0.01), 0.01, a_y_std=0.1,
                                           design_roll_rate=0.2)
    np.testing.assert_allclose(design.continuous.Q, Q, rtol=1e-12)


@pytest.mark.parametrize("filter_name, sensors", [("kalman", "paper"), ("kalman-bucy", "imu")])
def test_other_filters_and_suites_run(filter_name, sensors):
    _, summary = run(vehicle_scenario(filter_name, sensors=sensors, manoeuvre="step-steer",
                                      duration_s=2.0, seed=1), record=False, progress=False)
    assert np.rad2deg(summary["rmse"]["roll"]) < 0.5
    with pytest.raises(ValueError, match="expected one of"):
        run(vehicle_scenario("hinf", duration_s=0.1), record=False, progress=False)


def test_double_lane_change_at_one_time_equals_its_numpy_scalar_evaluation():
    """The double lane change at one time runs on Python floats (``_at``): bitwise the
    value of the same formula on numpy scalars (what a 0-d time computed before)."""
    from testbed.rigs.vehicle_roll.manoeuvres import MANOEUVRES

    f = MANOEUVRES["double-lane-change"]()
    times = np.concatenate([np.linspace(-1.0, 12.0, 1301),
                            np.random.default_rng(0).uniform(0.0, 10.0, 500)])
    fast = np.array([f(float(t)) for t in times])
    slow = []
    for t in times:
        _, k1, k2, a, b = f._terms(np.float64(t))
        ypp = 0.5 * f.offset_m * (-2 * k1**2 * a * (1 - a**2) + 2 * k2**2 * b * (1 - b**2))
        slow.append(float(f.speed_m_s**2 * ypp))
    assert fast.tobytes() == np.array(slow).tobytes()
