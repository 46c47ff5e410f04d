"""Every output option writes its file whatever form its path takes: relative, absolute,
through ``..``, through a symlink; alone and together; from another working directory; and
"wrote X" is said only once X is in place (issue 37, the output-path table)."""

from __future__ import annotations

from pathlib import Path

import pytest

from testbed.cli import main

#: (command line before the output option, option, file name) for each output option.
OUTPUTS = [
    (["run", "helicopter", "--duration", "0.3"], "--json", "o.json"),
    (["run", "helicopter", "--duration", "0.3"], "--plot", "o.png"),
    (["run", "helicopter", "--duration", "0.3"], "--rrd", "o.rrd"),
    (["run", "helicopter", "--duration", "0.3"], "--save-log", "o.csv"),
    (["run", "helicopter", "--duration", "0.3"], "--save-scenario", "o.toml"),
    (["mc", "helicopter", "--runs", "2", "--duration", "0.3"], "--save-npz", "o.npz"),
    (["mc", "helicopter", "--runs", "2", "--duration", "0.3"], "--plot", "o.png"),
    (["describe", "vehicle-roll"], "--json", "o.json"),
]
FORMS = ["relative", "absolute", "dotdot", "symlink"]


def _path(form: str, base: Path, name: str) -> tuple[str, Path]:
    """The path as typed (from the working directory ``base / 'cwd'``) and where the file
    must appear."""
    out = base / "out"
    out.mkdir(exist_ok=True)
    if form == "relative":
        return f"../out/{name}", out / name
    if form == "absolute":
        return str(out / name), out / name
    if form == "dotdot":
        (base / "cwd" / "sub").mkdir(exist_ok=True)
        return f"sub/../../out/{name}", out / name
    link = base / "cwd" / "link"
    if not link.exists():
        link.symlink_to(out, target_is_directory=True)
    return f"link/{name}", out / name


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("argv, option, name", OUTPUTS,
                         ids=[f"{a[0]}{o}" for a, o, _ in OUTPUTS])
def test_each_output_option_in_each_path_form(tmp_path, monkeypatch, capsys, argv, option,
                                              name, form):
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    typed, final = _path(form, tmp_path, name)
    assert main([*argv, option, typed, "--no-progress"] if argv[0] != "describe"
                else [*argv, option, typed]) == 0
    assert final.is_file() and final.stat().st_size > 0
    out = capsys.readouterr().out
    assert f"wrote {typed}" in out or f"wrote {final}" in out
    leftovers = [p for p in (tmp_path / "out").iterdir() if p.name.startswith(".")]
    assert not leftovers  # no temporary left behind
    if form == "dotdot":
        assert (tmp_path / "cwd" / "sub").is_dir()  # made by the test, not removed


def test_every_output_together_from_another_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "helicopter", "--duration", "0.3", "--json", "a/o.json", "--plot",
                 "a/o.png", "--rrd", "b/o.rrd", "--save-log", "b/../c/o.npz",
                 "--no-progress"]) == 0
    for path in ("a/o.json", "a/o.png", "b/o.rrd", "c/o.npz"):
        assert (tmp_path / path).is_file(), path
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("wrote")]
    assert len(lines) == 4  # said once each, after they are all in place


def test_nothing_is_said_or_left_when_an_output_cannot_be_written(tmp_path, monkeypatch,
                                                                 capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("a file, not a directory")
    assert main(["run", "helicopter", "--duration", "0.3", "--json", "o.json", "--plot",
                 "file/o.png", "--no-progress"]) == 2
    assert "wrote" not in capsys.readouterr().out
    assert not (tmp_path / "o.json").exists()
    assert main(["run", "helicopter", "--duration", "0.3", "--json",
                 "nosuchdir/../o.json", "--no-progress"]) == 0
    assert (tmp_path / "o.json").is_file() and not (tmp_path / "nosuchdir").exists()
