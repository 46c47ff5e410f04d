"""Real-time pacing: wall-clock schedule, hardware-style read/write, overrun counting."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from testbed.cli import main
from testbed.envs import RigEnv
from testbed.experiment.realtime import RealTimeRig, run_scenario
from testbed.experiment.scenario import Scenario

HOVER_V = [12.5, -3.8]


def _paced(rig: RealTimeRig, until_k: int, work_s: float = 0.0) -> tuple[list, float, int]:
    """Read every sample up to ``until_k``, 'compute' for ``work_s``, write a constant
    command; (samples, wall time at the last read since the rig's start, writes)."""
    command = HOVER_V if rig.sim.rig.name == "helicopter" else [0.0]
    rig.write(command)  # the first period's command, before the clock starts
    samples, writes = [rig.start()], 0
    try:
        while samples[-1].k < until_k:
            samples.append(rig.read())
            if work_s:
                time.sleep(work_s)
            rig.write(command)
            writes += 1
        wall_s = rig.clock() / rig.factor
    except BaseException:
        rig.close()
        raise
    return samples, wall_s, writes


def test_two_simulated_seconds_take_two_wall_seconds():
    rig = RealTimeRig("helicopter")
    samples, wall_s, writes = _paced(rig, 200)
    stats = rig.stop()
    rig.close()
    print(f"2 s simulated: last sample published at {samples[-1].wall_s:.4f} s, read at "
          f"{wall_s:.4f} s; pacing error {100 * stats.pacing_error:+.2f} %, overruns "
          f"{stats.overruns}, missed {stats.missed_samples}, sim overruns "
          f"{stats.sim_overruns}, max lateness {1e3 * stats.max_lateness_s:.2f} ms")
    assert samples[-1].k == 200 and samples[-1].t_s == pytest.approx(2.0)
    assert wall_s == pytest.approx(2.0, rel=0.05)
    assert stats.steps >= 200 and abs(stats.pacing_error) < 0.05
    # a caller that only reads and writes keeps up (a loaded machine may delay a few)
    assert stats.overruns <= 0.1 * writes


def test_slow_controller_produces_counted_overruns():
    rig = RealTimeRig("helicopter")
    samples, _, writes = _paced(rig, 40, work_s=1.5 * rig.period_wall_s)
    stats = rig.stop()
    rig.close()
    print(f"slow controller (1.5 periods per sample): {writes} commands, {stats.overruns} "
          f"overruns, {stats.missed_samples} missed samples")
    assert stats.overruns >= 0.9 * writes
    assert stats.missed_samples >= 0.3 * writes
    assert len({s.k for s in samples}) == len(samples)  # never the same sample twice


def test_realtime_factor_speeds_the_clock():
    rig = RealTimeRig("vehicle-roll", realtime_factor=4.0)
    samples, wall_s, _ = _paced(rig, 100)
    rig.close()
    last = samples[-1]  # sample 100, or a few later when a loaded machine made it miss one
    assert last.t_s == pytest.approx(0.01 * last.k) and 1.0 <= last.t_s <= 1.05
    assert wall_s == pytest.approx(last.t_s / 4.0, rel=0.05)  # four simulated s per wall s


def test_samples_equal_the_simulators_and_counts_are_encoder_counts():
    seed = 3
    rig = RealTimeRig("helicopter", seed=seed, realtime_factor=5.0)
    samples, _, _ = _paced(rig, 30)
    rig.close()
    env = RigEnv("helicopter")
    obs = [env.reset(seed=seed)[0]] + [env.step(np.array(HOVER_V))[0] for _ in range(30)]
    for sample in samples:  # the commands are constant: timing cannot change the samples
        np.testing.assert_array_equal(sample.y, obs[sample.k])
        q = 2 * np.pi / np.array([4096, 8192])
        counts = np.array([sample.counts["pitch"], sample.counts["yaw"]])
        np.testing.assert_allclose(counts * q, sample.y[:2], rtol=0, atol=1e-12)
    assert samples[0].counts["pitch"] == round(-np.deg2rad(40.5) / q[0])


def test_api_errors():
    with pytest.raises(ValueError, match="realtime_factor"):
        RealTimeRig("helicopter", realtime_factor=0.0)
    rig = RealTimeRig("helicopter")
    with pytest.raises(RuntimeError, match="start"):
        rig.read()
    rig.start()
    with pytest.raises(ValueError, match="actions must"):
        rig.write([np.nan, 0.0])
    with pytest.raises(RuntimeError, match="already running"):
        rig.start()
    rig.close()


def test_run_scenario_and_cli(tmp_path, capsys):
    result = run_scenario(Scenario(rig="helicopter", duration_s=0.5), realtime_factor=2.0)
    assert result["pacing"]["sim_s"] >= 0.5 and result["steps"] > 0
    assert np.isfinite(result["rmse"]["pitch"])
    path = tmp_path / "rt.json"
    assert main(["run", "vehicle-roll", "--realtime", "--realtime-factor", "4", "--duration",
                 "0.5", "--json", str(path), "--no-progress"]) == 0
    data = json.loads(path.read_text())
    assert data["pacing"]["steps"] >= 50 and abs(data["pacing"]["pacing_error"]) < 0.05
    assert "pacing error" in capsys.readouterr().out
    assert main(["run", "helicopter", "--realtime", "--plot", str(tmp_path / "p.png"),
                 "--duration", "0.1"]) == 2
    assert "--plot is not available with --realtime" in capsys.readouterr().err
