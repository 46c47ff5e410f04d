"""Reproduction of the example of Basin, Shi & Calderon-Alvarez (n.d.): central H-infinity
filter for a cubic polynomial system (see docs/references.md).

``testbed reproduce basin-polynomial-hinf``. The plant is the paper's system (22)-(24) with the
printed L2 disturbance (:class:`~testbed.reproductions.basin_polynomial.scenario.
PolynomialHinfScenario`), integrated with RK4 on a ``dt_s`` grid (default 0.1 ms, far below
the 0.126 s period of ``sin 50t``); the filters get the interval averages of ``y`` and step
on the same grid, all in one :func:`~testbed.experiment.numpy_plant.rollout`
(:func:`_simulate`). Filters (all from ``x_f(0) = 0``, ``P(0) = R^-1 = I``, ``gamma = 1.05``):

- **poly**: :class:`~filters.hinf_polynomial.PolynomialHInfFilter`, Theorem 1, with the ``L``
  for which (13) gives the printed (26) (``L = [1 0]``; a test proves the implementation
  equals (25)-(26));
- **linearized**: :class:`~filters.hinf_polynomial.LinearizedHInfFilter`, (27)-(28), (27) as
  printed (``state_equation="jacobian"``: ``0.2 m^2 + (0.3 + 0.3 sin 50t) m^3``); the
  variant ``"system"`` uses the system's ``0.1 m^2 + (0.1 + 0.1 sin 50t) m^3``;
- **L_identity**: both with the example's own output ``z = x`` (``L = I``) in the Riccati
  equation, i.e. Theorem 1 as stated.

``T(t) = ||z - z_f||_2 / (||w||_2^2 + x0^T R x0)^(1/2)`` over ``[0, t]`` with ``z = x``
(:func:`filters.analysis.noise_output_ratio`); the paper's ``||T_zw||^2`` is ``T^2``. A filter
whose ``x_f`` or ``P`` escapes stops existing at the last completed step (:func:`_filter_run`:
where its escape test fired and where its ODE becomes singular, the escape time to quote);
``T`` is reported where both filters of a pair exist (:func:`_pair`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from filters import positive_time
from filters.analysis import noise_output_ratio
from filters.hinf_polynomial import LinearizedHInfFilter, PolynomialHInfFilter
from testbed.experiment.numpy_plant import Rollout, rollout
from testbed.experiment.trajectory import Trajectory
from testbed.outputs.viz import Run
from testbed.reproductions.basin_polynomial.plant import PolynomialPlant
from testbed.reproductions.basin_polynomial.scenario import PolynomialHinfScenario, paper_model
from testbed.reproductions.outputs import (
    Claim,
    Paper,
    claims_figure,
    claims_json,
    finish_figure,
    legend_below,
    write_outputs,
)

NAME = "basin-polynomial-hinf"
PAPER = Paper("Basin, Shi & Calderon-Alvarez", "n.d.", "Section IV",
              "Polynomial H-infinity filter on a cubic system")
#: ``T_before_end`` is reported this long before the end of the common interval, s: near
#: an escape ``T`` rises steeply, so its value at the cut depends on where the escape test
#: stops the filter.
_BEFORE_END_S = 0.01


@dataclass
class _FilterRun:
    """One filter on the plant's data: rows ``0..last`` exist."""

    est: np.ndarray  # (last + 1, n)
    P: np.ndarray  # (last + 1, n, n)
    T: np.ndarray  # (last + 1,)
    escaped: dict[str, Any] | None

    @property
    def last(self) -> int:
        return len(self.T) - 1


