"""What the variance-constrained examples (Wang & Fang's parabolic-region filter and Liu,
Deng & Wang's discrete filter) share: :func:`run_example`, its pieces and the figure."""

from __future__ import annotations

import math
import textwrap
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.linalg import solve_discrete_lyapunov

from filters import zoh
from filters.analysis import error_covariance, error_system, robust_filter_analysis
from filters.variance_constrained import (
    DesignSearchRecord,
    LinearFilter,
    VarianceDesign,
    verify_design,
)
from testbed.experiment.numpy_plant import rollout
from testbed.experiment.trajectory import Trajectory
from testbed.outputs.viz import Run
from testbed.reproductions.outputs import claims_figure, finish_figure, legend_below
from testbed.reproductions.variance_constrained.plant import UncertainLinearPlant

#: Registered environment of the plant (``testbed/UncertainLinear-v0``).
ENV_ID = "testbed/UncertainLinear-v0"
#: The uncertainties at which the filters are checked in detail and simulated.
F_VALUES = (1.0, 0.0, -1.0)
#: Optimizer starts and objective evaluations per start of the design search (the printed
#: parameters are start 0).
SEARCH_STARTS = 8
SEARCH_EVALUATIONS = 300
#: Name of the best searched design in ``monte_carlo`` and the figure.
SEARCHED = "searched design"


def evaluate_published(s: Any, name: str, K: Any, G: Any, n_grid: int = 21) -> dict[str, Any]:
    """The three requirements of a given filter for all ``F`` on the scenario ``s``
    (``plant``, ``region``, ``gamma``, ``sigma2``), and ``P`` at ``F = 1, 0, -1``.

    Returns
    -------
    dict
        ``name, K, G, hinf_worst, variance_worst, poles_in_region, worst_F, covariance``
        (``{"1", "0", "-1"}``), ``pole_margin_worst``, ``meets``, ``analysis``.
    """
    plant, K, G = s.plant, np.array(K), np.array(G)
    ra = robust_filter_analysis(plant, G, K, region=s.region, gamma=s.gamma, sigma2=s.sigma2,
                                n_grid=n_grid)
    summary = ra.to_dict()
    cov = {}
    for F in F_VALUES:
        try:
            cov[f"{F:g}"] = error_covariance(plant, G, K, F).tolist()
        except Exception:  # unstable for this F: no steady state
            cov[f"{F:g}"] = None
    return {"name": name, "K": K.tolist(), "G": G.tolist(),
            **{key: summary[key] for key in ("hinf_worst", "variance_worst", "poles_in_region",
                                             "worst_F", "pole_margin_worst", "meets")},
            "covariance": cov, "analysis": summary,
            "filter_poles": [[float(z.real), float(z.imag)] for z in np.linalg.eigvals(G)]}


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
    Pg, Gy = (G, K) if sim.discrete else zoh(G, K, sim.dt_s)
    Az = np.block([[tr.Phi[:n], np.zeros((n, n))], [Gy @ tr.Phi[n:], Pg]])
    Bz = np.vstack([tr.S[:n], Gy @ tr.S[n:]])
    Xz = solve_discrete_lyapunov(Az, Bz @ Bz.T)
    T = np.hstack([np.eye(n), -np.eye(n)])
    P = T @ Xz @ T.T
    return 0.5 * (P + P.T)


