"""The output files of a command: which flags write what, checked before anything runs,
and the tables the commands print."""

from __future__ import annotations

import argparse
import os

from testbed.experiment import scenario_file
from testbed.io import check_output_path
from testbed.outputs.units import display

#: Output flags and the suffix of the file each writes.
OUTPUTS = {"json": ".json", "plot": ".png", "rrd": ".rrd", "save_npz": ".npz",
           "video": ".mp4", "markdown": ".md", "save_log": (".csv", ".npz", ".mat"),
           "twin": ".toml"}


#: Where ``testbed reproduce all`` writes by default.
REPRODUCE_OUT_DIR, REPRODUCE_DOC = "runs/reproductions", "docs/reproductions.md"


#: The "wrote PATH" lines of the command, said once the files are in place.
_WROTE: list[str] = []


def wrote(path: object) -> None:
    """Say ``wrote PATH`` once the command's outputs are in place: the outputs appear together
    when the command ends (:func:`testbed.io.outputs_together`), so the line waits for that
    (:func:`say_written`); a command that fails says nothing of files that never appeared."""
    _WROTE.append(f"wrote {path}")


def say_written(done: bool = True) -> None:
    """Print the lines of :func:`wrote` (``done``: the outputs are in place) and forget them."""
    lines = list(_WROTE) if done else []
    _WROTE.clear()
    for line in lines:
        print(line, flush=True)


def worst_case_path(json_path: str | os.PathLike) -> str:
    """The ``.worst_case.npz`` that ``testbed score --json X.json`` writes beside ``X.json``."""
    return os.fspath(json_path).removesuffix(".json") + ".worst_case.npz"


def output_paths(args: argparse.Namespace) -> dict[str, str]:
    """Every file (or directory) the command will write, derived ones included, by the flag
    that names it in messages."""
    paths = {}
    for attr in OUTPUTS:
        if attr == "twin" and args.command != "identify":
            continue  # elsewhere --twin is read, not written
        path = getattr(args, attr)  # every command's namespace has it (COMMON_DEFAULTS)
        if path is not None:
            paths["--" + attr.replace("_", "-")] = path
    if args.command == "score" and args.json is not None:
        paths["--json (its .worst_case.npz)"] = worst_case_path(args.json)
    if args.command == "reproduce" and args.name == "all":
        paths["--out-dir"] = args.out_dir or REPRODUCE_OUT_DIR
        paths["--doc"] = args.doc or REPRODUCE_DOC
    return paths


def check_outputs(args: argparse.Namespace) -> None:
    """Check every output path of the command, derived ones included, before anything runs
    (``ValueError`` naming the flag)."""
    if args.command == "reproduce" and args.name != "all":
        for flag, value in (("--out-dir", args.out_dir), ("--doc", args.doc)):
            if value is not None:
                raise ValueError(f"{flag} applies to 'reproduce all' only; for one example "
                                 "use --json, --plot and --rrd")
    suffixes = {**{"--" + a.replace("_", "-"): s for a, s in OUTPUTS.items()},
                "--json (its .worst_case.npz)": ".npz", "--out-dir": None, "--doc": ".md"}
    for flag, path in output_paths(args).items():
        check_output_path(path, flag, suffixes[flag])
    if args.video is not None:
        from testbed.outputs.render import check_rendering, check_video_path

        try:
            check_video_path(args.video)
            check_rendering()
        except ValueError as exc:
            raise ValueError(f"--video: {exc}") from None
    if args.save_scenario is not None:
        scenario_file.check_destination(args.save_scenario)


def units_note(units: dict[str, str]) -> str | None:
    """The line saying that the console shows display units and the JSON SI units."""
    shown = sorted({f"{u} as {display(u)[1]}" for u in units.values() if display(u)[0] != 1})
    if not shown:
        return None
    return f"(shown: {', '.join(shown)}; the JSON is in SI units, see its 'units')"


def format_table(summary: dict, units: dict[str, str]) -> str:
    width = max([len("state"), *map(len, summary["rmse"])]) + 2
    lines = [f"{'state':<{width}}{'estimate RMSE':>18}{'measurement RMSE':>22}"]
    for name, value in summary["rmse"].items():
        scale, unit = display(units.get(name, ""))
        meas = summary["measurement_rmse"].get(name)
        meas_txt = f"{meas * scale:.4f} {unit}" if meas is not None else "-"
        lines.append(f"{name:<{width}}{value * scale:>11.4f} {unit:<6}{meas_txt:>22}")
    if summary.get("nees_mean") is not None:
        lines.append(f"mean NEES {summary['nees_mean']:.3f} (consistent filter: "
                     f"{len(summary['rmse'])})")
    if summary.get("T_final") is not None:
        lines.append(f"noise-output ratio T = {summary['T_final']:.4f}")
    note = units_note({k: units.get(k, "") for k in summary["rmse"]})
    return "\n".join(lines + ([note] if note else []))