def _filter_run(run: Rollout, name: str, filt: PolynomialHInfFilter | LinearizedHInfFilter,
                w: np.ndarray, s: PolynomialHinfScenario) -> _FilterRun:
    """One filter of the rollout, its rows ``0..last`` and ``T`` while it exists.

    On an escape, ``escaped`` is ``{"quantity", "time", "singular_time", "singular"}``:
    ``time`` is where the escape test stopped the RK4 run (end of the failing substep),
    ``singular_time`` where the solution of the filter's ODE itself becomes singular
    (:func:`singular_time`, from the filter's state before the failing step).
    """
    est, P = run.estimates[name], run.covariances[name]
    last = len(est) - 1
    escaped = None
    if name in run.failures:
        k, exc = run.failures[name]
        sing = singular_time(filt, run.y[k:], run.t_s[k:])
        escaped = {"quantity": exc.quantity, "time": exc.time,  # type: ignore[attr-defined]
                   "singular_time": None if sing is None else sing["time"], "singular": sing}
    T = noise_output_ratio(run.t_s[:last + 1], run.x[:last + 1] - est, w[:last + 1], s.x0, s.R)
    return _FilterRun(est=est, P=P, T=T, escaped=escaped)


def singular_time(filt: PolynomialHInfFilter | LinearizedHInfFilter, y: np.ndarray,
                  t: np.ndarray, *, bound: float = 1e8) -> dict[str, Any] | None:
    """Where the filter's ODE, continued from its current state, becomes singular.

    The filter's right-hand side (:meth:`~filters.hinf_polynomial.PolynomialHInfFilter.
    derivatives`, the same ODE its RK4 steps integrate, with ``y[j]`` held over ``[t[j],
    t[j + 1]]``) is integrated by ``scipy.integrate.solve_ivp`` (DOP853, rtol = atol =
    1e-12) from ``t[0]`` until an entry of ``x_f`` or ``P`` reaches ``bound`` in magnitude.
    Near a finite escape that entry ``q`` grows like ``1 / (c (t* - t))``, so ``1 / q`` is
    extrapolated linearly to zero from there: ``t* = t_e + q / q'`` (error ``O(1 / bound)``).

    Parameters
    ----------
    filt : PolynomialHInfFilter or LinearizedHInfFilter
        In the state at ``t[0]`` (e.g. the last one before its escape test fired).
    y : numpy.ndarray, shape (K, m)
        The held observations from ``t[0]`` on.
    t : numpy.ndarray, shape (K + 1,) or longer
        Grid times, s.
    bound : float
        Magnitude at which the extrapolation starts.

    Returns
    -------
    dict or None
        ``time`` (``t*``, s), ``entry`` (e.g. ``"P22"``, 1-based), ``event_time`` (where the
        entry reached ``bound``); ``None`` if the solution stays below ``bound`` over the
        data.
    """
    from scipy.integrate import solve_ivp

    n = filt.x.shape[-1]
    names = [f"x{i + 1}" for i in range(n)] + [f"P{i + 1}{j + 1}" for i in range(n)
                                                for j in range(n)]

    def rhs(tau: float, z: np.ndarray, yj: np.ndarray) -> np.ndarray:
        dx, dP = filt.derivatives(z[:n], z[n:].reshape(n, n), yj, tau)
        return np.concatenate([dx, dP.ravel()])

    def reached(tau: float, z: np.ndarray, yj: np.ndarray) -> float:
        return bound - float(np.abs(z).max())

    reached.terminal = True  # type: ignore[attr-defined]
    z = np.concatenate([filt.x, filt.P.ravel()])
    for j in range(len(y)):
        sol = solve_ivp(rhs, (float(t[j]), float(t[j + 1])), z, method="DOP853", rtol=1e-12,
                        atol=1e-12, events=reached, args=(y[j],))
        if sol.status == 1:
            t_e, z_e = float(sol.t_events[0][0]), sol.y_events[0][0]
            i = int(np.argmax(np.abs(z_e)))
            dz = rhs(t_e, z_e, y[j])
            return {"time": t_e + float(z_e[i] / dz[i]), "entry": names[i], "event_time": t_e,
                    "bound": bound}
        z = sol.y[:, -1]
    return None


