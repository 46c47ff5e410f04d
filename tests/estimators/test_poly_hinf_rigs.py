"""The polynomial H-infinity filter ('poly-hinf') on the rigs' cubic expansions.

The expansions are checked against MuJoCo's own accelerations (``qacc`` after
``mj_forward``): the residual along the expanded coordinate is bounded by the Taylor
remainder of the next order, which a wrong coefficient of order <= 3 would exceed by orders
of magnitude at small offsets.
"""

from __future__ import annotations

import numpy as np
import pytest

from testbed import estimators
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs.base import Rig
from testbed.rigs.helicopter.rig import HelicopterParams, HelicopterRig, gravity_voltage
from testbed.rigs.linear_plant.rig import LinearPlantRig
from testbed.rigs.vehicle_roll.model import VehicleRollParams
from testbed.rigs.vehicle_roll.rig import VehicleRollRig

OFFSETS = np.array([-0.2, -0.1, -0.05, -0.02, 0.02, 0.05, 0.1, 0.2])


def _design(rig: str, **options):
    experiment = runner.build(Scenario(rig=rig, estimator="kalman", duration_s=0.1,
                                       **options), 1)
    experiment.close()
    return experiment.design


def _qacc(rig, x: np.ndarray) -> np.ndarray:
    """MuJoCo's joint accelerations at state ``x`` with zero input (ctrl, xfrc)."""
    rig.data.ctrl[:] = 0.0
    rig.data.xfrc_applied[:] = 0.0
    rig.set_state(x)
    return rig.data.qacc[rig.dof_adr].copy()


@pytest.mark.parametrize("pitch0", [0.0, 0.3])
def test_helicopter_gravity_expansion_matches_mujoco_to_third_order(pitch0):
    rig = HelicopterRig()
    design = _design("helicopter")
    cubic = HelicopterRig.cubic_model(design, pitch0_rad=pitch0)
    p = HelicopterParams()
    c = p.mass_kg * 9.81 * p.com_m / p.pitch_inertia
    for d in OFFSETS:
        x = np.array([pitch0 + d, 0.0, 0.0, 0.0])
        residual = _qacc(rig, x) - cubic.f(x)[2:]
        # -c cos: the remainder after the cubic is at most c d^4 / 24
        assert abs(residual[0]) <= 1.01 * c * d**4 / 24 + 1e-9
        assert abs(residual[1]) < 1e-9  # no yaw acceleration at rest without input
    # at the expansion point itself the model is exact, and the cubic term is c sin(p0) / 6
    a3 = 0.0 if cubic.a3 is None else cubic.a3[2, 0, 0, 0]
    assert a3 == pytest.approx(-c * np.sin(pitch0) / 6, abs=1e-12)
    # the input offset restores the absolute voltage: E V_g(pitch) = c cos(pitch) on pitch''
    pitch = np.array([[-0.6, 0, 0, 0], [0.4, 0, 0, 0]])
    torque = gravity_voltage(p, pitch[:, 0]) @ cubic.E.T
    np.testing.assert_allclose(cubic.input_offset(pitch) @ cubic.E.T, torque)
    np.testing.assert_allclose(torque[:, 2], c * np.cos(pitch[:, 0]), rtol=1e-4)
    np.testing.assert_allclose(torque[:, [0, 1, 3]], 0.0, atol=1e-3)


def test_vehicle_sin_roll_expansion_matches_mujoco_to_third_order():
    rig = VehicleRollRig()
    cubic = VehicleRollRig.cubic_model(_design("vehicle-roll"))
    p = VehicleRollParams()
    k = p.gravity_stiffness / p.roll_inertia
    assert cubic.a3[1, 0, 0, 0] == pytest.approx(-k / 6)
    for d in OFFSETS:
        x = np.array([d, 0.0])
        residual = _qacc(rig, x)[0] - cubic.f(x)[1]
        # m g h sin: the remainder after the cubic is at most k d^5 / 120
        assert abs(residual) <= 1.01 * k * abs(d) ** 5 / 120 + 1e-9
        # and the linear model alone misses the cubic term (the check has teeth)
        if abs(d) >= 0.1:
            assert abs(_qacc(rig, x)[0] - x @ cubic.a1[1]) > 100 * abs(residual)


class _NoExpansionRig(LinearPlantRig):
    """The calibration plant without its (exact, linear) expansion: a rig that gives none."""

    name = "no-expansion"
    cubic_model = classmethod(Rig.cubic_model.__func__)


def test_rig_without_expansion_is_refused_with_the_reason():
    design = runner.build(Scenario(rig=_NoExpansionRig, estimator="kalman", duration_s=0.1),
                          1).design
    with pytest.raises(ValueError, match="provides no cubic expansion"):
        estimators.build("poly-hinf", design)


def _rmse(rig: str, estimator: str, num: int = 3, duration_s: float = 2.0, **options):
    experiment = runner.build(Scenario(rig=rig, estimator=estimator, duration_s=duration_s,
                                       estimator_options=options), num)
    try:
        est = experiment.loop.stage.estimator
        result = experiment.loop.run(runner.run_seeds(0, num), duration_s, None)
    finally:
        experiment.close()
    return est, experiment.meta, {k: np.asarray(v) for k, v in result.metrics.rmse().items()}


@pytest.mark.parametrize("rig", ["helicopter", "vehicle-roll"])
def test_poly_hinf_runs_batched_with_finite_rmse_and_approaches_kalman_bucy(rig):
    est, meta, rmse = _rmse(rig, "poly-hinf")
    assert type(est).__name__ == "PolynomialHInfEstimator"  # batched: no per-member copies
    assert meta["design"]["gamma"] > meta["design"]["gamma_min_linear"] > 0
    assert all(np.all(np.isfinite(v)) and v.shape == (3,) for v in rmse.values())
    # gamma -> infinity: the H2 limit, Kalman-Bucy on the same continuous model; what
    # remains is the expanded nonlinearity (small here), so the RMSEs are close
    _, _, loose = _rmse(rig, "poly-hinf", gamma=1e6)
    _, _, kb = _rmse(rig, "kalman-bucy")
    for name in kb:
        np.testing.assert_allclose(loose[name].mean(), kb[name].mean(), rtol=0.05)
