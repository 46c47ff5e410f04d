"""Batched Monte Carlo and the vector environment: equal to the single-trajectory code."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import (
    check_action_space,
    check_observation_space,
    data_equivalence,
)
from gymnasium.vector import AutoresetMode

import testbed  # noqa: F401  (registers the environments)
from testbed import batch
from testbed.batch import (
    BatchClosedLoop,
    BatchLQRTracker,
    limit_blas_threads,
    monte_carlo,
    run_batch,
    run_seeds,
)
from testbed.control import LQRTracker
from testbed.envs.helicopter import Helicopter2DOFEnv
from testbed.envs.helicopter_vector import (
    Helicopter2DOFVectorEnv,
    HelicopterBatch,
    NoiseStreams,
)
from testbed.experiment import build_helicopter, run_episode
from testbed.metrics import EpisodeMetrics
from testbed.rigs.helicopter import HelicopterParams, gravity_voltage, paper_model

ENV_ID = "testbed/Helicopter2DOF-v0"
TOL = {"rtol": 1e-12, "atol": 1e-12}
NOISY = {"disturbance": "seed000", "process_noise_scale": 1.0, "sensors": "encoders+gyros",
         "sensor_kwargs": {"noise_std_rad": 0.002}}


def assert_summaries_close(batched: dict, single: dict) -> None:
    assert batched.keys() == single.keys()
    assert batched["steps"] == single["steps"]
    for key in ("rmse", "measurement_rmse"):
        assert batched[key].keys() == single[key].keys()
        np.testing.assert_allclose(list(batched[key].values()), list(single[key].values()),
                                   **TOL)
    for key in ("nees_mean", "T_final", "clipped_fraction"):
        if single[key] is None:
            assert batched[key] is None
        else:
            np.testing.assert_allclose(batched[key], single[key], **TOL)


# ---------------------------------------------------------------- batch == sequential
@pytest.mark.parametrize(("filter_name", "duration_s"), [("kalman", 3.0), ("kalman-bucy", 0.5)])
def test_batch_equals_sequential_episodes(filter_name, duration_s):
    seeds = [3, 7, 11, 19]
    options = [None, {"params": {"mass_kg": 1.1, "pitch_damping": 0.9}}, None,
               {"x0": [0.1, 0.2, 0.0, 0.0], "estimator": {"x0": [0.1, 0.2, 0.0, 0.0]}}]
    result = run_batch(filter_name, seeds=seeds, duration_s=duration_s, options=options,
                       record=True, **NOISY)
    rec = result.trajectory
    for i, seed in enumerate(seeds):
        traj, summary = run_episode(build_helicopter(filter_name, **NOISY), duration_s,
                                    seed=seed, options=options[i], progress=False)
        np.testing.assert_array_equal(rec["t_s"], traj.t_s)
        for key in ("state", "estimate", "covariance", "measurement", "action", "setpoint"):
            np.testing.assert_allclose(rec[key][i], getattr(traj, key), **TOL, err_msg=key)
        assert_summaries_close(result.summary(i), summary)
    # the perturbed member really flew a different rig
    assert not np.allclose(rec["state"][1], rec["state"][0])


def test_open_loop_paper_sensors_equal_sequential():
    kw = {"sensors": "paper", "controller": "open-loop", "disturbance": "seed000"}
    result = run_batch(seeds=[0, 1], duration_s=1.0, record=True, **kw)
    for i, seed in enumerate([0, 1]):
        traj, summary = run_episode(build_helicopter(**kw), 1.0, seed=seed, progress=False)
        np.testing.assert_allclose(result.trajectory["state"][i], traj.state, **TOL)
        np.testing.assert_allclose(result.trajectory["estimate"][i], traj.estimate, **TOL)
        assert_summaries_close(result.summary(i), summary)


def test_physics_thread_count_does_not_change_results():
    runs = {}
    for threads in (1, 3):
        res = run_batch(seeds=[1, 2, 3, 4, 5], duration_s=0.5, record=True,
                        num_threads=threads, **NOISY)
        runs[threads] = res.trajectory
    for key in ("state", "estimate", "measurement"):
        np.testing.assert_array_equal(runs[1][key], runs[3][key])


# ---------------------------------------------------------------- pieces
def test_streaming_metrics_match_single_episode_metrics(rng):
    names = ["pitch", "yaw", "pitch_rate", "yaw_rate"]
    n_traj, steps = 5, 50
    x_true = rng.normal(size=(steps, n_traj, 4))
    x_hat = x_true + 0.01 * rng.normal(size=(steps, n_traj, 4))
    A = rng.normal(size=(steps, n_traj, 4, 4))
    P = A @ np.swapaxes(A, -1, -2) + np.eye(4)
    y = rng.normal(size=(steps, n_traj, 2))
    w = rng.normal(size=(steps, n_traj, 4))
    batched = EpisodeMetrics(names, 0.01, [0, 1])
    singles = [EpisodeMetrics(names, 0.01, [0, 1]) for _ in range(n_traj)]
    x0 = rng.normal(size=(n_traj, 4))
    batched.reset(x0)
    for i, m in enumerate(singles):
        m.reset(x0[i])
    for k in range(steps):
        batched.update(x_true[k], x_hat[k], P[k], y[k], w[k])
        for i, m in enumerate(singles):
            m.update(x_true[k, i], x_hat[k, i], P[k, i], y[k, i], w[k, i])
    assert batched.batch_shape == (n_traj,)
    for i, m in enumerate(singles):
        assert batched.summary(i) == m.summary()  # bitwise
    assert batched.summary()["rmse"]["yaw"].shape == (n_traj,)
    with pytest.raises(ValueError, match="shape"):
        batched.reset(np.zeros(3))
    with pytest.raises(ValueError, match="batched"):
        singles[0].summary(0)


def test_batch_lqr_equals_lqr_trackers(rng):
    pm = paper_model()
    nominal = HelicopterParams()
    refs = np.array([0.1, -0.2])
    trackers = [LQRTracker(pm.A, pm.B, 0.01, lambda p: gravity_voltage(nominal, p),
                           lambda t: refs) for _ in range(6)]
    batched = BatchLQRTracker(trackers[0], lambda p: gravity_voltage(nominal, p),
                              lambda t: refs)
    batched.reset(6)
    for k in range(40):
        scale = 5.0 if k % 10 < 3 else 0.05  # large errors saturate: anti-windup
        x_hat = scale * rng.normal(size=(6, 4))
        u = batched(x_hat)
        expected = np.array([tr(x) for tr, x in zip(trackers, x_hat, strict=True)])
        np.testing.assert_array_equal(u, expected)
    assert np.any(np.abs(u) <= 24.0)


def test_noise_streams_equal_single_draws():
    streams = NoiseStreams(3, block=8)
    for i, seed in enumerate([5, 6, 7]):
        streams.seed(i, seed)
    got = [[] for _ in range(3)]
    for k in range(30):
        members = np.array([0, 2]) if k % 4 == 0 else None
        drawn = streams.draw(3, members)
        for row, i in zip(drawn, members if members is not None else range(3), strict=True):
            got[i].append(row)
    for i, seed in enumerate([5, 6, 7]):
        flat = np.concatenate(got[i])
        ref = gym.utils.seeding.np_random(seed)[0].standard_normal(len(flat))
        np.testing.assert_array_equal(flat, ref)


def test_limit_blas_threads_restores():
    controls = batch._openblas_thread_controls()
    before = [get() for get, _ in controls]
    with limit_blas_threads(1):
        assert all(get() == 1 for get, _ in controls)
    assert [get() for get, _ in controls] == before


# ---------------------------------------------------------------- vector env
def _sync_and_vector(num_envs: int, max_steps: int, **kwargs):
    sync = gym.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="sync",
                        max_episode_steps=max_steps, **kwargs)
    vec = gym.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point",
                       max_episode_steps=max_steps, **kwargs)
    return sync, vec


@pytest.mark.parametrize("kwargs", [
    {},
    {"sensors": "encoders+gyros", "sensor_kwargs": {"noise_std_rad": 0.001},
     "disturbance": "seed000"},
    {"sensors": "paper", "params": {"mass_kg": 1.05}},
])
def test_vector_env_equals_single_envs(kwargs, rng):
    sync, vec = _sync_and_vector(3, 7, **kwargs)
    assert data_equivalence(vec.reset(seed=40), sync.reset(seed=40), exact=True)
    for k in range(25):  # truncation at 7 steps: next-step autoresets, staggered after k = 3
        if k == 3:  # member 0 restarts on its own schedule: episodes no longer in lockstep
            options = {"reset_mask": np.array([True, False, False]),
                       "setpoints": [(0.0, 0.1, 0.2), (0.03, -0.1, 0.0)]}
            assert data_equivalence(vec.reset(options=dict(options)),
                                    sync.reset(options=dict(options)), exact=True)
        actions = rng.uniform(-30.0, 30.0, size=(3, 2)) if k % 5 else np.tile([14.0, -4.0],
                                                                            (3, 1))
        out_vec, out_sync = vec.step(actions), sync.step(actions)
        assert data_equivalence(out_vec, out_sync, exact=True), k
    assert vec.unwrapped.batch.steps.tolist() != [vec.unwrapped.batch.steps[0]] * 3
    options = {"x0": [0.0, 0.1, 0.0, 0.0], "params": {"yaw_damping": 1.2}}
    assert data_equivalence(vec.reset(seed=[1, 2, 3], options=options),
                            sync.reset(seed=[1, 2, 3], options=options), exact=True)
    for _ in range(3):
        assert data_equivalence(vec.step(np.ones((3, 2))), sync.step(np.ones((3, 2))),
                                exact=True)
    vec.close()
    sync.close()


def test_make_vec_contract():
    env = gym.make_vec(ENV_ID, num_envs=4, vectorization_mode="vector_entry_point",
                       sensors="encoders+gyros")
    assert isinstance(env.unwrapped, Helicopter2DOFVectorEnv)
    assert env.num_envs == 4
    assert env.unwrapped.max_episode_steps == 2000  # from the registration
    assert env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert env.single_observation_space.shape == (4,)
    assert env.observation_space.shape == (4, 4)
    assert env.single_action_space.shape == (2,)
    assert env.action_space.shape == (4, 2)
    check_observation_space(env.single_observation_space)
    check_action_space(env.single_action_space)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros((4, 2)))
    obs, info = env.reset(seed=0)
    assert obs.shape == (4, 4) and obs.dtype == np.float64
    assert env.observation_space.contains(obs)
    assert info["state"].shape == (4, 4) and info["_state"].all()
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert reward.shape == terminated.shape == truncated.shape == (4,)
    assert terminated.dtype == truncated.dtype == np.bool_
    assert info["t"].shape == (4,) and np.allclose(info["t"], 0.01)
    assert info["action_clipped"].dtype == np.bool_
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(2))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.full((4, 2), np.nan))
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"bogus": 1})
    with pytest.raises(ValueError, match="length must match"):
        env.reset(seed=[1, 2])
    # partial reset: only member 2 restarts
    env.step(np.zeros((4, 2)))
    mask = np.array([False, False, True, False])
    obs, info = env.reset(seed=5, options={"reset_mask": mask})
    assert info["_t"].tolist() == mask.tolist()
    assert env.unwrapped.batch.steps.tolist() == [2, 2, 0, 2]
    env.close()


def test_vector_env_same_step_autoreset_matches_sync():
    kwargs = {"disturbance": "seed000"}
    sync = gym.vector.SyncVectorEnv(
        [lambda: gym.wrappers.TimeLimit(Helicopter2DOFEnv(**kwargs), 3) for _ in range(2)],
        autoreset_mode=AutoresetMode.SAME_STEP)
    vec = Helicopter2DOFVectorEnv(2, max_episode_steps=3, autoreset_mode="SameStep", **kwargs)
    assert data_equivalence(vec.reset(seed=9), sync.reset(seed=9), exact=True)
    for _ in range(7):
        out_vec, out_sync = vec.step(np.full((2, 2), 10.0)), sync.step(np.full((2, 2), 10.0))
        assert data_equivalence(out_vec, out_sync, exact=True)
    disabled = Helicopter2DOFVectorEnv(2, max_episode_steps=1, autoreset_mode="Disabled")
    disabled.reset(seed=0)
    assert disabled.step(np.zeros((2, 2)))[3].all()
    with pytest.raises(RuntimeError, match="reset_mask"):
        disabled.step(np.zeros((2, 2)))
    disabled.reset(options={"reset_mask": np.array([True, True])})
    disabled.step(np.zeros((2, 2)))
    for env in (vec, sync, disabled):
        env.close()


def test_batch_rejects_unsupported_sensors():
    class Custom:
        dim = 1
        names = ["a"]
        measured_state_index = [0]

        def measure(self, x, t_s, rng, w=None):
            return x[:1]

    with pytest.raises(TypeError, match="measure_batch"):
        HelicopterBatch(Helicopter2DOFEnv(sensors=Custom()), 2)


# ---------------------------------------------------------------- monte carlo
def test_monte_carlo_runs_equal_single_envs_and_npz(tmp_path):
    path = tmp_path / "out" / "mc.npz"
    kw = {"disturbance": "seed000", "process_noise_scale": 0.5}
    res = monte_carlo(runs=3, duration_s=1.0, seed=5, batch_size=2, progress=False,
                      save_npz=path, **kw)
    json.dumps(res, allow_nan=False)
    assert res["runs"] == 3 and res["steps_per_run"] == 100
    assert set(res["rmse"]) == {"pitch", "yaw", "pitch_rate", "yaw_rate"}
    assert set(res["rmse"]["pitch"]) == {"mean", "q05", "q95"}
    assert set(res["T_final"]) == {"mean", "q05", "q95"}
    assert res["wall_s"] > 0 and res["traj_steps_per_s"] > 0
    assert sorted(p.name for p in path.parent.iterdir()) == ["mc.npz"]  # no temp files left
    data = np.load(path)
    assert data["state"].shape == (3, 101, 4) and data["covariance"].shape == (3, 101, 4, 4)
    np.testing.assert_array_equal(data["seeds"], run_seeds(5, 3))
    for i, seed in enumerate(run_seeds(5, 3)):
        traj, summary = run_episode(build_helicopter("kalman", **kw), 1.0, seed=int(seed),
                                    progress=False)
        np.testing.assert_allclose(data["state"][i], traj.state, **TOL)
        np.testing.assert_allclose(data["estimate"][i], traj.estimate, **TOL)
        np.testing.assert_allclose(data["rmse"][i], list(summary["rmse"].values()), **TOL)
        np.testing.assert_allclose(data["T_final"][i], summary["T_final"], **TOL)
    rmse_pitch = data["rmse"][:, 0]
    assert res["rmse"]["pitch"]["mean"] == pytest.approx(rmse_pitch.mean(), rel=1e-12)


def test_monte_carlo_determinism_and_batch_size_independence(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    kw = {"runs": 4, "duration_s": 0.5, "seed": 11, "progress": False, "sensors": "paper"}
    first, again = monte_carlo(**kw), monte_carlo(**kw)
    single = monte_carlo(batch_size=1, **kw)
    for key in ("rmse", "measurement_rmse", "nees_mean", "T_final"):
        assert first[key] == again[key]  # bitwise
    assert first["T_final"] is None
    for state, stats in first["rmse"].items():
        for stat, value in stats.items():
            assert single["rmse"][state][stat] == pytest.approx(value, rel=1e-12, abs=1e-15)
    assert single["nees_mean"] == pytest.approx(first["nees_mean"], rel=1e-12)
    assert list(tmp_path.iterdir()) == []  # nothing written unless asked
    assert np.array_equal(run_seeds(11, 2), run_seeds(11, 4)[:2])  # prefix-stable


def test_npz_not_written_when_run_fails(tmp_path, monkeypatch):
    path = tmp_path / "mc.npz"
    path.write_bytes(b"previous")
    calls = {"n": 0}
    original = BatchClosedLoop.run

    def failing(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("boom")
        return original(self, *args, **kwargs)

    monkeypatch.setattr(BatchClosedLoop, "run", failing)
    with pytest.raises(RuntimeError, match="boom"):
        monte_carlo(runs=2, duration_s=0.2, batch_size=1, progress=False, save_npz=path)
    assert path.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir()] == ["mc.npz"]


def test_monte_carlo_validates_arguments():
    with pytest.raises(ValueError, match="runs"):
        monte_carlo(runs=0, progress=False)
    with pytest.raises(ValueError, match="batch_size"):
        monte_carlo(runs=2, batch_size=0, progress=False)
    with pytest.raises(ValueError, match="duration_s"):
        monte_carlo(runs=2, duration_s=0.001, progress=False)
    with pytest.raises(ValueError, match="unknown filter"):
        monte_carlo(filter_name="bogus", runs=2, progress=False)


def test_monte_carlo_ms_hinf_equals_single_runs():
    """The mean-square H-infinity filter (y2 channel) batched equals the single loop."""
    kw = {"disturbance": "seed000"}
    res = monte_carlo("ms-hinf", runs=2, duration_s=0.5, seed=3, progress=False, **kw)
    single = [run_episode(build_helicopter("ms-hinf", **kw), 0.5, seed=int(s),
                          progress=False)[1] for s in run_seeds(3, 2)]
    assert res["rmse"]["pitch"]["mean"] == pytest.approx(
        np.mean([s["rmse"]["pitch"] for s in single]), rel=1e-10)
    assert res["T_final"]["mean"] == pytest.approx(
        np.mean([s["T_final"] for s in single]), rel=1e-10)
