"""Speed of the Theorem-4 LMI design of Zhang, Deng & Zhang (2018) (the size of its Example 5.2:
n = 2, n_y = 2, n_v = 1).

``python scripts/bench_lmi.py`` prints the JSON of :func:`bench_lmi`; ``scripts/benchmark.py``
may import :func:`bench_lmi`. Targets: one LMI solve (median) below 0.1 s, the gamma bisection
below 2 s.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages

from filters.lmi_hinf import design_lmi_hinf, minimal_gamma  # noqa: E402
from testbed.reproductions.zhang_lmi_hinf.scenario import paper_system  # noqa: E402


def bench_lmi(repeats: int = 11, bisections: int = 3) -> dict[str, float]:
    """Time the LMI (48) design and the gamma bisection on the paper's model (52).

    ``lmi_solve_s``: median wall time of :func:`filters.lmi_hinf.design_lmi_hinf` at
    ``gamma = 1`` (feasibility) on a FRESH system object each time, so it includes building
    and compiling the cvxpy problem (the module caches compiled problems per system object;
    a re-solve of a compiled problem takes 3-10 ms), solving it with CLARABEL and the
    a-posteriori check. ``gamma_bisection_s``: median wall time of
    :func:`filters.lmi_hinf.minimal_gamma` (relative tolerance 1e-3), also on fresh system
    objects. One warm-up call (imports, cvxpy's own caches) is not timed.

    Parameters
    ----------
    repeats : int
        Timed design calls.
    bisections : int
        Timed bisections.

    Returns
    -------
    dict
        ``{"lmi_solve_s": float, "gamma_bisection_s": float}`` (seconds).
    """
    design_lmi_hinf(paper_system(), 1.0)  # warm-up
    solves = []
    for _ in range(repeats):
        system = paper_system()
        start = time.perf_counter()
        design = design_lmi_hinf(system, 1.0)
        solves.append(time.perf_counter() - start)
        if not design.feasible:
            raise RuntimeError(f"benchmark design infeasible: {design.status}")
    searches = []
    for _ in range(bisections):
        system = paper_system()
        start = time.perf_counter()
        minimal_gamma(system)
        searches.append(time.perf_counter() - start)
    return {"lmi_solve_s": statistics.median(solves),
            "gamma_bisection_s": statistics.median(searches)}


if __name__ == "__main__":
    print(json.dumps(bench_lmi(), indent=2))
