"""Benchmark of ``testbed identify``: a 30 s, 1 kHz helicopter recording, 6 free parameters.

The metric ``identify_vs_rollout`` for ``scripts/benchmark.py``: the identification's wall
time over the wall time of one rollout of the recording (the fitted part simulated once,
one member), and the wall time itself (target: within 60 s on a 2-core machine).

The unit: the helicopter in the hardware profile (rotor lag, deadband, current limit) at
hidden parameter scales, flown in closed loop (a PD loop on pitch and yaw about random
setpoint steps, gravity compensated with the nominal parameters), encoders and gyros at
1 kHz with their noise.

Usage: ``python scripts/bench_identify.py [--duration S] [--smoke] [--json PATH]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

FREE = ("pitch_damping", "yaw_damping", "pitch_inertia", "yaw_inertia", "K_pp", "K_yy")
SCALES = {"pitch_damping": 1.3, "yaw_damping": 0.7, "pitch_inertia": 1.15,
          "yaw_inertia": 0.85, "K_pp": 0.9, "K_yy": 1.2}


def _controller(rng: np.random.Generator, dt_s: float, n: int):
    from testbed.rigs.helicopter.rig import HelicopterParams, gravity_voltage

    nominal = HelicopterParams()
    inverse = np.linalg.inv(nominal.torque_gains)
    ref = np.zeros((n, 2))
    k = first = int(0.5 / dt_s)
    while k < n:
        hold = int(rng.uniform(0.5, 1.5) / dt_s)
        ref[k:k + hold] = [rng.uniform(-0.35, 0.3), rng.uniform(-1.0, 1.0)]
        k += hold

    def control(k: int, y: np.ndarray) -> np.ndarray:
        if k < first:
            return np.zeros(2)
        torque = np.array([nominal.pitch_inertia * (25 * (ref[k, 0] - y[0]) - 8 * y[2]),
                           nominal.yaw_inertia * (9 * (ref[k, 1] - y[1]) - 5 * y[3])])
        return gravity_voltage(nominal, y[0]) + inverse @ torque

    return control


def identify_vs_rollout(duration_s: float = 30.0, dt_s: float = 0.001,
                        seed: int = 0) -> dict[str, float]:
    """Identify a simulated helicopter unit and time it against one rollout.

    Returns
    -------
    dict
        ``identify_wall_s``, ``rollout_s`` (one rollout of the fitted recording, one
        member), ``identify_vs_rollout`` (their ratio), ``max_rel_error`` (of the six scale
        factors), ``min_fit_percent``, ``method``, ``member_steps``, ``samples``.
    """
    from testbed.identify import identify
    from testbed.identify.synthetic import simulated_recording
    from testbed.rigs.helicopter.rig import HelicopterRig

    n = int(round(duration_s / dt_s))
    rng = np.random.default_rng(seed)
    rec = simulated_recording(HelicopterRig, (n, _controller(rng, dt_s, n)), dt_s=dt_s,
                              profile="hardware", scales=SCALES, seed=seed,
                              sensors="encoders+gyros", settle_s=0.5)
    t0 = time.perf_counter()
    res = identify(HelicopterRig, rec, profile="hardware", free=list(FREE),
                   sensors="encoders+gyros")
    wall = time.perf_counter() - t0
    errors = [abs(res.parameters[k].scale / v - 1.0) for k, v in SCALES.items()]
    return {"identify_wall_s": wall, "rollout_s": res.timings["rollout_s"],
            "identify_vs_rollout": wall / res.timings["rollout_s"],
            "max_rel_error": float(max(errors)),
            "min_fit_percent": float(min(res.fit_percent.values())), "method": res.method,
            "member_steps": res.timings["member_steps"], "samples": float(n)}


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print (and optionally write) its JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0, help="recording length, s")
    parser.add_argument("--smoke", action="store_true", help="a 2 s recording")
    parser.add_argument("--json", help="write the result here")
    args = parser.parse_args(argv)
    out = identify_vs_rollout(2.0 if args.smoke else args.duration)
    text = json.dumps(out, indent=2)
    print(text)
    if args.json:
        from testbed.io import write_json

        write_json(args.json, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
