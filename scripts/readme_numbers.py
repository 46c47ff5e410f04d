"""Regenerate the measured numbers of the README and the docs from the commands they show.

Each block between ``<!-- numbers:NAME:start -->`` and ``<!-- numbers:NAME:end -->`` in
README.md or any docs/*.md (:func:`doc_files`) is produced here by parsing the command line
printed in the block with the CLI's own parser (so the numbers are those of that command) and
running it through the runner. Blocks are found by their markers, wherever they are: a block
moves with its text from one file to another without a change here. Every block of
:data:`BLOCKS` must appear exactly once among the files, and every marker must name one.

    python scripts/readme_numbers.py            # rewrite the files in place
    python scripts/readme_numbers.py --check    # exit 1 if a block is out of date

``--check`` compares the text with every number replaced by a placeholder exactly, and the
numbers to a relative tolerance (:data:`RTOL`). Why a tolerance: on the same machine and
library versions the numbers are bitwise equal, but another OpenBLAS kernel
(``OPENBLAS_CORETYPE=Haswell``) rounds matrix products differently; through the LMI and
Riccati solvers and the quantized sensors of the closed loop that moves an RMSE by up to
4e-4 relative (measured: the vehicle roll ``lmi-hinf`` roll-rate RMSE, 3.6e-4), and on the
hardware helicopter, whose closed loop (the controller on the estimate) through quantized
encoders and the stops amplifies a rounding difference of the ``ukf`` (its simplex sigma
points through BLAS products) into up to 3 % of one run's RMSE (median 0.2 %), a mean over 20
runs by up to 2.5e-3. The numbers are printed to 4 significant digits (rounding alone: up to
5e-4 relative between two values that straddle a rounding boundary), so ``RTOL = 5e-3``
holds and still fails on a change of a design or of the loop, which moves the numbers by
percents. A quantile of a few runs (the ``(5 % / 95 %)`` in parentheses) is one run's RMSE:
it moves as one run does (measured 1.8 %), so numbers inside parentheses are compared to
``QTOL = 4e-2``.
"""

from __future__ import annotations

import argparse
import re
import shlex
import sys
from collections.abc import Callable
from pathlib import Path

from testbed.cli import build_parser, scenario_from_args
from testbed.experiment import runner
from testbed.io import atomic_path
from testbed.outputs.units import display

ROOT = Path(__file__).resolve().parents[1]
#: Relative tolerance of ``--check`` (see the module docstring).
RTOL = 5e-3
#: Relative tolerance of ``--check`` for numbers inside parentheses (quantiles of a few runs).
QTOL = 4e-2
#: A block's start marker; group 1 is its name.
_START = re.compile(r"<!-- numbers:([A-Za-z0-9_-]+):start -->")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_PARENTHESES = re.compile(r"\([^()]*\)")


def _in_parentheses(text: str) -> list[bool]:
    """For each number of ``text`` (:data:`_NUMBER`), whether it stands inside parentheses."""
    spans = [m.span() for m in _PARENTHESES.finditer(text)]
    return [any(lo < m.start() < hi for lo, hi in spans) for m in _NUMBER.finditer(text)]


def differences(old: str, new: str, rtol: float = RTOL, qtol: float = QTOL) -> list[str]:
    """Where ``new`` differs from ``old``: text with numbers masked must be equal, numbers
    equal to ``rtol`` relative (``qtol`` inside parentheses: quantiles). Returns one line per
    difference (empty: current)."""
    if _NUMBER.sub("#", old) != _NUMBER.sub("#", new):
        old_lines, new_lines = old.splitlines(), new.splitlines()
        return [f"text differs: {a!r} -> {b!r}" for a, b in zip(old_lines, new_lines, strict=False)
                if _NUMBER.sub("#", a) != _NUMBER.sub("#", b)] or ["line count differs"]
    out = []
    for a, b, quantile in zip(_NUMBER.findall(old), _NUMBER.findall(new),
                              _in_parentheses(old), strict=True):
        x, y = float(a), float(b)
        if abs(x - y) > (qtol if quantile else rtol) * max(abs(x), abs(y)):
            out.append(f"{a} -> {b}")
    return out


def _scenario(command: str):
    argv = shlex.split(command)
    assert argv[0] == "testbed", command
    args = build_parser().parse_args(argv[1:])
    return args, scenario_from_args(args)


def _value(summary: dict, key: str, name: str) -> str:
    value = summary[key].get(name)
    if value is None:
        return "(not measured)"
    factor, unit = display(summary["units"].get(name, ""))
    return f"{factor * value:.4g} {unit}".strip()


def _run_table(commands: list[str], label: Callable[[str], str]) -> str:
    """One row per command: estimate RMSE per state, NEES."""
    rows = []
    header = None
    for command in commands:
        _, scenario = _scenario(command)
        _, s = runner.run(scenario, record=False, progress=False)
        names = list(s["rmse"])
        if header is None:
            header = ["run", *[f"{n} RMSE" for n in names], "mean NEES", "T"]
        nees = "-" if s["nees_mean"] is None else f"{s['nees_mean']:.3g}"
        T = "-" if s.get("T_final") is None else f"{s['T_final']:.3g}"
        rows.append([label(command), *[_value(s, "rmse", n) for n in names], nees, T])
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def demo() -> str:
    """The `make demo` run: estimate vs raw encoder RMSE."""
    command = ("testbed run helicopter --filter kalman --controller lqr --duration 20 --seed 0")
    _, scenario = _scenario(command)
    _, s = runner.run(scenario, record=False, progress=False)
    lines = [f"`{command}`:", "", "| state | estimate RMSE | raw sensor RMSE |", "|---|---|---|"]
    for name in s["rmse"]:
        lines.append(f"| {name} | {_value(s, 'rmse', name)} | "
                     f"{_value(s, 'measurement_rmse', name)} |")
    nees = s["nees_mean"]
    lines += ["", f"Mean NEES {nees:.3g} ({len(s['rmse'])} for a consistent filter)."]
    return "\n".join(lines)


