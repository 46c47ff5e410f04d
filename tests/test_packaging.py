"""The distribution ``robust-estimator-testbed``: its wheel ships every package found by
setuptools' discovery, every module and the MJCF of the top-level ``models/`` (as
``testbed/models``), with the ``testbed`` command; ``pip install .`` and the wheel work in a
clean virtual environment."""

from __future__ import annotations

import email.parser
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DIST = "robust-estimator-testbed"


def _source_copy(tmp_path: Path) -> Path:
    """The files a build reads, copied (so that the build's ``build/`` and ``*.egg-info``
    do not land in the checkout); ``testbed/models`` stays a link to ``models/``."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in ("testbed", "filters", "models"):
        shutil.copytree(ROOT / name, src / name, symlinks=True, ignore=ignore)
    return src


def _build_wheel(tmp_path: Path) -> Path:
    """A wheel built offline from a copy of the checkout (no build isolation: the test
    environment's setuptools)."""
    out = tmp_path / "wheel"
    env = {**os.environ, "PIP_NO_INDEX": "1"}
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                    "--quiet", "-w", str(out), str(_source_copy(tmp_path))], check=True,
                   capture_output=True, env=env)
    (wheel,) = out.glob("*.whl")
    return wheel


def _packages() -> list[str]:
    """Every package directory of the checkout (an ``__init__.py``), as a dotted name."""
    found = []
    for top in ("testbed", "filters"):
        for init in sorted((ROOT / top).rglob("__init__.py")):
            found.append(".".join(init.parent.relative_to(ROOT).parts))
    return found


def test_wheel_ships_every_package_module_model_and_the_command(tmp_path):
    wheel = _build_wheel(tmp_path)
    assert wheel.name == "robust_estimator_testbed-0.1.0-py3-none-any.whl"
    archive = zipfile.ZipFile(wheel)
    names = set(archive.namelist())
    packages = _packages()
    assert {"testbed", "filters", "testbed.cli", "testbed.score.report"} <= set(packages)
    for package in packages:  # discovery found every package directory
        assert package.replace(".", "/") + "/__init__.py" in names, package
    for source in sorted((ROOT / "testbed").rglob("*.py")) + sorted(
            (ROOT / "filters").rglob("*.py")):
        assert source.relative_to(ROOT).as_posix() in names, source
    xmls = sorted((ROOT / "models").glob("*.xml"))
    assert len(xmls) == 4  # helicopter, aero, vehicle roll, the calibration plant
    assert sorted(n for n in names if n.startswith("testbed/models/")) == [
        f"testbed/models/{x.name}" for x in xmls]
    assert not any(n.startswith(("tests/", "docs/", "models/", "scripts/")) for n in names)

    info = "robust_estimator_testbed-0.1.0.dist-info"
    meta = email.parser.Parser().parsestr(archive.read(f"{info}/METADATA").decode())
    assert meta["Name"] == DIST and meta["Version"] == "0.1.0"
    requires = [r.split(";")[0] for r in meta.get_all("Requires-Dist")]
    assert any(r.startswith("mujoco") for r in requires)
    assert any(r.startswith("gymnasium") for r in requires)
    entry_points = archive.read(f"{info}/entry_points.txt").decode()
    assert "[console_scripts]\ntestbed = testbed.cli.entry:main" in entry_points
    assert archive.read(f"{info}/top_level.txt").decode().split() == ["filters", "testbed"]


def test_checkout_models_load_from_the_top_level_folder():
    """From a checkout, the built-in rigs read ``models/*.xml`` (what ``python -m
    mujoco.viewer --mjcf=models/vehicle_roll.xml`` opens); ``testbed/models`` is a link to
    it, through which the wheel ships it."""
    from testbed.rigs import resolve_rig
    from testbed.rigs.linear_plant.rig import LinearPlantRig

    assert (ROOT / "testbed" / "models").resolve() == ROOT / "models"
    for rig in [resolve_rig("helicopter"), resolve_rig("vehicle-roll"), LinearPlantRig]:
        assert rig.resolved_xml_path().parent == ROOT / "models", rig


_CHECK = ("import importlib, importlib.metadata as md, pkgutil, testbed, filters, mujoco;"
          "from testbed.rigs.helicopter import HelicopterRig as H;"
          "from testbed.rigs.vehicle_roll import VehicleRollRig as V;"
          "from testbed.rigs.linear_plant.rig import LinearPlantRig as L;"
          "assert all('clean' in str(r.resolved_xml_path()) for r in (H, V, L));"
          "[r() for r in (V, L)];"
          "[importlib.import_module(m.name) for pkg in (testbed, filters) for m in "
          "pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.')];"  # every module ships
          f"print(md.version('{DIST}'), mujoco.MjModel.from_xml_path("
          "str(H.resolved_xml_path())).nq)")


def _clean_venv(path: Path) -> Path:
    """A new virtual environment, without its own pip and setuptools, whose only extra path
    is this one's site-packages (the run-time dependencies, pip and setuptools; no ``.pth``
    of it runs, so this checkout's editable install is not seen)."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(path)], check=True,
                   capture_output=True)
    python = path / "bin" / "python"
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()"
                           "['purelib'])"], check=True, capture_output=True, text=True)
    Path(site.stdout.strip(), "dependencies.pth").write_text(
        sysconfig.get_paths()["purelib"] + "\n")
    return python


@pytest.mark.slow
@pytest.mark.parametrize("what", ["wheel", "source"])
def test_pip_install_in_a_clean_venv(tmp_path, what):
    """``pip install WHEEL`` and ``pip install .`` (offline) into a clean venv: the command
    runs, every module imports and the rigs load their MJCF from the installed copy."""
    target = _build_wheel(tmp_path) if what == "wheel" else _source_copy(tmp_path)
    python = _clean_venv(tmp_path / "clean")
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "PIP_NO_INDEX": "1",
           "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    subprocess.run([str(python), "-m", "pip", "install", "--no-deps", "--no-build-isolation",
                    "--quiet", str(target)], check=True, capture_output=True, env=env)
    version = subprocess.run([str(python.parent / "testbed"), "--version"], check=True,
                             capture_output=True, text=True, env=env, cwd=tmp_path)
    assert version.stdout.split() == ["testbed", "0.1.0"]
    result = subprocess.run([str(python), "-c", _CHECK], cwd=tmp_path, check=True,
                            capture_output=True, text=True, env=env)
    assert result.stdout.split() == ["0.1.0", "2"]
