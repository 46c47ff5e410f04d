"""Reproduction of the example of Wang & Fang (2006): variance-constrained robust H-infinity
filtering with parabolic pole assignment (see docs/references.md).

``testbed reproduce wang-variance-constrained-parabolic``. Four parts:

1. **design**: Theorem 1 with the printed parameters (eps1 = eps2 = 0.58, delta1 = delta2 =
   0.01, H = [0.1 0.1]^T, U = +-1) and the corrected equations
   (:func:`filters.variance_continuous.design_parabolic`); diagnostics when (17) has no
   positive definite solution (:func:`~filters.variance_continuous.equation17_margin`,
   :func:`~filters.variance_continuous.gamma_threshold`). A solved design is verified a
   posteriori (``design[U]["verification"]``, :func:`filters.variance_constrained.verify_design`).
2. **design_search**: ``(eps1, eps2)`` and the scale of ``H``
   (:func:`~filters.variance_continuous.search_parabolic`), each candidate verified.
3. **published**: the printed filters (K1, G1), (K2, G2) checked against the three
   requirements for all ``F`` (vertices and a grid,
   :func:`filters.analysis.robust_filter_analysis`), with the steady-state error covariance at
   ``F = 1, 0, -1``.
4. **Monte Carlo**: each printed filter on the plant
   (:class:`~testbed.plants.uncertain_linear.UncertainLinearPlant`, exact sampling of ``x`` and
   of the interval-averaged ``y``; the filter is the exact ZOH sampling of (4)), ``n_runs`` runs
   per ``F``; the empirical error variance (after a burn-in) against the continuous Lyapunov
   value and against the exact steady state of the sampled loop.

The helpers :func:`evaluate_published`, :func:`monte_carlo` and :func:`sampled_error_covariance`
are shared with :mod:`testbed.reproductions.liu_variance_constrained_discrete`.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.linalg import expm, solve_discrete_lyapunov

from filters._linalg import zoh
from filters.analysis import (
    PoleRegion,
    UncertainPlant,
    error_covariance,
    error_system,
    robust_filter_analysis,
)
from filters.variance_constrained import LinearFilter, VarianceDesign, verify_design
from filters.variance_continuous import (
    design_parabolic,
    equation16,
    equation17,
    equation17_margin,
    gamma_threshold,
    hat_terms,
    search_parabolic,
)
from testbed.plants.uncertain_linear import UncertainLinearPlant
from testbed.reproductions.outputs import write_outputs
from testbed.scenarios.wang_variance_parabolic import VarianceConstrainedContinuousScenario
from testbed.trajectory import Trajectory

NAME = "wang-variance-constrained-parabolic"
#: Sample period of the Monte-Carlo runs, s.
DT_S = 0.005
#: Default simulated time per run, s, and Monte-Carlo runs per (filter, F).
HORIZON_S = 20.0
N_RUNS = 1000
F_VALUES = (1.0, 0.0, -1.0)
#: Random starts of the equation solver for the printed parameters ((16) has two admissible
#: solutions; the default 6 starts find only the smaller one).
N_STARTS = 30


# ========================================================================= helpers
def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def evaluate_published(plant: UncertainPlant, name: str, K: np.ndarray, G: np.ndarray, *,
                       region: PoleRegion, gamma: float, sigma2: np.ndarray,
                       n_grid: int = 21) -> dict[str, Any]:
    """The three requirements of a given filter for all ``F``, and ``P`` at ``F = 1, 0, -1``.

    Returns
    -------
    dict
        ``name, K, G, hinf_worst, variance_worst, poles_in_region, worst_F, covariance``
        (``{"1", "0", "-1"}``), ``pole_margin_worst``, ``meets``, ``analysis``.
    """
    ra = robust_filter_analysis(plant, G, K, region=region, gamma=gamma, sigma2=sigma2,
                                n_grid=n_grid)
    summary = ra.to_dict()
    cov = {}
    for F in F_VALUES:
        try:
            cov[f"{F:g}"] = error_covariance(plant, G, K, F).tolist()
        except Exception:  # unstable for this F: no steady state
            cov[f"{F:g}"] = None
    return {
        "name": name, "K": np.asarray(K).tolist(), "G": np.asarray(G).tolist(),
        "hinf_worst": summary["hinf_worst"], "variance_worst": summary["variance_worst"],
        "poles_in_region": summary["poles_in_region"], "worst_F": summary["worst_F"],
        "covariance": cov, "pole_margin_worst": summary["pole_margin_worst"],
        "meets": summary["meets"], "analysis": summary,
        "filter_poles": [[float(z.real), float(z.imag)] for z in np.linalg.eigvals(G)],
    }


def _filter_maps(sim: UncertainLinearPlant, G: np.ndarray, K: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    if sim.discrete:
        return G, K
    return expm(G * sim.dt_s), zoh(G, K, sim.dt_s)[1]


def sampled_error_covariance(sim: UncertainLinearPlant, G: np.ndarray, K: np.ndarray,
                             F: float) -> np.ndarray:
    """Exact steady-state error covariance of the *sampled* loop plant + filter, shape (n, n).

    ``z = [x; xhat]``, ``z(k+1) = [[Phi_x, 0], [Gy Phi_y, Phi_g]] z + [[S_x], [Gy S_y]] xi``
    (discrete Lyapunov). For a discrete plant this equals
    :func:`filters.analysis.error_covariance`; for a continuous one it differs from it by the
    sampling of the filter, O(dt).
    """
    tr = sim.transition(F)
    n = sim.model.n
    Pg, Gy = _filter_maps(sim, G, K)
    Az = np.block([[tr.Phi[:n], np.zeros((n, n))], [Gy @ tr.Phi[n:], Pg]])
    Bz = np.vstack([tr.S[:n], Gy @ tr.S[n:]])
    Xz = solve_discrete_lyapunov(Az, Bz @ Bz.T)
    T = np.hstack([np.eye(n), -np.eye(n)])
    P = T @ Xz @ T.T
    return 0.5 * (P + P.T)


def monte_carlo(sim: UncertainLinearPlant, G: np.ndarray, K: np.ndarray, F: float, *,
                n_runs: int, n_steps: int, burn_in: int, rng: np.random.Generator
                ) -> dict[str, Any]:
    """``n_runs`` independent runs of plant + filter, batched; error statistics after burn-in.

    Every run starts at ``x = xhat = 0``. The per-run time average of ``e e^T`` over steps
    ``burn_in + 1 .. n_steps`` is averaged over runs; the standard error of each variance is
    the spread of the per-run averages over ``sqrt(n_runs)`` (runs are independent).

    Returns
    -------
    dict
        ``covariance`` (n, n), ``variance`` (n,), ``std_error`` (n,), ``n_runs``, ``n_steps``,
        ``burn_in``, and ``sample``: ``t`` (T,), ``x``, ``xhat`` (T, n), ``y`` (T - 1, p) of
        the first run.
    """
    n = sim.model.n
    x = np.zeros((n_runs, n))
    filt = LinearFilter(G, K, np.zeros((n_runs, n)), discrete=sim.discrete,
                        dt_s=sim.dt_s)
    acc = np.zeros((n_runs, n, n))
    xs = np.empty((n_steps + 1, n))
    hs = np.empty((n_steps + 1, n))
    ys = np.empty((n_steps, sim.model.p))
    xs[0] = hs[0] = 0.0
    for k in range(n_steps):
        x, y, _ = sim.step(x, F, rng)
        xhat = filt.step(y)
        xs[k + 1], hs[k + 1], ys[k] = x[0], xhat[0], y[0]
        if k + 1 > burn_in:
            e = x - xhat
            acc += e[:, :, None] * e[:, None, :]
    count = max(n_steps - burn_in, 1)
    per_run = acc / count
    cov = per_run.mean(axis=0)
    var_runs = np.diagonal(per_run, axis1=1, axis2=2)
    stderr = var_runs.std(axis=0, ddof=1) / math.sqrt(n_runs) if n_runs > 1 else np.zeros(n)
    return {"covariance": 0.5 * (cov + cov.T), "variance": np.diag(cov).copy(),
            "std_error": stderr, "n_runs": n_runs, "n_steps": n_steps, "burn_in": burn_in,
            "sample": {"t": np.arange(n_steps + 1) * sim.dt_s, "x": xs, "xhat": hs, "y": ys}}


def monte_carlo_block(sim: UncertainLinearPlant, published: list[dict[str, Any]],
                      plant: UncertainPlant, *, n_runs: int, n_steps: int, burn_in: int,
                      seed: int) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Monte Carlo of every published filter at ``F = 1, 0, -1``.

    Returns the JSON entries (one per filter and ``F``) and the first run of the first
    filter at ``F = 1`` (for the ``.rrd``).
    """
    seeds = np.random.SeedSequence(seed).spawn(len(published) * len(F_VALUES))
    out, sample = [], None
    for i, pub in enumerate(published):
        G, K = np.array(pub["G"]), np.array(pub["K"])
        for j, F in enumerate(F_VALUES):
            rng = np.random.default_rng(seeds[i * len(F_VALUES) + j])
            mc = monte_carlo(sim, G, K, F, n_runs=n_runs, n_steps=n_steps, burn_in=burn_in,
                             rng=rng)
            lyap = np.diag(error_covariance(plant, G, K, F))
            sampled = np.diag(sampled_error_covariance(sim, G, K, F))
            z = (mc["variance"] - sampled) / np.maximum(mc["std_error"], 1e-300)
            out.append({"filter": pub["name"], "F": F, "variance_mc": mc["variance"].tolist(),
                        "std_error": mc["std_error"].tolist(),
                        "variance_lyapunov": lyap.tolist(),
                        "variance_sampled_loop": sampled.tolist(),
                        "z_vs_sampled": z.tolist(),
                        "relative_to_lyapunov": (mc["variance"] / lyap - 1.0).tolist(),
                        "n_runs": n_runs, "n_steps": n_steps, "burn_in": burn_in,
                        "dt_s": sim.dt_s})
            if sample is None:
                sample = {**mc["sample"], "filter": pub["name"], "F": F,
                          "P": error_covariance(plant, G, K, F)}
    return out, sample


