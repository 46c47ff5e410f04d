"""Zhang, Deng & Zhang (2018), Example 5.1: plant (49), env ``testbed/NonlinearDiscrete-v0``,
filter (50), Corollary 3 checker and the reproduction."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import testbed  # noqa: F401  (registers the environments)
from testbed.envs.wrappers import FilterInLoop
from testbed.experiment.numpy_plant import rollout
from testbed.reproductions.zhang_lmi_hinf import nonlinear_discrete as rep
from testbed.reproductions.zhang_lmi_hinf import plant
from testbed.reproductions.zhang_lmi_hinf.env import NonlinearDiscreteEnv


# ------------------------------------------------------------------ plant
def test_plant_equations_49_verbatim():
    x, v, w = np.array([0.7, -0.4]), 1.3, 0.6
    x1 = 0.6 * 0.7**3 / (1 + 0.49 + 0.16) + 0.1 * v * 0.7 + 0.5 * (-0.4) * np.sin(v) * w
    x2 = 0.65 * (-0.4) + 0.1 * (-0.4) * 0.7 + 0.5 * v * np.sin(-0.4) * w
    assert np.allclose(plant.step(x, v, w), [x1, x2])
    assert np.allclose(plant.measure(x, v), 0.5 * x + v * np.sin(x))
    assert plant.output(x) == pytest.approx(0.03)
    assert plant.paper_disturbance(3) == pytest.approx(2 * 0.9999**3)
    assert np.allclose(plant.filter_step([1.0, 2.0], [3.0, 4.0]), [2.0, 3.0])


def simulate(x0, w):
    """(49) with the filter (50) over ``w`` (R, N): states and estimates (R, N + 1, 2)."""
    runs, n = w.shape
    out = rollout(plant.NonlinearDiscretePlant(), np.tile(x0, (runs, 1)), n,
                  noise=lambda k: w[:, k],
                  estimators={"50": plant.printed_filter(np.zeros((runs, 2)))})
    return out.x, out.estimates["50"], out.escape


def test_zero_state_stays_zero():
    x, xh, _ = simulate(np.zeros(2), np.random.default_rng(0).standard_normal((3, 50)))
    assert np.all(x == 0) and np.all(xh == 0)


def test_batched_simulation_equals_row_by_row_and_the_recursion():
    w = np.random.default_rng(1).standard_normal((5, 30))
    x, xh, _ = simulate([1.0, -0.5], w)
    for r in range(5):
        xr, xhr, _ = simulate([1.0, -0.5], w[r:r + 1])
        assert np.array_equal(x[r], xr[0]) and np.array_equal(xh[r], xhr[0])
    for k in range(30):
        v = plant.paper_disturbance(k)
        assert np.allclose(x[:, k + 1], plant.step(x[:, k], v, w[:, k]))
        assert np.allclose(xh[:, k + 1], plant.filter_step(xh[:, k], plant.measure(x[:, k], v)))


def test_escape_is_reported_with_its_step():
    x, _, escape = simulate([1.0, 1.0], np.full((2, 40), 1e3))
    assert escape is not None and escape.quantity == "state" and np.isfinite(x).all()
    assert escape.time == x.shape[1]


# ------------------------------------------------------------------ Corollary 3 / HJI
def test_corollary3_forms_and_values():
    x, xh = np.array([0.5, 1.0]), np.array([0.2, -0.3])
    c35, c36 = plant.quadratic_conditions_values(x, xh, 2.0)
    h1 = np.array([0.05, 0.0])
    h2 = np.array([0.5, 0.5 * np.sin(1.0)])
    gg = 0.5 * np.sin(x)
    assert c35 == pytest.approx(2 * (h1 @ h1 + h2 @ h2 + gg @ gg) - 4.0)
    f1 = plant.drift(x)
    filt = 0.5 * xh + 0.25 * x
    expected = (2 * (f1 @ f1 + filt @ filt) - x @ x - xh @ xh + 2 * plant.output(x) ** 2
                + 2 * plant.output(xh) ** 2)
    assert c36 == pytest.approx(expected)
    p35, p36 = plant.quadratic_conditions_values(x, xh, 2.0, printed=True)
    assert p35 == pytest.approx(2 * (h1 @ h1 + gg @ gg) - 4.0)
    assert p36 == pytest.approx(expected + 2 * xh @ xh)


def test_corollary3_fails_even_near_the_origin():
    """(36) is an indefinite quadratic form at 0: violated along (x2, xhat2) ~ (1, 0.53)."""
    assert plant.quadratic_conditions_origin_curvature() > 0.1
    s = 1e-3
    _, c36 = plant.quadratic_conditions_values(np.array([0.0, s]), np.array([0.0, 0.53 * s]), 0.0)
    assert c36 > 0
    chk = plant.quadratic_conditions_check(2.0, 2.0, 11)
    assert chk["max_36"] > 0.5 and chk["max_35"] < 0 and chk["gamma_needed_35"] < 2.0


def test_hji_values_are_the_exact_expectation(rng):
    x, xh, v, gamma = np.array([0.8, -1.1]), np.array([0.3, 0.4]), 1.7, 0.9
    w = rng.standard_normal(400_000)
    xs = plant.step(np.broadcast_to(x, (w.size, 2)), v, w)
    xhs = plant.filter_step(xh, plant.measure(x, v))
    V = np.sum(xs**2, axis=1) + xhs @ xhs
    mc = V.mean() - (x @ x + xh @ xh) + (plant.output(x) - plant.output(xh)) ** 2 - gamma**2 * v**2
    se = V.std() / np.sqrt(w.size)
    assert abs(plant.hji_values(x, xh, v, gamma) - mc) < 4 * se


# ------------------------------------------------------------------ environment
@pytest.mark.filterwarnings("ignore::UserWarning")
def test_check_env_and_registration():
    check_env(NonlinearDiscreteEnv(), skip_render_check=True)
    env = gym.make("testbed/NonlinearDiscrete-v0")
    assert env.spec.max_episode_steps == 200
    env.reset(seed=0)
    truncated = False
    for _ in range(200):
        *_, truncated, _ = env.step(np.zeros(1))
    assert truncated


def test_env_follows_the_plant_with_its_own_noise():
    env = NonlinearDiscreteEnv()
    y, info = env.reset(seed=3, options={"x0": [0.4, -0.9]})
    assert np.allclose(y, plant.measure([0.4, -0.9], 2.0)) and info["t"] == 0
    x = info["state"]
    for k in range(20):
        y, r, term, trunc, info = env.step(np.array([0.1]))
        v = plant.paper_disturbance(k) + 0.1
        assert info["disturbance"][0] == pytest.approx(v)
        assert info["action_applied"][0] == pytest.approx(v)
        x = plant.step(x, v, info["noise"])
        assert np.allclose(info["state"], x)
        assert np.allclose(y, plant.measure(x, plant.paper_disturbance(k + 1)))
        assert r == pytest.approx(-plant.output(x) ** 2) and info["t"] == k + 1


def test_same_seed_bitwise_identical_other_seed_differs():
    def run(seed):
        env = NonlinearDiscreteEnv()
        env.reset(seed=seed)
        return np.array([env.step(np.zeros(1))[0] for _ in range(30)])

    assert np.array_equal(run(5), run(5))
    assert not np.array_equal(run(5), run(6))


@pytest.mark.parametrize("action", [np.array([np.nan]), np.zeros(2), "x", [[1.0]]])
def test_bad_action_raises_and_leaves_state_unchanged(action):
    env = NonlinearDiscreteEnv()
    env.reset(seed=0)
    state = env.np_random.bit_generator.state
    before = env._x.copy()
    with pytest.raises(ValueError, match="action"):
        env.step(action)
    assert np.array_equal(env._x, before) and env.np_random.bit_generator.state == state


def test_bad_options_and_arguments():
    env = NonlinearDiscreteEnv()
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"params": {}})
    with pytest.raises(ValueError, match="x0"):
        env.reset(options={"x0": [1.0, np.inf]})
    with pytest.raises(ValueError, match="disturbance"):
        NonlinearDiscreteEnv(disturbance="other")
    env = NonlinearDiscreteEnv(disturbance=None)
    env.reset(seed=0)
    *_, info = env.step(np.array([20.0]))
    assert info["disturbance"][0] == 10.0 and info["action_clipped"][0]


def test_filter_50_in_the_loop_equals_the_recursion():
    run = rep.run_in_loop(np.array([1.0, -0.5]), 40, seed=2)
    xh = np.zeros(2)
    for k in range(40):
        assert np.allclose(run["xhat"][k], xh)
        xh = plant.filter_step(xh, run["y"][k])
    env = NonlinearDiscreteEnv()
    loop = FilterInLoop(env, plant.printed_filter(), output_matrix=plant.C_Z)
    loop.reset(seed=2)
    _, _, _, _, info = loop.step(np.zeros(1))
    assert info["covariance"] is None


# ------------------------------------------------------------------ reproduction
KEYS = {"x0", "gamma", "runs", "sum_E_z2", "gamma2_sum_v2", "inequality_holds",
        "smallest_gamma_mc", "corollary3_max_violation"}


def test_reproduction_defaults_and_outputs(tmp_path):
    from testbed.cli import main

    code = main(["reproduce", "zhang-nonlinear-discrete", "--json", str(tmp_path / "r.json"),
                 "--plot", str(tmp_path / "r.png"), "--rrd", str(tmp_path / "r.rrd")])
    assert code == 0
    r = json.loads((tmp_path / "r.json").read_text())
    assert KEYS <= set(r)
    assert r["x0"] == [1.0, 1.0] and r["gamma"] == 2.0 and r["runs"] == 1000
    assert r["inequality_holds"] and r["sum_E_z2"] < r["gamma2_sum_v2"]
    # ztilde_0 = z_0 = 0.2 against v_0 = 2: the k = 0 term sets the smallest gamma
    assert r["smallest_gamma_mc"] == pytest.approx(0.1, rel=1e-9)
    assert r["corollary3_max_violation"] > 0 and r["hji_27"]["max_violation"] <= 0
    # (27) is sampled for negative v too, and fails on a wider state box; (26) cannot hold
    assert r["hji_27"]["v_range"] == [-10.0, 10.0]
    assert r["hji_27_wide"]["max_violation"] > 0
    assert r["condition_26"]["possible"] is False
    assert r["bound_13_holds"]
    assert (tmp_path / "r.png").stat().st_size > 10_000
    assert (tmp_path / "r.rrd").stat().st_size > 1_000
    assert f"{r['sum_E_z2']:.4g}" in r["claims"][0]["ours"]
    assert "neither x0 nor gamma" in rep.why(r) and f"x0 = {r['x0']}" in r["claims"][0]["ours"]


def test_condition26_cannot_hold():
    """|ztilde(eta, 0)|^2 vanishes on a 3-dimensional subspace of eta: no positive W fits."""
    out = plant.output_lower_bound_check()
    assert out["possible"] is False and out["null_space_dim"] == 3
    assert out["min_on_unit_sphere"] == pytest.approx(0.0, abs=1e-15)
    eta = np.array(out["null_direction"])
    assert np.linalg.norm(eta) == pytest.approx(1.0)
    # ztilde = z - zhat at this eta, from the plant's own output map: zero
    assert abs(plant.output(eta[:2]) - plant.output(eta[2:])) < 1e-15
    # and it is positive off the subspace (e.g. along c)
    c = np.array(out["c"])
    assert plant.output(c[:2]) - plant.output(c[2:]) == pytest.approx(c @ c)


def test_reproduction_parameters():
    r = rep.reproduce(horizon_s=20, x0=[0.5, -0.2], gamma=0.05, runs=50, seed=1)
    assert r["steps"] == 20 and r["runs"] == 50 and r["x0"] == [0.5, -0.2]
    assert r["inequality_holds"] == (r["smallest_gamma_mc"] <= 0.05)
    with pytest.raises(ValueError, match="gamma"):
        rep.reproduce(gamma=-1.0)
    with pytest.raises(ValueError, match="x0"):
        rep.reproduce(x0=[1.0])
