"""Writing a reproduction's outputs: the JSON result, the PNG figure and the Rerun file."""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

from testbed.trajectory import Trajectory


def agreement(findings: list[dict[str, Any]]) -> str:
    """The "agree" cell of ``docs/reproductions.md`` from a reproduction's findings.

    Parameters
    ----------
    findings : list of dict
        Each with ``label`` (short name of a claim) and ``agree`` (bool).

    Returns
    -------
    str
        ``"yes"``, ``"no"`` or ``"partly"``, followed by what agreed and what did not, e.g.
        ``"partly: yes - a, b; no - c"``.
    """
    yes = [f["label"] for f in findings if f["agree"]]
    no = [f["label"] for f in findings if not f["agree"]]
    verdict = "yes" if not no else ("no" if not yes else "partly")
    parts = ([f"yes - {', '.join(yes)}"] if yes else []) + ([f"no - {', '.join(no)}"]
                                                            if no else [])
    return f"{verdict}: " + "; ".join(parts)


def write_outputs(result: dict[str, Any], *, json_path: str | os.PathLike | None,
                  plot_path: str | os.PathLike | None, rrd_path: str | os.PathLike | None,
                  plot: Callable[[str | os.PathLike], None],
                  trajectory: Callable[[], Trajectory], application_id: str,
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
    trajectory : callable ``() -> Trajectory``
        Builds the run logged to the ``.rrd`` (only called when ``rrd_path`` is given).
    application_id : str
        Rerun application id.
    **rrd_kwargs
        Passed to :func:`testbed.viz.write_rrd` (``model``, ``degrees``).
    """
    if json_path:
        from testbed.io import write_json

        write_json(json_path, result)
    if plot_path:
        plot(plot_path)
    if rrd_path:
        from testbed.viz import write_rrd

        write_rrd(trajectory(), rrd_path, application_id=application_id, **rrd_kwargs)