def trajectory(sample: dict[str, Any], scenario: str) -> Trajectory:
    """A :class:`Trajectory` of one Monte-Carlo run (``covariance``: the steady-state ``P``)."""
    t, x, xhat, y = sample["t"], sample["x"], sample["xhat"], sample["y"]
    n, p = x.shape[1], y.shape[1]
    meas = np.vstack([np.zeros((1, p)), y])
    return Trajectory(t_s=t, state=x, state_names=[f"x{i + 1}" for i in range(n)],
                      measurement=meas, measurement_names=[f"y{i + 1}" for i in range(p)],
                      measured_state_index=[None] * p, action=np.zeros((len(t), 1)),
                      action_names=["u [-]"], estimate=xhat,
                      covariance=np.broadcast_to(sample["P"], (len(t), n, n)).copy(),
                      meta={"scenario": scenario, "filter": sample["filter"],
                            "F": sample["F"], "covariance": "steady-state P (Lyapunov)"})


def design_entry(d: VarianceDesign, plant: UncertainPlant, s: Any) -> dict[str, Any]:
    """A design's JSON with its a-posteriori verification (``None`` when not solved)."""
    out = d.to_dict()
    out["verification"] = None
    if d.solved:
        out["verification"] = verify_design(plant, d.G, d.K, region=s.region, gamma=s.gamma,
                                            sigma2=s.sigma2).to_dict()
    return out