def _pair(t: np.ndarray, poly: _FilterRun, lin: _FilterRun,
          s: PolynomialHinfScenario) -> dict[str, Any]:
    """The summary of one (poly, linearized) pair: ``T`` where both exist, escapes, curve."""
    k = min(poly.last, lin.last)
    dt = float(t[1] - t[0])

    def at(run: _FilterRun, tau: float) -> float | None:
        i = int(round(tau / dt))
        return float(run.T[i]) if 0 <= i <= run.last else None

    def curve(run: _FilterRun) -> list[float | None]:
        return [at(run, tau) for tau in s.curve_times]

    def crossing(run: _FilterRun) -> float | None:
        above = np.nonzero(run.T > s.gamma)[0]
        return float(t[above[0]]) if above.size else None

    back = int(round(_BEFORE_END_S / dt))
    return {
        "horizon": float(t[k]),
        "T_poly": float(poly.T[k]),
        "T_linearized": float(lin.T[k]),
        "escaped": {"poly": poly.escaped, "linearized": lin.escaped},
        "exists_until": {"poly": float(t[poly.last]), "linearized": float(t[lin.last])},
        "T_end": {"poly": float(poly.T[-1]), "linearized": float(lin.T[-1])},
        "T_before_end": {"t": float(t[max(k - back, 0)]), "poly": float(poly.T[max(k - back, 0)]),
                         "linearized": float(lin.T[max(k - back, 0)])},
        "T_at_paper_horizon": {"poly": at(poly, s.horizon_s),
                               "linearized": at(lin, s.horizon_s)},
        "exceeds_gamma_at": {"poly": crossing(poly), "linearized": crossing(lin)},
        "curve": {"t": list(s.curve_times), "poly": curve(poly), "linearized": curve(lin)},
    }


def _simulate(s: PolynomialHinfScenario, horizon_s: float, dt_s: float) -> dict[str, Any]:
    """The plant (22)-(24) (the plant of ``testbed/PolynomialCubic-v0`` with one RK4 substep
    per ``dt_s``, input 0) and every filter on its interval averages ``y``, one rollout."""
    n_steps = int(round(horizon_s / dt_s))
    plant = PolynomialPlant(paper_model(E=np.array([[0.0], [1.0]])), dt_s=dt_s, w=s.w)
    printed = paper_model(L=s.printed_gain_L)
    filters = {
        "poly": PolynomialHInfFilter(printed, s.gamma, s.R, dt_s, s.xf0),
        "linearized": LinearizedHInfFilter(printed, s.gamma, s.R, dt_s, s.xf0,
                                           state_equation="jacobian"),
        "linearized_system": LinearizedHInfFilter(printed, s.gamma, s.R, dt_s, s.xf0,
                                                  state_equation="system"),
        "poly_L_identity": PolynomialHInfFilter(s.model, s.gamma, s.R, dt_s, s.xf0),
        "linearized_L_identity": LinearizedHInfFilter(s.model, s.gamma, s.R, dt_s, s.xf0,
                                                      state_equation="jacobian"),
    }
    run = rollout(plant, s.x0, n_steps, estimators=filters)
    w = np.array([s.w(ti) for ti in run.t_s])
    esc = run.escape
    return {"t": run.t_s, "x": run.x, "y": run.y, "w": w,
            "runs": {name: _filter_run(run, name, f, w, s) for name, f in filters.items()},
            "plant_escape": None if esc is None else {"quantity": esc.quantity,
                                                      "time": esc.time}}


