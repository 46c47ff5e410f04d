"""Identification: recovery on simulated units, coverage of the intervals, identifiability,
the sensor model from a still segment, the method choice and bad input."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from identify_units import (
    AERO_FREE,
    AERO_LOCKED_FREE,
    HELI_FREE,
    TINY_FREE,
    VEHICLE_FREE,
    TinyRig,
    aero_unit,
    helicopter_unit,
    tiny_unit,
    vehicle_unit,
)

from testbed.identify import IdentificationError, fit_percent, identify
from testbed.identify.hac import hac_inflation as _hac_inflation
from testbed.identify.sensor_model import quantization_step
from testbed.rigs.aero import AeroRig
from testbed.rigs.helicopter.rig import HelicopterRig
from testbed.rigs.vehicle_roll.rig import VehicleRollRig
from testbed.sensors import Bias, Quantize, StateChannel, Suite, WhiteNoise


def _inside(result, scales):
    """Per free parameter: the truth inside its 95 % interval (a held one is a miss)."""
    out = []
    for name, truth in scales.items():
        p = result.parameters[name]
        if not p.identifiable:
            out.append(False)
            continue
        lo, hi = sorted(np.asarray(p.ci95) / p.nominal)  # (a negative nominal flips them)
        out.append(bool(lo <= truth <= hi))
    return out


def _fit_floor(result) -> dict:
    """95 %, or less where the channel's own noise caps the fit: ``100 (1 - noise / spread)``
    (the noise from the still segment), less 5 points."""
    out = {}
    for c, name in enumerate(result.channels):
        y = result.measured[:result.n_fit, c]
        ceiling = 100.0 * (1.0 - result.sensors[name]["noise_std"] / np.std(y))
        out[name] = min(95.0, ceiling - 5.0)
    return out


def test_fit_percent_closed_form():
    y = np.array([[0.0], [1.0], [2.0], [3.0]])
    assert fit_percent(y, y)[0] == pytest.approx(100.0)
    assert fit_percent(y, np.full_like(y, 1.5))[0] == pytest.approx(0.0)  # the mean: 0 %
    err = np.array([[0.1], [-0.1], [0.1], [-0.1]])
    expected = 100 * (1 - np.linalg.norm(err) / np.linalg.norm(y - 1.5))
    assert fit_percent(y, y + err)[0] == pytest.approx(expected)


def test_newey_west_inflation_of_an_ar1_mean():
    # the mean of an AR(1) series: long-run over white variance is (1 + rho) / (1 - rho)
    rng = np.random.default_rng(0)
    rho, T = 0.6, 20000
    e = rng.standard_normal(T)
    r = np.empty(T)
    r[0] = e[0]
    for k in range(1, T):
        r[k] = rho * r[k - 1] + e[k]
    ratio, bandwidth, _ = _hac_inflation(np.ones((T, 1)), r - r.mean(), T, 1)
    assert ratio[0] == pytest.approx((1 + rho) / (1 - rho), rel=0.15)
    white, _, _ = _hac_inflation(np.ones((T, 1)), e - e.mean(), T, 1)
    assert white[0] == pytest.approx(1.0, abs=0.1)


def test_newey_west_interval_of_a_regression_with_ar1_noise_has_its_closed_form():
    """``y = X beta + e``, ``e`` AR(1) (``rho``, innovations ``s``): least squares has the
    covariance ``(X'X)^-1 X' Sigma X (X'X)^-1`` with ``Sigma_ij = s^2 rho^|i-j| / (1 - rho^2)``.
    The prewhitened sandwich's variances are within 10 % of it (a Bartlett window alone
    falls 20 % short), the white ones far below (rho = 0.8: 9 times); intervals
    from the inflated white variances cover beta in about 95 % of 200 draws (the white ones
    in far fewer)."""
    from scipy.signal import lfilter

    rng = np.random.default_rng(5)
    T, rho, s = 2000, 0.8, 0.3
    t = np.arange(T) / T
    X = np.column_stack([np.ones(T), np.sin(2 * np.pi * 3 * t), t])
    beta = np.array([0.5, -1.0, 2.0])
    lag = np.abs(np.subtract.outer(np.arange(T), np.arange(T)))
    Sigma = s**2 * rho**lag / (1 - rho**2)
    XtX_inv = np.linalg.inv(X.T @ X)
    exact = XtX_inv @ X.T @ Sigma @ X @ XtX_inv
    hits_hac, hits_white, ratios = [], [], []
    for _ in range(200):
        v = rng.normal(0.0, s, T)
        v[0] /= np.sqrt(1 - rho**2)  # stationary from the start
        e = lfilter([1.0], [1.0, -rho], v)  # e_k = rho e_(k-1) + v_k
        y = X @ beta + e
        b = XtX_inv @ X.T @ y
        r = y - X @ b
        J = -X  # the Jacobian of the residual r = y - X b
        inflation, _, hac = _hac_inflation(J, r, T, 1)
        white = r @ r / (T - 3) * np.diag(XtX_inv)
        ratios.append(np.diag(hac) / np.diag(exact))
        hits_white.append(np.abs(b - beta) <= 1.96 * np.sqrt(white))
        hits_hac.append(np.abs(b - beta) <= 1.96 * np.sqrt(white * inflation))
    np.testing.assert_allclose(np.median(ratios, axis=0), 1.0, atol=0.1)  # 0.93-0.98
    assert 0.92 <= np.mean(hits_hac) <= 0.98, np.mean(hits_hac, axis=0)  # 0.94-0.965
    assert np.mean(hits_white) < 0.6, np.mean(hits_white)


def test_quantization_step_is_the_greatest_common_step():
    rng = np.random.default_rng(1)
    q = 2 * np.pi / 4096
    y = np.round(np.cumsum(rng.normal(0, 3 * q, 2000)) / q) * q
    assert quantization_step(y) == pytest.approx(q, rel=1e-9)
    assert quantization_step(rng.normal(size=2000)) == 0.0


def test_vehicle_noise_free_recovery_and_fit():
    rec, scales = vehicle_unit(0, duration_s=6.0, noise_free=True)
    res = identify(VehicleRollRig, rec, free=list(VEHICLE_FREE), sensors="imu",
                   channels=["roll_rate", "lateral_accel"])
    assert res.method == "output-error", res.method_reason
    for name, truth in scales.items():
        assert res.parameters[name].scale == pytest.approx(truth, rel=1e-3)
    assert min(res.fit_percent.values()) >= 99.0


def test_helicopter_hardware_noisy_short(tmp_path):
    rec, scales = helicopter_unit(0, duration_s=3.0)
    res = identify(HelicopterRig, rec, free=list(HELI_FREE), sensors="encoders+gyros",
                   holdout=0.2)
    # the yaw integrates: the nominal free run drifts; multiple shooting starts the fit
    assert "the free run drifts" in res.method_reason
    assert "fitted by multiple shooting" in res.method_reason
    assert res.method in ("multiple-shooting", "output-error")
    for name, truth in scales.items():  # well excited: within 5 %
        assert res.parameters[name].scale == pytest.approx(truth, rel=0.05), name
    assert min(res.fit_percent.values()) >= 95.0
    assert set(res.holdout_fit_percent) == {"pitch", "yaw", "pitch_rate", "yaw_rate"}
    # the held-out part's excitation: its spread over the noise level, near 0 for a still end
    snr = res.holdout_signal_to_noise()
    assert set(snr) == set(res.holdout_fit_percent)
    still = res.measured.copy()
    still[res.n_fit:] = still[res.n_fit]
    quiet = dataclasses.replace(res, measured=still).holdout_signal_to_noise()
    assert max(quiet.values()) < 1e-9 and max(snr.values()) > 3.0
    doc = json.loads(json.dumps(res.to_json()))
    assert doc["holdout_signal_to_noise"] == pytest.approx(snr)
    p = doc["parameters"]["K_pp"]
    assert set(p) >= {"value", "ci95", "nominal", "identifiable", "scale"}
    assert p["value"] == pytest.approx(p["scale"] * p["nominal"])
    assert doc["recording_sha256"] == rec.sha256 and doc["method"] == res.method
    assert np.asarray(doc["correlation"]["matrix"]).shape == (6, 6)


def test_tiny_rig_coverage_short():
    inside = []
    for seed in range(4):
        rec, scales = tiny_unit(seed)
        res = identify(TinyRig, rec, profile="paper", free=list(TINY_FREE))
        inside += _inside(res, scales)
        floor = _fit_floor(res)
        assert all(res.fit_percent[c] >= floor[c] for c in floor), (res.fit_percent, floor)
    assert np.mean(inside) >= 0.9, inside


#: Coverage the slow test holds each rig to: the target, 0.9. Measured on these 12 units per
#: rig (12 per Aero configuration): tiny 1.0, vehicle 0.917, helicopter 0.972, aero yaw
#: locked 0.967, aero free 0.906 (rms z 1.12). The misses: a helicopter unit whose pitch
#: leans on its stop, kept by multiple shooting (its output-error refit 1.6 times the
#: segments' residual): the measured initial states' errors are not in its intervals; a
#: vehicle unit 3-4 % off in the common scale of its stiffness, damping and height, at 2.0-2.4
#: of its (correlated) standard deviations; the free Aero's misses at 2.0-2.4 standard
#: deviations but one (3.4), with white gyro residuals (docs/twin.md, "Coverage, measured").
COVERAGE_FLOOR = {"tiny": 0.9, "vehicle": 0.9, "helicopter": 0.9, "aero-locked": 0.9,
                  "aero": 0.9}


@pytest.mark.slow
@pytest.mark.parametrize("rig", ["tiny", "vehicle", "helicopter", "aero-locked", "aero"])
def test_coverage_across_units(rig):
    """Every free parameter inside its 95 % interval in >= 90 % of (unit, parameter) pairs;
    >= 90 % of them within 5 % and of the units' fits above their noise floor. The vehicle's
    sensors without their 1 % sensitivity errors: left unfitted (``fit_scale=False``) they
    bias its weakly determined common scale of stiffness, damping and height by about 5 %,
    which no noise interval covers."""
    inside, close, fits = [], [], []
    for seed in range(12):
        if rig == "tiny":
            rec, scales = tiny_unit(seed)
            res = identify(TinyRig, rec, profile="paper", free=list(TINY_FREE))
        elif rig == "vehicle":
            rec, scales = vehicle_unit(seed, duration_s=10.0, scale_errors=False)
            res = identify(VehicleRollRig, rec, free=list(VEHICLE_FREE))
        elif rig == "helicopter":
            rec, scales = helicopter_unit(seed, duration_s=4.0)
            res = identify(HelicopterRig, rec, free=list(HELI_FREE), sensors="encoders+gyros")
        else:  # the Aero, hardware profile, yaw locked or free
            locked = rig == "aero-locked"
            rec, scales = aero_unit(seed, locked)
            res = identify(AeroRig, rec, options={"yaw_locked": locked},
                           free=list(AERO_LOCKED_FREE if locked else AERO_FREE))
        floor = _fit_floor(res)
        fits.append(all(res.fit_percent[c] >= floor[c] for c in floor))
        inside += _inside(res, scales)
        close += [abs(res.parameters[n].scale / s - 1) < 0.05 for n, s in scales.items()]
    assert np.mean(inside) >= COVERAGE_FLOOR[rig], np.mean(inside)
    assert np.mean(close) >= 0.9, np.mean(close)
    assert np.mean(fits) >= 0.9, fits


def test_a_product_only_pair_is_flagged_and_held_at_nominal():
    # the vehicle's mass and centre-of-mass height enter only as m_s h_cr
    scales = {"sprung_mass_kg": 1.25, "com_height_m": 0.8, "roll_stiffness": 1.3}
    rec, _ = vehicle_unit(3, duration_s=6.0, noise_free=True, scales=scales)
    res = identify(VehicleRollRig, rec, free=list(scales), sensors="imu",
                   channels=["roll_rate", "lateral_accel"])
    held = [n for n, p in res.parameters.items() if not p.identifiable]
    assert len(held) == 1 and held[0] in ("sprung_mass_kg", "com_height_m"), held
    p = res.parameters[held[0]]
    assert p.value == p.nominal and p.ci95 is None and p.scale == 1.0
    assert "correlation" in p.reason or "interval" in p.reason or "singular" in p.reason
    doc = res.to_json()
    assert doc["parameters"][held[0]]["identifiable"] is False
    assert doc["unidentifiable"] == held
    # the product m_s h_cr is what was seen: the kept one carries it (1.25 x 0.8 = 1)
    kept = "com_height_m" if held[0] == "sprung_mass_kg" else "sprung_mass_kg"
    assert res.parameters[kept].scale == pytest.approx(1.0, rel=1e-3)
    assert res.parameters["roll_stiffness"].scale == pytest.approx(1.3, rel=1e-3)


def test_still_segment_recovers_a_planted_bias_and_quantization_step():
    q, bias, std = 1e-3, 0.05, 0.002
    sensors = Suite(Quantize(StateChannel(0, 2, 1, "position", "m"), q),
                    Bias(WhiteNoise(StateChannel(1, 2, 1, "velocity", "m/s"), std=std), bias))
    rec, scales = tiny_unit(1, sensors=sensors, still_s=2.0)
    res = identify(TinyRig, rec, profile="paper", free=list(TINY_FREE), sensors=sensors)
    assert res.still_segment_s is not None and res.still_segment_s[0] < 0.2
    pos, vel = res.sensors["position"], res.sensors["velocity"]
    assert pos["quantization_step"] == pytest.approx(q, rel=1e-6)
    assert vel["quantization_step"] == 0.0
    n_still = 2.0 / rec.dt_s
    assert vel["still_bias"] == pytest.approx(bias, abs=4 * std / np.sqrt(n_still))
    assert vel["noise_std"] == pytest.approx(std, rel=0.15)
    assert vel["noise_density"] == pytest.approx(vel["noise_std"] * np.sqrt(rec.dt_s))
    assert vel["bias"] == pytest.approx(bias, abs=1e-3)  # the fit's own
    assert vel["bias_fitted"] is True
    # the quantized position of a joint without limits: its offset is fitted, within a step
    assert pos["bias_fitted"] is True and abs(pos["bias"]) <= q
    for name, truth in scales.items():
        assert res.parameters[name].scale == pytest.approx(truth, rel=0.05)


@pytest.mark.parametrize("kwargs, match", [
    ({"free": ["mass"]}, "unknown free parameter 'mass'"),
    ({"free": "mass_kg"}, "free must be a list"),
    ({"channels": ["velocity"]}, "'velocity'"),
    ({"channels": ["pitch"]}, "'pitch' is not a channel of rig 'tiny-linear'"),
    ({"holdout": 0.95}, r"holdout must be a fraction in \[0, 0.9\)"),
    ({"holdout": -0.1}, "holdout"),
    ({"method": "magic"}, "method must be one of"),
    ({"profile": "hardware"}, "unknown profile 'hardware'"),
    ({"segment_s": 0.0}, "segment_s"),
    ({"fit_scale": "yes"}, "fit_scale must be"),
])
def test_bad_arguments_are_one_line_errors(kwargs, match):
    rec, _ = tiny_unit(0, duration_s=1.0)
    kwargs = {"profile": "paper", **kwargs}
    with pytest.raises(IdentificationError, match=match) as info:
        identify(TinyRig, rec, **kwargs)
    assert "\n" not in str(info.value)
