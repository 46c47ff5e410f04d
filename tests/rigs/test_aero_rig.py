"""The Quanser Aero rig against Quanser's linear model, its own physics and its options."""

from __future__ import annotations

import json

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from scipy.integrate import solve_ivp

from testbed.envs import RigEnv
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs import resolve_rig
from testbed.rigs.aero import AeroHardware, AeroIMU, AeroParams, AeroRig, quanser_model
from testbed.sensors import Sample
from testbed.sim import build_simulator

LOCKED = {"yaw_locked": True}


def _quanser_from_the_table(locked: bool) -> tuple[np.ndarray, np.ndarray]:
    """Quanser's A, B written here from the parameter script's parts (independent of the
    rig's code): J_p = m_b L^2 / 12 + 2 m_p r^2, J_y = J_p + m_y r_y^2 / 2."""
    j_p = 0.094 * 0.1651**2 / 12 + 2 * 0.43 * 0.15875**2
    j_y = j_p + 0.526 * 0.02**2 / 2
    k_sp, d_p, d_y = 0.037463, 0.0071116, 0.0220
    k_pp, k_py, k_yp, k_yy = 0.0011, 0.0021, -0.0027, 0.0022
    if locked:
        return (np.array([[0, 1], [-k_sp / j_p, -d_p / j_p]]),
                np.array([[0, 0], [k_pp / j_p, k_py / j_p]]))
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-k_sp / j_p, 0, -d_p / j_p, 0],
                  [0, 0, 0, -d_y / j_y]])
    B = np.array([[0, 0], [0, 0], [k_pp / j_p, k_py / j_p], [k_yp / j_y, k_yy / j_y]])
    return A, B


@pytest.mark.parametrize("profile", ["paper", "hardware"])
@pytest.mark.parametrize("locked", [False, True])
def test_linearization_equals_quanser_linear_model(locked, profile):
    """Within 1e-9 (absolute, entries up to 1.7): central differences of MuJoCo at level."""
    rig = AeroRig(profile=profile, options={"yaw_locked": locked})
    A, B = rig.linearize()
    A_q, B_q = _quanser_from_the_table(locked)
    np.testing.assert_allclose(A, A_q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(B, B_q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(quanser_model(AeroParams(), locked)[0], A_q, rtol=1e-12)
    # the table's rounded inertias
    p = AeroParams()
    assert p.pitch_inertia == pytest.approx(0.0219, abs=5e-5)
    assert p.yaw_inertia == pytest.approx(0.0220, abs=5e-5)


def test_joint_names_axes_actuators_and_nominal_model():
    rig = AeroRig()
    m = rig.model
    pitch, yaw = rig.joint_id("pitch"), rig.joint_id("yaw")
    np.testing.assert_allclose(m.jnt_axis[yaw], [0, 0, 1])
    np.testing.assert_allclose(m.jnt_axis[pitch], [0, -1, 0])
    assert not m.jnt_limited[pitch] and not m.jnt_limited[yaw]
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(m.nu)]
    assert names == ["pitch_motor", "yaw_motor"]
    np.testing.assert_allclose(m.actuator_ctrlrange, [[-24, 24], [-24, 24]])
    body = rig.body_id("aero")
    assert m.body_mass[body] == pytest.approx(0.954)
    # the MJCF's written numbers are the nominal ones the rig writes at load
    raw = mujoco.MjModel.from_xml_path(str(AeroRig.resolved_xml_path()))
    for field in ("body_mass", "body_ipos", "body_inertia", "dof_damping", "dof_frictionloss",
                  "actuator_gear", "site_pos"):
        np.testing.assert_allclose(getattr(m, field), getattr(raw, field), rtol=2e-4,
                                   atol=1e-9, err_msg=field)
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, AeroRig.render_camera) >= 0