def reproduce(horizon_s: float | None = None, seed: int = 0,
              json_path: str | Path | None = None, plot_path: str | Path | None = None,
              rrd_path: str | Path | None = None, dt_s: float = 1e-4) -> dict[str, Any]:
    """Run the example and write the requested outputs.

    Parameters
    ----------
    horizon_s : float, optional
        Default: the paper's 1.4 s.
    seed : int
        Recorded only: the scenario is deterministic (L2 disturbances, no noise).
    json_path, plot_path, rrd_path : path, optional
    dt_s : float
        Integration step of the plant and sample period of the filters, s.

    Returns
    -------
    dict
        ``T_poly``, ``T_linearized``, ``horizon`` (end of the interval where both exist),
        ``escaped`` (``poly``, ``linearized``, ``plant``: None or ``{"quantity", "time"}``),
        ``curve``, ``paper``, ``linearized_variant`` (``printed``, ``system``: the same keys
        for (27) as printed and with the system's coefficients), ``L_identity`` (the same
        keys for both filters with ``L = I``), ``exists_until``, ``T_end``,
        ``T_before_end`` (10 ms before the end of the common interval),
        ``T_at_paper_horizon``, ``exceeds_gamma_at`` and timings.
    """
    s = PolynomialHinfScenario()
    horizon_s = s.horizon_s if horizon_s is None else positive_time("horizon_s", horizon_s)
    if not (np.isfinite(dt_s) and 0 < dt_s <= horizon_s):
        raise ValueError(f"dt_s must be positive and at most the horizon, got {dt_s}")
    start = time.perf_counter()
    sim = _simulate(s, horizon_s, dt_s)
    t, r = sim["t"], sim["runs"]
    main = _pair(t, r["poly"], r["linearized"], s)
    system = _pair(t, r["poly"], r["linearized_system"], s)
    identity = _pair(t, r["poly_L_identity"], r["linearized_L_identity"], s)
    result: dict[str, Any] = {
        "scenario": NAME,
        "requested_horizon": float(t[0] + round(horizon_s / dt_s) * dt_s),
        "dt_s": dt_s,
        "seed": seed,
        "gamma": s.gamma,
        "x0": s.x0,
        "R": s.R,
        **main,
        "paper": {"T_poly": s.paper_T_poly, "T_linearized": s.paper_T_linearized,
                  "horizon": s.horizon_s},
        "linearized_variant": {"main": "printed", "printed": main, "system": system},
        "L_identity": identity,
        "wall_s": 0.0,
    }
    result["escaped"] = {**main["escaped"], "plant": sim["plant_escape"]}
    result["claims"] = claims_json(claims(result))
    result["wall_s"] = time.perf_counter() - start
    write_outputs(result, json_path=json_path, plot_path=plot_path, rrd_path=rrd_path,
                  plot=lambda path: _plot(sim, result, s, path),
                  units={"state": "1 (dimensionless system)", "time": "s",
                         "T": "1 (noise-output ratio)"},
                  runs=lambda: _runs(sim, result), degrees=False)
    return result


#: The runs of the ``.rrd``: key of ``sim["runs"]`` -> (entity prefix, what it is).
RRD_RUNS = {
    "poly": ("polynomial_filter", "Polynomial H-infinity filter (25)-(26) as printed "
             "(Theorem 1 with L = [1 0])"),
    "linearized": ("linearized_filter", "Linearized H-infinity filter (27)-(28) as printed "
                   "((27) is the Jacobian at the estimate, J(m) m)"),
}


def _runs(sim: dict[str, Any], result: dict[str, Any]) -> list[Run]:
    """One run per filter (:data:`RRD_RUNS`) on the same plant data, each until it escapes:
    truth, the filter's estimate and ``P`` and the measured ``y`` (interval average), every
    10th row. The system is dimensionless (no units)."""
    t, out = sim["t"], []
    y = np.concatenate([sim["y"][:1], sim["y"]])[:, 0]  # row j: average over [t_j-1, t_j]
    for key, (prefix, what) in RRD_RUNS.items():
        run = sim["runs"][key]
        rows = np.arange(0, run.last + 1, 10)
        traj = Trajectory(t_s=t[rows], state=sim["x"][rows], state_names=["x1", "x2"],
                          measurement=y[rows, None], measurement_names=["y"],
                          measured_state_index=[0], action=np.zeros((len(rows), 0)),
                          action_names=[], estimate=run.est[rows], covariance=run.P[rows],
                          meta={"scenario": NAME, "filter": what, "escaped": run.escaped})
        out.append(Run(traj, prefix, (
            f"# {what}\n\nThe plant (22)-(24) with the printed L2 disturbances w1 = "
            "1/(1+t)^2, w2 = 2/(2+t)^2 (no noise, deterministic), x(0) = "
            f"{list(result['x0'])}; the filter from x_f(0) = 0, P(0) = I, gamma = "
            f"{result['gamma']}, on the interval averages of y. State: truth x1, x2 and the "
            f"filter's estimate with +-3 sqrt(P). Until t = {t[run.last]:.4f} s: "
            f"{_esc(run.escaped)}. Dimensionless system (no units).")))
    return out


