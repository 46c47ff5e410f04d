"""``testbed reproduce``: one paper example (or all of them, regenerating the docs)."""

from __future__ import annotations

import argparse

from testbed.cli import values
from testbed.cli.outputs import REPRODUCE_DOC, REPRODUCE_OUT_DIR, wrote
from testbed.cli.scenario_options import MAX_DURATION_S


def add_arguments(rep: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``rep``."""
    from testbed.reproductions import REPRODUCTIONS

    rep.add_argument("name", choices=[*sorted(REPRODUCTIONS), "all"])
    rep.add_argument("--horizon", type=values.positive, default=None,
                     help="simulated seconds (default: the paper's horizon; at most "
                     f"{MAX_DURATION_S:g} without --allow-long)")
    rep.add_argument("--allow-long", action="store_true",
                     help=f"accept a --horizon above {MAX_DURATION_S:g} s")
    rep.add_argument("--seed", type=values.seed, default=0)
    rep.add_argument("--json")
    rep.add_argument("--plot")
    rep.add_argument("--rrd")
    rep.add_argument("--out-dir", default=None,
                     help=f"with 'all' only: where the JSON/PNG/RRD files go (default "
                     f"{REPRODUCE_OUT_DIR})")
    rep.add_argument("--doc", default=None,
                     help=f"with 'all' only: the Markdown table to regenerate (default "
                     f"{REPRODUCE_DOC})")


def command(args: argparse.Namespace) -> int:
    """``testbed reproduce``: one paper example (or all, regenerating the docs)."""
    from testbed import reproductions

    if args.horizon is not None and args.horizon > MAX_DURATION_S and not args.allow_long:
        raise ValueError(f"--horizon {args.horizon:g} s is above the limit of "
                         f"{MAX_DURATION_S:g} s; add --allow-long to run it anyway")
    from testbed.reproductions.outputs import agree_text, format_claims

    if args.name == "all":
        out_dir, doc = args.out_dir or REPRODUCE_OUT_DIR, args.doc or REPRODUCE_DOC
        results = reproductions.reproduce_all(out_dir, doc)
        for name, result in results.items():
            print(f"{name}: {agree_text(result['claims'])}")
        wrote(f"{doc}, its figures and {out_dir}/")
        return 0
    module = reproductions.load(args.name)
    result = module.reproduce(horizon_s=args.horizon, seed=args.seed, json_path=args.json,
                              plot_path=args.plot, rrd_path=args.rrd)
    print(f"{args.name}: {module.PAPER.citation}\n  {agree_text(result['claims'])}\n"
          "  claims (paper | ours):\n" + format_claims(result["claims"]))
    for path in (args.json, args.plot, args.rrd):
        if path:
            wrote(path)
    return 0
