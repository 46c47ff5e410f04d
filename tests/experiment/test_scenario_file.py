"""Experiments as files (``--scenario``, ``--save-scenario``, the JSON's ``scenario`` block)
and the command-line conventions (``--version``, ``python -m testbed``, completion, progress
bars only on a terminal)."""

from __future__ import annotations

import inspect
import json
import os
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import tomli_w

from testbed.cli import main
from testbed.experiment import runner

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "docs" / "examples").glob("*.toml"))


def _read(path: Path) -> dict:
    return json.loads(path.read_text())


def _as_toml(block: dict, path: Path) -> Path:
    path.write_text(tomli_w.dumps(block))
    return path


def _header(path: Path, prefix: str) -> list[str]:
    """The command of a ``# PREFIX testbed ...`` line of an example file, as argv."""
    for line in path.read_text().splitlines():
        if line.startswith(f"# {prefix}testbed "):
            return shlex.split(line[len(f"# {prefix}testbed "):])
    raise AssertionError(f"{path.name} has no '# {prefix}testbed ...' line")


def test_run_json_scenario_block_as_toml_reproduces_the_run_bitwise(tmp_path):
    first, again = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["run", "helicopter", "--duration", "0.5", "--seed", "3", "--process-noise",
                 "0.2", "--param", "mass_kg=1.05", "--json", str(first), "--no-progress"]) == 0
    data = _read(first)
    assert set(data) >= {"scenario", "meta", "units"} and "config" not in data
    assert data["meta"]["sensors"] and "scenario" not in data["meta"]
    toml = _as_toml(data["scenario"], tmp_path / "s.toml")
    assert main(["run", "--scenario", str(toml), "--json", str(again), "--no-progress"]) == 0
    redo = _read(again)
    assert redo["rmse"] == data["rmse"] and redo["nees_mean"] == data["nees_mean"]
    assert redo["scenario"] == data["scenario"]
    # the block as JSON, unchanged, is a scenario file too
    block_json = tmp_path / "s.json"
    block_json.write_text(json.dumps(data["scenario"]))
    assert main(["run", "--scenario", str(block_json), "--json", str(again)]) == 0
    assert _read(again)["rmse"] == data["rmse"]


def test_mc_json_scenario_block_reproduces_the_study_bitwise(tmp_path):
    first, again = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["mc", "vehicle-roll", "--runs", "3", "--duration", "0.4", "--seed", "5",
                 "--filter", "lmi-hinf", "--json", str(first)]) == 0
    data = _read(first)
    assert set(data) >= {"scenario", "meta", "units"}
    toml = _as_toml(data["scenario"], tmp_path / "s.toml")
    assert main(["mc", "--scenario", str(toml), "--runs", "3", "--json", str(again)]) == 0
    redo = _read(again)
    assert redo["rmse_per_run"] == data["rmse_per_run"] and redo["seeds"] == data["seeds"]
    assert redo["scenario"] == data["scenario"]


def test_sweep_json_scenario_block_reproduces_the_sweep_bitwise(tmp_path):
    first, again = tmp_path / "a.json", tmp_path / "b.json"
    grid = ["--grid", "process_noise=0,0.3", "--runs", "2", "--workers", "1"]
    assert main(["sweep", "helicopter", "--duration", "0.3", "--seed", "1", *grid,
                 "--json", str(first)]) == 0
    data = _read(first)
    assert set(data) >= {"scenario", "units", "grid", "runs"}
    toml = _as_toml(data["scenario"], tmp_path / "s.toml")
    assert main(["sweep", "--scenario", str(toml), *grid, "--json", str(again)]) == 0
    redo = _read(again)
    assert [p["result"]["rmse_per_run"] for p in redo["points"]] == [
        p["result"]["rmse_per_run"] for p in data["points"]]
    assert redo["scenario"] == data["scenario"]


def test_only_the_options_typed_override_the_file(tmp_path):
    source = tmp_path / "s.toml"
    source.write_text('rig = "helicopter"\nduration_s = 0.3\nseed = 5\nprocess_noise = 0.1\n'
                      '[params]\nmass_kg = 1.1\n[study]\nruns = 4\n')
    saved = tmp_path / "out.toml"
    # mc's default --duration (10 s) and --runs (100) do not override the file
    assert main(["mc", "--scenario", str(source), "--save-scenario", str(saved)]) == 0
    out = tomllib.loads(saved.read_text())
    assert out["duration_s"] == 0.3 and out["seed"] == 5 and out["study"] == {"runs": 4}
    assert out["params"] == {"mass_kg": 1.1} and out["process_noise"] == 0.1
    assert main(["mc", "--scenario", str(source), "--seed", "7", "--runs", "6",
                 "--param", "pitch_damping=1.2", "--filter", "kalman-bucy",
                 "--save-scenario", str(saved)]) == 0
    out = tomllib.loads(saved.read_text())
    assert out["seed"] == 7 and out["duration_s"] == 0.3 and out["study"] == {"runs": 6}
    assert out["params"] == {"mass_kg": 1.1, "pitch_damping": 1.2}
    assert out["estimator"] == "kalman-bucy"
    # a key the file leaves out takes the command's default (mc: 10 s)
    source.write_text('rig = "helicopter"\n')
    assert main(["mc", "--scenario", str(source), "--save-scenario", str(saved)]) == 0
    assert tomllib.loads(saved.read_text())["duration_s"] == 10.0
    # --save-scenario runs nothing: no other file appears
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.toml", "s.toml"]