def test_pitch_stiffness_is_gravity_on_the_mass_offset():
    p = AeroParams()
    assert p.com_depth_m == pytest.approx(0.037463 / (0.954 * 9.81))
    rig = AeroRig(p.scaled({"pitch_stiffness": 2.2}))
    np.testing.assert_allclose(rig.model.body_ipos[rig.body_id("aero")],
                               [0, 0, -2.2 * p.com_depth_m])
    assert rig.model.jnt_stiffness[rig.joint_id("pitch")] == 0.0  # not a spring
    A = rig.linearize()[0]
    assert A[2, 0] == pytest.approx(-2.2 * 0.037463 / p.pitch_inertia, rel=1e-7)
    rig.model.opt.gravity[:] = 0.0
    assert abs(rig.linearize()[0][2, 0]) < 1e-9


def test_free_pitch_response_is_the_pendulum_ode():
    """Yaw locked, no friction: J_p th'' = -m g d sin(th) - D_p th' (solve_ivp)."""
    p = AeroParams(pitch_coulomb_Nm=0.0)
    rig = AeroRig(p, options=LOCKED)
    data = mujoco.MjData(rig.model)
    th0 = np.deg2rad(40.0)
    rig.set_state(np.array([th0, 0.0]), data)
    steps = 3000
    got = np.zeros(steps)
    for k in range(steps):
        mujoco.mj_step(rig.model, data)
        got[k] = data.qpos[rig.qpos_adr[0]]
    t = rig.model.opt.timestep * np.arange(1, steps + 1)

    def ode(_, y):
        return [y[1], (-p.pitch_stiffness * np.sin(y[0]) - p.pitch_damping * y[1])
                / p.pitch_inertia]

    ref = solve_ivp(ode, (0, t[-1]), [th0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12).y[0]
    np.testing.assert_allclose(got, ref, atol=2e-3 * th0)
    # the nonlinearity is there: the period is longer than the small-angle one
    assert np.max(np.abs(got - ref)) < 0.05 * np.max(np.abs(ref - th0 * np.cos(
        np.sqrt(p.pitch_stiffness / p.pitch_inertia) * t)))


def test_coulomb_friction_is_the_joint_frictionloss_and_holds_small_offsets():
    p = AeroParams()
    rig = AeroRig(p.scaled({"pitch_coulomb_Nm": 3.0, "yaw_coulomb_Nm": 2.0}))
    assert rig.model.dof_frictionloss[rig.dof_adr[0]] == pytest.approx(1.5e-3)
    assert rig.model.dof_frictionloss[rig.dof_adr[1]] == pytest.approx(1e-3)
    # friction 0.01 N m holds an offset whose gravity torque is smaller (K_sp th = 0.0065)
    held = AeroRig(AeroParams(pitch_coulomb_Nm=0.01), options=LOCKED)
    data = mujoco.MjData(held.model)
    held.set_state(np.array([np.deg2rad(10.0), 0.0]), data)
    for _ in range(2000):
        mujoco.mj_step(held.model, data)
    assert np.rad2deg(data.qpos[0]) > 9.0
    free = AeroRig(AeroParams(pitch_coulomb_Nm=0.0), options=LOCKED)
    data = mujoco.MjData(free.model)
    free.set_state(np.array([np.deg2rad(10.0), 0.0]), data)
    for _ in range(2000):
        mujoco.mj_step(free.model, data)
    assert np.rad2deg(data.qpos[0]) < 5.0


def test_voltage_signs_and_cross_couplings():
    """Positive V_pitch raises the nose and yaws negative (K_yp < 0); positive V_yaw yaws
    positive and raises the nose (K_py > 0)."""
    rig = AeroRig(AeroParams(pitch_coulomb_Nm=0.0, yaw_coulomb_Nm=0.0))
    for u, signs in (([5.0, 0.0], (1, -1)), ([0.0, 5.0], (1, 1))):
        data = mujoco.MjData(rig.model)
        rig.set_state(np.zeros(4), data)
        data.ctrl[:] = u
        for _ in range(200):
            mujoco.mj_step(rig.model, data)
        x = rig.get_state(data)
        assert np.sign(x[0]) == signs[0] and np.sign(x[1]) == signs[1]


def test_rig_option_yaw_locked_changes_the_instance_declarations():
    free, locked = AeroRig(), AeroRig(options={"yaw_locked": "true"})
    assert (free.model.nq, locked.model.nq) == (2, 1)
    assert locked.options == LOCKED and free.options == {"yaw_locked": False}
    assert locked.state_names == ("pitch", "pitch_rate") and locked.n_states == 2
    assert locked.action_names == free.action_names == ("V_pitch", "V_yaw")
    assert AeroRig.state_names == free.state_names  # the class is unchanged
    assert locked.tracked_states == ("pitch",) and locked.validate_setpoints(
        locked.default_setpoints).shape[1] == 2
    assert locked.sensors().names == ("pitch",)
    motors = ("rotor_speed_pitch", "rotor_speed_yaw", "current_pitch", "current_yaw")
    assert AeroRig(profile="hardware", options=LOCKED).sensors().names == (
        "pitch", "gyro_pitch", "accel_x", *motors)
    assert AeroRig(profile="hardware").sensors().names == (
        "pitch", "yaw", "gyro_pitch", "gyro_yaw", "accel_x", *motors)
    assert locked.random_x0(np.ones((3, locked.x0_draws))).shape == (3, 2)
    assert locked.process_noise_matrix().shape == (2, 1)
    mismatch = locked.parameter_mismatch()
    assert mismatch.options == LOCKED
    assert mismatch.derivatives()["pitch_stiffness"].shape == (2, 2)
    with pytest.raises(ValueError, match="no option 'yaw_lock'"):
        AeroRig(options={"yaw_lock": True})
    with pytest.raises(ValueError, match="'yaw_locked' must be a bool"):
        AeroRig(options={"yaw_locked": "maybe"})


def test_rotor_lag_time_constant_on_hardware():
    """filterexact act' = (V - act) / tau: 63 % of a step after tau (0.04 s, or scaled)."""
    for scale in (1.0, 2.0):
        rig = AeroRig(AeroParams().scaled({"rotor_time_constant_pitch_s": scale}),
                      profile="hardware")
        assert rig.model.na == 2
        data = mujoco.MjData(rig.model)
        data.ctrl[:] = [4.0, 4.0]
        tau = 0.04 * scale
        for _ in range(int(round(tau / rig.model.opt.timestep))):
            mujoco.mj_step(rig.model, data)
        assert data.act[0] / 4.0 == pytest.approx(1 - np.exp(-1), abs=2e-3)
        assert data.act[1] / 4.0 == pytest.approx(1 - np.exp(-scale), abs=2e-3)
    A, _ = AeroRig(profile="hardware").linearize(motor_states=True)
    np.testing.assert_allclose(np.diag(A)[-2:], [-25.0, -25.0], rtol=1e-6)
    assert AeroRig().model.na == 0


@pytest.mark.parametrize("locked", [False, True])
def test_imu_channels_equal_mujoco_gyro_and_accelerometer(locked):
    spec = mujoco.MjSpec.from_file(str(AeroRig.resolved_xml_path()))
    if locked:
        spec.delete(spec.joint("yaw"))
    for name, kind in (("gyro", mujoco.mjtSensor.mjSENS_GYRO),
                       ("acc", mujoco.mjtSensor.mjSENS_ACCELEROMETER)):
        spec.add_sensor(name=name, type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu")
    model = spec.compile()
    data = mujoco.MjData(model)
    rig, imu = AeroRig(options={"yaw_locked": locked}), AeroIMU(locked)
    rng = np.random.default_rng(1)
    for _ in range(20):
        x = rng.normal(0, 1, rig.n_states)
        rig.set_state(x, data, model)
        ours = imu.measure(Sample(x[None], np.zeros(1), np.zeros((1, 2)), np.zeros((1, 0))),
                           None)[0]
        gyro, acc = data.sensordata[:3], data.sensordata[3:6]
        expected = [-gyro[1], acc[0]] if locked else [-gyro[1], gyro[2], acc[0]]
        np.testing.assert_allclose(ours, expected, rtol=1e-9, atol=1e-9)
    C = imu.linear_model().C
    assert C.shape == (len(imu.names), rig.n_states)


def test_hardware_gyro_errors_bias_noise_and_quantization():
    """At rest (no friction to settle on, zero input): gyro = standing bias + white noise,
    quantized; the bias spread over members is the declared 0.0125 rad/s."""
    hw = AeroHardware()
    n = 400
    sim = build_simulator("aero", n, profile="hardware", ambient_noise=0.0,
                          reset_noise_scale=0.0, num_threads=1)
    sim.reset(seeds=list(range(n)))
    names = sim.sensors.names
    g = names.index("gyro_pitch")
    rows = []
    for _ in range(30):
        sim.step(np.zeros((n, 2)))
        rows.append(np.array(sim.obs[:, g]))
    y = np.array(rows)  # (steps, members)
    assert np.allclose(y / hw.gyro_step, np.round(y / hw.gyro_step), atol=1e-6)
    bias = y.mean(axis=0)
    assert np.std(bias) == pytest.approx(hw.gyro_bias0_std, rel=0.1)
    noise = np.std(np.diff(y, axis=0)) / np.sqrt(2)
    assert noise == pytest.approx(hw.gyro_noise_std, rel=0.05)
    sim.close()


def test_params_validation_names_the_field():
    with pytest.raises(ValueError, match="pitch_inertia must be positive"):
        AeroParams(pitch_inertia=-1.0).validate()
    with pytest.raises(ValueError, match="yaw_damping must be >= 0"):
        AeroParams(yaw_damping=-0.1).validate()
    with pytest.raises(ValueError, match="yaw_inertia must exceed yoke_inertia"):
        AeroParams(yaw_inertia=1e-5).validate()
    with pytest.raises(ValueError, match="unknown params key 'stiffness'"):
        AeroParams().scaled({"stiffness": 2.0})
    assert AeroParams().scaled({"pitch_coulomb_Nm": 0.0}).pitch_coulomb_Nm == 0.0
    for name, (low, high) in AeroRig.identifiable.items():
        assert low < 1 < high, name
    assert AeroRig.identifiable["pitch_stiffness"][1] >= 2.2  # a real unit's stiffness


def test_cubic_model_matches_the_mujoco_gravity_torque():
    """The expansion's pitch acceleration against MuJoCo's at 0.3 rad: error O(th^5)."""
    for locked in (False, True):
        rig = AeroRig(options={"yaw_locked": locked})
        design = rig.design_model(rig.sensors(), 0.01)
        cubic = AeroRig.cubic_model(design)
        x = np.zeros(rig.n_states)
        x[0] = 0.3
        row = rig.state_names.index("pitch_rate")
        data = mujoco.MjData(rig.model)
        rig.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS)
        rig.set_state(x, data)
        mujoco.mj_forward(rig.model, data)
        truth = data.qacc[rig.dof_adr[0]]
        c = AeroParams().pitch_stiffness / AeroParams().pitch_inertia
        assert truth == pytest.approx(-c * np.sin(0.3), rel=1e-6)
        assert cubic.f(x)[row] == pytest.approx(truth, abs=1.5 * c * 0.3**5 / 120)
        assert abs(design.continuous.A[row] @ x - truth) > 10 * c * 0.3**5 / 120


def test_designer_options_reach_the_nonlinear_filters_rig():
    from testbed.estimators.nonlinear import nominal_rig

    rig = AeroRig(profile="hardware", options=LOCKED)
    design = rig.design_model(rig.sensors(dt_s=0.01), 0.01)
    assert design.extras["rig_options"] == LOCKED
    assert design.state_names[:4] == ("pitch", "pitch_rate", "rotor_pitch", "rotor_yaw")
    assert "bias_gyro_pitch" in design.state_names
    assert nominal_rig(design).n_states == 2 and nominal_rig(design).profile == "paper"


def test_registered_env_passes_check_env_and_a_locked_rig_env_too():
    env = gym.make("testbed/Aero2DOF-v0")
    assert env.spec.max_episode_steps == 2000
    check_env(env.unwrapped, skip_render_check=True)
    assert resolve_rig("aero") is AeroRig
    locked = RigEnv(AeroRig(profile="hardware", options=LOCKED))
    check_env(locked, skip_render_check=True)
    obs, info = locked.reset(seed=3)
    # pitch, gyro_pitch, accel_x and the four motor channels
    assert obs.shape == (7,) and info["state"].shape == (2,)


@pytest.mark.parametrize("profile", ["paper", "hardware"])
def test_yaw_locked_closed_loop_with_kalman_tracks_pitch(profile):
    traj, summary = runner.run(Scenario(rig="aero", rig_options=LOCKED, profile=profile,
                                        estimator="kalman", duration_s=8.0, seed=2),
                               record=True)
    assert traj.state_names == ["pitch", "pitch_rate"] or tuple(traj.state_names) == (
        "pitch", "pitch_rate")
    pitch = np.asarray(traj.state).reshape(-1, 2)[:, 0]
    t = np.asarray(traj.t_s).ravel()
    # the 10 deg step at 5 s is reached within 1 deg by 8 s
    assert abs(np.rad2deg(pitch[-1]) - 10.0) < 1.0
    assert np.all(np.abs(np.rad2deg(pitch[t < 4.9])) < 1.0)
    assert summary["rmse"]["pitch"] < np.deg2rad(0.2)


def _cli(argv: list[str]) -> int:
    """``testbed ARGS`` in this process (the command's own entry point)."""
    from testbed.cli import main

    return main(argv)


@pytest.mark.parametrize("profile", ["paper", "hardware"])
def test_cli_runs_aero_closed_loop_with_kalman(profile, tmp_path):
    path = tmp_path / "aero.json"
    assert _cli(["run", "aero", "--duration", "2", "--profile", profile, "--filter", "kalman",
                 "--json", str(path), "--no-progress"]) == 0
    data = json.loads(path.read_text())
    assert data["scenario"]["rig"] == "aero"
    rmse = data["rmse"]
    assert set(rmse) == {"pitch", "yaw", "pitch_rate", "yaw_rate"}
    assert rmse["pitch"] < np.deg2rad(0.2) and rmse["yaw"] < np.deg2rad(0.2)


def test_cli_acceptance_command_yaw_locked_real_stiffness(tmp_path):
    """``testbed run aero --profile hardware --rig-option yaw_locked=true --param
    pitch_stiffness=2.2``: the pitch-only rig with a real unit's stiffness, designers nominal."""
    path = tmp_path / "aero.json"
    assert _cli(["run", "aero", "--profile", "hardware", "--rig-option", "yaw_locked=true",
                 "--param", "pitch_stiffness=2.2", "--duration", "2", "--json", str(path),
                 "--no-progress"]) == 0
    data = json.loads(path.read_text())
    assert set(data["rmse"]) == {"pitch", "pitch_rate"}
    assert data["rmse"]["pitch"] < np.deg2rad(0.2)


@pytest.mark.parametrize("estimator", ["kalman-bucy", "ekf", "ukf", "lmi-hinf", "poly-hinf"])
def test_estimator_families_run_on_both_configurations(estimator):
    for options in ({}, LOCKED):
        _, summary = runner.run(Scenario(rig="aero", rig_options=options, profile="hardware",
                                         estimator=estimator, duration_s=1.0, seed=4),
                                record=False)
        assert all(np.isfinite(v) and v < 0.05 for v in summary["rmse"].values()), summary


@pytest.mark.slow
def test_vc_discrete_runs_free_and_locked_with_output_injection():
    _, free = runner.run(Scenario(rig="aero", estimator="vc-discrete", duration_s=1.0),
                         record=False)
    _, locked = runner.run(Scenario(rig="aero", rig_options=LOCKED, estimator="vc-discrete",
                                    estimator_options={"output_injection": True},
                                    duration_s=1.0), record=False)
    assert max(free["rmse"].values()) < 0.05 and max(locked["rmse"].values()) < 0.05


# ---------------------------------------------------------------- rotor speeds, currents
MOTORS = ("rotor_speed_pitch", "rotor_speed_yaw", "current_pitch", "current_yaw")
#: The DC motor written here from its assumptions (independent of the rig's code): R, k and
#: the load b giving a real unit's steady-to-peak current ratio 0.09 / 1.6.
R_OHM, K_M = 8.4, 0.042
B_LOAD = (0.09 / 1.6) * K_M**2 / (R_OHM * (1 - 0.09 / 1.6))
G_RAD_S_V = K_M / (R_OHM * B_LOAD + K_M**2)


def _motor_sim(n: int, locked: bool, sensors=None, tau_scale: float = 1.0):
    from testbed.rigs.aero import AeroMotors
    from testbed.sensors import Suite
    from testbed.sim.simulator import Simulator

    rig = AeroRig(profile="hardware", options={"yaw_locked": locked})
    suite = Suite(AeroMotors(n_states=rig.n_states)) if sensors is None else sensors(rig)
    sim = Simulator(rig, suite, n, frame_skip=1, num_threads=1, reset_noise_scale=0.0,
                    params={"rotor_time_constant_pitch_s": tau_scale})
    return rig, sim


@pytest.mark.parametrize("locked", [False, True])
def test_rotor_speed_and_current_are_the_dc_motor_closed_form(locked):
    """A voltage step from rest: w = G V (1 - exp(-t / tau)) with G = k / (R b + k^2),
    i = (V - k w) / R (peak V / R, steady V b / (R b + k^2)); the unit's own (hidden) time
    constant, read from MuJoCo's actuator state; and the motor's ODE integrated here."""
    rig, sim = _motor_sim(2, locked, tau_scale=1.5)
    sim.reset(seeds=[0, 1])
    V = np.array([[10.0, -6.0], [-3.0, 24.0]])
    tau = np.array([0.06, 0.04])
    dt = rig.model.opt.timestep
    assert np.all(sim.obs == 0.0)  # at rest
    for k in range(1, 1001):
        sim.step(V)
        y = np.array(sim.obs)
        act = sim.physics.actuator_states()
        np.testing.assert_array_equal(y[:, :2], G_RAD_S_V * act)  # MuJoCo's rotor state
        w = G_RAD_S_V * V * (1 - np.exp(-k * dt / tau))
        np.testing.assert_allclose(y[:, :2], w, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(y[:, 2:], (V - K_M * w) / R_OHM, rtol=1e-8, atol=1e-12)
        if k == 1:
            np.testing.assert_allclose(y[:, 2:], V / R_OHM, rtol=0.03)  # the peak
    # steady after 1 s (at least 16 time constants: exp(-16) = 1e-7)
    np.testing.assert_allclose(y[:, :2], K_M * V / (R_OHM * B_LOAD + K_M**2), rtol=1e-6)
    np.testing.assert_allclose(y[:, 2:], V * B_LOAD / (R_OHM * B_LOAD + K_M**2), rtol=1e-5)
    assert sim.sensors.units == ("rad/s", "rad/s", "A", "A")
    # the motor ODE J_r w' = k (V - k w) / R - b w, J_r from tau (the lag is this motor)
    J_r = 0.06 * (R_OHM * B_LOAD + K_M**2) / R_OHM
    ode = solve_ivp(lambda t, w: [(K_M * (10.0 - K_M * w[0]) / R_OHM - B_LOAD * w[0]) / J_r],
                    (0.0, 0.1), [0.0], t_eval=[0.1], rtol=1e-10, atol=1e-10)
    sim.reset(seeds=[0, 1])
    for _ in range(100):
        sim.step(V)
    assert sim.obs[0, 0] == pytest.approx(ode.y[0, -1], rel=1e-6)
    sim.close()


@pytest.mark.parametrize("locked", [False, True])
@pytest.mark.parametrize("n", [1, 3])
def test_motor_channels_leave_the_other_channels_bitwise(locked, n):
    """The hardware preset with the motor channels gives every other channel's numbers of
    the preset without them, bitwise (their noise comes from streams of their own)."""
    from testbed.sensors import Suite

    def without_motors(rig):
        return Suite(*rig.sensors("hardware", dt_s=0.001).sensors[:-1])

    _, new = _motor_sim(n, locked, sensors=lambda rig: rig.sensors("hardware", dt_s=0.001))
    _, old = _motor_sim(n, locked, sensors=without_motors)
    m = old.sensors.dim
    assert new.sensors.names[m:] == MOTORS and new.sensors.names[:m] == old.sensors.names
    rng = np.random.default_rng(3)
    for sim in (new, old):
        sim.reset(seeds=list(range(10, 10 + n)))
    np.testing.assert_array_equal(new.obs[:, :m], old.obs)
    for _ in range(60):
        u = rng.uniform(-8, 8, (n, 2))
        new.step(u)
        old.step(u)
        np.testing.assert_array_equal(new.obs[:, :m], old.obs)
        np.testing.assert_array_equal(new.info["state"], old.info["state"])
    new.close()
    old.close()


def test_hardware_motor_channels_noise_quantization_and_seeds():
    """At rest: the readings are the declared white noise, quantized; same seed, same
    numbers; another seed, others."""
    hw = AeroHardware()
    n = 300

    def readings(seeds):
        _, sim = _motor_sim(n, False, sensors=lambda rig: rig.sensors("hardware", dt_s=0.001))
        sim.reset(seeds=seeds)
        rows = []
        for _ in range(10):
            sim.step(np.zeros((n, 2)))
            rows.append(np.array(sim.obs[:, -4:]))
        sim.close()
        return np.array(rows)  # (steps, members, 4)

    y = readings(list(range(n)))
    steps = np.array([hw.rotor_speed_step] * 2 + [hw.current_step] * 2)
    np.testing.assert_allclose(y / steps, np.round(y / steps), atol=1e-9)
    std = np.array([hw.rotor_speed_noise_std] * 2 + [hw.current_noise_std] * 2)
    expected = np.sqrt(std**2 + steps**2 / 12)
    np.testing.assert_allclose(y.reshape(-1, 4).std(axis=0), expected, rtol=0.05)
    np.testing.assert_array_equal(readings(list(range(n))), y)
    assert not np.any(np.all(readings(list(range(1, n + 1))) == y, axis=(0, 2)))


def test_motor_channels_are_described_recorded_and_left_out_of_designs(tmp_path):
    from testbed.io.formats import read_recording
    from testbed.rigs.describe import describe_rig

    channels = describe_rig("aero", profile="hardware")["profiles"]["hardware"]["sensors"]
    listed = {c["name"]: c["unit"] for c in channels["hardware"]["channels"]}
    assert {n: listed[n] for n in MOTORS} == dict(zip(MOTORS, ("rad/s", "rad/s", "A", "A"),
                                                      strict=True))
    rig = AeroRig(profile="hardware")
    suite = rig.sensors()
    design = rig.design_model(suite, 0.01)
    assert not set(np.asarray(design.measurement_index).tolist()) & {
        suite.names.index(n) for n in MOTORS}
    log = tmp_path / "unit.csv"
    assert _cli(["run", "aero", "--profile", "hardware", "--duration", "1", "--save-log",
                 str(log), "--no-progress"]) == 0
    rec = read_recording(log)
    assert set(MOTORS) <= set(rec.channels)
    # the rotor follows its recorded voltage through the lag (exact for a held input)
    speed = np.asarray(rec.channels["rotor_speed_pitch"])
    volts = np.asarray(rec.inputs["V_pitch"])
    decay = np.exp(-rec.dt_s / 0.04)
    act = np.zeros(len(volts))
    for k in range(1, len(volts)):
        act[k] = volts[k - 1] + (act[k - 1] - volts[k - 1]) * decay
    hw = AeroHardware()
    error = speed - G_RAD_S_V * act
    assert np.std(speed) > 5 * hw.rotor_speed_noise_std
    assert np.std(error) < 1.5 * hw.rotor_speed_noise_std
