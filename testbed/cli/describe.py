"""``testbed describe RIG``: a rig's inputs, sensor channels, units, profiles, options and
identifiable parameters (what a recording of the rig may hold, what ``identify`` can fit)."""

from __future__ import annotations

import argparse

from testbed.cli import values
from testbed.cli.outputs import wrote


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``p``."""
    p.add_argument("rig", help="a registered rig or package.module:RigClass")
    p.add_argument("--profile", default=None, help="only this profile (default: every one)")
    p.add_argument("--rig-option", type=values.name_setting, action="append", default=[],
                   metavar="NAME=VALUE", help="describe the rig built with this option")
    p.add_argument("--json", help="write the description here")


def command(args: argparse.Namespace) -> int:
    """``testbed describe``: the description as tables (and JSON)."""
    from testbed.io import write_json
    from testbed.rigs import resolve_rig
    from testbed.rigs.describe import describe_rig, format_description

    try:
        rig = resolve_rig(args.rig)
    except ValueError as exc:
        raise ValueError(f"rig: {exc}") from None
    if args.profile is not None and args.profile not in rig.profiles:
        raise ValueError(f"--profile must be one of {rig.profiles} for rig {rig.name!r}, got "
                         f"{args.profile!r}")
    try:
        options = rig.resolve_options(dict(args.rig_option))
    except ValueError as exc:
        raise ValueError(f"--rig-option: {exc}") from None
    description = describe_rig(rig, profile=args.profile, options=options)
    print(format_description(description))
    if args.json:
        wrote(write_json(args.json, description))
    return 0
