"""Reproduction of the example of Liu, Deng & Wang (n.d.): discrete robust H2/H-infinity filtering
with variance constraints (OCR-damaged paper; our reading of the example, see
docs/references.md).

``testbed reproduce liu-variance-constrained-discrete``: what
:func:`~testbed.reproductions.variance_constrained.family.run_example` computes, with the
design of :func:`filters.variance_discrete.design_discrete` ((11) and the reconstructed
(12r)) at the printed parameters and our assumptions ``delta2 = delta1``, ``H = 0`` (then
``U = +-1`` give the same gain), the existence threshold of (11) in ``delta1``
(:func:`~filters.variance_discrete.delta1_threshold`), the search of
:func:`filters.variance_discrete.search_discrete_design`, the printed filter's steady-state
error covariances next to the printed ones, and the Monte Carlo (exact: the discrete loop
has no sampling error; the horizon is in samples, ``dt_s = 1``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from filters.variance_constrained import VarianceDesign
from filters.variance_discrete import (
    delta1_threshold,
    design_discrete,
    least_state_bound_discrete,
    search_discrete_design,
)
from testbed.reproductions.outputs import Claim, Paper, claims_json, write_outputs
from testbed.reproductions.variance_constrained.family import (
    ENV_ID,
    _fmt,
    episode_run,
    plot_figure,
    run_example,
)
from testbed.reproductions.variance_constrained.scenario import (
    VarianceConstrainedDiscreteScenario,
)

NAME = "liu-variance-constrained-discrete"
PAPER = Paper("Liu, Deng & Wang", "n.d.", "Section 4 (OCR damaged)",
              "Variance-constrained discrete filter")
#: Default samples per Monte-Carlo run and runs per F.
HORIZON = 400
N_RUNS = 2000
#: Relative difference below which our covariance of the printed filter counts as the printed
#: one (the printed numbers have 4 significant digits).
COVARIANCE_RTOL = 0.01


def reproduce(horizon_s: float | None = None, seed: int = 0,
              json_path: str | Path | None = None, plot_path: str | Path | None = None,
              rrd_path: str | Path | None = None, n_runs: int = N_RUNS,
              search_starts: int | None = None,
              search_evaluations: int | None = None) -> dict[str, Any]:
    """Run the example and write the requested outputs.

    Parameters
    ----------
    horizon_s : float, optional
        Samples per Monte-Carlo run (``dt_s = 1``; default 400; burn-in a quarter, at most
        100).
    json_path, plot_path, rrd_path : path, optional
    seed, n_runs, search_starts, search_evaluations : int
        As :func:`~testbed.reproductions.variance_constrained.family.run_example` (its
        default search takes about 10 s).

    Returns
    -------
    dict
        :func:`~testbed.reproductions.variance_constrained.family.run_example`'s keys and
        ``parameters``, ``paper``, ``paper_covariance``, ``covariance_comparison``,
        ``claims``.
    """
    s = VarianceConstrainedDiscreteScenario()
    plant = s.plant
    n_steps = HORIZON if horizon_s is None else int(round(float(horizon_s)))
    if n_steps < 1:
        raise ValueError(f"horizon_s must be >= 1 sample, got {horizon_s}")

    def design() -> tuple[dict[str, VarianceDesign], dict[str, Any]]:
        _, iters, how = least_state_bound_discrete(plant, s.parameters())
        return ({f"U={U:g}": design_discrete(plant, s.parameters(U), sigma2=s.sigma2)
                 for U in (1.0, -1.0)},
                {"equation11_existence": how, "equation11_iterations": iters,
                 "delta1_threshold_at_printed_eps": delta1_threshold(plant, s.parameters()),
                 "assumed": {"delta2": s.delta2, "H": s.H.tolist()}})

    result, sample = run_example(
        NAME, s, design, lambda n, m: search_discrete_design(
            plant, s.parameters(), s.sigma2, n_starts=n, seed=0, max_evaluations=m),
        dt_s=1.0, n_steps=n_steps, burn_in=min(100, n_steps // 4), n_runs=n_runs, seed=seed,
        search_starts=search_starts, search_evaluations=search_evaluations)
    result.update({
        "parameters": {"gamma": s.gamma, "sigma2": s.sigma2.tolist(), "eps": s.eps,
                       "delta1": s.delta1, "delta2 (assumed)": s.delta2,
                       "H (assumed)": s.H.tolist()},
        "paper": {"G": s.paper_G.tolist(), "K": s.paper_K.tolist(), "gamma": s.gamma,
                  "eps": s.eps, "delta1": s.delta1, "bound_matrix": s.paper_bound.tolist()},
        "paper_covariance": {k: v.tolist() for k, v in s.paper_covariance.items()},
        "covariance_comparison": {}})
    for key, printed in s.paper_covariance.items():
        ours = np.array(result["published"][0]["covariance"][key])
        result["covariance_comparison"][key] = {
            "ours": ours.tolist(), "paper": printed.tolist(),
            "relative_difference": (ours / printed - 1.0).tolist()}
    result["claims"] = claims_json(claims(result))
    write_outputs(result, json_path=json_path, plot_path=plot_path, rrd_path=rrd_path,
                  plot=lambda path: _plot(result, s, sample, path), degrees=False,
                  units={"state": "1 (dimensionless system)", "time": "samples"},
                  runs=lambda: [episode_run(sample, NAME, "t counts samples (dt_s = 1).")])
    return result


def _plot(result: dict[str, Any], s: VarianceConstrainedDiscreteScenario,
          sample: dict[str, Any], path: str | Path) -> None:
    def paper_marks(ax: Any) -> None:
        for key, P in s.paper_covariance.items():
            ax[1, 0].plot([float(key)] * 2, np.diag(P), "rx", ms=7,
                          label="paper's P (diagonal)" if key == "1" else None)

    solved = "yes" if result["design"]["U=1"]["solved"] else "no"
    plot_figure(result, s, sample, [
        f"{PAPER.authors} ({PAPER.year}): the printed filter and the searched design, checked "
        "for all |F| <= 1", f"Printed eps, delta1: (11) solvable: {solved}"], path, paper_marks)


def claims(result: dict[str, Any]) -> list[Claim]:
    """The paper's claims next to ours, verdicts computed from ``result``."""
    p, d = result["parameters"], result["design"]["U=1"]
    pub, summary = result["published"][0], result["design_search"]["summary"]
    thr = result["design_diagnostics"]["delta1_threshold_at_printed_eps"]
    rel = {k: max(abs(v) for r in c["relative_difference"] for v in r)
           for k, c in result["covariance_comparison"].items()}
    if d["solved"]:
        design_txt = f"solved, diag P2 = {_fmt(np.diag(np.array(d['Q2'])))}"
    elif d["residual_12r"] is None:
        design_txt = (f"(11) has no positive definite solution (smallest residual "
                      f"{d['residual_11']:.2e})"
                      + (f"; at eps = {p['eps']:g} it has one only for delta1 < {thr:.4f}"
                         if thr is not None else ""))
    else:
        design_txt = f"(11) solved, (12r) not (smallest residual {d['residual_12r']:.3g})"
    spec = f"var <= {p['sigma2']}, ||H||inf <= {p['gamma']:g}, stable for every |F| <= 1"
    return [
        Claim("printed filter meets the requirements", f"yes: {spec}",
              f"worst ||H||inf {pub['hinf_worst']:.3g}, worst variances "
              f"{_fmt(pub['variance_worst'])}, stable: {pub['poles_in_region']}",
              Claim.judge(all(v is not False for v in pub["meets"].values()))),
        Claim("printed covariances for F = 1, 0",
              "printed P, " + "; ".join(f"F = {k}: diagonal {_fmt(np.diag(np.array(v)))}"
                                        for k, v in result["paper_covariance"].items()),
              ", ".join(f"F = {k}: up to {v:.1%} off" for k, v in rel.items()),
              Claim.judge(max(rel.values()) <= COVARIANCE_RTOL),
              f"tolerance {COVARIANCE_RTOL:.0%}; Monte Carlo confirms ours, so the gap is in "
              "the reading of the OCR-damaged example or in the paper's numbers"),
        Claim("design solvable at the printed eps, delta1",
              f"yes (eps = {p['eps']:g}, delta1 = {p['delta1']:g}, gamma = {p['gamma']:g})",
              design_txt, Claim.judge(bool(d["solved"])),
              "OCR-damaged: (12) reconstructed, delta2 = delta1 and H = 0 assumed"),
        Claim("a design meeting the specification exists", f"yes: {spec}",
              "no verified design found" if summary is None else
              f"yes, with other eps, delta and H (design search): worst ||H||inf "
              f"{summary['hinf_worst']:.3g}, worst variances "
              f"{_fmt(summary['variance_worst'])}, spectral radius margin "
              f"{summary['pole_margin_worst']:.3g}", Claim.judge(summary is not None)),
    ]


def why(result: dict[str, Any]) -> str:
    """What the claims do not say (``docs/reproductions.md``), from ``result``."""
    p, d = result["parameters"], result["design"]["U=1"]
    thr = result["design_diagnostics"]["delta1_threshold_at_printed_eps"]
    worst_z = max(abs(v) for m in result["monte_carlo"] for v in m["z_vs_sampled"])
    text = ("The text is OCR-damaged: the second Riccati equation and the gain are "
            "reconstructed (completion of squares of the cited construction, as in Wang & Fang "
            "(2006)); delta2 and H are not legible (delta2 = delta1 and H = 0 assumed). ")
    if thr is not None and not d["solved"]:
        text += (f"The threshold on delta1 at eps = {p['eps']:g} (third claim) comes from a "
                 f"monotone iteration; it lies {p['delta1'] - thr:.4f} below the printed "
                 f"{p['delta1']:g}, so a misread digit could explain it. ")
    return text + (f"Monte Carlo in {ENV_ID} confirms our Lyapunov covariances within "
                   f"{worst_z:.1f} standard errors, so the gap to the printed ones is in the "
                   "reading of the example or in the paper's numbers.")