def _plot(sim: dict[str, Any], result: dict[str, Any], s: PolynomialHinfScenario,
          path: str | Path) -> None:
    t, x, r = sim["t"], sim["x"], sim["runs"]
    fig, grid = claims_figure(result["claims"], 11, 9.5, [4.0, 4.6], wrap=120)
    top = fig.add_subplot(grid[0])
    bottom = fig.add_subplot(grid[1], sharex=top)
    styles = (("poly", "polynomial filter (25)-(26)", dict(color="C0", lw=2.5)),
              ("linearized", "linearized (27)-(28) as printed", dict(color="C3", lw=1.0)),
              ("linearized_system", "linearized, (27) with the system's f",
               dict(color="C1", lw=1.0, ls="--")),
              ("poly_L_identity", "polynomial filter, L = I", dict(color="C0", lw=1, ls=":")),
              ("linearized_L_identity", "linearized, L = I", dict(color="C3", lw=1, ls=":")))
    for key, label, style in styles:
        run = r[key]
        tt = t[:run.last + 1]
        err = np.linalg.norm(x[:run.last + 1] - run.est, axis=1)
        top.plot(tt, err, label=label, **style)
        bottom.plot(tt, run.T, label=label, **style)
        if run.escaped is not None:
            for ax in (top, bottom):
                ax.axvline(run.escaped["time"], color=style["color"], lw=0.6, ls="-.")
    bottom.axhline(s.gamma, color="k", lw=0.8, label=f"gamma = {s.gamma}")
    bottom.plot([s.horizon_s] * 2, [s.paper_T_poly, s.paper_T_linearized], "k*", ms=9,
                label=f"paper at t = {s.horizon_s}: {s.paper_T_poly}, {s.paper_T_linearized}")
    bottom.axvline(result["horizon"], color="grey", lw=0.8, ls="--",
                   label=f"both exist until t = {result['horizon']:.4f} s")
    top.set(title="Fig. 1 (above): output estimation error ||z - z_f||, z = x (dash-dot: "
                  "escape detected)", xlabel="t [s]", ylabel="||z - z_f|| (dimensionless)")
    top.set_yscale("log")
    bottom.set(title="Fig. 1 (below): noise-output ratio T(t) = ||z - z_f||_2 / (||w||_2^2 + "
                     "x0' R x0)^1/2", xlabel="t [s]", ylabel="T (dimensionless)")
    legend_below(bottom, 3, 0.16, title="both panels (dash-dot lines: escape detected)")
    finish_figure(fig, grid, result["claims"], [
        f"{PAPER.authors} ({PAPER.year}): central H-infinity filters, gamma = {s.gamma}"],
        path, wrap=120)


def _checks(result: dict[str, Any]) -> dict[str, Any]:
    """What the verdicts rest on: ``survives`` (both filters exist to the paper's horizon),
    ``close`` (both ``T`` within 5 % of the paper's), ``better`` (the polynomial filter below
    gamma and below the linearized one where both exist), ``both`` (the curve's points where
    both exist: ``(t, T_poly, T_linearized)``)."""
    paper, gamma = result["paper"], result["gamma"]
    H, Tp, Tl = result["horizon"], result["T_poly"], result["T_linearized"]
    esc, curve = result["escaped"], result["curve"]
    both = [(ti, p, lv) for ti, p, lv in zip(curve["t"], curve["poly"], curve["linearized"],
                                              strict=True) if p is not None and lv is not None]
    return {"both": both,
            "survives": esc["poly"] is None and esc["linearized"] is None
            and H >= paper["horizon"],
            "better": Tp < Tl and Tp < gamma and all(p < lv for _, p, lv in both),
            "close": (abs(Tp - paper["T_poly"]) <= 0.05 * paper["T_poly"]
                      and abs(Tl - paper["T_linearized"]) <= 0.05 * paper["T_linearized"])}