def monte_carlo_block(sim: UncertainLinearPlant, filters: list[dict[str, Any]], *,
                      n_runs: int, n_steps: int, burn_in: int, seed: int) -> list[dict[str, Any]]:
    """Monte Carlo of every filter at ``F = 1, 0, -1``: ``n_runs`` runs from
    ``x = xhat = 0`` stepped as one batch (:func:`~testbed.experiment.numpy_plant.rollout`).

    The per-run time average of ``e e^T`` over steps ``burn_in + 1 .. n_steps`` is averaged
    over runs; the standard error of each variance is the spread of the per-run averages over
    ``sqrt(n_runs)`` (runs are independent).

    Parameters
    ----------
    sim : UncertainLinearPlant
    filters : list of dict
        Each with ``name``, ``K`` (n, p) and ``G`` (n, n) (the ``published`` entries, then
        e.g. the searched design).
    n_runs, n_steps, burn_in, seed : int
        Filter ``i`` at ``F_VALUES[j]`` uses the generator of child ``3 i + j`` of
        ``SeedSequence(seed)`` (appending a filter leaves the others' numbers unchanged);
        each step draws ``(n_runs, r)`` standard normals from it.

    Returns
    -------
    list of dict
        One entry per filter and ``F``: ``filter``, ``F``, ``variance_mc``, ``std_error``,
        ``variance_lyapunov``, ``variance_sampled_loop``, ``z_vs_sampled``,
        ``relative_to_lyapunov``, ``n_runs``, ``n_steps``, ``burn_in``, ``dt_s``.
    """
    seeds = np.random.SeedSequence(seed).spawn(len(filters) * len(F_VALUES))
    plant, n = sim.model, sim.model.n
    out = []
    for i, entry in enumerate(filters):
        G, K = np.array(entry["G"]), np.array(entry["K"])
        for j, F in enumerate(F_VALUES):
            acc = np.zeros((n_runs, n, n))

            def gather(k: int, x: np.ndarray, est: dict[str, np.ndarray]) -> None:
                if k + 1 > burn_in:
                    e = x - est["filter"]
                    acc[...] += e[:, :, None] * e[:, None, :]  # noqa: B023 (used at once)

            filt = LinearFilter(G, K, np.zeros((n_runs, n)), discrete=sim.discrete,
                                dt_s=sim.dt_s)
            rollout(sim.at(F), np.zeros((n_runs, n)), n_steps,
                    noise=np.random.default_rng(seeds[i * len(F_VALUES) + j]),
                    estimators={"filter": filt}, record=False, on_step=gather)
            per_run = acc / max(n_steps - burn_in, 1)
            variance = np.diag(per_run.mean(axis=0)).copy()
            var_runs = np.diagonal(per_run, axis1=1, axis2=2)
            stderr = (var_runs.std(axis=0, ddof=1) / math.sqrt(n_runs) if n_runs > 1
                      else np.zeros(n))
            lyap = np.diag(error_covariance(plant, G, K, F))
            sampled = np.diag(sampled_error_covariance(sim, G, K, F))
            z = (variance - sampled) / np.maximum(stderr, 1e-300)
            out.append({"filter": entry["name"], "F": F, "variance_mc": variance.tolist(),
                        "std_error": stderr.tolist(), "variance_lyapunov": lyap.tolist(),
                        "variance_sampled_loop": sampled.tolist(), "z_vs_sampled": z.tolist(),
                        "relative_to_lyapunov": (variance / lyap - 1.0).tolist(),
                        "n_runs": n_runs, "n_steps": n_steps, "burn_in": burn_in,
                        "dt_s": sim.dt_s})
    return out


def loop_sample(sim: UncertainLinearPlant, name: str, G: np.ndarray, K: np.ndarray, F: float, *,
                n_steps: int, seed: int) -> dict[str, Any]:
    """One run at ``F`` with the filter ``(G, K)`` in the loop, from ``x = xhat = 0``, its
    noise drawn from ``default_rng(seed)`` step by step (as an episode of :data:`ENV_ID`
    after ``reset(seed=seed, options={"F": F})``), with the filter's steady-state error
    covariance ``P`` (Lyapunov) as its covariance.

    Parameters
    ----------
    sim : UncertainLinearPlant
    name : str
        Filter name (recorded).
    G, K : numpy.ndarray, shapes (n, n), (n, p)
    F : float
    n_steps, seed : int

    Returns
    -------
    dict
        ``t`` (T,), ``x``, ``xhat`` (T, n), ``y`` (T - 1, p) with ``T = n_steps + 1``,
        ``P`` (n, n), ``filter``, ``F``, ``seed``.
    """
    n, P = sim.model.n, error_covariance(sim.model, G, K, F)
    est = LinearFilter(G, K, np.zeros(n), discrete=sim.discrete, dt_s=sim.dt_s, covariance=P)
    run = rollout(sim.at(F), np.zeros(n), n_steps, noise=np.random.default_rng(seed),
                  estimators={name: est})
    return {"t": run.t_s, "x": run.x, "xhat": run.estimates[name], "y": run.y,
            "filter": name, "F": F, "P": P, "seed": seed}


