"""docs/cli_reference.md is what scripts/cli_reference.py makes from the current parser."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

from testbed.cli import build_parser
from testbed.cli.parser import COMMANDS

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def module():
    spec = importlib.util.spec_from_file_location("cli_reference",
                                                  ROOT / "scripts" / "cli_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def page(module) -> str:
    return module.render(build_parser())


def test_the_reference_is_current(module, page):
    assert module.REFERENCE == ROOT / "docs" / "cli_reference.md"
    assert module.REFERENCE.read_text() == page, (
        "docs/cli_reference.md is stale: run python scripts/cli_reference.py")
    assert module.main(["--check"]) == 0


def test_every_command_and_option_is_listed_with_its_help(page):
    headings = re.findall(r"^## `testbed ?([a-z-]*)`$", page, re.M)
    assert headings == ["", *COMMANDS]
    sections = dict(zip(headings, re.split(r"^## .*$", page, flags=re.M)[1:], strict=True))
    parser = build_parser()
    subparsers = next(a for a in parser._actions if a.nargs == "A...").choices
    for name, command in [("", parser), *subparsers.items()]:
        for action in command._actions:
            if action.option_strings and action.dest != "help":
                assert f"`{action.option_strings[0]}" in sections[name], (name, action.dest)
    run = sections["run"]
    row = next(line for line in run.splitlines() if line.startswith("| `--filter FILTER`"))
    assert "| `kalman` |" in row and "package.module:factory" in row  # deferred default
    assert re.search(r"^\| `--duration DURATION` \| `20.0` \| simulated seconds", run, re.M)


def test_a_changed_parser_makes_the_file_stale(module, page):
    """A new option (or command) changes the page: the check above then fails."""
    parser = build_parser()
    subparsers = next(a for a in parser._actions if a.nargs == "A...")
    subparsers.choices["run"].add_argument("--brand-new", metavar="X", help="a new option")
    changed = module.render(parser)
    assert changed != page and "| `--brand-new X` |  | a new option |" in changed
    subparsers.add_parser("extra", help="a new command").add_argument("--flag", default=3)
    assert "| [`extra`](#testbed-extra) | a new command |" in module.render(parser)


def test_table_cells_escape_markdown(module):
    assert module._cell("a | b <c> 2**63 x_y\n  z") == "a \\| b &lt;c&gt; 2\\*\\*63 x\\_y z"
