"""What a reproduction shows: its claims as data (:class:`Claim`, verdicts computed from our
numbers, never typed in), its figure and its Rerun file.

The same claims go into the JSON result (:func:`claims_json`), onto the figure
(:func:`claims_figure`, :func:`finish_figure`), into the printed summary
(:func:`format_claims`) and into the module's section of ``docs/reproductions.md``
(:func:`section`, with its :class:`Paper` and ``why(result)``: what the claims do not say).
:func:`write_outputs` writes the JSON, the PNG and the ``.rrd`` (one
:class:`testbed.outputs.viz.Run` per run it shows).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

VERDICTS = ("agrees", "differs", "not checked")
_VERDICT_TEXT = {"agrees": "#1b7a33", "differs": "#b3261e", "not checked": "#555555"}


@dataclass(frozen=True)
class Claim:
    """One claim of a paper next to our number.

    Attributes
    ----------
    claim : str
        What the paper claims (short, names the figure/equation).
    paper : str
        The paper's value or statement.
    ours : str
        Our value.
    verdict : str
        One of :data:`VERDICTS`, computed from our result.
    why : str
        Cause of a difference (or what limits the check); may be empty.
    """

    claim: str
    paper: str
    ours: str
    verdict: str
    why: str = ""

    def __post_init__(self) -> None:
        if self.verdict not in VERDICTS:
            raise ValueError(f"verdict must be one of {VERDICTS}, got {self.verdict!r}")

    @staticmethod
    def judge(agrees: bool) -> str:
        """``"agrees"`` or ``"differs"``."""
        return "agrees" if agrees else "differs"


@dataclass(frozen=True)
class Paper:
    """The paper a reproduction checks.

    Attributes
    ----------
    authors : str
        ``"Basin, Elvira-Ceja & Sanchez"``.
    year : str
        ``"2018"`` or ``"n.d."``.
    where : str
        Where the example is in the paper (``"Section IV"``, ``"Example 5.2"``).
    example : str
        What the example is, short (the section's heading).
    """

    authors: str
    year: str
    where: str
    example: str

    @property
    def citation(self) -> str:
        """``authors (year), where``."""
        return f"{self.authors} ({self.year}), {self.where}"


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def claims_table(claims: Sequence[Claim | dict[str, str]]) -> list[str]:
    """The claims as a Markdown table (claim, paper, ours, verdict), one row per claim,
    then their notes (``why``) as a numbered list referenced from the verdict cell."""
    claims = _as_claims(claims)
    lines = ["| claim | paper | ours | verdict |", "|---|---|---|---|"]
    notes = []
    for c in claims:
        verdict = f"**{c.verdict}**" if c.verdict == "differs" else c.verdict
        if c.why:
            notes.append(c.why)
            verdict += f" ({len(notes)})"
        lines.append("| " + " | ".join(_cell(x) for x in (c.claim, c.paper, c.ours, verdict))
                     + " |")
    if notes:
        lines += ["", "Notes: " + " ".join(f"({i}) {_cell(n)}{'' if n.endswith('.') else '.'}"
                                           for i, n in enumerate(notes, 1))]
    return lines


def section(name: str, paper: Paper, claims: Sequence[Claim | dict[str, str]], why: str,
            figure: str | None = None, width: int = 100) -> str:
    """The section of ``docs/reproductions.md`` for one reproduction (Markdown).

    Parameters
    ----------
    name : str
        The reproduction's name (``testbed reproduce NAME``).
    paper : Paper
    claims : sequence of Claim
    why : str
        The module's ``why(result)`` paragraph.
    figure : str, optional
        Path of its figure relative to the document.
    width : int
        Prose is wrapped to this many characters (table rows are one line each).
    """
    import re
    import textwrap

    def fill(text: str) -> str:  # no wrapped line may read as a list, quote or heading
        out: list[str] = []
        for line in textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False,
                                  break_long_words=False):
            while out and re.match(r"([-+*>#=|]|\d+[.)])(\s|$)", line) and " " in out[-1]:
                head, last = out[-1].rsplit(" ", 1)  # carry words down instead
                out[-1], line = head, f"{last} {line}"
            out.append(line)
        return "\n".join(out)

    verdict = textwrap.wrap(f"- Verdict: {agree_text(claims)}.", width, subsequent_indent="  ",
                            break_on_hyphens=False, break_long_words=False)
    lines = [f"## {paper.example}", "", f"- Paper: {paper.citation}",
             f"- Run: `testbed reproduce {name}`", *verdict, "", *claims_table(claims), ""]
    notes = [i for i, line in enumerate(lines) if line.startswith("Notes: ")]
    for i in notes:  # the notes are prose: wrapped
        lines[i] = fill(lines[i])
    lines += [fill(f"**Why.** {why}"), ""]
    if figure:
        lines += [f"![{paper.example}: figure of `{name}`]({figure})", ""]
    return "\n".join(lines)


def claims_json(claims: Sequence[Claim]) -> list[dict[str, str]]:
    """The claims as JSON-ready dicts."""
    return [asdict(c) for c in claims]


def _as_claims(claims: Sequence[Claim | dict[str, str]]) -> list[Claim]:
    return [c if isinstance(c, Claim) else Claim(**c) for c in claims]


def format_claims(claims: Sequence[Claim | dict[str, str]]) -> str:
    """One line per claim: ``[verdict] claim: paper <value> | ours <value> (why)``."""
    lines = []
    for c in _as_claims(claims):
        why = f" ({c.why})" if c.why else ""
        lines.append(f"  [{c.verdict}] {c.claim}: paper {c.paper} | ours {c.ours}{why}")
    return "\n".join(lines)


def agree_text(claims: Sequence[Claim | dict[str, str]]) -> str:
    """``"k of n claims agree"`` and the claims that differ, for the docs table."""
    claims = _as_claims(claims)
    agree = sum(c.verdict == "agrees" for c in claims)
    differ = [c.claim for c in claims if c.verdict == "differs"]
    text = f"{agree} of {len(claims)} claims agree"
    return text + (f"; differs: {'; '.join(differ)}" if differ else "")


def _claim_lines(claim: Claim, wrap: int) -> list[str]:
    import textwrap

    text = f"{claim.claim}: paper {claim.paper}; ours {claim.ours}"
    if claim.why:
        text += f" ({claim.why})"
    return textwrap.wrap(text, wrap) or [""]


def claims_height_in(claims: Sequence[Claim | dict[str, str]], *, wrap: int = 150,
                     fontsize: float = 8.0) -> float:
    """Height (inches) :func:`draw_claims` needs, to size the figure row it goes in."""
    lines = sum(len(_claim_lines(c, wrap)) for c in _as_claims(claims))
    return (lines * 1.3 + 2.0 * len(claims) * 0.3 + 1.5) * fontsize / 72.0


def draw_claims(ax: Any, claims: Sequence[Claim | dict[str, str]], *, wrap: int = 150,
                fontsize: float = 8.0) -> None:
    """Draw the claims in ``ax`` (frame hidden), one block per claim: the verdict in
    colour, then ``claim: paper P; ours O (why)`` wrapped to ``wrap`` characters.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        A panel reserved for the claims, at least :func:`claims_height_in` high.
    claims : sequence of Claim
    wrap : int
        Characters per line.
    fontsize : float
        Points (at least 8).
    """
    fontsize = max(fontsize, 8.0)
    ax.set_axis_off()
    offset = 0.0
    for c in _as_claims(claims):
        lines = _claim_lines(c, wrap)
        ax.annotate(f"[{c.verdict}]", xy=(0.0, 1.0), xycoords="axes fraction",
                    xytext=(0.0, -offset), textcoords="offset points", va="top",
                    fontsize=fontsize, weight="bold", color=_VERDICT_TEXT[c.verdict],
                    annotation_clip=False)
        ax.annotate("\n".join(lines), xy=(0.0, 1.0), xycoords="axes fraction",
                    xytext=(8.0 * fontsize, -offset), textcoords="offset points", va="top",
                    fontsize=fontsize, family="monospace", annotation_clip=False)
        offset += (len(lines) * 1.3 + 0.6) * fontsize


#: ``units`` of a reproduction of a dimensionless system.
DIMENSIONLESS = {"state": "1 (dimensionless system)", "time": "s"}


def legend_below(ax: Any, ncols: int = 2, offset: float = 0.2, title: str | None = None
                 ) -> None:
    """The legend of ``ax`` below it, outside the data, with an optional ``title`` (font
    :data:`testbed.outputs.plots.FONT_PT`)."""
    from testbed.outputs.plots import FONT_PT

    ax.legend(fontsize=FONT_PT, loc="upper center", bbox_to_anchor=(0.5, -offset),
              ncols=ncols, frameon=False, title=title, title_fontsize=FONT_PT)


def claims_figure(claims: Sequence[Claim | dict[str, str]], width_in: float, height_in: float,
                  panel_heights: Sequence[float], cols: int = 1, wrap: int = 150
                  ) -> tuple[Any, Any]:
    """A figure of ``width_in`` by ``height_in`` plus the claims' height, whose last grid row
    (the whole width) is for the claims (:func:`finish_figure`).

    Returns
    -------
    fig : matplotlib.figure.Figure
    grid : matplotlib.gridspec.GridSpec
        ``len(panel_heights) + 1`` rows of ``cols`` columns.
    """
    from testbed.outputs.plots import new_figure

    claims_in = claims_height_in(claims, wrap=wrap)
    fig = new_figure(width_in, height_in + claims_in)
    return fig, fig.add_gridspec(len(panel_heights) + 1, cols,
                                 height_ratios=[*panel_heights, claims_in])


def finish_figure(fig: Any, grid: Any, claims: Sequence[Claim | dict[str, str]],
                  title: list[str], path: str | os.PathLike, wrap: int = 150) -> None:
    """Draw the claims in the grid's last row, the title lines and the claims' summary
    (:func:`agree_text`) on top, and save the figure."""
    from testbed.outputs.plots import save_figure, set_title

    draw_claims(fig.add_subplot(grid[-1, :]), claims, wrap=wrap)
    set_title(fig, [*title, agree_text(claims)])
    save_figure(fig, path)


def write_outputs(result: dict[str, Any], *, json_path: str | os.PathLike | None,
                  plot_path: str | os.PathLike | None, rrd_path: str | os.PathLike | None,
                  plot: Callable[[str | os.PathLike], None],
                  runs: Callable[[], list[Any]] | None = None, application_id: str | None = None,
                  units: dict[str, str] | None = None,
                  **rrd_kwargs: Any) -> None:
    """Write whichever outputs were asked for (each atomically).

    Parameters
    ----------
    result : dict
        JSON-ready result of the reproduction.
    json_path, plot_path, rrd_path : path or None
        Destinations; None skips that output.
    plot : callable ``path -> None``
        Draws the reproduction's figure into ``path``.
    runs : callable ``() -> list of testbed.outputs.viz.Run``
        The runs of the ``.rrd``, each under its own prefix with its description
        (:func:`testbed.outputs.viz.write_runs`); only called (and needed) when ``rrd_path``
        is given.
    application_id : str, optional
        Rerun application id (default ``"testbed-" + result["scenario"]``).
    units : dict, optional
        The units of the result's quantities, stored as its ``units`` (every JSON output has
        one; default: the system is dimensionless, time in s).
    **rrd_kwargs
        Passed to :func:`testbed.outputs.viz.write_runs` (``degrees``).
    """
    if rrd_path and runs is None:
        raise ValueError("write_outputs needs runs for the .rrd")
    result.setdefault("units", dict(units) if units is not None else DIMENSIONLESS)
    if json_path:
        from testbed.io import write_json

        write_json(json_path, result)
    if plot_path:
        plot(plot_path)
    if rrd_path:
        from testbed.outputs.viz import write_runs

        write_runs(runs(), rrd_path, **rrd_kwargs,
                   application_id=application_id or "testbed-" + result["scenario"])
