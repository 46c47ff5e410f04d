"""scripts/benchmark.py runs end to end at tiny sizes and reports every metric with its target.

No timing assertions: the numbers of a smoke run mean nothing; what is checked is that the
script still runs against the current code and that its report is complete and consistent.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"
sys.path.insert(0, str(SCRIPTS))

import bench_mc  # noqa: E402
import benchmark  # noqa: E402

#: Only the full mode measures these (minutes each).
LONG = {"mc_1000x80s_wall_s", "sweep_ray_wall_s", "sweep_ray_speedup", "mc_ray_wall_s",
        "mc_ray_speedup"}


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> dict:
    path = tmp_path_factory.mktemp("bench") / "benchmark.json"
    assert benchmark.main(["--smoke", "--json", str(path)]) == 0
    return json.loads(path.read_text())


def test_smoke_run_reports_every_metric_with_its_target(smoke):
    metrics = smoke["metrics"]
    assert set(metrics) == set(benchmark.METRICS) - LONG
    for key, entry in metrics.items():
        assert set(entry) == {"value", "unit", "what", "target", "met"}
        assert entry["unit"] == benchmark.METRICS[key][0]
        if key == "scaling":
            assert all(v["us_per_traj_step"] > 0 for v in entry["value"].values())
        else:
            assert math.isfinite(entry["value"]) and entry["value"] > 0, key
    for key, (op, bound) in benchmark.TARGETS.items():
        if key in LONG:
            continue
        assert metrics[key]["target"] == f"{op} {bound:g}"
        value = metrics[key]["value"]
        assert metrics[key]["met"] == {"<=": value <= bound, ">=": value >= bound,
                                       "<": value < bound}[op]
    assert smoke["targets_missed"] == [k for k, m in metrics.items() if m["met"] is False]
    assert {"mc_vs_raw", "mc_vehicle_vs_raw", "env_overhead_ratio", "mshinf_vs_kf",
            "poly_step_us", "kf_vs_filterpy"} <= set(benchmark.TARGETS)
    # the ratios are the quotients of the measured quantities, from the same run
    assert metrics["mc_vs_raw"]["value"] == pytest.approx(
        metrics["mc_traj_steps_per_s"]["value"] / metrics["raw_rollout_traj_steps_per_s"]["value"])
    assert metrics["mc_vehicle_vs_raw"]["value"] == pytest.approx(
        metrics["mc_vehicle_traj_steps_per_s"]["value"]
        / metrics["raw_rollout_vehicle_traj_steps_per_s"]["value"])
    assert metrics["mshinf_vs_kf"]["value"] == pytest.approx(
        metrics["mshinf_step_us"]["value"] / metrics["kf_step_us"]["value"])
    assert len(smoke["settings"]["mc_vs_raw_pairs"]) == bench_mc.SMOKE["repeats"]


def test_markdown_table_and_doc_update(smoke, tmp_path):
    table = benchmark.markdown([smoke, smoke])
    lines = table.splitlines()
    assert lines[0] == "| metric | value | target | met |"
    assert len(lines) == 2 + len(smoke["metrics"])
    for key, entry in smoke["metrics"].items():
        row = next(line for line in lines if line.startswith(f"| `{key}`"))
        if entry["met"] is not None:
            assert row.endswith(f"| {entry['target']} | {2 * int(entry['met'])}/2 |")
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n## Speed\n\n{benchmark.TABLE_START}\nold\n{benchmark.TABLE_END}"
                      "\n\n## Next\nkept\n")
    paths = []
    for i in range(2):
        paths.append(tmp_path / f"b{i}.json")
        paths[-1].write_text(json.dumps(smoke))
    assert benchmark.main(["--markdown", *map(str, paths), "--doc", str(readme)]) == 0
    text = readme.read_text()
    assert "old" not in text and table in text and text.endswith("## Next\nkept\n")
    assert "from 2 smoke run(s)" in text
    bare = tmp_path / "bare.md"
    bare.write_text("no markers\n")
    with pytest.raises(ValueError, match="markers"):
        benchmark.main(["--markdown", str(paths[0]), "--doc", str(bare)])
    assert bare.read_text() == "no markers\n"


def test_only_nonlinear_reports_the_filter_step_metrics(tmp_path):
    path = tmp_path / "nonlinear.json"
    assert benchmark.main(["--smoke", "--only-nonlinear", "--json", str(path)]) == 0
    result = json.loads(path.read_text())
    metrics = result["metrics"]
    assert result["settings"]["only"] == "nonlinear"
    assert {"ukf_batch32_vs_kalman", "ukf_physics_fraction", "ukf_scaled_batch32_vs_kalman",
            "ukf_scaled_physics_fraction", "ekf_physics_fraction"} <= set(metrics)
    assert set(metrics) <= set(benchmark.METRICS)
    for key in ("ukf_physics_fraction", "ukf_scaled_physics_fraction"):
        assert 0 < metrics[key]["value"] < 1  # the rollouts are timed (a share, not zero)
    assert metrics["ukf_scaled_batch32_vs_kalman"]["value"] > 0


def test_performance_doc_has_the_table_markers():
    assert benchmark.PERFORMANCE_DOC == SCRIPTS.parent / "docs" / "performance.md"
    text = benchmark.PERFORMANCE_DOC.read_text()
    start, end = text.find(benchmark.TABLE_START), text.find(benchmark.TABLE_END)
    assert 0 < start < end
    section = text[start:end]
    for key in ("mc_vs_raw", "mc_vehicle_vs_raw", "env_overhead_ratio", "mshinf_vs_kf",
                "poly_step_us", "kf_vs_filterpy"):
        assert f"`{key}`" in section


@pytest.mark.slow
def test_ray_sweep_section_runs():
    pytest.importorskip("ray")
    out = benchmark.bench_ray_sweep(runs=2, duration_s=0.05)
    assert set(out) == {"sweep_ray_wall_s", "sweep_ray_speedup"}
    assert set(out["sweep_ray_wall_s"]) == {1, 2} and out["sweep_ray_speedup"] > 0
