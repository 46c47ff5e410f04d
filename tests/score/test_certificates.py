"""Gammas beside the sampled loop's gain, and no avoidable skip of poly-hinf."""

from __future__ import annotations

import numpy as np
import pytest

from testbed.rigs.linear_plant.rig import LinearPlantRig
from testbed.score.harness import score
from testbed.score.report import certificate, results


def test_certificate_semantics():
    assert certificate(None, None, 1.0) is None
    assert certificate(0.5, "discrete", 0.4) == "holds"
    assert certificate(0.5, "discrete", 0.6) == "violated"
    # a continuous-observation gamma certifies no sampled loop, whatever the numbers
    assert certificate(0.5, "continuous-observation", 0.4).startswith("not a sampled")
    assert certificate(0.5, "discrete", None).startswith("sampled-loop gain not computed")


def test_linear_plant_cubic_expansion_is_exact():
    from testbed.experiment import runner
    from testbed.score.suite import get_suite

    (entry,) = [e for e in get_suite("quick") if e.name == "calibration"]
    experiment = runner.build(entry.resolved_scenario().replace(estimator="kalman"), 1)
    design = experiment.design
    experiment.close()
    cubic = LinearPlantRig.cubic_model(design)
    x = np.random.default_rng(0).standard_normal((5, 2))
    u = np.random.default_rng(1).standard_normal((5, 1))
    assert np.allclose(cubic.f(x, u), x @ design.continuous.A.T + u @ design.continuous.B.T)
    assert cubic.a2 is None and cubic.a3 is None


@pytest.fixture(scope="module")
def calibration_run():
    return results(score(["kalman", "poly-hinf", "lmi-hinf"], "quick", seed=0,
                         scenarios=["calibration"], runs=8))


def test_poly_hinf_is_scored_on_the_linear_plant(calibration_run):
    rows = {r["estimator"]: r for r in calibration_run["results"]}
    assert rows["poly-hinf"]["skipped"] is None
    assert np.isfinite(rows["poly-hinf"]["rmse"]["position"])


def test_every_gamma_sits_beside_its_sampled_loop_gain(calibration_run):
    stated = [r for r in calibration_run["results"] if r["certified_gamma"] is not None]
    assert {r["estimator"] for r in stated} == {"poly-hinf", "lmi-hinf"}
    for r in stated:
        assert r["sampled_loop_gain"] is not None and r["sampled_loop_gain"] > 0
        assert r["gamma_kind"] in ("discrete", "continuous-observation")
    kinds = {r["estimator"]: r["gamma_kind"] for r in stated}
    assert kinds == {"poly-hinf": "continuous-observation", "lmi-hinf": "discrete"}
    lmi = next(r for r in stated if r["estimator"] == "lmi-hinf")
    assert lmi["certificate"] == "holds"  # Theorem 4's bound holds on the sampled loop