def episode_run(sample: dict[str, Any], scenario: str, time_text: str) -> Run:
    """The recorded run of a reproduction (:func:`loop_sample`) as the run ``"episode"`` of
    its ``.rrd``: truth, estimate and the steady-state ``P`` as covariance, with its
    description; ``time_text`` says what ``t`` counts."""
    t, x, xhat, y = sample["t"], sample["x"], sample["xhat"], sample["y"]
    n, p = x.shape[1], y.shape[1]
    traj = Trajectory(t_s=t, state=x, state_names=[f"x{i + 1}" for i in range(n)],
                      measurement=np.vstack([np.zeros((1, p)), y]),
                      measurement_names=[f"y{i + 1}" for i in range(p)],
                      action=np.zeros((len(t), 1)), action_names=["u"], estimate=xhat,
                      covariance=np.broadcast_to(sample["P"], (len(t), n, n)).copy(),
                      meta={"scenario": scenario, "filter": sample["filter"],
                            "F": sample["F"], "seed": sample["seed"], "env": ENV_ID,
                            "covariance": "steady-state P (Lyapunov)"})
    return Run(traj, "episode", (
        f"# {ENV_ID} episode: filter {sample['filter']}, F = {sample['F']:g} (seed "
        f"{sample['seed']})\n\nOne run of the uncertain plant with the filter in the loop "
        "(its noise seeded as an episode of the environment), from x = xhat = 0: truth, "
        "estimate and the steady-state error covariance P (Lyapunov) as the +-3 sigma band; "
        "what the figure's last panel shows. The Monte-Carlo statistics are separate runs, "
        f"not logged. {time_text} The system is dimensionless (no units)."))


def search_summary(record: DesignSearchRecord) -> dict[str, Any] | None:
    """The best verified design of a search, compactly (``None`` if none was verified).

    Returns
    -------
    dict or None
        ``parameters``, ``start``, ``certified``, ``diag_Q2``, ``K``, ``G``, ``residuals``
        (of the two equations), ``hinf_worst``, ``variance_worst``, ``pole_margin_worst``,
        ``n_candidates``, ``n_solved``, ``n_certified``, ``n_verified``, ``evaluations``,
        ``wall_s``.
    """
    best, ra, d = record.best, record.verification, record.design
    if best is None or ra is None or d is None:
        return None
    cands = record.candidates
    return {
        "parameters": best.parameters, "start": best.start, "certified": best.certified,
        "diag_Q2": np.diag(d.Q2).tolist(), "K": d.K.tolist(), "G": d.G.tolist(),
        "residuals": [d.residual_1, d.residual_2],
        "hinf_worst": ra.hinf_worst, "variance_worst": ra.variance_worst.tolist(),
        "pole_margin_worst": ra.pole_margin_worst,
        "n_candidates": len(cands), "n_solved": sum(c.solved for c in cands),
        "n_certified": sum(c.certified for c in cands),
        "n_verified": sum(c.verified for c in cands),
        "evaluations": record.evaluations, "wall_s": record.wall_s,
    }


def _fmt(v: Any) -> str:
    return "[" + ", ".join(f"{float(x):.3g}" for x in v) + "]"


def design_entry(d: VarianceDesign, s: Any) -> dict[str, Any]:
    """A design's JSON with its a-posteriori verification on the scenario ``s`` (``None``
    when not solved)."""
    out = d.to_dict()
    out["verification"] = None
    if d.solved:
        out["verification"] = verify_design(s.plant, d.G, d.K, region=s.region, gamma=s.gamma,
                                            sigma2=s.sigma2).to_dict()
    return out


