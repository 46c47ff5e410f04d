"""Bounded, regular inputs (issue 37, item 4): a scenario file is read only from a regular
file of at most ``MAX_FILE_BYTES`` with at most ``MAX_NESTING`` levels of arrays and tables;
anything else is exit 2 with one line naming the file, fast."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from testbed.cli import main
from testbed.experiment import scenario_file
from testbed.experiment.scenario_file import MAX_FILE_BYTES, MAX_NESTING, ScenarioFileError

ROOT = Path(__file__).resolve().parents[2]


def _fifo(tmp_path: Path) -> Path:
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs here")
    path = tmp_path / "pipe.toml"
    os.mkfifo(path)
    return path


def _nested_json(tmp_path: Path, depth: int) -> Path:
    path = tmp_path / f"nested{depth}.json"
    path.write_text('{"rig": "helicopter", "params": {"x": ' + "[" * depth + "]" * depth + "}}")
    return path


def _nested_toml(tmp_path: Path, depth: int) -> Path:
    path = tmp_path / f"nested{depth}.toml"
    path.write_text("rig = 'helicopter'\nparams = " + "{a = " * depth + "1" + "}" * depth
                    + "\n")
    return path


@pytest.mark.parametrize("make, needle", [
    (lambda tmp: Path("/dev/zero"), "a character device; the scenario file must be a regular file"),
    (lambda tmp: (tmp / "zero.toml").symlink_to("/dev/zero") or tmp / "zero.toml",
     "a character device; the scenario file must be a regular file"),
    (_fifo, "a FIFO; the scenario file must be a regular file"),
    (lambda tmp: tmp, "a directory; the scenario file must be a regular file"),
    (lambda tmp: _nested_json(tmp, 100_000), f"nested more than {MAX_NESTING} deep"),
    (lambda tmp: _nested_toml(tmp, 5_000), f"nested more than {MAX_NESTING} deep"),
    (lambda tmp: _nested_json(tmp, MAX_NESTING + 1), f"nested more than {MAX_NESTING} deep"),
])
def test_unbounded_or_irregular_scenario_files_are_refused_naming_the_file(tmp_path, make,
                                                                           needle):
    path = make(tmp_path)
    start = time.perf_counter()
    with pytest.raises(ScenarioFileError) as info:
        scenario_file.read(path)
    assert time.perf_counter() - start < 5.0
    message = str(info.value)
    assert message.startswith(f"{path}: ") and needle in message and "\n" not in message


def test_the_size_limit_is_stated_and_applied(tmp_path):
    assert MAX_FILE_BYTES == 1 << 20
    path = tmp_path / "big.toml"
    at_limit = "rig = 'helicopter'\n#"
    path.write_text(at_limit + "x" * (MAX_FILE_BYTES - len(at_limit) - 1) + "\n")
    assert path.stat().st_size == MAX_FILE_BYTES
    assert scenario_file.read(path).fields == {"rig": "helicopter"}  # the limit itself: read
    with path.open("a") as f:
        f.write("#")
    with pytest.raises(ScenarioFileError, match=f"larger than {MAX_FILE_BYTES:,} bytes"):
        scenario_file.read(path)


def test_nesting_at_the_limit_is_read(tmp_path):
    """A grid is 3 levels deep; the limit only stops files no scenario needs."""
    path = tmp_path / "ok.json"
    path.write_text('{"rig": "helicopter", "study": {"grid": {"process_noise": [0, 1]}}}')
    assert scenario_file.read(path).study["grid"] == [("process_noise", [0.0, 1.0])]
    assert scenario_file._depth([[[]]], 5) == 3 and scenario_file._depth(1, 5) == 0
    assert scenario_file._depth([[[[[[]]]]]], 2) == 3  # counted up to limit + 1 only


@pytest.mark.parametrize("kind", ["device", "symlink", "fifo", "nested-json", "nested-toml"])
def test_the_command_exits_2_naming_the_file(tmp_path, capsys, kind):
    path = {"device": lambda: Path("/dev/zero"),
            "symlink": lambda: (tmp_path / "z.toml").symlink_to("/dev/zero") or
            tmp_path / "z.toml",
            "fifo": lambda: _fifo(tmp_path),
            "nested-json": lambda: _nested_json(tmp_path, 100_000),
            "nested-toml": lambda: _nested_toml(tmp_path, 5_000)}[kind]()
    assert main(["run", "helicopter", "--scenario", str(path), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("testbed: error: ") and str(path) in err[0]


def test_a_fifo_with_no_writer_does_not_block_the_command(tmp_path):
    path = _fifo(tmp_path)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "testbed.cli", "run", "helicopter",
                           "--scenario", str(path)], capture_output=True, text=True,
                          timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 2 and "a FIFO" in done.stderr
    assert time.perf_counter() - start < 30  # the interpreter's start; the FIFO: at once