def claims(result: dict[str, Any]) -> list[Claim]:
    """The paper's claims next to ours, verdicts computed from ``result``."""
    paper, gamma = result["paper"], result["gamma"]
    H, Tp, Tl = result["horizon"], result["T_poly"], result["T_linearized"]
    esc = result["escaped"]
    c = _checks(result)
    both, survives, better = c["both"], c["survives"], c["better"]
    at_paper = result["T_at_paper_horizon"]
    h = paper["horizon"]
    escape_why = ("(26) has the positive term (0.6 + 0.6 sin 50t) P22^2 (Remark 2): P22, then "
                  "x_f, escape in finite time")
    return [
        Claim(f"the filters (25)-(26), (27)-(28) exist on [0, {h:g}] s", "yes",
              f"(25)-(26): {_esc(esc['poly'])}; (27)-(28): {_esc(esc['linearized'])}",
              Claim.judge(survives), "" if survives else escape_why),
        Claim(f"Fig. 1: ||T_zw|| at t = {h:g} s (polynomial; linearized)",
              f"{paper['T_poly']}; {paper['T_linearized']}",
              "; ".join("none (escaped)" if v is None else f"{v:.3f}"
                        for v in (at_paper["poly"], at_paper["linearized"]))
              + f" (at the cut t = "
              f"{H:.4f} s where both exist: {Tp:.3f}; {Tl:.3f})",
              Claim.judge(survives and c["close"]),
              "tolerance 5 %" + ("" if survives else "; not computable after the escape, "
                                 "and the value at the cut depends on where the escape test "
                                 "stops the filter")),
        Claim("the polynomial filter stays below gamma and below the linearized one",
              f"T_poly < gamma = {gamma} and < T_linearized",
              f"where both exist (to t = {H:.4f} s): T_poly = {Tp:.3f}, T_linearized = "
              f"{Tl:.3f}; " + ", ".join(f"{ti:g} s: {p:.3f}/{lv:.3f}" for ti, p, lv in both),
              Claim.judge(better)),
        Claim(f"the linearized filter exceeds gamma at t = {h:g} s",
              f"T_linearized = {paper['T_linearized']} > gamma = {gamma}",
              f"T_linearized({h:g} s) = {_num(at_paper['linearized'])} (exceeds gamma from "
              + ("never" if result["exceeds_gamma_at"]["linearized"] is None else
                 f"t = {result['exceeds_gamma_at']['linearized']:.3f} s") + ")",
              Claim.judge(at_paper["linearized"] is not None and at_paper["linearized"] > gamma)),
    ]


def _esc(e: dict[str, Any] | None) -> str:
    if e is None:
        return "exists throughout"
    sing = e.get("singular")
    if sing is None:
        return f"{e['quantity']} escapes at t = {e['time']:.4f} s (escape test)"
    return (f"{sing['entry']} becomes singular at t = {sing['time']:.5f} s (the escape test "
            f"stops the RK4 run at {e['time']:.4f} s)")


def _num(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


def why(result: dict[str, Any]) -> str:
    """What the claims do not say (``docs/reproductions.md``), from ``result``."""
    paper, H = result["paper"], result["horizon"]
    before = result["T_before_end"]
    sysv = result["linearized_variant"]["system"]["T_at_paper_horizon"]["linearized"]
    ident = result["L_identity"]["escaped"]
    if _checks(result)["survives"]:
        text = "The printed equations survive to the horizon. "
    else:
        text = (f"The printed equations do not survive to {paper['horizon']:g} s: (26) has "
                "the positive term (0.6 + 0.6 sin 50t) P22^2 (Remark 2), so P22 and then x_f "
                "escape in finite time. T_poly at the cut is set by where the escape test "
                f"stops the filter: it was {before['poly']:.3f} "
                f"{1000 * (H - before['t']):.0f} ms before the cut, so a match with the paper "
                "there says little. ")
    return text + (
        "(26) and (28) as printed are (13) with L = C = [1 0]; with the example's z = x "
        "(L = I) both Riccati equations gain +gamma^-2 P22^2 and escape earlier (polynomial "
        f"filter: {_esc(ident['poly'])}). (27) as printed is J(m) m, the linearization at "
        "the estimate, not the system's f(m); with f(m), T_linearized at "
        f"{paper['horizon']:g} s is {_num(sysv)}. (32) misprints (14); (14) is implemented.")