def run_example(name: str, s: Any,
                design: Callable[[], tuple[dict[str, VarianceDesign], dict[str, Any]]],
                search: Callable[[int, int], DesignSearchRecord], *, dt_s: float,
                n_steps: int, burn_in: int, n_runs: int, seed: int,
                search_starts: int | None = None, search_evaluations: int | None = None
                ) -> tuple[dict[str, Any], dict[str, Any]]:
    """What both examples compute: the designs at the printed parameters, the design search,
    the printed filters and the best searched design checked for every ``F``, their Monte
    Carlo (:func:`monte_carlo_block`) and one run with the first printed filter at ``F = 1``
    (:func:`loop_sample`).

    Parameters
    ----------
    name : str
        The reproduction.
    s : scenario
        ``plant``, ``region``, ``gamma``, ``sigma2``, ``published()``.
    design : callable ``() -> (designs, diagnostics)``
        The designs at the printed parameters (``{"U=1": ..., "U=-1": ...}``).
    search : callable ``(n_starts, max_evaluations) -> DesignSearchRecord``
    dt_s : float
        Sample period of the runs.
    n_steps, burn_in : int
        Steps of each run and steps left out of its averages.
    n_runs : int
        Monte-Carlo runs per filter and ``F``.
    seed : int
        Seed of the Monte Carlo and of the environment episode (the designs and the search
        are deterministic; the search's random starts use seed 0).
    search_starts, search_evaluations : int or None
        Optimizer starts of the design search (the printed parameters included) and objective
        evaluations per start (``None``: :data:`SEARCH_STARTS`, :data:`SEARCH_EVALUATIONS`).

    Returns
    -------
    result : dict
        ``scenario``, ``design``, ``design_diagnostics``, ``design_search`` (with
        ``summary``), ``published``, ``searched``, ``monte_carlo``, ``env``, ``horizon_s``,
        ``dt_s``, ``seed``, ``wall_s``.
    sample : dict
        The run of :func:`loop_sample`.
    """
    search_starts = SEARCH_STARTS if search_starts is None else search_starts
    search_evaluations = SEARCH_EVALUATIONS if search_evaluations is None else search_evaluations
    for label, value in (("n_runs", n_runs), ("search_starts", search_starts),
                         ("search_evaluations", search_evaluations)):
        if int(value) != value or value < 1:
            raise ValueError(f"{label} must be a positive integer, got {value!r}")
    start = time.perf_counter()
    designs, diagnostics = design()
    t_design = time.perf_counter() - start
    record = search(int(search_starts), int(search_evaluations))
    summary = search_summary(record)
    t_search = time.perf_counter() - start - t_design
    published = [evaluate_published(s, name, K, G) for name, (K, G) in s.published().items()]
    searched = (None if summary is None
                else evaluate_published(s, SEARCHED, summary["K"], summary["G"]))
    sim = UncertainLinearPlant(s.plant, dt_s)
    mc = monte_carlo_block(sim, published + ([searched] if searched else []),
                           n_runs=int(n_runs), n_steps=n_steps, burn_in=burn_in, seed=seed)
    first = published[0]
    sample = loop_sample(sim, first["name"], np.array(first["G"]), np.array(first["K"]),
                         F_VALUES[0], n_steps=n_steps, seed=seed)
    search_dict = record.to_dict()
    search_dict["summary"] = summary
    return {
        "scenario": name,
        "design": {k: design_entry(d, s) for k, d in designs.items()},
        "design_diagnostics": diagnostics, "design_search": search_dict,
        "published": published, "searched": searched, "monte_carlo": mc,
        "env": {"id": ENV_ID, "episode": {"filter": sample["filter"], "F": sample["F"],
                                          "seed": seed, "steps": n_steps}},
        "horizon_s": n_steps * dt_s, "dt_s": dt_s, "seed": seed,
        "wall_s": {"design": t_design, "search": t_search,
                   "total": time.perf_counter() - start},
    }, sample


