"""Reproduction of Zhang, Deng & Zhang (2018), Example 5.1: the nonlinear system (49) with the
filter (50) (see docs/references.md).

``testbed reproduce zhang-nonlinear-discrete``. The paper states neither ``x0`` nor ``gamma``
(:class:`testbed.reproductions.zhang_lmi_hinf.scenario.NonlinearDiscreteScenario`: ``x0 = [1, 1]``,
``gamma = 2``; both are in the output).

- **Monte Carlo** (1000 runs, as in the paper): one batch of
  :func:`testbed.experiment.numpy_plant.rollout` with the library's filter (50),
  ``v_k = 2 * 0.9999^k``, ``w_k ~ N(0, 1)``, ``xhat_0 = 0``; the inequality of Figure 3 at
  every ``k`` (:func:`~testbed.reproductions.zhang_lmi_hinf.plant.cumulative_sums`) and the
  proof's bound for ``eta_0 != 0``, ``gamma^2 sum v^2 + V(eta_0)``.
- **Corollary 3**: the sufficient conditions (35)-(36) with ``Q1 = Q2 = I`` on a grid of
  ``(x, xhat)``, corrected and as printed, and the curvature of (36) at the origin.
- **Corollary 2**: the HJI (27) itself on the grid times ``v in [-10, 10]`` and on a wider
  state box (a grid samples (27) and certifies nothing outside it), and whether (26) can
  hold (:func:`~testbed.reproductions.zhang_lmi_hinf.plant.output_lower_bound_check`).
- One run with the filter (50) in the loop (:func:`run_in_loop`) for the ``.rrd`` and
  Figures 1-2.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from testbed.experiment.numpy_plant import rollout
from testbed.experiment.trajectory import Trajectory
from testbed.outputs.viz import Run
from testbed.reproductions.outputs import (
    Claim,
    Paper,
    claims_figure,
    claims_json,
    finish_figure,
    legend_below,
    write_outputs,
)
from testbed.reproductions.zhang_lmi_hinf import plant
from testbed.reproductions.zhang_lmi_hinf.scenario import NonlinearDiscreteScenario

NAME = "zhang-nonlinear-discrete"
PAPER = Paper("Zhang, Deng & Zhang", "2018", "Example 5.1",
              "H-infinity filter for a nonlinear discrete system")
#: The HJI (27) must hold for every v: it is sampled on [-HJI_V_MAX, HJI_V_MAX] (the paper's
#: v_k lie in (0, 2]), on the scenario's state box and on a wider one.
HJI_V_MAX = 10.0
HJI_V_POINTS = 41
HJI_WIDE_HALFWIDTH = 10.0


def run_in_loop(x0: np.ndarray, steps: int, seed: int) -> dict[str, np.ndarray]:
    """One run of (49) with the filter (50) in the loop, its noise ``w_k`` drawn from
    ``default_rng(seed)`` step by step (as ``testbed/NonlinearDiscrete-v0`` after
    ``reset(seed=seed)``).

    Returns
    -------
    dict
        ``t`` (steps + 1,), ``x``, ``xhat``, ``y`` (steps + 1, 2; ``y_0 .. y_steps``), ``v``
        (steps + 1,), ``z_err`` (steps + 1,).
    """
    system = plant.NonlinearDiscretePlant()
    run = rollout(system, np.asarray(x0, dtype=float), steps,
                  noise=np.random.default_rng(seed), estimators={"(50)": plant.printed_filter()})
    x, n = run.x, len(run.t_s)
    y = np.concatenate([system.observe(x[0], 0)[None], run.y])
    return {"t": run.t_s, "x": x, "xhat": run.estimates["(50)"], "y": y,
            "v": np.array([system.schedule(max(i - 1, 0)) for i in range(n)]),
            "z_err": plant.output(x) - plant.output(run.estimates["(50)"])}


def reproduce(horizon_s: float | None = None, seed: int = 0, json_path: str | Path | None = None,
              plot_path: str | Path | None = None, rrd_path: str | Path | None = None,
              x0: np.ndarray | None = None, gamma: float | None = None,
              runs: int | None = None) -> dict[str, Any]:
    """Run Example 5.1 and write the requested outputs.

    Parameters
    ----------
    horizon_s : float, optional
        Number of steps (the system has no time unit: one step = one time unit; default 200).
    seed : int
        Seed of the noise ``w`` (``default_rng(seed)``; the in-the-loop run uses ``seed``).
    json_path, plot_path, rrd_path : path, optional
    x0 : array_like, shape (2,), optional
        Initial state (default ``[1, 1]``).
    gamma : float, optional
        Attenuation level (default 2).
    runs : int, optional
        Monte-Carlo runs (default 1000).

    Returns
    -------
    dict
        ``x0``, ``gamma``, ``runs``, ``sum_E_z2``, ``gamma2_sum_v2``, ``inequality_holds``,
        ``smallest_gamma_mc``, ``corollary3_max_violation`` and diagnostics.
    """
    s = NonlinearDiscreteScenario()
    x0 = s.x0 if x0 is None else np.asarray(x0, dtype=float)
    if x0.shape != (2,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"x0 must be a finite array of shape (2,), got {x0!r}")
    gamma = s.gamma if gamma is None else float(gamma)
    if not (np.isfinite(gamma) and gamma > 0):
        raise ValueError(f"gamma must be positive, got {gamma}")
    runs = s.runs if runs is None else int(runs)
    if runs < 2:
        raise ValueError(f"runs must be >= 2, got {runs}")
    steps = s.steps if horizon_s is None else int(round(float(horizon_s)))
    if steps < 1:
        raise ValueError(f"horizon_s must be at least 1 step, got {horizon_s}")
    start = time.perf_counter()

    v = np.asarray(plant.paper_disturbance(np.arange(steps)), dtype=float)
    w = np.random.default_rng(seed).standard_normal((runs, steps))
    mc = rollout(plant.NonlinearDiscretePlant(v=v), np.tile(x0, (runs, 1)), steps,
                 noise=lambda k: w[:, k],
                 estimators={"(50)": plant.printed_filter(np.zeros((runs, 2)))})
    if mc.escape is not None:
        raise mc.escape
    x, xh = mc.x, mc.estimates["(50)"]
    z_err = plant.output(x[:, :steps]) - plant.output(xh[:, :steps])
    sums = plant.cumulative_sums(z_err, v, gamma)
    sum_z, sum_v = sums["curve_z"], np.cumsum(v**2)
    bound = sums["gamma2_sum_v2"] + float(x0 @ x0)  # V(eta_0) = |x0|^2 + |xhat0|^2, xhat0 = 0
    cor = plant.quadratic_conditions_check(gamma, s.grid_halfwidth, s.grid_points)
    cor_printed = plant.quadratic_conditions_check(gamma, s.grid_halfwidth, s.grid_points,
                                                   printed=True)
    v_test = np.linspace(-HJI_V_MAX, HJI_V_MAX, HJI_V_POINTS)
    hji = plant.hji_check(gamma, s.grid_halfwidth, v_values=v_test)
    hji_wide = plant.hji_check(gamma, HJI_WIDE_HALFWIDTH, v_values=v_test)
    result: dict[str, Any] = {
        "scenario": NAME,
        "x0": x0.tolist(),
        "xhat0": [0.0, 0.0],
        "gamma": gamma,
        "runs": runs,
        "steps": steps,
        "seed": seed,
        "defaults_note": "the paper gives neither x0 nor gamma; defaults x0 = [1, 1], "
                         "gamma = 2 (just above the 1.84 that (35) needs on the grid)",
        **{key: sums[key] for key in ("sum_E_z2", "sum_E_z2_stderr", "gamma2_sum_v2",
                                      "inequality_holds")},
        "smallest_gamma_mc": sums["gamma_needed"],
        "smallest_gamma_mc_step": int(np.argmax(sum_z / sum_v)),
        "smallest_gamma_mc_after_k0": float(np.sqrt(((sum_z - sum_z[0]) / sum_v)[1:].max()))
        if steps > 1 else 0.0,
        "bound_13": bound,
        "bound_13_holds": bool(sum_z[-1] <= bound),
        "corollary3_max_violation": cor["max_violation"],
        "corollary3": cor,
        "corollary3_printed": cor_printed,
        "hji_27": hji,
        "hji_27_wide": hji_wide,
        "condition_26": plant.output_lower_bound_check(),
        "max_abs_state": float(np.abs(x).max()),
    }
    result["claims"] = claims_json(claims(result))
    loop = run_in_loop(x0, steps, seed) if (plot_path or rrd_path) else None
    result["wall_s"] = time.perf_counter() - start
    write_outputs(result, json_path=json_path, plot_path=plot_path, rrd_path=rrd_path,
                  units={"state": "1 (dimensionless system)", "time": "steps"},
                  plot=lambda path: _plot(result, sum_z, sums["curve_v"], loop, x, xh, gamma,
                                          s, path),
                  runs=lambda: _runs(loop, result), degrees=False)
    return result


def _runs(run: dict[str, np.ndarray], result: dict[str, Any]) -> list[Run]:
    """The run of the ``.rrd``: one episode with the filter (50) in the loop; the system is
    dimensionless (no units), ``t_s`` counts steps."""
    traj = Trajectory(t_s=run["t"], state=run["x"], state_names=list(plant.STATE_NAMES),
                      measurement=run["y"], measurement_names=list(plant.MEASUREMENT_NAMES),
                      action=run["v"][:, None], action_names=["v"], estimate=run["xhat"],
                      meta={"scenario": NAME, "filter": "(50)"})
    return [Run(traj, "filter_in_loop", (
        f"# System (49) with the filter (50) in the loop (seed {result['seed']})\n\n"
        "One run of (49) with the filter (50) in the loop (its noise seeded as "
        "testbed/NonlinearDiscrete-v0's): "
        f"x0 = {result['x0']}, xhat_0 = 0, disturbance v_k = 2 * 0.9999^k (logged as the "
        "action), noise w_k ~ N(0, 1). What Figs. 1-2 show; Fig. 3 averages "
        f"{result['runs']} such runs (simulated separately, vectorized). Time counts steps; "
        "the system is dimensionless (no units)."))]


def _plot(result: dict, sum_z: np.ndarray, gv: np.ndarray, loop: dict, x: np.ndarray,
          xh: np.ndarray, gamma: float, s: NonlinearDiscreteScenario, path: str | Path) -> None:
    fig, grid = claims_figure(result["claims"], 12, 9, [4.0, 4.0], cols=2, wrap=140)
    k_label = "k [steps]"

    ax = fig.add_subplot(grid[0, 0])
    ax.plot(loop["t"], plant.output(loop["x"]), label="z_k")
    ax.plot(loop["t"], plant.output(loop["xhat"]), "--", label="zhat_k (filter (50))")
    ax.set(title="Fig. 1: z_k and zhat_k (one run, filter in the loop)", xlabel=k_label,
           ylabel="z_k, zhat_k (dimensionless)")
    legend_below(ax)
    ax = fig.add_subplot(grid[0, 1])
    ax.plot(loop["t"], loop["z_err"], label="ztilde_k, in-the-loop run")
    ax.set(title="Fig. 2: estimation error ztilde_k", xlabel=k_label,
           ylabel="ztilde_k = z_k - zhat_k\n(the paper's: truth - estimate)")
    legend_below(ax)
    ax = fig.add_subplot(grid[1, 0])
    k = np.arange(len(sum_z))
    ax.plot(k, sum_z, label=f"sum E ztilde^2 ({result['runs']} runs)")
    ax.plot(k, gv, "--", label=f"gamma^2 sum v^2 (gamma = {gamma:g})")
    ax.set_yscale("log")
    ax.set(title=f"Fig. 3: cumulative sums, x0 = {result['x0']}", xlabel=k_label,
           ylabel="cumulative sum (dimensionless)")
    legend_below(ax)
    ax = fig.add_subplot(grid[1, 1])
    axis = np.linspace(-s.grid_halfwidth, s.grid_halfwidth, 161)
    X2, XH2 = np.meshgrid(axis, axis, indexing="xy")
    zero = np.zeros_like(X2)
    _, c36 = plant.quadratic_conditions_values(np.stack([zero, X2], axis=-1),
                                     np.stack([zero, XH2], axis=-1), gamma)
    top = float(np.abs(c36).max())
    mesh = ax.pcolormesh(X2, XH2, c36, cmap="RdBu_r", vmin=-top, vmax=top, shading="auto")
    ax.contour(X2, XH2, c36, levels=[0.0], colors="k", linewidths=1.0)
    fig.colorbar(mesh, cax=ax.inset_axes((1.03, 0.0, 0.04, 1.0)),
                 label="(36) left-hand side (> 0: violated)")
    ax.set(title="Corollary 3 (36), Q1 = Q2 = I, slice x1 = xhat1 = 0 (black: 0 contour)",
           xlabel="x2 (dimensionless)", ylabel="xhat2 (dimensionless)")
    finish_figure(fig, grid, result["claims"], [
        f"{PAPER.authors} ({PAPER.year}), {PAPER.where}: filter (50) for (49); x0, gamma ours"],
        path, wrap=140)


def claims(result: dict[str, Any]) -> list[Claim]:
    """The paper's claims next to ours, verdicts computed from ``result``."""
    cor, pr = result["corollary3"], result["corollary3_printed"]
    hji, wide, c26 = result["hji_27"], result["hji_27_wide"], result["condition_26"]
    v0, v1 = hji["v_range"]
    return [
        Claim(f"Fig. 3: sum E ztilde^2 < gamma^2 sum v^2 at every k ({result['runs']} runs)",
              "holds (x0, gamma not stated)",
              f"{'holds' if result['inequality_holds'] else 'fails'}: "
              f"{result['sum_E_z2']:.4g} vs {result['gamma2_sum_v2']:.4g} at k = "
              f"{result['steps']} (gamma = {result['gamma']:g}, x0 = {result['x0']}); "
              f"smallest gamma that works {result['smallest_gamma_mc']:.3g}",
              Claim.judge(result["inequality_holds"]),
              "x0 and gamma are ours; the sums are dominated by k = 0 (smallest gamma "
              f"{result['smallest_gamma_mc_after_k0']:.3g} without it)"),
        Claim("Corollary 3: (35)-(36) hold with Q1 = Q2 = I", "'easily' hold",
              f"max violation {cor['max_violation']:.3g} on [-{cor['halfwidth']:g}, "
              f"{cor['halfwidth']:g}]^4 ((36) violated on {cor['fraction_violated_36']:.1%} "
              f"of the grid); as printed {pr['max_violation']:.3g}",
              Claim.judge(cor["max_violation"] <= 0),
              f"(36) is violated arbitrarily close to 0 (Hessian eigenvalue "
              f"{cor['hessian_36_max_eig_at_0']:.3g} > 0)"),
        Claim("(50) is an H-infinity filter for (49) (Corollary 2: HJI (27) and (26))", "yes",
              f"HJI (27), v in [{v0:g}, {v1:g}]: max {hji['max_violation']:.3g} on "
              f"[-{hji['halfwidth']:g}, {hji['halfwidth']:g}]^4, {wide['max_violation']:.3g} "
              f"on [-{wide['halfwidth']:g}, {wide['halfwidth']:g}]^4; (26) possible: "
              f"{'yes' if c26['possible'] else 'no'}",
              Claim.judge(bool(c26["possible"] and hji["max_violation"] <= 0
                               and wide["max_violation"] <= 0)),
              f"ztilde(eta, 0) = 0 on a {c26['null_space_dim']}-dimensional subspace, so no "
              "positive W satisfies (26); (27) is only sampled on grids"),
    ]


def why(result: dict[str, Any]) -> str:
    """What the claims do not say (``docs/reproductions.md``), from ``result``."""
    hji, wide = result["hji_27"], result["hji_27_wide"]
    return (
        "The paper states neither x0 nor gamma (ours are in the first claim). The Monte-Carlo "
        "inequality holds, but neither corollary "
        "certifies (50). Corollary 3: (36) is violated arbitrarily close to 0, and the printed "
        "(35)-(36) also miss the noise terms h2, f2 and have +xhat'Q2 xhat instead of "
        "-xhat'Q2 xhat. Corollary 2: the HJI (27) with V = |x|^2 + |xhat|^2 holds on "
        f"[-{hji['halfwidth']:g}, {hji['halfwidth']:g}]^4 (a grid check) but not on "
        f"[-{wide['halfwidth']:g}, {wide['halfwidth']:g}]^4, and its condition (26) cannot "
        "hold: ztilde(eta, 0) = 0.1 (x1 + x2 - xhat1 - xhat2) vanishes for eta != 0, so no "
        "positive W is below |ztilde|^2. The HJI alone does not imply (26).")
