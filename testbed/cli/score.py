"""``testbed score``: estimators on a scenario suite, the leaderboard and output files."""

from __future__ import annotations

import argparse
import sys
import threading
import time
from typing import Any

from testbed.cli import values
from testbed.cli.outputs import worst_case_path, wrote
from testbed.estimators import ESTIMATORS


def add_arguments(sc: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``sc``."""
    sc.add_argument("--filter", "--estimator", dest="estimator", action="append", default=[],
                    metavar="[LABEL=]NAME_OR_MODULE:FACTORY",
                    help=f"{', '.join(ESTIMATORS)}, an installed package's (entry points "
                         "testbed.estimators), package.module:factory or "
                         "path/to/file.py:factory, optionally LABEL= (default label: the "
                         "plug-in's name attribute, else file:factory); repeatable "
                         "(--estimator: the same)")
    sc.add_argument("--suite", default="quick",
                    help="quick (default), standard or an installed package's (entry points "
                         "testbed.suites)")
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
                    help="processes (entries in parallel; default 1: in this process)")
    sc.add_argument("--json", help="write the results here")
    sc.add_argument("--markdown", help="write the leaderboard as Markdown here")
    sc.add_argument("--plot", help="write a PNG here")
    sc.add_argument("--rrd", help="write the comparison Rerun recording here")
    sc.add_argument("--no-progress", action="store_true",
                    help="no progress on stderr (default: a bar over the (entry, "
                         "estimator) pairs with the elapsed time and an ETA from the cost "
                         "model on a terminal, one line per scored entry otherwise)")


def planned_pairs(args: argparse.Namespace, chosen: list, reference: Any) -> tuple[
        list, set[str]]:
    """The (entry, estimator) pairs the call will score with their expected costs
    (:func:`testbed.score.progress.pair_costs`) and the names of the estimators taken as
    running one instance per run (all but those known to be batched); no pairs when the
    suite or the twin is bad (the harness says why)."""
    from testbed.score import harness, progress
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
    names = [harness.estimator_name(f) for f in chosen]
    unbatched = {n for n, f in zip(names, chosen, strict=True)
                 if progress.is_batched(f) is not True}
    pairs = progress.pair_costs(entries, names, harness.estimator_name(reference),
                                worst_case=not args.no_worst_case, unbatched=unbatched)
    return pairs, unbatched


def _minutes(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.0f} min"


def unbatched_notes(chosen: list, pairs: list) -> list[str]:
    """One line per plug-in that runs (or may run) one instance per run, with its expected
    cost, said before the work starts."""
    from testbed.score import harness, progress

    total = sum(p.cost for p in pairs) * progress.SECONDS_PER_UNIT
    out = []
    for factory in chosen:
        batched = progress.is_batched(factory)
        if batched:
            continue
        name = harness.estimator_name(factory)
        own = sum(p.cost for p in pairs if p.estimator == name) * progress.SECONDS_PER_UNIT
        why = ("has no batched = True: it runs" if batched is False else
               "(a factory function) runs, unless its estimator has batched = True,")
        out.append(f"note: {name} {why} one instance per run: expected cost about "
                   f"{progress.UNBATCHED_FACTOR:g}x a batched estimator's (1.1-7.6x "
                   f"measured), {_minutes(own)} of the call's {_minutes(total)} of CPU")
    return out


class Progress:
    """``testbed score``'s progress on stderr. On a terminal: a bar over the (entry,
    estimator) pairs weighted by their expected costs
    (:func:`testbed.score.progress.pair_costs`), with the elapsed time, the ETA (elapsed
    time over the cost done) and the pair just scored. Otherwise one line per scored entry
    (all its pairs) with the count and the time left."""

    def __init__(self, pairs: list, estimators: int):
        from tqdm import tqdm

        self.cost = {(p.entry, p.estimator): max(p.cost, 1.0) for p in pairs}
        self.entries = list(dict.fromkeys(p.entry for p in pairs))
        self.total, self.done, self.count = sum(self.cost.values()), 0.0, 0
        self.scored: set[tuple[str, str]] = set()
        self.lock = threading.Lock()
        self.start = time.monotonic()
        terminal = sys.stderr.isatty()
        self.bar = tqdm(total=self.total, desc=f"score ({estimators} estimators)",
                        file=sys.stderr, unit="", disable=not terminal, smoothing=0,
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}"
                                   "]{postfix}", postfix=f"0/{len(self.cost)} pairs")
        #: called by the harness as each pair ends (a terminal only)
        self.pair = self._pair if terminal else None

    def _pair(self, entry: str, estimator: str) -> None:
        with self.lock:
            if (entry, estimator) in self.scored:
                return
            self.scored.add((entry, estimator))
            cost = self.cost.get((entry, estimator), 0.0)
            self.done += cost
            self.bar.set_postfix_str(f"{len(self.scored)}/{len(self.cost)} pairs: {entry} "
                                     f"{estimator}", refresh=False)
            self.bar.update(cost)

    def __call__(self, entry: str) -> None:
        """The entry's job ended: every pair of it is scored."""
        self.count += 1
        pairs = [key for key in self.cost if key[0] == entry]
        if not self.bar.disable:
            for key in pairs:  # those not reported one by one (a Ray task)
                self._pair(*key)
            return
        self.done += sum(self.cost[key] for key in pairs)
        elapsed = time.monotonic() - self.start
        left = elapsed * (self.total - self.done) / self.done if self.done else 0.0
        print(f"  scored {entry} ({self.count}/{len(self.entries)} entries, {elapsed:.0f} s, "
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
    from testbed import estimators
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
    pairs, _ = planned_pairs(args, chosen, reference)
    for note in unbatched_notes(chosen, pairs):  # one instance per run, said up front
        print(note, file=sys.stderr)
    bar = None if args.no_progress else Progress(pairs, len(chosen))
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
