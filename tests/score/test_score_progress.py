"""``testbed score``'s progress: per (entry, estimator) pair costs from the harness's cost
model, the pairs reported as they end (in this process and from worker processes), the bar's
ETA, and the up-front note on plug-ins that run one instance per run."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import pytest

from testbed import estimators
from testbed.cli import build_parser
from testbed.cli import score as cli_score
from testbed.score import progress
from testbed.score.harness import entry_cost, run_entries, score_entry
from testbed.score.suite import get_suite

EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples"


def _entry(name: str, runs: int = 2, duration_s: float = 0.3):
    entry = next(e for e in get_suite("quick") if e.name == name)
    return entry.replace(runs=runs, scenario=entry.scenario.replace(duration_s=duration_s))


def test_pair_costs_split_the_entry_cost_model():
    entries = get_suite("quick")
    pairs = progress.pair_costs(entries, ["ekf", "mine"], "kalman", unbatched={"mine"})
    # every entry: the asked-for estimators, then the Kalman (timing and comparison) reference
    assert [(p.entry, p.estimator) for p in pairs] == [
        (e.name, n) for e in entries for n in ("ekf", "mine", "kalman")]
    for entry in entries:
        ekf, mine, kalman = [p for p in pairs if p.entry == entry.name]
        assert ekf.cost == pytest.approx(entry_cost(entry))  # Monte Carlo + worst case
        assert mine.cost == pytest.approx(progress.UNBATCHED_FACTOR * entry_cost(entry))
        # the reference not asked for: its Monte Carlo only (no worst-case search)
        assert kalman.cost == pytest.approx(entry_cost(entry.replace(worst_case=None)))
        assert not kalman.worst_case and ekf.worst_case == (entry.worst_case is not None)
    searched = [e for e in entries if e.worst_case is not None]
    assert searched and all(entry_cost(e) > entry_cost(e.replace(worst_case=None))
                            for e in searched)
    quiet = progress.pair_costs(entries, ["ekf"], "kalman", worst_case=False)
    assert all(p.cost == pytest.approx(entry_cost(e.replace(worst_case=None)))
               for e in entries for p in quiet if p.entry == e.name)
    # a reference asked for is not run twice; another reference is a third pair per entry
    assert len(progress.pair_costs(entries, ["kalman"], "kalman")) == len(entries)
    assert len(progress.pair_costs(entries, ["ekf"], "ukf")) == 3 * len(entries)


class _Recorder:
    def __init__(self):
        self.pairs, self.entries = [], []

    def pair(self, entry, estimator):
        self.pairs.append((entry, estimator))

    def __call__(self, entry):
        self.entries.append(entry)


def test_pairs_reported_in_the_planned_order_in_this_process():
    entry = _entry("calibration")
    seen = []
    result = score_entry(entry, ["kalman-bucy"], 0, worst_case=False,
                         on_pair=lambda *pair: seen.append(pair))
    planned = progress.pair_costs([entry], ["kalman-bucy"], "kalman", worst_case=False)
    assert seen == [(p.entry, p.estimator) for p in planned] == [
        ("calibration", name) for name in result]
    recorder = _Recorder()
    run_entries([entry], ["kalman-bucy"], 0, workers=1, worst_case=False, progress=recorder)
    assert recorder.pairs == seen and recorder.entries == ["calibration"]


def test_pairs_reported_from_worker_processes():
    entries = [_entry("calibration"), _entry("vehicle-dlc", duration_s=0.2)]
    recorder = _Recorder()
    run_entries(entries, ["kalman-bucy"], 0, workers=2, worst_case=False, progress=recorder)
    planned = progress.pair_costs(entries, ["kalman-bucy"], "kalman", worst_case=False)
    assert sorted(recorder.pairs) == sorted((p.entry, p.estimator) for p in planned)
    for entry in ("calibration", "vehicle-dlc"):  # each entry's pairs in their order
        assert [p for p in recorder.pairs if p[0] == entry] == [
            (entry, "kalman-bucy"), (entry, "kalman")]
    assert sorted(recorder.entries) == ["calibration", "vehicle-dlc"]


def test_no_channel_without_a_pair_method_or_on_ray():
    with progress.pair_channel(None, "local", 2) as channel:
        assert channel is None
    with progress.pair_channel(_Recorder(), "ray", 2) as channel:
        assert channel is None
    recorder = _Recorder()
    with progress.pair_channel(recorder, "local", 1) as channel:
        channel.put(("a", "b"))
    assert recorder.pairs == [("a", "b")]


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_bar_over_pairs_with_elapsed_and_eta(monkeypatch):
    """On a terminal: the bar advances by each pair's expected cost, names the pair just
    scored, and its ETA is the elapsed time over the cost done (the cost model's ratios)."""
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    pairs = [progress.PairCost("a", "kalman", 1000.0, False),
             progress.PairCost("a", "mine", 3000.0, False),
             progress.PairCost("b", "kalman", 4000.0, False),
             progress.PairCost("b", "mine", 2000.0, False)]
    bar = cli_score.Progress(pairs, 2)
    assert bar.pair is not None
    bar.pair("a", "mine")
    bar.pair("a", "mine")  # reported twice: counted once
    assert bar.bar.n == 3000.0
    bar.bar.start_t -= 100.0  # 100 s elapsed
    shown = bar.bar.format_dict
    assert shown["rate"] is None  # smoothing 0: the ETA is elapsed * left / done
    line = bar.bar.format_meter(**shown)
    # 3000 of 10000 done in 100 s: 7000 left take 233 s (03:53)
    assert "30%" in line and "[01:40<03:53], 1/4 pairs: a mine" in line
    bar("a")  # the entry's end: its pair not yet reported counts now
    assert bar.bar.n == 4000.0 and "2/4 pairs: a kalman" in bar.bar.postfix
    bar("b")
    assert bar.bar.n == 10000.0
    bar.close()
    assert "4/4 pairs" in terminal.getvalue()


def test_not_a_terminal_one_line_per_entry(monkeypatch, capsys):
    pairs = [progress.PairCost("a", "kalman", 1000.0, False),
             progress.PairCost("b", "kalman", 3000.0, False)]
    bar = cli_score.Progress(pairs, 1)
    assert bar.pair is None  # no per-pair channel
    bar("a")
    bar.close()
    err = capsys.readouterr().err
    assert "scored a (1/2 entries" in err and "left)" in err


def test_notes_name_unbatched_plugins_with_their_expected_cost():
    pytest.importorskip("filterpy")
    fp = estimators.labelled(f"{EXAMPLES / 'fp_ekf.py'}:make")
    user = estimators.labelled(f"{EXAMPLES / 'userkf.py'}:make")
    assert progress.is_batched("kalman") is True
    assert progress.is_batched(estimators.labelled("mine=ekf")) is True
    assert progress.is_batched(fp) is False and progress.is_batched(user) is None
    args = build_parser().parse_args(["score", "--scenario", "calibration"])
    pairs, unbatched = cli_score.planned_pairs(args, ["kalman", fp, user], "kalman")
    assert unbatched == {"fp-ekf", "userkf:make"}
    notes = cli_score.unbatched_notes(["kalman", fp, user], pairs)
    assert len(notes) == 2 and all("\n" not in n for n in notes)
    factor = f"{progress.UNBATCHED_FACTOR:g}x"
    assert notes[0].startswith("note: fp-ekf has no batched = True: it runs one instance "
                               f"per run: expected cost about {factor} a batched estimator's")
    assert notes[1].startswith("note: userkf:make (a factory function) runs, unless its "
                               "estimator has batched = True, one instance per run")
    fp_s = sum(p.cost for p in pairs if p.estimator == "fp-ekf") * progress.SECONDS_PER_UNIT
    total_s = sum(p.cost for p in pairs) * progress.SECONDS_PER_UNIT
    assert f"measured), {fp_s:.0f} s of the call's {total_s:.0f} s of CPU" in notes[0]