# ==================================================================== reproduction
def reproduce(horizon_s: float | None = None, seed: int = 0,
              json_path: str | Path | None = None, plot_path: str | Path | None = None,
              rrd_path: str | Path | None = None, n_runs: int = N_RUNS,
              search_points: int = 7) -> dict[str, Any]:
    """Run the example and write the requested outputs.

    Parameters
    ----------
    horizon_s : float, optional
        Simulated time of each Monte-Carlo run (default 20 s; burn-in a quarter of it, at
        most 5 s).
    seed : int
        Seed of the Monte Carlo (the designs are deterministic).
    json_path, plot_path, rrd_path : path, optional
    n_runs : int
        Monte-Carlo runs per filter and ``F``.
    search_points : int
        Values of ``eps1`` and of ``eps2`` in the search (log-spaced over [0.05, 10]).

    Returns
    -------
    dict
        ``design`` (``"U=1"``, ``"U=-1"``), ``design_diagnostics``, ``design_search``,
        ``published``, ``paper``, ``paper_checks``, ``monte_carlo``, settings and timings.
    """
    s = VarianceConstrainedContinuousScenario()
    plant = s.plant
    horizon_s = HORIZON_S if horizon_s is None else float(horizon_s)
    if not (np.isfinite(horizon_s) and horizon_s > 0):
        raise ValueError(f"horizon_s must be positive, got {horizon_s}")
    n_steps = max(int(round(horizon_s / DT_S)), 1)
    burn_in = min(int(round(5.0 / DT_S)), n_steps // 4)
    start = time.perf_counter()

    designs = {f"U={U:g}": design_parabolic(plant, s.parameters(U), sigma2=s.sigma2,
                                            n_random=N_STARTS)
               for U in (1.0, -1.0)}
    d1 = designs["U=1"]
    diag: dict[str, Any] = {"equation16_solutions": [], "equation17_margin": []}
    if d1.equation_1 is not None and d1.equation_1.solved:
        for Q1 in d1.equation_1.solutions:
            m, Q2m = equation17_margin(plant, s.parameters(1.0), Q1)
            diag["equation16_solutions"].append(Q1.tolist())
            diag["equation17_margin"].append({"Q1": Q1.tolist(), "min_lambda_max": m,
                                              "at_Q2": Q2m.tolist()})
    thr = s.gamma
    if not d1.solved and d1.equation_1 is not None and d1.equation_1.solved:
        thr = gamma_threshold(plant, s.parameters(1.0),
                              Q1_solutions=list(d1.equation_1.solutions))
    diag["gamma_threshold"] = thr
    t_design = time.perf_counter() - start

    search = search_parabolic(plant, s.parameters(1.0), s.sigma2,
                              eps1_values=np.geomspace(0.05, 10.0, search_points),
                              eps2_values=np.geomspace(0.05, 10.0, search_points),
                              h_scales=[0.0, 0.5, 1.0, 2.0])
    t_search = time.perf_counter() - start - t_design

    published = [evaluate_published(plant, name, K, G, region=s.region, gamma=s.gamma,
                                    sigma2=s.sigma2)
                 for name, (K, G) in s.published().items()]
    disk = s.region.proof_disk()
    for pub in published:
        lam = [np.linalg.eigvals(error_system(plant, pub["G"], pub["K"], F)[0])
               for F in np.linspace(-1, 1, 21)]
        pub["poles_in_proof_disk"] = bool(all(disk.contains(v) for v in lam))

    sim = UncertainLinearPlant(plant, DT_S)
    mc, sample = monte_carlo_block(sim, published, plant, n_runs=n_runs, n_steps=n_steps,
                                   burn_in=burn_in, seed=seed)

    paper = {"Q1": s.paper_Q1.tolist(), "Q2": s.paper_Q2.tolist(),
             "K1": s.paper_K1.tolist(), "G1": s.paper_G1.tolist(),
             "K2": s.paper_K2.tolist(), "G2": s.paper_G2.tolist()}
    result: dict[str, Any] = {
        "scenario": NAME,
        "parameters": {"a": s.a, "b": s.b, "gamma": s.gamma, "sigma2": s.sigma2.tolist(),
                       "eps1": s.eps1, "eps2": s.eps2, "delta1": s.delta1,
                       "delta2": s.delta2, "H": s.H.tolist()},
        "design": {k: design_entry(d, plant, s) for k, d in designs.items()},
        "design_diagnostics": diag,
        "design_search": search.to_dict(),
        "published": published,
        "paper": paper,
        "paper_checks": _paper_checks(s, plant),
        "proof_disk": {"center": float(np.real(disk.center)), "radius": disk.radius},
        "monte_carlo": mc,
        "horizon_s": n_steps * DT_S, "dt_s": DT_S, "seed": seed,
        "wall_s": {"design": t_design, "search": t_search,
                   "total": time.perf_counter() - start},
    }
    write_outputs(result, json_path=json_path, plot_path=plot_path, rrd_path=rrd_path,
                  plot=lambda path: _plot(result, s, plant, sample, path),
                  trajectory=lambda: trajectory(sample, NAME),
                  application_id="testbed-" + NAME, degrees=False)
    return result


def _paper_checks(s: VarianceConstrainedContinuousScenario,
                  plant: UncertainPlant) -> dict[str, Any]:
    """How the printed Q1, Q2, K1, K2, G1, G2 relate to (16)-(18).

    * residuals of (16) at the printed ``Q1`` and of (17) at the printed ``Q2`` (with the
      printed ``Q1``);
    * the gains (18) computed from the printed ``Q1``, ``Q2`` for ``U = +-1``;
    * what the printed pair implies: (18) gives ``K1 - K2 = 2 H U1 R^-1/2`` and
      ``G1 - G2 = -(K1 - K2) C_hat``, so ``K1 - K2`` must be parallel to ``H``.
    """
    prm = s.parameters(1.0)
    out: dict[str, Any] = {}
    r16 = equation16(s.paper_Q1, plant, prm)
    out["residual_16_at_printed_Q1"] = float(np.linalg.norm(r16))
    try:
        t = hat_terms(s.paper_Q1, plant, prm)
        r17 = equation17(s.paper_Q2, plant, prm, t)
        out["residual_17_at_printed_Q1_Q2"] = float(np.linalg.norm(r17))
        from filters.variance_continuous import gains18

        g = {}
        for U in (1.0, -1.0):
            K, G = gains18(s.paper_Q2, plant, prm, t, [[U]])
            g[f"U={U:g}"] = {"K": K.tolist(), "G": G.tolist()}
        out["gains18_from_printed_Q1_Q2"] = g
    except np.linalg.LinAlgError as exc:
        out["residual_17_at_printed_Q1_Q2"] = None
        out["gains18_error"] = str(exc)
    dK = (s.paper_K1 - s.paper_K2).ravel()
    h = s.H.ravel()
    cosang = float(dK @ h / (np.linalg.norm(dK) * np.linalg.norm(h)))
    out["K1_minus_K2"] = dK.tolist()
    out["angle_K1_minus_K2_to_H_deg"] = math.degrees(math.acos(min(1.0, abs(cosang))))
    out["implied_R_sqrt_per_component"] = (2.0 * h / dK).tolist()
    dG = s.paper_G1 - s.paper_G2
    C_hat = -(dK @ dG) / (dK @ dK)
    out["implied_C_hat"] = C_hat.tolist()
    out["implied_C_hat_fit_residual"] = float(np.abs(dG + np.outer(dK, C_hat)).max())
    return out


def _plot(result: dict[str, Any], s: VarianceConstrainedContinuousScenario,
          plant: UncertainPlant, sample: dict[str, Any], path: str | Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from testbed.io import atomic_path

    fig = Figure(figsize=(12, 9), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots(2, 2)
    plot_published(ax, result, plant, s.region, s.gamma, s.sigma2, sample,
                   discrete=False)
    fig.suptitle("Wang & Fang (2006), example: printed filters checked for all |F| <= 1; "
                 f"Theorem 1 design solved: {result['design']['U=1']['solved']}")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)


def plot_published(ax: Any, result: dict[str, Any], plant: UncertainPlant,
                   region: PoleRegion, gamma: float, sigma2: np.ndarray,
                   sample: dict[str, Any], *, discrete: bool) -> None:
    """Four panels: poles over F with the region, H-infinity norm over F, variances
    (Lyapunov curve, Monte-Carlo points), a sample error trajectory with +-2 sigma."""
    Fs = np.linspace(-1.0, 1.0, 41)
    markers = ["o", "s", "^"]
    for i, pub in enumerate(result["published"]):
        G, K = np.array(pub["G"]), np.array(pub["K"])
        lam = np.concatenate([np.linalg.eigvals(error_system(plant, G, K, F)[0]) for F in Fs])
        ax[0, 0].plot(lam.real, lam.imag, markers[i % 3], ms=3, alpha=0.6, label=pub["name"])
        rows = [robust_filter_analysis(plant, G, K, region=region,
                                       samples=[("grid", F) for F in Fs])]
        ra = rows[0]
        ax[0, 1].plot(Fs, ra.hinf, label=pub["name"])
        for j in range(plant.n):
            ax[1, 0].plot(Fs, ra.variances[:, j], label=f"{pub['name']}: var e{j + 1}")
        for mc in result["monte_carlo"]:
            if mc["filter"] == pub["name"]:
                ax[1, 0].errorbar([mc["F"]] * plant.n, mc["variance_mc"],
                                  yerr=[2 * e for e in mc["std_error"]], fmt="k.", ms=4)
    if discrete:
        th = np.linspace(0, 2 * np.pi, 200)
        ax[0, 0].plot(np.cos(th), np.sin(th), "k", lw=0.8, label="unit circle")
    else:
        a, b = region.a, region.b  # type: ignore[attr-defined]
        im = np.linspace(-3, 3, 200)
        ax[0, 0].plot(-a - b * im**2 / 2, im, "k", lw=0.8, label=f"P({a:g}, {b:g})")
        disk = region.proof_disk()  # type: ignore[attr-defined]
        th = np.linspace(0, 2 * np.pi, 200)
        c = float(np.real(disk.center))
        ax[0, 0].plot(c + disk.radius * np.cos(th), disk.radius * np.sin(th), "k:", lw=0.8,
                      label="disk of proof (28)")
    ax[0, 0].set(title="poles of A_f + M_f F N_f, F in [-1, 1]", xlabel="Re", ylabel="Im")
    ax[0, 0].legend(fontsize=7)
    ax[0, 1].axhline(gamma, color="k", lw=0.8, label=f"gamma = {gamma:g}")
    ax[0, 1].set(title="||H||_inf from w to L e over F", xlabel="F", yscale="log")
    ax[0, 1].legend(fontsize=7)
    for j, v in enumerate(sigma2):
        ax[1, 0].axhline(v, color="k", ls="--", lw=0.8,
                         label=f"sigma_i^2 = {[float(x) for x in sigma2]}" if j == 0 else None)
    ax[1, 0].set(title="steady-state error variances (lines: Lyapunov; dots: Monte Carlo "
                 "+-2 s.e.)", xlabel="F", yscale="log")
    ax[1, 0].legend(fontsize=6)
    t, e = sample["t"], sample["x"] - sample["xhat"]
    sd = np.sqrt(np.diag(sample["P"]))
    for j in range(e.shape[1]):
        ax[1, 1].plot(t, e[:, j], lw=0.6, label=f"e{j + 1}")
        ax[1, 1].axhline(2 * sd[j], color=f"C{j}", ls=":", lw=0.8)
        ax[1, 1].axhline(-2 * sd[j], color=f"C{j}", ls=":", lw=0.8)
    ax[1, 1].set(title=f"one run: {sample['filter']}, F = {sample['F']:g} (dotted: +-2 sigma)",
                 xlabel="t [s]" if not discrete else "k")
    ax[1, 1].legend(fontsize=7)


def row(result: dict[str, Any]) -> dict[str, str]:
    """The line of ``docs/reproductions.md`` for this reproduction."""
    p = result["parameters"]
    d = result["design"]["U=1"]
    pubs = result["published"]
    ok_pub = all(all(v is not False for v in pub["meets"].values()) for pub in pubs)
    pub_txt = "; ".join(
        f"{pub['name']}: max ||H||inf = {pub['hinf_worst']:.4f}, max var = "
        f"[{pub['variance_worst'][0]:.4f}, {pub['variance_worst'][1]:.4f}], poles in "
        f"P: {pub['poles_in_region']}" for pub in pubs)
    mc = result["monte_carlo"]
    worst_rel = max(abs(v) for m in mc for v in m["relative_to_lyapunov"])
    worst_z = max(abs(v) for m in mc for v in m["z_vs_sampled"])
    search = result["design_search"]
    diag = result["design_diagnostics"]
    margins = [m["min_lambda_max"] for m in diag.get("equation17_margin", [])]
    thr = diag.get("gamma_threshold")
    if d["solved"]:
        design_txt = (f"(16), (17) solved: diag Q2 = "
                      f"{np.round(np.diag(np.array(d['Q2'])), 4).tolist()}")
    else:
        design_txt = (f"(16) solved (Q1 diag "
                      f"{np.round(np.diag(np.array(d['Q1'])), 4).tolist() if d['Q1'] else '-'}"
                      f", residual {d['residual_16']:.1e}); (17) has no positive definite "
                      f"solution (smallest residual {d['residual_17']:.3f})"
                      if d["residual_17"] is not None else f"not solved: {d['message']}")
    search_txt = ("search found a verified design at " + search["design"]["message"]
                  if search["found"] else
                  f"search over {search['tried']} (eps1, eps2, H scale) points: no feasible "
                  f"design (best (17) residual {search['best_residual_second_equation']:.3f})")
    checks = result["paper_checks"]
    why = (f"The printed Q1 does not satisfy (16) (residual "
           f"{checks['residual_16_at_printed_Q1']:.3f}) nor Q2 (17) (residual "
           f"{checks['residual_17_at_printed_Q1_Q2']:.3f}); (16) itself is solvable. ")
    if margins and not d["solved"]:
        why += (f"(17) cannot hold for any H: lambda_max of its left side without H H^T stays "
                f">= {min(margins):.3f} > 0 over Q2 > 0 (local search)")
        why += (f"; it first reaches 0 at gamma = {thr:.3g} (printed {p['gamma']:g}). "
                if thr else ". ")
    why += (f"The printed pair is not (18) with one H: K1 - K2 is "
            f"{checks['angle_K1_minus_K2_to_H_deg']:.1f} deg off H = E. The printed filters "
            f"{'do' if ok_pub else 'do not'} meet all three requirements for every |F| <= 1 "
            "(Theorem 1 is only sufficient). Monte Carlo (exact plant sampling, "
            f"dt = {result['dt_s']:g} s) agrees with the Lyapunov variances within "
            f"{worst_rel:.1%} and with the sampled loop's steady state within "
            f"{worst_z:.1f} standard errors. Misprints corrected: (11) C_hat, (14)/(17) M1 M1^T.")
    return {
        "paper": "Wang & Fang (2006), Section IV",
        "claim": (f"(16), (17) solved with eps1 = eps2 = {p['eps1']:g}, delta = "
                  f"{p['delta1']:g}, H = [0.1 0.1]^T; (K1, G1), (K2, G2) give poles in "
                  f"P({p['a']:g}, {p['b']:g}), ||H||inf <= {p['gamma']:g} and var <= "
                  f"{p['sigma2']} for all |F| <= 1"),
        "ours": f"{design_txt}; {search_txt}. Printed filters: {pub_txt}",
        "agree": "partly" if ok_pub else "no",
        "why": why,
    }
