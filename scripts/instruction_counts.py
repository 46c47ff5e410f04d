"""Instruction counts of the benchmark's thin ratios: the same blocks, counted, not timed.

``scripts/benchmark.py`` times ``RigEnv.step`` against a bare ``mj_step`` of the same model
(``env_overhead_ratio``, ``env_vehicle_overhead_ratio``). Times move with the machine's load
and with the processor; the number of instructions a block executes does not (to a few
parts in a thousand: the same code, the same data). This script runs the same blocks under
Valgrind's callgrind and counts the instructions of each, so that a change can be judged
on a busy or a different machine::

    python scripts/instruction_counts.py                    # a table
    python scripts/instruction_counts.py --json runs/instructions.json --steps 2000

It compiles a two-function helper with ``valgrind/callgrind.h``'s client requests (collect
on, collect off and dump) into a private temporary directory, runs itself under
``valgrind --tool=callgrind --collect-atstart=no`` and reads one dump per block. Needs
``valgrind``, its headers and a C compiler; about a minute and a half per thousand steps on
the two-core machine. Metrics (instructions per env step, all threads):

- ``raw_instructions``, ``env_instructions``: bare ``mj_step(nstep=10)`` of the helicopter's
  member model hovering at level pitch, and ``RigEnv('helicopter').step`` there (ambient
  disturbance off: the benchmark's blocks, built by its ``_raw_step``);
- ``env_overhead_instructions_ratio``: their ratio (the companion of ``env_overhead_ratio``);
- ``vraw_instructions``, ``venv_instructions``, ``env_vehicle_overhead_instructions_ratio``:
  the same for the vehicle roll rig at rest.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

HELPER_C = """
#include <valgrind/callgrind.h>
void testbed_collect_on(void) { CALLGRIND_TOGGLE_COLLECT; }
void testbed_collect_off(const char *name) {
    CALLGRIND_TOGGLE_COLLECT;
    CALLGRIND_DUMP_STATS_AT(name);
}
"""
#: The blocks in the order they run (each a dump of its own).
BLOCKS = ("raw", "env", "vraw", "venv")
#: Uncounted calls before a block's count (caches, lazily built tables).
WARM_UP_STEPS = 50


def _blocks() -> dict[str, Any]:
    """The benchmark's physics blocks (:func:`benchmark.bench_physics`'s setup)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import numpy as np
    from benchmark import _raw_step

    from testbed.envs import RigEnv

    env = RigEnv("helicopter", ambient_noise=0.0)
    x0 = np.zeros(4)
    u = env.rig.operating_input(env.nominal_params, x0[None])[0]
    env.reset(seed=0, options={"x0": x0})
    vehicle = RigEnv("vehicle-roll", ambient_noise=0.0)
    v_x0, v_u = np.zeros(2), np.zeros(1)
    vehicle.reset(seed=0, options={"x0": v_x0})
    return {"raw": _raw_step(env, x0, u), "env": lambda: env.step(u),
            "vraw": _raw_step(vehicle, v_x0, v_u), "venv": lambda: vehicle.step(v_u)}


def inner(helper: str, steps: int) -> None:
    """Under callgrind: each block's ``steps`` calls counted and dumped by name."""
    lib = ctypes.CDLL(helper)
    lib.testbed_collect_off.argtypes = [ctypes.c_char_p]
    blocks = _blocks()
    for name in BLOCKS:
        step = blocks[name]
        for _ in range(WARM_UP_STEPS):
            step()
        lib.testbed_collect_on()
        for _ in range(steps):
            step()
        lib.testbed_collect_off(name.encode())


def _summaries(out_dir: Path) -> dict[str, int]:
    """Each block's instruction count from its callgrind dump (``desc: Trigger`` names it)."""
    counts: dict[str, int] = {}
    for path in sorted(out_dir.glob("cg.out*")):
        text = path.read_text(errors="replace")
        trigger = re.search(r"^desc: Trigger: Client Request: (\S+)", text, re.M)
        summary = re.search(r"^summary:\s+(\d+)", text, re.M)
        if trigger and summary and trigger.group(1) in BLOCKS:
            counts[trigger.group(1)] = int(summary.group(1))
    return counts


def count(steps: int) -> dict[str, Any]:
    """Run the blocks under callgrind; instructions per step of each and the two ratios.

    Raises
    ------
    RuntimeError
        Valgrind, its headers or a C compiler missing, or a block without its dump.
    """
    compiler = shutil.which("cc") or shutil.which("gcc")
    if shutil.which("valgrind") is None or compiler is None:
        raise RuntimeError("instruction counts need valgrind and a C compiler")
    with tempfile.TemporaryDirectory(prefix="testbed-callgrind-") as tmp:  # mode 0700
        out = Path(tmp)
        (out / "helper.c").write_text(HELPER_C)
        helper = out / "helper.so"
        subprocess.run([compiler, "-shared", "-fPIC", "-O1", "-o", str(helper),
                        str(out / "helper.c")], check=True, capture_output=True)
        env = {**os.environ, "RERUN_ANALYTICS": "off"}
        proc = subprocess.run(
            ["valgrind", "--tool=callgrind", "--collect-atstart=no",
             f"--callgrind-out-file={out / 'cg.out'}", sys.executable, __file__, "--inner",
             str(helper), "--steps", str(steps)], env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"callgrind run failed: {proc.stderr.strip().splitlines()[-1:]}")
        counts = _summaries(out)
    missing = [b for b in BLOCKS if b not in counts]
    if missing:
        raise RuntimeError(f"no callgrind dump for the blocks {missing}")
    per_step = {f"{b}_instructions": counts[b] / steps for b in BLOCKS}
    return {**per_step, "steps": steps,
            "env_overhead_instructions_ratio": counts["env"] / counts["raw"],
            "env_vehicle_overhead_instructions_ratio": counts["venv"] / counts["vraw"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000,
                        help="counted env steps per block (default 1000)")
    parser.add_argument("--json", help="write the counts here")
    parser.add_argument("--inner", metavar="HELPER", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.steps < 1:
        parser.error(f"--steps must be a positive integer, got {args.steps}")
    if args.inner:
        inner(args.inner, args.steps)
        return 0
    result = count(args.steps)
    for key, value in result.items():
        print(f"{key:42s} {value:,.3f}" if isinstance(value, float) else f"{key:42s} {value}")
    if args.json:
        from testbed.io import atomic_path

        with atomic_path(args.json) as tmp:
            Path(tmp).write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
