"""The commands of the README and the docs are valid command lines, and their numbers come
from them (``scripts/readme_numbers.py``)."""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from testbed.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


#: Every file whose commands are checked: README.md and docs/*.md (the generated
#: docs/cli_reference.md shows usage lines in ``text`` blocks, which are not read here).
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


#: A word standing for a value: NAME, S, FILE.rrd (not HEAD_HOST:6379, a value itself).
_PLACEHOLDER = re.compile(r"[A-Z][A-Z_]*(?:\.[a-z]+)?")


def _commands(text: str) -> list[str]:
    """The ``testbed`` command lines of a Markdown text: in ``bash`` blocks and in inline code,
    leaving out templates (a placeholder word such as ``NAME``, ``S`` or ``FILE.rrd``,
    ``...``, ``[optional]``, ``<value>``) and lines ending in an option (a fragment)."""
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S) + re.findall(r"`(testbed [^`]+)`", text)
    out = []
    for block in blocks:
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split("#")[0].strip()
            words = line.split()
            template = (any(mark in line for mark in ("...", "[", "<"))
                        or any(_PLACEHOLDER.fullmatch(w) for w in words))
            if (line.startswith("testbed ") and len(words) >= 3 and not template
                    and not words[-1].startswith("--")):
                out.append(" ".join(words))
    return out


COMMANDS = [(doc.name, command) for doc in DOCS for command in _commands(doc.read_text())]


def test_the_docs_show_commands():
    assert len(_commands(ROOT.joinpath("README.md").read_text())) >= 10
    assert {"README.md", "cli.md", "scoring.md"} <= {doc for doc, _ in COMMANDS}


def test_commands_are_found_and_templates_left_out():
    text = ("```bash\ntestbed run helicopter \\\n    --seed 0   # comment\n"
            "testbed reproduce NAME --json x.json\ntestbed view FILE.rrd [--web]\n"
            "testbed mc --runs 1 --seed S\n```\n`testbed mc vehicle-roll --runs 3`, "
            "`testbed run --filter`")
    assert _commands(text) == ["testbed run helicopter --seed 0",
                               "testbed mc vehicle-roll --runs 3"]


@pytest.fixture(scope="module")
def parser():
    return build_parser()


@pytest.mark.parametrize("doc, command", COMMANDS, ids=[f"{d}:{c[:60]}" for d, c in COMMANDS])
def test_every_documented_command_parses(parser, doc, command):
    argv = shlex.split(command)[1:]
    if argv and argv[-1].startswith("mypkg"):
        pytest.skip("a user's package")
    try:
        parser.parse_args(argv)
    except SystemExit as exc:  # argparse error
        raise AssertionError(f"{doc}: command does not parse: {command}") from exc


@pytest.mark.slow
@pytest.mark.parametrize("coretype", [None, "Haswell"])
def test_readme_numbers_are_current(coretype):
    """``scripts/readme_numbers.py --check``: the blocks equal a fresh run of their commands
    (to the script's stated tolerance), with the native OpenBLAS kernel and with the Haswell
    kernel that some machines of this kind select."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    if coretype:
        env["OPENBLAS_CORETYPE"] = coretype
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "readme_numbers.py"),
                             "--check"], cwd=ROOT, env=env, capture_output=True, text=True)
    assert result.returncode == 0, (
        f"README numbers are stale (OPENBLAS_CORETYPE={coretype}): run "
        f"scripts/readme_numbers.py\n{result.stderr}")


def test_readme_check_tolerates_rounding_only():
    """The tolerance has teeth: a 1 % change of a number or any change of text fails."""
    spec = importlib.util.spec_from_file_location("readme_numbers",
                                                  ROOT / "scripts" / "readme_numbers.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.differences("| kalman | 0.04947 deg |", "| kalman | 0.04948 deg |") == []
    assert module.differences("| kalman | 0.04947 deg |", "| kalman | 0.04997 deg |")
    assert module.differences("| kalman | 0.04947 deg |", "| kalman | 0.04947 rad |")
    assert module.differences("1.94", "1.94e-3")
    # quantiles in parentheses to QTOL: one run's RMSE (the hardware helicopter's ukf)
    row = "| pitch | 0.01331 ({} / 0.02314) deg | 3.11 |"
    assert module.differences(row.format("0.009996"), row.format("0.01017")) == []
    assert module.differences(row.format("0.009996"), row.format("0.0105"))
    assert module.differences("| 0.01331 (0.01 / 0.02) |", "| 0.01345 (0.01 / 0.02) |")


def _readme_numbers():
    spec = importlib.util.spec_from_file_location("readme_numbers",
                                                  ROOT / "scripts" / "readme_numbers.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_numbers_blocks_are_found_in_any_doc():
    """Every block the script makes is in exactly one of README.md and docs/*.md."""
    module = _readme_numbers()
    files = module.doc_files()
    assert files[0] == ROOT / "README.md" and set(files[1:]) == set(DOCS[1:])
    where = module.find_blocks({path: path.read_text() for path in files})
    assert set(where) == set(module.BLOCKS)
    assert where["demo"] == ROOT / "README.md"


def test_numbers_block_errors_name_the_file_and_block(tmp_path):
    module = _readme_numbers()
    blocks = "".join(f"<!-- numbers:{n}:start -->\nx\n<!-- numbers:{n}:end -->\n"
                     for n in module.BLOCKS)
    a, b = tmp_path / "a.md", tmp_path / "b.md"
    assert set(module.find_blocks({a: blocks, b: "no blocks"}).values()) == {a}
    with pytest.raises(ValueError, match=r"b.md: numbers:demo: block also in .*a.md"):
        module.find_blocks({a: blocks, b: "<!-- numbers:demo:start -->"})
    with pytest.raises(ValueError, match="numbers:nope: no such block"):
        module.find_blocks({a: blocks + "<!-- numbers:nope:start -->"})
    with pytest.raises(ValueError, match="no file has the numbers block.* demo"):
        module.find_blocks({a: blocks.replace("numbers:demo:", "")})
    with pytest.raises(ValueError, match="no numbers:demo block"):
        module.render("text", ["demo"])