def ms_hinf() -> str:
    """Kalman vs mean-square H-infinity on the rig with the paper's disturbance."""
    commands = [f"testbed run helicopter --filter {f} --disturbance basin-helicopter "
                "--duration 20 --seed 0" for f in ("kalman", "ms-hinf")]
    return "\n".join([*(f"`{c}`" for c in commands), "",
                      _run_table(commands, lambda c: c.split("--filter ")[1].split()[0])])


def vehicle() -> str:
    """The vehicle roll with the Kalman and the LMI filter."""
    commands = [f"testbed run vehicle-roll --filter {f} --manoeuvre double-lane-change "
                "--duration 10 --seed 0" for f in ("kalman", "lmi-hinf")]
    commands.append("testbed run vehicle-roll --filter kalman --manoeuvre double-lane-change "
                    "--duration 10 --seed 0 --design-option a_y_source=oracle")
    return "\n".join([*(f"`{c}`" for c in commands), "",
                      _run_table(commands, lambda c: " ".join(
                          [c.split("--filter ")[1].split()[0]]
                          + (["(oracle a_y)"] if "oracle" in c else [])))])


def profiles() -> str:
    """Kalman filter, paper vs hardware profile (matched and paper design), then the EKF and
    the UKF on the rig's nominal MuJoCo model (composed with the matched design's states on
    the hardware profile; fewer runs: each runs MuJoCo rollouts per member and step): mean
    and 5/95 % over the runs."""
    commands = []
    for rig in ("helicopter", "vehicle-roll"):
        for profile in ("paper", "hardware", "hardware --design-profile paper"):
            commands.append(f"testbed mc {rig} --filter kalman --profile {profile} --runs 100 "
                            "--duration 10 --seed 0")
    for rig in ("helicopter", "vehicle-roll"):
        for name in ("ekf", "ukf"):
            for profile in ("paper", "hardware"):
                commands.append(f"testbed mc {rig} --filter {name} --profile {profile} "
                                "--runs 20 --duration 10 --seed 0")
    lines = ["| command | state | RMSE mean (5 % / 95 %) | mean NEES |", "|---|---|---|---|"]
    for command in commands:
        args, scenario = _scenario(command)
        r = runner.monte_carlo(scenario, runs=args.runs, progress=False)
        for name in ("pitch", "yaw", "roll"):
            if name not in r["rmse"]:
                continue
            st = r["rmse"][name]
            factor, unit = display(r["units"].get(name, ""))
            lines.append(f"| `{command}` | {name} | {factor * st['mean']:.4g} "
                         f"({factor * st['q05']:.4g} / {factor * st['q95']:.4g}) {unit} | "
                         f"{r['nees_mean']:.3g} |")
    return "\n".join(lines)


BLOCKS: dict[str, Callable[[], str]] = {"demo": demo, "ms-hinf": ms_hinf,
                                         "vehicle": vehicle, "profiles": profiles}


def doc_files(root: Path = ROOT) -> list[Path]:
    """The files whose numbers blocks this script keeps: README.md, then docs/*.md sorted."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def find_blocks(texts: dict[Path, str]) -> dict[str, Path]:
    """Which file holds each numbers block.

    Parameters
    ----------
    texts : dict of Path to str
        The files' texts.

    Returns
    -------
    dict of str to Path
        Every name of :data:`BLOCKS`, with the one file that holds its block.

    Raises
    ------
    ValueError
        A marker names no block of :data:`BLOCKS`, a block appears twice (in one file or
        two), or a block of :data:`BLOCKS` appears nowhere.
    """
    where: dict[str, Path] = {}
    for path, text in texts.items():
        for name in _START.findall(text):
            if name not in BLOCKS:
                raise ValueError(f"{path}: numbers:{name}: no such block (known: "
                                 f"{', '.join(BLOCKS)})")
            if name in where:
                raise ValueError(f"{path}: numbers:{name}: block also in {where[name]}")
            where[name] = path
    missing = [name for name in BLOCKS if name not in where]
    if missing:
        raise ValueError(f"no file has the numbers block(s) {', '.join(missing)}")
    return where


def render(text: str, names: list[str] | None = None) -> str:
    """``text`` with its numbers blocks ``names`` (default: every block of :data:`BLOCKS`)
    regenerated; a block named but missing is a ``ValueError``."""
    for name in BLOCKS if names is None else names:
        pattern = re.compile(rf"(<!-- numbers:{name}:start -->\n).*?(<!-- numbers:{name}:end -->)",
                             re.S)
        if not pattern.search(text):
            raise ValueError(f"no numbers:{name} block (or no end marker)")
        body = BLOCKS[name]()
        text = pattern.sub(lambda m, body=body: m.group(1) + body + "\n" + m.group(2), text)
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="fail if a block is stale")
    args = parser.parse_args(argv)
    texts = {path: path.read_text() for path in doc_files()}
    where = find_blocks(texts)
    stale = False
    for path, old in texts.items():
        names = [name for name, found in where.items() if found == path]
        if not names:
            continue
        new = render(old, names)
        shown = path.relative_to(ROOT)
        if args.check:
            for line in differences(old, new):
                print(f"{shown}: {line}", file=sys.stderr)
                stale = True
            continue
        with atomic_path(path) as tmp:
            tmp.write_text(new)
        print(f"wrote {shown}")
    return int(stale)


if __name__ == "__main__":
    sys.exit(main())
