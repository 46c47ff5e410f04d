"""``testbed identify LOG --rig RIG``: fit a rig's physical parameters and its sensor model to
a recording, with intervals, identifiability and fit per channel; ``--twin FILE.toml`` keeps
the result for ``run``, ``mc``, ``sweep``, ``replay`` and ``compare`` (:mod:`testbed.identify`).
"""

from __future__ import annotations

import argparse
from typing import Any

from testbed.cli import values
from testbed.cli.outputs import wrote
from testbed.cli.replay import add_recording_arguments

#: A held-out channel whose spread is below this many times its noise level is reported as not
#: excited (a fit near 0 % there is the noise, not the model).
UNEXCITED_SIGNAL_TO_NOISE = 3.0


def _names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"expected NAME,NAME,..., got {text!r}")
    return names


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``p``."""
    add_recording_arguments(p)
    p.add_argument("--free", type=_names, default=None, metavar="NAME,...",
                   help="the parameters to fit (default: every identifiable one the rig "
                   "declares: testbed describe RIG)")
    p.add_argument("--channels", type=_names, default=None, metavar="NAME,...",
                   help="the channels to fit (default: every recorded state channel)")
    p.add_argument("--sensors", default=None,
                   help="the sensor preset that made the recording (default: the profile's)")
    p.add_argument("--holdout", type=values.non_negative, default=0.0, metavar="FRACTION",
                   help="the end of the recording held out of the fit and scored apart, in "
                   "[0, 0.9)")
    p.add_argument("--method", default="auto",
                   choices=("auto", "output-error", "multiple-shooting"),
                   help="output error (one free run) or multiple shooting (short segments "
                   "re-initialised from the measured state: rigs that drift); auto chooses "
                   "by the free run's drift")
    p.add_argument("--segment", type=values.positive, default=1.0, metavar="S",
                   help="multiple-shooting segment length, s")
    p.add_argument("--fit-scale", action="store_true",
                   help="also fit each channel's scale factor (besides its bias)")
    p.add_argument("--json", help="write the identification here")
    p.add_argument("--plot", help="write the measured vs predicted channels and residuals here")


def command(args: argparse.Namespace) -> int:
    """``testbed identify``: the fit, its table, the twin and the outputs."""
    from testbed.cli.replay import read_log
    from testbed.identify import identify, plot_identification, write_twin

    if not 0.0 <= args.holdout < 0.9:
        raise ValueError(f"--holdout must be in [0, 0.9), got {args.holdout:g}")
    twin_out, args.twin = args.twin, None  # here --twin is the output
    recording, unit = read_log(args)
    result = identify(unit["rig"], recording, profile=unit["profile"],
                      options=unit["options"], free=args.free, holdout=args.holdout,
                      method=args.method, channels=args.channels, sensors=args.sensors,
                      fit_scale=args.fit_scale, segment_s=args.segment)
    print(format_identification(result))
    if args.json:
        from testbed.io import write_json

        wrote(write_json(args.json, result.to_json()))
    if twin_out:
        wrote(write_twin(twin_out, result))
    if args.plot:
        wrote(plot_identification(result, args.plot))
    return 0


def format_identification(result: Any) -> str:
    """The terminal table: each parameter with its interval, then the fit per channel."""
    lines = [f"{result.recording_source} | rig {result.rig} ({result.profile}) | method "
             f"{result.method}: {result.method_reason}"]
    width = max([len("parameter"), *map(len, result.parameters)]) + 2
    lines.append(f"{'parameter':<{width}}{'value':>13}{'95 % interval':>28}{'nominal':>13}"
                 f"{'x nominal':>11}")
    for name, p in result.parameters.items():
        interval = "" if p.ci95 is None else f"[{p.ci95[0]:.5g}, {p.ci95[1]:.5g}]"
        held = "" if p.identifiable else f"  held at nominal: {p.reason}"
        lines.append(f"{name:<{width}}{p.value:>13.6g}{interval:>28}{p.nominal:>13.6g}"
                     f"{p.scale:>11.4g}{held}")
    cells = [f"{ch} {result.fit_percent[ch]:.1f} %" for ch in result.fit_percent]
    lines.append("fit (NRMSE): " + ", ".join(cells))
    if result.holdout_fit_percent:
        lines.append("held-out fit: " + ", ".join(
            f"{ch} {v:.1f} %" for ch, v in result.holdout_fit_percent.items()))
        quiet = {ch: r for ch, r in result.holdout_signal_to_noise().items()
                 if r < UNEXCITED_SIGNAL_TO_NOISE}
        if quiet:
            lines.append("  not excited in the held-out part (its spread over the noise: "
                         + ", ".join(f"{ch} {r:.2g}" for ch, r in quiet.items())
                         + "): its fit compares the prediction with the noise")
    return "\n".join(lines)
