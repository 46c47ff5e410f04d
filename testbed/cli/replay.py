"""``testbed replay LOG``: an estimator over a recording's inputs and sensor channels (a
real unit's log, or one written by ``testbed run --save-log``), with consistency from its
innovations and, with ``--reference CHANNEL``, the RMSE against a held-out channel
(:mod:`testbed.experiment.replay`)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from testbed.cli import values
from testbed.cli.outputs import wrote


def add_recording_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments every command reading a recording shares: the log, its mapping, the
    rig and its options, a twin (``replay``, ``identify``, ``compare``)."""
    p.add_argument("log", nargs="+", metavar="LOG",
                   help="the recording: a .csv, .npz or .mat file (several .mat files or a "
                   "directory: QUARC's To File layout, with --mapping)")
    p.add_argument("--mapping", metavar="FILE.toml", default=None,
                   help="which column is which input or channel, units, signs, offsets and "
                   "the segment (docs/twin.md)")
    p.add_argument("--rig", default=None, help="the rig (default: the one the recording names)")
    p.add_argument("--profile", default=None, choices=("paper", "hardware"),
                   help="the rig's profile (default: the twin's, the recording's, else "
                   "hardware)")
    p.add_argument("--rig-option", type=values.name_setting, action="append", default=[],
                   metavar="NAME=VALUE", help="a construction option of the rig (testbed "
                   "describe RIG; default: the twin's, or those the recording names); "
                   "repeatable")
    p.add_argument("--twin", metavar="FILE.toml", default=None,
                   help="a twin of the unit (testbed identify --twin): its rig, profile, "
                   "options and parameters")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``p``."""
    add_recording_arguments(p)
    p.add_argument("--filter", default="kalman",
                   help="a built-in estimator or package.module:factory")
    p.add_argument("--filter-option", type=values.name_setting, action="append", default=[],
                   metavar="NAME=VALUE",
                   help="keyword option of the filter factory (a number, true/false or a word)")
    p.add_argument("--sensors", default=None,
                   help="the sensor preset the recording's channels come from (default: the "
                   "recording's, else the profile's)")
    p.add_argument("--sensor-option", type=values.name_setting, action="append", default=[],
                   metavar="NAME=VALUE", help="option of the sensor preset; repeatable")
    p.add_argument("--design-option", type=values.name_setting, action="append", default=[],
                   metavar="NAME=VALUE", help="design option the rig declares; repeatable")
    p.add_argument("--reference", metavar="CHANNEL", default=None,
                   help="hold this channel out of the estimator and report the estimate's "
                   "RMSE against it (e.g. the pitch encoder for an IMU-only estimator)")
    p.add_argument("--exclude", metavar="CHANNEL", action="append", default=[],
                   help="hold this channel out too (not reported); repeatable")
    p.add_argument("--period", type=values.positive, default=None, metavar="S",
                   help="the estimator's period, a whole multiple of the recording's (every "
                   "k-th sample, the input held; default: the recording's)")
    p.add_argument("--json", help="write the summary JSON here")
    p.add_argument("--plot", help="write a PNG here (estimates +-3 sigma, innovations)")
    p.add_argument("--rrd", help="write a Rerun recording here")
    p.add_argument("--no-progress", action="store_true", help="never show a progress bar")


def read_log(args: argparse.Namespace) -> tuple[Any, dict[str, Any]]:
    """The recording and the rig it is of, from ``LOG``, ``--mapping``, ``--rig``,
    ``--profile``, ``--rig-option`` and ``--twin`` (checked, one-line errors, before anything
    runs): ``(recording, {"rig", "profile", "options", "params", "twin"})``."""
    from testbed.io.formats import read_recording
    from testbed.rigs import resolve_rig

    twin = None
    if args.twin is not None:
        from testbed.identify.twin import read_twin

        twin = read_twin(args.twin)
    paths = args.log[0] if len(args.log) == 1 else list(args.log)
    first = read_recording(paths, mapping=args.mapping)
    name = args.rig or (twin.rig if twin is not None else None) or first.meta.get("rig")
    if name is None:
        raise ValueError(f"--rig: {first.source} names no rig; give --rig RIG (or --twin)")
    try:
        rig_cls = resolve_rig(name)
    except ValueError as exc:
        raise ValueError(f"--rig: {exc}") from None
    if twin is not None and twin.rig != rig_cls.name:
        raise ValueError(f"--twin {args.twin}: a twin of rig {twin.rig!r}, not {rig_cls.name!r}")
    recording = read_recording(paths, mapping=args.mapping, rig=rig_cls)
    options = dict(twin.options) if twin is not None else \
        dict(recording.meta.get("options") or {}) if recording.meta.get("rig") == rig_cls.name \
        else {}
    options.update(dict(args.rig_option))
    try:
        options = rig_cls.resolve_options(options)
    except ValueError as exc:
        raise ValueError(f"--rig-option: {exc}") from None
    profile = args.profile or (twin.profile if twin is not None else None) \
        or recording.meta.get("profile") or "hardware"
    if profile not in rig_cls.profiles:
        raise ValueError(f"--profile must be one of {rig_cls.profiles} for rig "
                         f"{rig_cls.name!r}, got {profile!r}")
    params = twin.params() if twin is not None else None
    return recording, {"rig": rig_cls, "profile": profile, "options": options,
                       "params": params, "twin": twin}


def twin_provenance(path: str) -> dict[str, str]:
    """``{"path", "sha256"}`` of a twin file (what an output says it used)."""
    import hashlib

    with open(path, "rb") as file:
        return {"path": path, "sha256": hashlib.sha256(file.read()).hexdigest()}


def command(args: argparse.Namespace) -> int:
    """``testbed replay``: the estimator over the recording, its consistency and outputs."""
    from testbed.experiment.replay import replay

    recording, unit = read_log(args)
    sensors = args.sensors if args.sensors is not None else recording.meta.get("sensors")
    result = replay(recording, rig=unit["rig"], profile=unit["profile"],
                    options=unit["options"], params=unit["params"], estimator=args.filter,
                    estimator_options=dict(args.filter_option), sensors=sensors,
                    sensor_options=dict(args.sensor_option),
                    design_options=dict(args.design_option), reference=args.reference,
                    exclude=tuple(args.exclude), period_s=args.period,
                    progress=not args.no_progress and sys.stderr.isatty())
    summary = result.to_json()
    if unit["twin"] is not None:
        summary["twin"] = twin_provenance(args.twin)
    print(format_replay(summary))
    if args.json:
        from testbed.io import write_json

        wrote(write_json(args.json, summary))
    if args.plot:
        from testbed.outputs.replay import plot_replay

        wrote(plot_replay(result, args.plot))
    if args.rrd:
        from testbed.outputs.replay import log_replay_rerun

        wrote(log_replay_rerun(result, args.rrd))
    return 0


def format_replay(summary: dict[str, Any]) -> str:
    """The terminal summary of a replay: what ran, its consistency, the reference RMSE."""
    from testbed.outputs.units import display

    lines = [f"{summary['recording']['source']} | rig {summary['rig']} ({summary['profile']}) "
             f"| filter {summary['estimator']} | {summary['steps']} steps of "
             f"{summary['period_s']:g} s in {summary['wall_s']:.2f} s wall "
             f"({summary['real_time_factor']:.0f}x real time)"]
    consistency = summary.get("consistency")
    if consistency:
        lo, hi = consistency["band"]
        lines.append(f"ANIS {consistency['anis']:.3f} (consistent: {consistency['dim']}, "
                     f"{100 * consistency['level']:g} % band [{lo:.3f}, {hi:.3f}]): "
                     f"{consistency['verdict']}; {100 * consistency['band_fraction']:.1f} % "
                     f"of steps outside the one-step band (expected "
                     f"{100 * consistency['band_fraction_expected']:.0f} %)")
        white = consistency.get("whiteness")
        if white:
            lines.append(f"innovations: whiteness p {white['p']:.3g} ({white['verdict']})")
    reference = summary.get("reference")
    if reference:
        scale, unit = display(reference.get("unit", ""))
        lines.append(f"reference {reference.get('channel')}: RMSE "
                     f"{reference.get('rmse', float('nan')) * scale:.4g} {unit}")
    for note in summary.get("notes", []):
        lines.append(f"note: {note}")
    return "\n".join(lines)
