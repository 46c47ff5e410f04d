"""The README's commands are valid command lines, and its numbers come from them."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from testbed.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


def _commands() -> list[str]:
    text = ROOT.joinpath("README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S) + re.findall(r"`(testbed [^`]+)`", text)
    out = []
    for block in blocks:
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split("#")[0].strip()
            words = line.split()
            if (line.startswith("testbed ") and len(words) >= 3 and "..." not in line
                    and "NAME" not in line and not words[-1].startswith("--")):
                out.append(line)
    return out


def test_every_readme_command_parses():
    commands = _commands()
    assert len(commands) >= 10
    parser = build_parser()
    for command in commands:
        argv = shlex.split(command)[1:]
        if argv and argv[-1].startswith("mypkg"):
            continue
        try:
            parser.parse_args(argv)
        except SystemExit as exc:  # argparse error
            raise AssertionError(f"README command does not parse: {command}") from exc


@pytest.mark.slow
def test_readme_numbers_are_current():
    """``scripts/readme_numbers.py --check``: the blocks equal a fresh run of their commands."""
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "readme_numbers.py"),
                             "--check"], cwd=ROOT)
    assert result.returncode == 0, "README numbers are stale: run scripts/readme_numbers.py"
