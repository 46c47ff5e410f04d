"""The README's commands are valid command lines, and its numbers come from them."""

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
