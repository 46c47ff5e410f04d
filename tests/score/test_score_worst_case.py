"""The worst-case search's linear machinery and the per-member disturbance hook."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from filters import DiscreteLinearSystem, KalmanFilter, zoh
from testbed.experiment.runner import build, monte_carlo
from testbed.rigs.disturbances import SampledDisturbance
from testbed.score.worst_case import (
    ErrorOperator,
    causal_conv,
    error_response,
    estimator_markov,
    plant_markov,
    top_singular,
)


def _dense(t: np.ndarray, K: int) -> np.ndarray:
    q, s = t.shape[1:]
    T = np.zeros((K * q, K * s))
    for k in range(1, K + 1):
        for i in range(K):
            if 0 <= k - i < len(t):
                T[(k - 1) * q:k * q, i * s:(i + 1) * s] = t[k - i]
    return T


def test_error_operator_is_the_block_toeplitz_matrix_and_its_adjoint(rng):
    K, q, s = 30, 2, 3
    t = rng.standard_normal((K + 1, q, s)) * 0.7 ** np.arange(K + 1)[:, None, None]
    op, T = ErrorOperator(t, K), _dense(t, K)
    w, z = rng.standard_normal((2, K, s)), rng.standard_normal((2, K, q))
    assert np.allclose(op.forward(w).reshape(2, -1), w.reshape(2, -1) @ T.T, atol=1e-12)
    assert np.allclose(op.adjoint(z).reshape(2, -1), z.reshape(2, -1) @ T, atol=1e-12)
    gains, V, _ = top_singular(op, 3, rng, max_iter=2000, rtol=1e-12)
    sv = np.linalg.svd(T, compute_uv=False)
    assert gains[0] == pytest.approx(sv[0], rel=1e-8)
    assert np.linalg.norm(op.forward(V[:1])) == pytest.approx(sv[0], rel=1e-8)
    assert gains[0] >= gains[1] >= gains[2]


def test_plant_markov_and_conv_against_direct_simulation(rng):
    A = np.array([[0.0, 1.0], [-4.0, -0.4]])
    G = np.array([[0.0], [1.0]])
    dt, K = 0.05, 40
    A_d, G_d = zoh(A, G, dt)
    M = expm(np.block([[A, G], [np.zeros((1, 3))]]) * dt)
    assert np.allclose(A_d, M[:2, :2]) and np.allclose(G_d, M[:2, 2:])
    C, Hw = np.array([[1.0, 0.0]]), np.array([[0.3]])
    gx, gy = plant_markov(A_d, G_d, C, Hw, K)
    w = rng.standard_normal(K)
    x, ys = np.zeros(2), []
    for k in range(K):  # y_k = C x_k + Hw w_k, then x_(k+1) = A_d x_k + G_d w_k
        ys.append(C @ x + Hw[:, 0] * w[k])
        x = A_d @ x + G_d[:, 0] * w[k]
    conv = causal_conv(gy, w[:, None, None], K)[:, :, 0]
    assert np.allclose(conv, np.array(ys), atol=1e-12)


def test_estimator_markov_of_a_steady_state_kalman_filter():
    F = np.array([[1.0, 0.01], [-0.1, 0.99]])
    system = DiscreteLinearSystem(F=F, B=np.array([[0.0], [0.01]]), H=np.array([[1.0, 0.0]]),
                                  Q=np.diag([1e-6, 1e-4]), R=np.array([[1e-4]]), dt_s=0.01)
    P, K = KalmanFilter(system, np.zeros(2), np.eye(2)).steady_state()
    P_post = P - K @ system.H @ P
    kf = KalmanFilter(system, np.zeros(2), P_post)
    y = np.zeros((51, 1))
    u = np.zeros((50, 1))
    h = estimator_markov(kf, None, (np.zeros(2), P_post), y, u, 10, np.array([1e-3]), 3)
    Phi = (np.eye(2) - K @ system.H) @ F  # x_k = Phi x_(k-1) + K y_k
    for a in range(5):
        assert np.allclose(h[a], np.linalg.matrix_power(Phi, a) @ K, rtol=1e-6, atol=1e-12)
    t = error_response(np.zeros((4, 2, 1)), np.ones((4, 1, 1)), h[:4], np.eye(2))
    assert np.allclose(t[0], -h[0]) and np.allclose(t[1], -(h[0] + h[1]))


def test_sampled_disturbance_validates_and_is_per_member():
    values = np.arange(12.0).reshape(2, 3, 2)
    d = SampledDisturbance(np.array([[0.0, 0.0], [1.0, 0.0]]), values, 0.01, n_positions=1)
    out = d.member_signal(np.array([0.0, 0.01, 0.02, 0.03]), np.array([0, 1, 1, 0]))
    assert np.array_equal(out, [values[0, 0], values[1, 1], values[1, 2], [0.0, 0.0]])
    assert np.array_equal(d.signal(0.01), values[0, 1])
    with pytest.raises(ValueError, match="shape"):
        SampledDisturbance(None, np.zeros((2, 3)), 0.01)
    with pytest.raises(ValueError, match="dt_s"):
        SampledDisturbance(None, np.zeros((1, 2, 1)), 0.0)
    with pytest.raises(ValueError, match="outside"):
        d.member_signal(np.array([0.0]), np.array([2]))


def test_sampled_named_signal_equals_the_runner_bitwise():
    from testbed.rigs.helicopter import HelicopterRig
    from testbed.score.suite import get_suite

    entry = next(e for e in get_suite("quick") if e.name == "helicopter")
    scenario = entry.scenario.replace(duration_s=0.3, estimator="ms-hinf")
    ref = monte_carlo(scenario, 3, progress=False, num_threads=1)
    rig = HelicopterRig()
    base = rig.disturbance(scenario.disturbance, scenario.process_noise)
    t = np.arange(31) * 0.01
    values = np.broadcast_to(np.array([base.signal(ti) for ti in t]), (3, 31, 4)).copy()
    dist = SampledDisturbance(base.G, values, 0.01, b=base.b)
    experiment = build(scenario.replace(disturbance=dist, process_noise=0.0), 3, num_threads=1)
    try:
        result = experiment.loop.run(np.array(ref["seeds"]), 0.3)
    finally:
        experiment.close()
    for state, per_run in ref["rmse_per_run"].items():
        assert np.array_equal(result.metrics.rmse()[state], per_run)
    assert float(np.mean(result.metrics.nees_mean())) == ref["nees_mean"]


def _measure(sensor, x: np.ndarray, seed: int = 3) -> np.ndarray:
    from testbed.sensors.base import NoiseStreams, Sample

    streams = NoiseStreams(len(x))
    for i in range(len(x)):
        streams.seed(i, seed + i)
    sensor.allocate(len(x))
    sample = Sample(x, np.zeros(len(x)), np.zeros((len(x), 2)), np.full((len(x), 4), 0.3))
    sensor.reset(sample, streams.view(slice(None)))
    return sensor.measure(sample, streams.view(slice(None)))


def test_without_quantization_keeps_everything_but_the_rounding(rng):
    from testbed.rigs.helicopter import HelicopterRig
    from testbed.score.worst_case import without_quantization
    from testbed.sensors import Quantize, Suite, WhiteNoise
    from testbed.sensors.decorators import Decorator

    rig = HelicopterRig()
    sensors = rig.sensors("encoders+gyros", noise_std_rad=1e-4, disturbance_channel=True)
    probe, removed = without_quantization(sensors)
    assert removed == ["pitch", "yaw"]

    def nodes(s):
        yield s
        for child in (s.sensors if isinstance(s, Suite) else
                      (s.inner,) if isinstance(s, Decorator) else ()):
            yield from nodes(child)

    assert not any(isinstance(n, Quantize) for n in nodes(probe))
    assert any(isinstance(n, Quantize) for n in nodes(sensors))  # the original is untouched
    assert {id(n) for n in nodes(probe)}.isdisjoint(id(n) for n in nodes(sensors))
    assert sum(isinstance(n, WhiteNoise) for n in nodes(probe)) == 2  # the noise stays
    assert probe.names == sensors.names and probe.units == sensors.units
    before, after = sensors.linear_model(), probe.linear_model()
    for key in ("C", "R", "Hw"):
        assert np.array_equal(getattr(after, key), getattr(before, key))  # the design's model
    x = rng.standard_normal((3, 4))
    y_probe, y_orig = _measure(probe, x), _measure(sensors, x)
    assert not np.allclose(y_probe[:, :2], y_orig[:, :2], atol=1e-12)
    step = sensors.sensors[0].inner.step  # WhiteNoise(Quantize(pitch + yaw))
    # the same noise draws: the quantized measurement is within half a step of the probe's
    assert np.all(np.abs(y_probe[:, :2] - y_orig[:, :2]) <= step / 2 + 1e-12)
    assert np.array_equal(y_probe[:, 2:], y_orig[:, 2:])
    unquantized = rig.sensors("paper")
    assert without_quantization(unquantized) == (unquantized, [])


def test_worst_case_search_ranks_the_helicopter_filters_like_their_error_systems():
    """Without the quantization floor the measured gains follow the linearized error systems
    (with the encoders' rounding every filter measured about 1e-3: the change of the
    quantization error) and reach them. A short horizon and no refinement keep it fast."""
    from testbed.score.harness import score_pair
    from testbed.score.suite import WorstCaseSpec, get_suite

    entry = next(e for e in get_suite("quick") if e.name == "helicopter")
    entry = entry.replace(runs=2, scenario=entry.scenario.replace(duration_s=1.5),
                          worst_case=WorstCaseSpec(energy=1.0, horizon_s=1.5, random_draws=2,
                                                   generations=0))
    found, linear = {}, {}
    for name in ("kalman", "kalman-bucy", "poly-hinf"):
        pair = score_pair(entry, name, 0, num_threads=1)
        assert pair.skipped is None and pair.worst is not None, pair.worst_skipped
        assert pair.worst.quantization_removed == ["pitch", "yaw"]
        assert pair.worst.describe()["quantization"] == "removed"
        found[name], linear[name] = pair.worst.worst_case_gain, pair.worst.linear_gain
        assert found[name] >= pair.worst.random_gain
    print({n: f"found {found[n]:.3g}, linear {linear[n]:.3g}" for n in found})
    assert sorted(found, key=found.get) == sorted(linear, key=linear.get)
    assert sorted(found, key=found.get) == ["kalman", "poly-hinf", "kalman-bucy"]
    # each gain is its loop's error system's (measured impulse responses, the controller's
    # reaction included), no longer the quantization floor
    for name in found:
        assert found[name] == pytest.approx(linear[name], rel=0.05)
    assert found["kalman"] < 1e-4


def test_loop_evaluator_baseline_run_once_equals_a_baseline_in_the_batch(rng):
    """The candidates' gains against the impulse run's baseline (member 0, simulated once)
    equal those against a member without ``w`` in the candidates' own batch, bitwise."""
    from testbed.score.suite import get_suite
    from testbed.score.worst_case import LoopEvaluator

    entry = next(e for e in get_suite("quick") if e.name == "calibration")
    scenario = entry.scenario.replace(estimator="ekf", process_noise=0.0)
    K, seed, G = 40, 5, np.array([[0.0], [1.0]])

    def probe(num):
        dist = SampledDisturbance(G, np.zeros((num, K + 1, 1)), 0.01, n_positions=1)
        return build(scenario.replace(disturbance=dist), num, num_threads=1), dist

    (cand, dist), (imp, imp_dist), (ref, ref_dist) = probe(3), probe(2), probe(4)
    try:
        L = cand.design.output_matrix
        evaluator = LoopEvaluator(cand, dist, imp, imp_dist, seed, K, L)
        W = rng.standard_normal((5, K, 1))
        gains = evaluator.run(W)  # the baseline run on its own (no impulse response yet)
        evaluator.impulse_response(K // 4, 1e-3)  # and again as the impulse run's member 0
        assert np.array_equal(evaluator.run(W), gains)
        expected = []
        for start in range(0, len(W), 3):  # member 0 without w, the candidates after it
            chunk = W[start:start + 3]
            ref_dist.values[:] = 0.0
            ref_dist.values[1:1 + len(chunk), :K] = chunk
            rec = ref.loop.run(np.full(4, seed), K * 0.01, record=True).trajectory
            z = np.einsum("qn,btn->btq", L, rec["estimate"] - rec["state"])[:, 1:]
            dz = z[1:1 + len(chunk)] - z[0]
            expected += list(np.sqrt(np.sum(dz**2, axis=(1, 2))
                                     / np.sum(chunk**2, axis=(1, 2))))
        assert np.array_equal(gains, np.array(expected))
        assert evaluator.evaluations == 10
    finally:
        for experiment in (cand, imp, ref):
            experiment.close()
