"""``testbed score``: estimators on a scenario suite, the leaderboard and output files."""

from __future__ import annotations

import argparse
import sys
import time

from testbed.cli import values
from testbed.cli.outputs import worst_case_path, wrote
from testbed.estimators import ESTIMATORS


def add_arguments(sc: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``sc``."""
    sc.add_argument("--filter", "--estimator", dest="estimator", action="append", default=[],
                    metavar="[LABEL=]NAME_OR_MODULE:FACTORY",
                    help=f"{', '.join(ESTIMATORS)}, package.module:factory or "
                         "path/to/file.py:factory, optionally LABEL= (default label: the "
                         "plug-in's name attribute, else file:factory); repeatable "
                         "(--estimator: the same)")
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
    sc.add_argument("--reference", default="kalman", metavar="[LABEL=]NAME_OR_MODULE:FACTORY",
                    help="estimator the others are compared with, paired (default kalman)")
    sc.add_argument("--no-worst-case", action="store_true", help="skip the worst-case search")
    sc.add_argument("--backend", default="local", choices=("local", "ray"))
    sc.add_argument("--workers", type=values.positive_int, default=None,
                    help="processes (entries in parallel; default 1)")
    sc.add_argument("--json", help="write the results here")
    sc.add_argument("--markdown", help="write the leaderboard as Markdown here")
    sc.add_argument("--plot", help="write a PNG here")
    sc.add_argument("--rrd", help="write the comparison Rerun recording here")
    sc.add_argument("--no-progress", action="store_true",
                    help="no progress on stderr (default: a bar with an ETA on a terminal, "
                         "one line per scored entry otherwise)")


class Progress:
    """``testbed score``'s progress on stderr, per scored entry (all its estimators): a bar
    weighted by the entries' estimated costs (:func:`testbed.score.harness.entry_cost`)
    with the elapsed time and an ETA on a terminal, else one line per entry."""

    def __init__(self, args: argparse.Namespace, estimators: int):
        from tqdm import tqdm

        from testbed.score import harness
        from testbed.score.suite import get_suite

        try:
            entries = get_suite(args.suite)
        except ValueError:
            entries = []
        if args.scenario is not None:
            entries = [e for e in entries if e.name in args.scenario]
        if args.twin is not None:  # the twin's entries (errors: later)
            try:
                entries = harness.twin_entries(entries, args.twin, args.suite,
                                               selected=args.scenario is not None)
            except ValueError:
                entries = []
        if args.runs is not None:
            entries = [e.replace(runs=args.runs) for e in entries]
        self.cost = {e.name: max(harness.entry_cost(e), 1.0) for e in entries}
        self.total, self.done, self.count = sum(self.cost.values()), 0.0, 0
        self.start = time.monotonic()
        self.bar = tqdm(total=self.total, desc=f"score ({estimators} estimators)",
                        file=sys.stderr, unit="", disable=not sys.stderr.isatty(),
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}"
                                   "] {postfix}")

    def __call__(self, entry: str) -> None:
        cost = self.cost.get(entry, 1.0)
        self.done, self.count = self.done + cost, self.count + 1
        if not self.bar.disable:
            self.bar.set_postfix_str(f"{self.count}/{len(self.cost)} {entry}", refresh=False)
            self.bar.update(cost)
            return
        elapsed = time.monotonic() - self.start
        left = elapsed * (self.total - self.done) / self.done if self.done else 0.0
        print(f"  scored {entry} ({self.count}/{len(self.cost)} entries, {elapsed:.0f} s, "
              f"about {left:.0f} s left)", file=sys.stderr)

    def close(self) -> None:
        """End the bar."""
        self.bar.close()


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
    from filters.base import Batched
    from testbed import estimators
    from testbed.plugins import LabelledFactory
    from testbed.score.suite import LINEUP

    if not args.estimator:
        raise ValueError("give the estimators: --filter NAME (or --estimator; repeatable), "
                         f"e.g. --filter kalman --filter ekf; the suite's lineup: "
                         f"{' '.join(LINEUP)}; or --list")
    names = args.estimator
    chosen = []
    for name in [*names, args.reference]:  # loaded (a plug-in's failure named) before any work
        try:
            chosen.append(estimators.labelled(name))
        except ValueError as exc:
            flag = "--reference" if len(chosen) == len(names) else "--filter"
            raise ValueError(f"{flag}: {exc}") from None
    *chosen, reference = chosen
    for factory in chosen:  # a plug-in class that runs one instance per run, said up front
        target = factory._target if isinstance(factory, LabelledFactory) else None
        cls = target() if callable(target) else None
        if isinstance(cls, type) and not (isinstance(cls, Batched) and cls.batched):
            print(f"note: {factory.__name__} has no batched = True: it runs one instance per "
                  "run (up to the largest entry's runs per step); expect a cost of several "
                  "times a batched estimator's", file=sys.stderr)
    bar = None if args.no_progress else Progress(args, len(chosen))
    try:
        run = harness.score(chosen, args.suite, seed=args.seed, runs=args.runs,
                            scenarios=args.scenario, backend=args.backend,
                            workers=args.workers, worst_case=not args.no_worst_case,
                            reference=reference, progress=bar, twin=args.twin)
    finally:
        if bar is not None:
            bar.close()
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
