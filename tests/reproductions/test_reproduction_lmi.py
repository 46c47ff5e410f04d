"""Zhang, Deng & Zhang (2018), Example 5.2: scenario data, the rig model, the CLI helper and
the reproduction."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from filters.lmi_hinf import check_design, lmi_gamma_for_solution, minimal_gamma
from testbed.cli import main
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.reproductions.outputs import agree_text
from testbed.reproductions.zhang_lmi_hinf import vehicle_roll as rep
from testbed.reproductions.zhang_lmi_hinf.scenario import (
    PAPER_K_HAT,
    PAPER_P1,
    PAPER_P2,
    PAPER_P_K,
    identify_rig_step,
    paper_system,
    rig_system,
)
from testbed.rigs.vehicle_roll import paper_model

CASES = {"x0_zero", "x0_paper"}
KEYS = {"gamma_min", "gamma_used", "K_hat", "lmi_solve_s", "error_spectral_radius",
        "sum_E_z2", "gamma2_sum_v2", "inequality_holds"}


def test_paper_system_is_52_verbatim():
    s, m = paper_system(), paper_model()
    for a, b in ((s.A, m.A), (s.B, m.B), (s.C_y, m.H), (s.D_y, m.L), (s.C_z, m.M),
                 (s.A_w, m.C)):
        assert np.array_equal(a, b)
    assert np.all(s.B_w == 0) and np.all(s.D_z == 0)


def test_printed_solution_needs_gamma_near_7():
    """The printed P1, P2, P_K satisfy (48) only above gamma = 6.9967; P2^-1 P_K != Khat."""
    g = lmi_gamma_for_solution(paper_system(), PAPER_P1, PAPER_P2, PAPER_P_K)
    assert g == pytest.approx(6.9967, abs=1e-3)
    k = np.linalg.solve(PAPER_P2, PAPER_P_K)
    assert np.allclose(k[0], PAPER_K_HAT[0], atol=0.01)
    assert not np.allclose(k[1], PAPER_K_HAT[1], atol=0.1)  # ill-conditioned P2 (references.md)


def test_printed_gain_is_certified_from_gamma_5():
    s = minimal_gamma(paper_system(), gain=PAPER_K_HAT)
    assert s.gamma_min == pytest.approx(5.01, abs=0.01)
    d = s.design
    assert check_design(paper_system(), PAPER_K_HAT, d.P1, d.P2, s.gamma_min).ok


def test_rig_model_is_the_zoh_of_the_physics_and_close_to_mujoco():
    s = rig_system()
    A_id, B_id = identify_rig_step()
    assert np.abs(A_id - s.A).max() / np.abs(s.A).max() < 0.01
    assert np.abs(B_id - s.B).max() / np.abs(s.B).max() < 0.03
    # damping noise: the derivative of the ZOH map times D_n, against finite differences
    from scipy.linalg import expm

    from testbed.rigs.vehicle_roll import VehicleRollParams, physical_model
    p = VehicleRollParams()
    h = 1.0
    hi = expm(physical_model(p.scaled({"roll_damping": 1 + h / p.roll_damping}))[0] * 0.01)
    lo = expm(physical_model(p.scaled({"roll_damping": 1 - h / p.roll_damping}))[0] * 0.01)
    assert np.allclose(s.A_w, p.damping_noise * (hi - lo) / (2 * h), rtol=1e-5, atol=1e-12)


@pytest.mark.parametrize("sensors, kwargs", [("paper", {}), ("imu", {"roll_sensor": True})])
def test_cli_estimator_flies_the_rig(sensors, kwargs):
    scenario = Scenario(rig="vehicle-roll", estimator="lmi-hinf", sensors=sensors,
                        sensor_options=kwargs, duration_s=4.0, seed=0, ambient_noise=0.0,
                        reset_noise_scale=0.0)
    experiment = runner.build(scenario)
    meta = experiment.meta["design"]
    experiment.close()
    assert meta["status"] == "feasible" and meta["gamma"] >= meta["gamma_min"]
    assert meta["spectral_radius"] < 1
    traj, summary = runner.run(scenario, progress=False)
    assert traj.covariance is None and np.isfinite(traj.estimate).all()
    # the manoeuvre rolls ~1.4 deg; the reproducible default design (gamma on the 1-2-5 grid
    # at least 5 gamma_min, filters.lmi_hinf.design_on_grid) gives 0.03-0.07 deg
    assert np.rad2deg(summary["rmse"]["roll"]) < 0.1


def test_reproduction_short_run_writes_all_keys(tmp_path):
    code = main(["reproduce", "zhang-lmi-hinf-vehicle-roll", "--horizon", "0.5", "--json",
                 str(tmp_path / "o.json"), "--plot", str(tmp_path / "o.png"), "--rrd",
                 str(tmp_path / "o.rrd")])
    assert code == 0
    r = json.loads((tmp_path / "o.json").read_text())
    assert KEYS <= set(r) and KEYS <= set(r["paper_K_hat"]) and KEYS <= set(r["rig"])
    for entry in (r, r["paper_K_hat"], r["rig"]):
        for key in ("sum_E_z2", "gamma2_sum_v2", "inequality_holds"):
            assert set(entry[key]) == CASES
        assert entry["gamma_used"] >= entry["gamma_min"] and entry["error_spectral_radius"] < 1
    assert r["steps"] == 50 and r["runs"] == 100
    # on the paper's model: (7) holds from eta_0 = 0, not with the paper's x0; bound (13) holds
    for entry in (r, r["paper_K_hat"]):
        assert entry["inequality_holds"] == {"x0_zero": True, "x0_paper": False}
        assert all(entry["bound_13_holds"].values())
        for case in CASES:  # Monte Carlo against the exact moments of (46)
            mc, exact = entry["sum_E_z2"][case], entry["sum_E_z2_exact"][case]
            assert abs(mc - exact) <= 5 * entry["sum_E_z2_stderr"][case] + 1e-9 * exact
    assert r["paper_K_hat"]["K_hat"] == PAPER_K_HAT.tolist()
    assert r["paper_K_hat"]["gamma_min"] == pytest.approx(5.01, abs=0.01)
    assert r["exact_decoupling"]["gamma_infimum_is_zero"]
    assert not r["rig"]["exact_decoupling"]["gamma_infimum_is_zero"]
    assert (tmp_path / "o.png").stat().st_size > 20_000
    assert (tmp_path / "o.rrd").stat().st_size > 10_000
    assert f"{r['gamma_min']:.3g}" in r["claims"][0]["ours"]
    assert "V(eta_0)" in rep.why(r) and rep.PAPER.year == "2018"
    # claims as data: verdicts follow the numbers above
    claims = {c["claim"].split(":")[0]: c for c in r["claims"]}
    assert len(r["claims"]) == 7 and agree_text(r["claims"]).startswith("5 of 7 claims agree")
    assert claims["Fig. 7, x0 = [0.1, 1]"]["verdict"] == "differs"
    assert claims["(7) from eta_0 = 0 (x0 = xhat_0 = 0)"]["verdict"] == "agrees"
    assert claims["the printed Khat equals P2^-1 P_K"]["verdict"] == "differs"
    assert "6.997" in claims["the printed P1, P2, P_K solve LMI (48)"]["ours"]
    # the .rrd: each run under its own path with a text saying what it is
    from testbed.outputs.rrd_inspect import inspect_rrd

    c = inspect_rrd(tmp_path / "o.rrd")
    assert set(c.texts) == {"rig_x0_paper/about", "rig_x0_zero/about", "model52_x0_paper/about"}
    assert "x0 = 0" in c.texts["rig_x0_zero/about"]
    for prefix in ("rig_x0_paper", "rig_x0_zero", "model52_x0_paper"):
        assert c.rows[f"{prefix}/state/roll/actual"] == 51
    assert c.rows["rig_x0_zero/rig/sprung_mass"] == 51
    assert c.time_range_s == pytest.approx((0.0, 0.5))
    assert c.styles["rig_x0_paper/measurement/y1"]["names"][0].startswith("measured y1")


def test_claims_mechanism(figure_checks):
    from testbed.outputs.plots import new_figure
    from testbed.reproductions.outputs import (
        Claim,
        agree_text,
        claims_height_in,
        claims_json,
        draw_claims,
        format_claims,
    )

    claims = [Claim("a", "1", "1.0", Claim.judge(True)),
              Claim("b", "2", "3", Claim.judge(False), "because"),
              Claim("c", "x", "-", "not checked")]
    with pytest.raises(ValueError, match="verdict"):
        Claim("d", "1", "1", "maybe")
    assert agree_text(claims) == "1 of 3 claims agree; differs: b"
    text = format_claims(claims_json(claims))
    assert text.splitlines()[1] == "  [differs] b: paper 2 | ours 3 (because)"
    fig = new_figure(8, 1 + claims_height_in(claims))
    draw_claims(fig.add_subplot(), claims)
    shown = [t.get_text() for t in figure_checks.texts(fig)]
    assert "[differs]" in shown and any("b: paper 2; ours 3 (because)" in t for t in shown)
    figure_checks.readable(fig)


def test_bench_lmi_keys():
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    from bench_lmi import bench_lmi

    out = bench_lmi(repeats=1, bisections=1)
    assert set(out) == {"lmi_solve_s", "gamma_bisection_s"}
    assert all(np.isfinite(v) and v > 0 for v in out.values())


@pytest.mark.slow
def test_full_reproduction_numbers():
    r = rep.reproduce()
    assert r["steps"] == 200 and r["runs"] == 100
    assert r["inequality_holds"]["x0_zero"] and not r["inequality_holds"]["x0_paper"]
    assert r["paper_K_hat"]["gamma_needed"]["x0_paper"] > 10
    assert r["wall_s"] < 120