@pytest.mark.parametrize("text, key", [
    ('rig = "helicopter"\ndurations = 3\n', "durations"),
    ('rig = "helicopter"\nseed = "1"\n', "seed"),
    ('rig = "helicopter"\nduration_s = true\n', "duration_s"),
    ('rig = "helicopter"\nparams = 3\n', "params"),
    ('rig = "helicopter"\n[study]\nruns = 0\n', "study.runs"),
    ('rig = "vehicle-roll"\nprocess_noise = 1.0\n', "process_noise"),
    ('rig = "vehicle-roll"\n[design_options]\nprocess_noise_floor = 1.0\n', "design_options"),
    ('rig = "helicopter"\nmanoeuvre = "step-steer"\n', "manoeuvre"),
    ('rig = "nope"\n', "rig"),
    ('rig = "helicopter"\nduration_s = 5000.0\n', "duration_s"),
    ('rig = "helicopter\n', "not valid TOML"),
    ('rig = "helicopter"\n[study]\ngrid = {nope = [1.0]}\n', "study.grid"),
])
def test_bad_files_are_one_line_errors_naming_the_file_and_the_key(tmp_path, capsys, text,
                                                                    key):
    source = tmp_path / "bad.toml"
    source.write_text(text)
    out = tmp_path / "r.json"
    command = "sweep" if "grid" in text else "mc"
    assert main([command, "--scenario", str(source), "--runs", "2", "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"testbed: error: {source}: {key}"), err
    assert not out.exists()


def test_a_typed_option_is_named_as_the_flag_not_the_file(tmp_path, capsys):
    source = tmp_path / "s.toml"
    source.write_text('rig = "vehicle-roll"\n')
    assert main(["run", "--scenario", str(source), "--process-noise", "1"]) == 2
    assert capsys.readouterr().err.startswith("testbed: error: --process-noise: ")
    assert main(["run"]) == 2
    assert "--scenario FILE" in capsys.readouterr().err
    assert main(["run", "helicopter", "--save-scenario", str(tmp_path / "s.yaml")]) == 2
    assert "--save-scenario" in capsys.readouterr().err


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_every_example_file_is_its_readme_command(path, tmp_path):
    """The file and the command of its ``# same as:`` line give the same scenario."""
    argv = _header(path, "same as: ")
    command = _header(path, "")
    assert command == [argv[0], "--scenario", f"docs/examples/{path.name}"]
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    assert main([*argv, "--save-scenario", str(a)]) == 0
    assert main([argv[0], "--scenario", str(path), "--save-scenario", str(b)]) == 0
    assert tomllib.loads(a.read_text()) == tomllib.loads(b.read_text())


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_every_example_file_runs(path, tmp_path):
    command = _header(path, "")[0]
    short = ["--duration", "0.2"] + (["--runs", "2"] if command in ("mc", "sweep") else [])
    workers = ["--workers", "1"] if command == "sweep" else []
    out = tmp_path / "r.json"
    assert main([command, "--scenario", str(path), *short, *workers, "--json", str(out)]) == 0
    data = _read(out)
    assert data["scenario"]["duration_s"] == 0.2 and data["units"]


def _testbed(*argv: str, **kwargs) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    return subprocess.run([sys.executable, "-m", "testbed", *argv], cwd=ROOT, env=env,
                          text=True, **kwargs)


def test_version_and_python_dash_m(capsys):
    from testbed import __version__

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"testbed {__version__}"
    done = _testbed("--version", capture_output=True)
    assert done.returncode == 0 and done.stdout.strip() == f"testbed {__version__}"


@pytest.mark.parametrize("shell", ["bash", "zsh"])
def test_shell_completion_is_generated(shell, capsys):
    pytest.importorskip("shtab")
    with pytest.raises(SystemExit) as exc:
        main(["--print-completion", shell])
    out = capsys.readouterr().out
    assert exc.value.code == 0 and "testbed" in out and "--scenario" in out


def test_no_progress_bar_off_a_terminal(tmp_path):
    """``testbed mc ... 2> err.txt`` leaves no carriage return; the library draws no bar
    unless asked."""
    err = tmp_path / "err.txt"
    with err.open("w") as f:
        done = _testbed("mc", "helicopter", "--runs", "3", "--duration", "0.5",
                        stdout=subprocess.PIPE, stderr=f)
    assert done.returncode == 0, err.read_text()
    assert "\r" not in err.read_text()
    for function in (runner.run, runner.monte_carlo, runner.sweep):
        assert inspect.signature(function).parameters["progress"].default is False


def test_the_cli_guide_toml_snippet_is_its_example_file():
    import re

    guide = (ROOT / "docs" / "cli.md").read_text()
    snippet = re.search(r"```toml\n(.*?)```", guide, re.S).group(1)
    example = ROOT / "docs" / "examples" / "helicopter_kalman.toml"
    assert f"`docs/examples/{example.name}`" in guide
    assert tomllib.loads(snippet) == tomllib.loads(example.read_text())


def test_units_in_the_reproduce_json(tmp_path):
    from testbed.reproductions.outputs import DIMENSIONLESS, write_outputs

    out = tmp_path / "r.json"
    assert main(["reproduce", "basin-ms-hinf-helicopter", "--horizon", "1", "--json",
                 str(out)]) == 0
    assert _read(out)["units"]["final_error"] == "rad"
    result = {"x": 1.0}
    write_outputs(result, json_path=tmp_path / "d.json", plot_path=None, rrd_path=None,
                  plot=lambda path: None, application_id="t")
    assert _read(tmp_path / "d.json")["units"] == DIMENSIONLESS == result["units"]
