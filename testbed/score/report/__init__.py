"""Outputs of a score: the JSON results, a terminal leaderboard, Markdown, a PNG and a
comparison Rerun recording.

JSON (:func:`results`): top level ``suite``, ``suite_version``, ``suite_hash``, ``seed``,
``level``, ``reference``, ``estimators``, ``scenarios`` (the entries' descriptions),
``units``, ``wall_s`` and ``results``, one entry per estimator and scenario with exactly the
keys of :data:`RESULT_KEYS`. ``nees_test``/``nis_test`` are
:func:`testbed.score.consistency.consistency_test` (with the per-step curve),
``whiteness`` :func:`~testbed.score.consistency.whiteness_test` and ``versus_reference``
the paired comparison of each state's per-run MSE with the reference's
(:mod:`testbed.score.paired`: the ratio interval, the +-2 % margin, Holm over the lineup).
``worst_case_search`` is
:meth:`testbed.score.worst_case.SearchResult.describe` (the linear prediction, the probe
sensors and the channels measured without quantization). ``cpu_s`` is the pair's CPU seconds
per stage (:attr:`~testbed.score.harness.PairResult.cpu_s`: where the time goes; not
deterministic). Gains are in the output's unit per
unit of the scenario's ``w``; RMSE in the states' units (SI; the leaderboard, the Markdown
and the PNG show angles in degrees).

One module per output kind: :mod:`~testbed.score.report.document` (JSON, remarks, the
worst-case file), :mod:`~testbed.score.report.tables` (leaderboard, Markdown),
:mod:`~testbed.score.report.figure` (PNG), :mod:`~testbed.score.report.rerun` (``.rrd``);
their public names are importable from here.
"""

from testbed.score.report.document import (
    RESULT_KEYS,
    _entry_result,  # noqa: F401 - for the tests
    certificate,
    comparisons,
    notes,
    results,
    write_results,
    write_worst_cases,
)
from testbed.score.report.figure import (
    AXIS_NAME_CHARS,
    VERDICT_MARKERS,
    score_figure,
    short_name,
    write_png,
)
from testbed.score.report.rerun import write_rrd
from testbed.score.report.tables import (  # noqa: F401 - _ranks for the tests
    TIE_RTOL,
    _ranks,
    leaderboard,
    markdown,
    write_markdown,
)

__all__ = ["AXIS_NAME_CHARS", "RESULT_KEYS", "TIE_RTOL", "VERDICT_MARKERS", "certificate",
           "comparisons", "leaderboard", "markdown", "notes", "results", "score_figure",
           "short_name", "write_markdown", "write_png", "write_results", "write_rrd",
           "write_worst_cases"]
