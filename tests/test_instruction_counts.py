"""scripts/instruction_counts.py: its dump parsing, its argument check and (slow) a real count.

No assertion on the counts' values beyond their sanity: the env step executes more
instructions than the bare physics it contains, and every block has its own dump.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"
sys.path.insert(0, str(SCRIPTS))

import instruction_counts  # noqa: E402


def _dump(path: Path, trigger: str, summary: int) -> None:
    path.write_text(f"version: 1\ncreator: callgrind\ncmd: python\npart: 1\n"
                    f"desc: Trigger: Client Request: {trigger}\n\nevents: Ir\n"
                    f"summary: {summary}\n\nfn=(1) main\n0 {summary}\n")


def test_each_block_is_read_from_the_dump_its_trigger_names(tmp_path):
    for part, (name, count) in enumerate({"raw": 10, "env": 17, "vraw": 3, "venv": 9}.items()):
        _dump(tmp_path / f"cg.out.{part + 1}", name, count)
    _dump(tmp_path / "cg.out", "program-end", 99)  # the final dump is not a block
    assert instruction_counts._summaries(tmp_path) == {"raw": 10, "env": 17, "vraw": 3,
                                                       "venv": 9}


def test_steps_must_be_positive(capsys):
    with pytest.raises(SystemExit):
        instruction_counts.main(["--steps", "0"])
    assert "--steps must be a positive integer" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("valgrind") is None, reason="needs valgrind")
def test_a_short_count_gives_every_block_and_sane_ratios():
    result = instruction_counts.count(steps=5)
    assert set(result) >= {f"{b}_instructions" for b in instruction_counts.BLOCKS}
    assert result["env_overhead_instructions_ratio"] > 1
    assert result["env_vehicle_overhead_instructions_ratio"] > 1
