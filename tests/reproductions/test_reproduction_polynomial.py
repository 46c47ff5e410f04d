"""``testbed reproduce basin-polynomial-hinf``: outputs, an independent check of the numbers
(solve_ivp on the printed equations), escape reporting, and the full run (slow)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from testbed.cli import main
from testbed.reproductions import REPRODUCTIONS, load
from testbed.reproductions.basin_polynomial import example as ph
from testbed.reproductions.outputs import agree_text

KEYS = {"T_poly", "T_linearized", "horizon", "escaped", "curve", "paper",
        "linearized_variant", "L_identity", "gamma"}
G = 1.05


def test_registered():
    assert (REPRODUCTIONS["basin-polynomial-hinf"]
            == "testbed.reproductions.basin_polynomial.example")
    assert load("basin-polynomial-hinf") is ph


def test_cli_short_horizon_writes_outputs(tmp_path):
    code = main(["reproduce", "basin-polynomial-hinf", "--horizon", "0.3", "--json",
                 str(tmp_path / "o.json"), "--plot", str(tmp_path / "o.png"), "--rrd",
                 str(tmp_path / "o.rrd")])
    assert code == 0
    text = (tmp_path / "o.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    data = json.loads(text)
    assert KEYS <= set(data)
    assert data["paper"] == {"T_poly": 0.952, "T_linearized": 1.079, "horizon": 1.4}
    assert data["horizon"] == pytest.approx(0.3)
    assert data["escaped"] == {"poly": None, "linearized": None, "plant": None}
    assert data["curve"]["t"] == [0.25, 0.5, 0.75, 0.9, 1.0]
    assert data["curve"]["poly"][1:] == [None] * 4 and data["curve"]["poly"][0] > 0
    assert set(data["linearized_variant"]) == {"main", "printed", "system"}
    assert data["linearized_variant"]["printed"]["T_linearized"] == data["T_linearized"]
    assert (tmp_path / "o.png").stat().st_size > 10_000
    assert (tmp_path / "o.rrd").stat().st_size > 10_000


def reference_ratios(t_end):
    """Plant, (25)-(26) and (27)-(28) as printed, and the running integrals of ||z - z_f||^2
    and ||w||^2, as one ODE solved by scipy (independent of the testbed's integrators)."""
    k = 1 - G**-2

    def rhs(t, s):
        x1, x2, f1, f2, P11, P12, P22, m1, m2, K11, K12, K22, *_ = s
        c = 0.1 + 0.1 * np.sin(50 * t)
        w1, w2 = 1 / (1 + t) ** 2, 2 / (2 + t) ** 2
        y = x1 + w2
        J = 0.2 * m2 + 3 * c * m2**2
        return [x2, 0.1 * x2**2 + c * x2**3 + w1,
                f2 + P11 * (y - f1),
                0.1 * f2**2 + 3 * c * P22 * f2 + 0.1 * P22 + c * f2**3 + P12 * (y - f1),
                2 * P12 - k * P11**2,
                P22 + 3 * c * f2**2 * P12 + 0.2 * f2 * P12 + 3 * c * P22 * P12 - k * P11 * P12,
                1 + 6 * c * f2**2 * P22 + 0.4 * f2 * P22 + 6 * c * P22**2 - k * P12**2,
                m2 + K11 * (y - m1), 0.2 * m2**2 + 3 * c * m2**3 + K12 * (y - m1),
                2 * K12 - k * K11**2, K22 + J * K12 - k * K11 * K12,
                1 + 2 * J * K22 - k * K12**2,
                (x1 - f1) ** 2 + (x2 - f2) ** 2, (x1 - m1) ** 2 + (x2 - m2) ** 2,
                w1**2 + w2**2]

    s0 = [1, 1, 0, 0, 1, 0, 1, 0, 0, 1, 0, 1, 0, 0, 0]
    sol = solve_ivp(rhs, (0, t_end), s0, rtol=1e-10, atol=1e-12, method="DOP853")
    num_p, num_l, ww = sol.y[12:, -1]
    return math.sqrt(num_p / (ww + 2)), math.sqrt(num_l / (ww + 2))


def reference_singular_time(L, t_end=1.2):
    """Where P22 of Theorem 1's filter for the example (output matrix ``L``) becomes singular:
    plant and filter as one ODE (continuous ``y``) solved by scipy until |P22| = 1e8, then
    ``1 / P22`` extrapolated to zero (written here, independent of the testbed)."""
    LtL = L.T @ L
    C = np.array([[1.0, 0.0]])

    def rhs(t, s):
        x1, x2, f1, f2 = s[:4]
        P = s[4:8].reshape(2, 2)
        c = 0.1 + 0.1 * np.sin(50 * t)
        w1, w2 = 1 / (1 + t) ** 2, 2 / (2 + t) ** 2
        f_hat = np.array([f2, 0.1 * f2**2 + 0.1 * P[1, 1] + c * f2**3 + 3 * c * f2 * P[1, 1]])
        A_hat = np.array([[0.0, 1.0], [0.0, 0.2 * f2 + 3 * c * (f2**2 + P[1, 1])]])
        dP = (A_hat @ P + P @ A_hat.T + np.diag([0.0, 1.0]) - P @ C.T @ C @ P
              + G**-2 * P @ LtL @ P)
        df = f_hat + P[:, 0] * (x1 + w2 - f1)
        return np.concatenate([[x2, 0.1 * x2**2 + c * x2**3 + w1], df, dP.ravel()])

    def big(t, s):
        return 1e8 - abs(s[7])

    big.terminal = True
    sol = solve_ivp(rhs, (0, t_end), [1, 1, 0, 0, 1, 0, 0, 1], rtol=1e-12, atol=1e-12,
                    method="DOP853", events=big)
    t_e, s_e = sol.t_events[0][0], sol.y_events[0][0]
    return t_e + s_e[7] / rhs(t_e, s_e)[7]


def test_numbers_agree_with_an_independent_solution_and_L_identity_escapes():
    r = ph.reproduce(horizon_s=0.55, dt_s=2.5e-4)
    T_poly, T_lin = reference_ratios(0.5)
    assert r["curve"]["poly"][1] == pytest.approx(T_poly, rel=2e-5)
    assert r["curve"]["linearized"][1] == pytest.approx(T_lin, rel=2e-5)
    assert r["escaped"]["poly"] is None and r["escaped"]["linearized"] is None
    # Theorem 1 with the example's L = I: P22 becomes singular at 0.5418 s (printed
    # L = [1 0]: 1.0222 s); the escape test stops the RK4 run a few steps before
    esc = r["L_identity"]["escaped"]["poly"]
    assert esc["quantity"] == "P" and 0.535 < esc["time"] < esc["singular_time"]
    assert esc["singular"]["entry"] == "P22"
    assert esc["singular_time"] == pytest.approx(reference_singular_time(np.eye(2)), abs=1e-6)
    assert r["L_identity"]["curve"]["poly"][2:] == [None, None, None]
    text = " ".join(" ".join(c.values()) for c in r["claims"]) + ph.why(r)
    assert "nan" not in text.lower()


def test_plant_and_filter_escapes_are_reported_not_nan(tmp_path):
    r = ph.reproduce(horizon_s=2.0, dt_s=1e-3, json_path=tmp_path / "o.json")
    assert r["escaped"]["plant"]["quantity"] == "state"
    assert 1.77 < r["escaped"]["plant"]["time"] < 1.79
    assert r["escaped"]["poly"]["quantity"] == "P"
    assert r["horizon"] < r["escaped"]["poly"]["time"] < 1.03
    assert r["exists_until"]["linearized"] <= r["escaped"]["plant"]["time"]
    json.loads((tmp_path / "o.json").read_text())  # strict JSON (no NaN)


@pytest.mark.slow
def test_full_run_numbers():
    r = ph.reproduce()
    assert r["requested_horizon"] == pytest.approx(1.4)
    esc = r["escaped"]
    assert esc["poly"]["quantity"] == "P" and 1.019 < esc["poly"]["time"] < 1.0215
    # the escape time to quote: where the Riccati solution is singular, not where the growth
    # test stopped the run (about 1 ms earlier)
    t_star = reference_singular_time(np.array([[1.0, 0.0]]))
    assert esc["poly"]["singular_time"] == pytest.approx(t_star, abs=1e-7)
    assert "1.02218" in r["claims"][0]["ours"]
    assert esc["linearized"] is None and esc["plant"] is None
    assert r["horizon"] < esc["poly"]["time"]
    # measured (dt 0.1 ms): T_poly 0.493 0.689 0.807 0.831 0.864, T_lin 0.497 0.711 0.876
    # 0.958 1.008 at t = 0.25 0.5 0.75 0.9 1.0
    np.testing.assert_allclose(r["curve"]["poly"], [0.4925, 0.6894, 0.8070, 0.8314, 0.8640],
                               atol=2e-4)
    np.testing.assert_allclose(r["curve"]["linearized"],
                               [0.4972, 0.7109, 0.8760, 0.9584, 1.0079], atol=2e-4)
    assert r["T_poly"] < r["T_linearized"] and r["T_poly"] < G
    assert r["T_at_paper_horizon"]["poly"] is None
    assert r["T_at_paper_horizon"]["linearized"] == pytest.approx(1.175, abs=2e-3)
    # the filters escape before the paper's horizon; where both exist the ordering holds
    verdicts = [c["verdict"] for c in r["claims"]]
    assert verdicts == ["differs", "differs", "agrees", "agrees"]
    assert agree_text(r["claims"]).startswith("2 of 4 claims agree; differs: the filters")
