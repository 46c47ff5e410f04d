"""The contracts are typed, not probed: ``getattr(`` / ``hasattr(`` in ``testbed/`` (comments
and docstrings included, as ``grep -rEo "getattr\\(|hasattr\\(" testbed`` counts them) stay
at most :data:`LIMIT`, half the count when the redesign asked for it (108)."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import testbed

#: At most this many probes in testbed/ (issue 41: 108 halved).
LIMIT = 54
PROBE = re.compile(r"getattr\(|hasattr\(")
PACKAGE = Path(testbed.__file__).resolve().parent


def probes(root: Path) -> Counter[str]:
    """Probes per file under ``root`` (text files; caches skipped), by path from ``root``."""
    out: Counter[str] = Counter()
    for path in sorted(root.rglob("*")):
        if not path.is_file() or "__pycache__" in path.parts:
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue  # a compiled helper, an image
        found = len(PROBE.findall(text))
        if found:
            out[str(path.relative_to(root.parent))] = found
    return out


def test_the_counter_counts_what_grep_counts(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text('x = getattr(o, "a", None)  # hasattr(o, "b")\n"""getattr(y"""\n')
    (pkg / "sub" / "b.py").write_text("ok = o.a\nsetattr(o, 'a', 1)\n_getattr = 1\n")
    (pkg / "sub" / "c.txt").write_text("hasattr(x, 'y') getattr (x)\n")
    (pkg / "__pycache__").mkdir()
    (pkg / "__pycache__" / "a.pyc").write_bytes(b"\x00\xffgetattr(")
    assert probes(pkg) == {"pkg/a.py": 3, "pkg/sub/c.txt": 1}


def test_probes_in_testbed_halved():
    found = probes(PACKAGE)
    total = sum(found.values())
    worst = ", ".join(f"{path} {n}" for path, n in found.most_common())
    assert total <= LIMIT, (f"{total} getattr/hasattr probes in testbed/ (at most {LIMIT}): "
                            f"declare the attribute on its contract and read it; {worst}")
