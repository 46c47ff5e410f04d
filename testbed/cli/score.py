"""``testbed score``: estimators on a scenario suite, the leaderboard and output files."""

from __future__ import annotations

import argparse
import sys

from testbed.cli import values
from testbed.cli.outputs import worst_case_path, wrote
from testbed.estimators import ESTIMATORS


def add_arguments(sc: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``sc``."""
    sc.add_argument("--estimator", action="append", default=[], metavar="NAME_OR_MODULE:FACTORY",
                    help=f"{', '.join(ESTIMATORS)} or package.module:factory; repeatable")
    sc.add_argument("--suite", default="quick", help="quick or standard")
    sc.add_argument("--list", action="store_true", help="list the suite's scenarios and exit")
    sc.add_argument("--scenario", action="append", default=None, metavar="NAME",
                    help="only this scenario of the suite; repeatable")
    sc.add_argument("--runs", type=values.positive_int, default=None,
                    help="override the runs of every entry")
    sc.add_argument("--twin", metavar="FILE.toml", default=None,
                    help="a twin of a real unit (testbed identify --twin): the suite's entries "
                         "of its rig, with its identified parameters")
    sc.add_argument("--seed", type=values.seed, default=0)
    sc.add_argument("--reference", default="kalman", metavar="NAME_OR_MODULE:FACTORY",
                    help="estimator the others are compared with, paired (default kalman)")
    sc.add_argument("--no-worst-case", action="store_true", help="skip the worst-case search")
    sc.add_argument("--backend", default="local", choices=("local", "ray"))
    sc.add_argument("--workers", type=values.positive_int, default=None,
                    help="processes (entries in parallel)")
    sc.add_argument("--json", help="write the results here")
    sc.add_argument("--markdown", help="write the leaderboard as Markdown here")
    sc.add_argument("--plot", help="write a PNG here")
    sc.add_argument("--rrd", help="write the comparison Rerun recording here")
    sc.add_argument("--no-progress", action="store_true",
                    help="do not report each scored entry on stderr")


def command(args: argparse.Namespace) -> int:
    """``testbed score``: estimators on a scenario suite, leaderboard and output files."""
    from testbed.score import harness, report
    from testbed.score.suite import describe_suite, suite_identity

    if args.list:
        identity = suite_identity(args.suite)
        print(f"suite {identity['suite']} version {identity['version']} sha256 "
              f"{identity['hash']}")
        for entry in describe_suite(args.suite):
            status = f"skipped: {entry['skipped']}" if entry["skipped"] else \
                f"{entry['runs']} runs"
            search = "worst case" if entry["worst_case"] else ""
            print(f"{entry['name']:<28}{status:<44}{search:<12}{entry['description']}")
        return 0
    if not args.estimator:
        raise ValueError("give --estimator NAME (repeatable), or --list")
    from testbed import estimators

    for name in args.estimator:  # loaded (and a plug-in's failure named) before any work
        try:
            estimators.resolve(name)
        except ValueError as exc:
            raise ValueError(f"--estimator: {exc}") from None
    run = harness.score(args.estimator, args.suite, seed=args.seed, runs=args.runs,
                        scenarios=args.scenario, backend=args.backend, workers=args.workers,
                        worst_case=not args.no_worst_case, reference=args.reference,
                        twin=args.twin,
                        progress=None if args.no_progress else
                        lambda name: print(f"  scored {name}", file=sys.stderr))
    summary = report.results(run)
    remarks = report.notes(run)
    print(report.leaderboard(summary))
    for remark in remarks:
        print(f"note: {remark}")
    if args.json:
        wrote(report.write_results(args.json, summary))
        npz = report.write_worst_cases(worst_case_path(args.json), run)
        if npz is not None:
            wrote(npz)
    if args.markdown:
        wrote(report.write_markdown(args.markdown, summary, remarks))
    if args.plot:
        wrote(report.write_png(args.plot, summary))
    if args.rrd:
        wrote(report.write_rrd(args.rrd, run))
    return 0
