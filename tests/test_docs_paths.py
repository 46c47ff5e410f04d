"""Every repository path and every module the README and the docs name exists."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: A repository path in backticks: models/..., testbed/..., docs/...; Gymnasium ids
#: (``testbed/Name-v0``) are not paths.
PATH = re.compile(r"`((?:models|testbed|filters|docs|scripts|tests|examples)/[A-Za-z0-9_./*-]+)`")
GYM_ID = re.compile(r"^testbed/[A-Z][A-Za-z0-9]+-v\d+$")
#: A module or attribute in backticks: testbed.x.y, filters.x.
MODULE = re.compile(r"`((?:testbed|filters)(?:\.[A-Za-z_][A-Za-z0-9_]*)+)`")
#: Markdown links to local files.
LINK = re.compile(r"\]\(([^)#:\s]+)(?:#[^)]*)?\)")


def _mentions(pattern: re.Pattern) -> list[tuple[str, str]]:
    return sorted({(doc.name, m) for doc in DOCS for m in pattern.findall(doc.read_text())})


def test_the_docs_name_paths_at_all():
    assert len(_mentions(PATH)) >= 10 and len(_mentions(MODULE)) >= 10


@pytest.mark.parametrize("doc, path", [m for m in _mentions(PATH) if not GYM_ID.match(m[1])])
def test_every_path_exists(doc, path):
    matches = list(ROOT.glob(path.rstrip("/"))) if "*" in path else [ROOT / path]
    assert matches and all(p.exists() for p in matches), f"{doc} names {path}, which is missing"


@pytest.mark.parametrize("doc, name", _mentions(MODULE))
def test_every_module_or_attribute_imports(doc, name):
    parts = name.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            assert hasattr(obj, attr), f"{doc} names {name}: {attr!r} not found"
            obj = getattr(obj, attr)
        return
    raise AssertionError(f"{doc} names {name}, which does not import")


@pytest.mark.parametrize("doc, target", [m for m in _mentions(LINK)])
def test_every_local_link_resolves(doc, target):
    base = ROOT if doc == "README.md" else ROOT / "docs"
    assert (base / target).exists(), f"{doc} links to {target}, which is missing"


#: Every ``python`` block of the README and the docs, run alone in a fresh interpreter from
#: ``docs/examples`` on ``PYTHONPATH`` (where docs/extending.md says its modules live).
SNIPPETS = [(doc.name, i, block) for doc in DOCS
            for i, block in enumerate(re.findall(r"```python\n(.*?)```", doc.read_text(), re.S))]


def test_the_docs_have_snippets():
    assert len(SNIPPETS) >= 4


@pytest.mark.parametrize("doc, index, code", SNIPPETS,
                         ids=[f"{d}-{i}" for d, i, _ in SNIPPETS])
def test_every_snippet_runs_when_pasted_alone(doc, index, code, tmp_path):
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT / "docs" / "examples"), str(ROOT), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, f"{doc} snippet {index}:\n{result.stderr[-2000:]}"