def plot_figure(result: dict[str, Any], s: Any, sample: dict[str, Any], title: list[str],
                path: str | Path, extra: Callable[[Any], None] | None = None) -> None:
    """The figure of a variance-constrained reproduction: four panels (poles over F with the
    region, H-infinity norm over F, variances: Lyapunov curve and Monte-Carlo points, one
    environment episode's error with +-2 sigma), the claims (``result["claims"]``) under
    them, ``title`` and the claims' summary on top.

    Parameters
    ----------
    result : dict
        :func:`run_example`'s result with ``claims``; its filters are ``result["published"]``
        and, if found, ``result["searched"]``.
    s : scenario
        ``plant``, ``region``, ``gamma``, ``sigma2``. The system is dimensionless; time is in
        s (continuous plant) or samples (discrete).
    sample : dict
        The episode (:func:`loop_sample`).
    title : list of str
        The title's lines; the last one gets the design search's outcome appended.
    path : path
    extra : callable ``ax -> None``, optional
        Draws more into the panels (``ax``: ndarray of Axes, shape (2, 2)) before their
        legends, which go below them.
    """
    found = "verified design found" if result["searched"] is not None else "nothing verified"
    fig, grid = claims_figure(result["claims"], 12, 12, [5.6, 5.6], cols=2, wrap=140)
    ax = np.array([[fig.add_subplot(grid[i, j]) for j in range(2)] for i in range(2)])
    plant, region, gamma, sigma2 = s.plant, s.region, s.gamma, s.sigma2
    discrete = plant.discrete
    Fs = np.linspace(-1.0, 1.0, 41)
    markers = ["o", "s", "^"]
    filters = result["published"] + ([result["searched"]] if result.get("searched") else [])
    for i, pub in enumerate(filters):
        G, K = np.array(pub["G"]), np.array(pub["K"])
        lam = np.concatenate([np.linalg.eigvals(error_system(plant, G, K, F)[0]) for F in Fs])
        ax[0, 0].plot(lam.real, lam.imag, markers[i % 3], ms=3, alpha=0.6, label=pub["name"])
        ra = robust_filter_analysis(plant, G, K, region=region,
                                    samples=[("grid", F) for F in Fs])
        ax[0, 1].plot(Fs, ra.hinf, label=pub["name"])
        for j in range(plant.n):
            ax[1, 0].plot(Fs, ra.variances[:, j], label=f"{pub['name']}: var e{j + 1}")
        for mc in result["monte_carlo"]:
            if mc["filter"] == pub["name"]:
                ax[1, 0].errorbar([mc["F"]] * plant.n, mc["variance_mc"],
                                  yerr=[2 * e for e in mc["std_error"]], fmt="k.", ms=4,
                                  label="Monte Carlo +-2 s.e." if i == 0 and mc["F"] == 1.0
                                  else None)
    th = np.linspace(0, 2 * np.pi, 200)
    if discrete:
        ax[0, 0].plot(np.cos(th), np.sin(th), "k", lw=0.8, label="unit circle")
        ax[0, 0].set(xlabel="Re z", ylabel="Im z")
    else:
        a, b = region.a, region.b  # type: ignore[attr-defined]
        im = np.linspace(-3, 3, 200)
        ax[0, 0].plot(-a - b * im**2 / 2, im, "k", lw=0.8, label=f"P({a:g}, {b:g})")
        disk = region.proof_disk()  # type: ignore[attr-defined]
        c = float(np.real(disk.center))
        ax[0, 0].plot(c + disk.radius * np.cos(th), disk.radius * np.sin(th), "k:", lw=0.8,
                      label="disk of proof (28)")
        ax[0, 0].set(xlabel="Re s [1/s]", ylabel="Im s [1/s]")
    ax[0, 0].set_title("poles of A_f + M_f F N_f, F in [-1, 1]")
    ax[0, 1].axhline(gamma, color="k", lw=0.8, label=f"gamma = {gamma:g}")
    ax[0, 1].set(title="||H||_inf from w to L e over F", xlabel="F (dimensionless)",
                 ylabel="||H||_inf (dimensionless)", yscale="log")
    for j, v in enumerate(sigma2):
        ax[1, 0].axhline(v, color="k", ls="--", lw=0.8,
                         label=f"sigma_i^2 = {[float(x) for x in sigma2]}" if j == 0 else None)
    ax[1, 0].set(title="steady-state error variances (lines: Lyapunov; dots: Monte Carlo)",
                 xlabel="F (dimensionless)", ylabel="error variance (dimensionless)",
                 yscale="log")
    t, e = sample["t"], sample["x"] - sample["xhat"]
    sd = np.sqrt(np.diag(sample["P"]))
    for j in range(e.shape[1]):
        ax[1, 1].plot(t, e[:, j], lw=0.6, label=f"e{j + 1}")
        ax[1, 1].axhline(2 * sd[j], color=f"C{j}", ls=":", lw=0.8,
                         label=f"e{j + 1}: +-2 sigma (steady state)")
        ax[1, 1].axhline(-2 * sd[j], color=f"C{j}", ls=":", lw=0.8)
    ax[1, 1].set(title=f"estimation error, one {ENV_ID} episode: {sample['filter']}, "
                       f"F = {sample['F']:g}",
                 xlabel="k [samples]" if discrete else "t [s]",
                 ylabel="e = x - xhat, dimensionless\n(the paper's: truth - estimate)")
    if extra is not None:
        extra(ax)
    for a_ in ax.ravel():
        a_.set_title(textwrap.fill(a_.get_title(), 60), fontsize=10)
        legend_below(a_, 2, 0.14)
    finish_figure(fig, grid, result["claims"],
                  [*title[:-1], f"{title[-1]}; design search: {found}"], path, wrap=140)
