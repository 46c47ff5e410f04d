"""``testbed compare LOG --twin FILE`` (or ``--rig RIG``: the nominal rig): the rig simulated
with the recording's inputs from its initial state, over the recording; fit per channel, and
overlays as PNG and Rerun (:func:`testbed.identify.comparison.compare`)."""

from __future__ import annotations

import argparse
from typing import Any

from testbed.cli.outputs import wrote
from testbed.cli.replay import add_recording_arguments


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``p``."""
    add_recording_arguments(p)
    p.add_argument("--sensors", default=None,
                   help="the sensor preset of the recording (default: the twin's or the "
                   "profile's)")
    p.add_argument("--method", default=None, choices=("output-error", "multiple-shooting"),
                   help="one free run over the recording, or short segments re-initialised "
                   "from the measured state (default: the twin's, else output error)")
    p.add_argument("--json", help="write the fit per channel here")
    p.add_argument("--plot", help="write the measured vs simulated overlay here")
    p.add_argument("--rrd", help="write the overlay as a Rerun recording here")


def command(args: argparse.Namespace) -> int:
    """``testbed compare``: the fit of the simulated rig to the recording."""
    from testbed.cli.replay import read_log
    from testbed.identify import compare, compare_json, plot_compare

    recording, unit = read_log(args)
    twin = unit["twin"]
    if twin is not None:
        result = compare(twin, recording, sensors=args.sensors, method=args.method)
    else:
        result = compare(unit["rig"], recording, profile=unit["profile"],
                         options=unit["options"], sensors=args.sensors, method=args.method)
    print(format_compare(result))
    if args.json:
        from testbed.io import write_json

        wrote(write_json(args.json, compare_json(result)))
    if args.plot:
        wrote(plot_compare(result, args.plot))
    if args.rrd:
        from testbed.outputs.overlay import write_overlay_rrd

        wrote(write_overlay_rrd(result, args.rrd))
    return 0


def format_compare(result: dict[str, Any]) -> str:
    """The fit per channel, one line."""
    what = f"twin {result.get('twin')}" if result.get("source") == "twin" else "nominal"
    cells = ", ".join(f"{ch} {v:.1f} %" for ch, v in result["fit_percent"].items())
    return (f"rig {result['rig']} ({result['profile']}, {what}) | method "
            f"{result['method']} | fit (NRMSE): {cells}")
