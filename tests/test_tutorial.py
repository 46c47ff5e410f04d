"""docs/tutorial.ipynb runs from top to bottom and shows what it says it shows; every page of
docs/ is in the site's table of contents (``make docs`` fails on an orphan page)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "docs" / "tutorial.ipynb"


def _text(cell) -> str:
    out = []
    for output in cell.get("outputs", []):
        if output["output_type"] == "stream":
            out.append(output["text"])
        elif output["output_type"] in ("execute_result", "display_data"):
            out.append(output["data"].get("text/plain", ""))
    return "".join(out)


def test_the_tutorial_runs_and_reads_the_verdicts(tmp_path):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    assert not any(cell.get("outputs") for cell in notebook.cells if cell.cell_type == "code"), (
        "commit the tutorial without outputs (make docs executes it)")
    client = nbclient.NotebookClient(notebook, timeout=300, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # raises CellExecutionError naming the cell on any error
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    run, score, verdicts, recording = (_text(code[i]) for i in (1, 2, 3, 4))
    assert re.search(r"^pitch +ours [\d.]+ deg +built-in kalman [\d.]+ deg$", run, re.M)
    assert "mean NEES: ours" in run
    assert "steady_kalman" in score and "kalman" in score
    for entry in ("calibration", "helicopter"):
        assert re.search(rf"^{entry}: NEES (consistent|overconfident|underconfident|"
                         rf"inconclusive)", verdicts, re.M)
    assert re.search(r"vs kalman: (better|worse|equivalent|inconclusive)", verdicts)
    assert "state/pitch/estimate" in recording
    assert (tmp_path / "runs" / "tutorial.rrd").stat().st_size > 0
    assert (tmp_path / "runs" / "tutorial.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert any("image/png" in output.get("data", {}) for output in code[4].outputs)


def test_every_page_is_in_the_table_of_contents():
    index = (ROOT / "docs" / "index.md").read_text()
    listed = set()
    for block in re.findall(r"```\{toctree\}\n(.*?)```", index, re.S):
        listed |= {line.strip() for line in block.splitlines()
                   if line.strip() and not line.startswith(":")}
    pages = {p.stem for p in (ROOT / "docs").glob("*.md")} | {NOTEBOOK.stem}
    assert pages - {"index"} == listed, "add the page to a toctree of docs/index.md"
