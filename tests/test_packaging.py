"""The MJCF files of the top-level ``models/`` ship in the wheel (as ``testbed/models``) and
load from an installed copy."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_contains_models_and_loads_them(tmp_path):
    wheel_dir = tmp_path / "wheel"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                    "--quiet", "-w", str(wheel_dir), str(ROOT)], check=True,
                   capture_output=True)
    (wheel,) = wheel_dir.glob("testbed-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    xmls = sorted((ROOT / "models").glob("*.xml"))
    assert len(xmls) == 4  # helicopter, aero, vehicle roll, the calibration plant
    for xml in xmls:
        assert f"testbed/models/{xml.name}" in names, xml
    for source in sorted((ROOT / "testbed").rglob("*.py")) + sorted(
            (ROOT / "filters").rglob("*.py")):
        assert source.relative_to(ROOT).as_posix() in names, source
    assert any(n.startswith("filters/") for n in names)

    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet",
                    "--target", str(target), str(wheel)], check=True, capture_output=True)
    code = ("import importlib, pkgutil, testbed, filters, mujoco;"
            "from testbed.rigs.helicopter import HelicopterRig as H;"
            "from testbed.rigs.vehicle_roll import VehicleRollRig as V;"
            "from testbed.rigs.linear_plant.rig import LinearPlantRig as L;"
            "assert all('site' in str(r.resolved_xml_path()) for r in (V, L));"
            "[r() for r in (V, L)];"
            "[importlib.import_module(m.name) for pkg in (testbed, filters) for m in "
            "pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.')];"  # every module ships
            "p = H.resolved_xml_path(); assert 'site' in str(p), p;"
            "print(mujoco.MjModel.from_xml_path(str(p)).nq)")
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, check=True,
                            capture_output=True, text=True,
                            env={"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin"})
    assert result.stdout.strip() == "2"


def test_checkout_models_load_from_the_top_level_folder():
    """From a checkout, the built-in rigs read ``models/*.xml`` (what ``python -m
    mujoco.viewer --mjcf=models/vehicle_roll.xml`` opens)."""
    from testbed.rigs import resolve_rig
    from testbed.rigs.linear_plant.rig import LinearPlantRig

    for rig in [resolve_rig("helicopter"), resolve_rig("vehicle-roll"), LinearPlantRig]:
        assert rig.resolved_xml_path().parent == ROOT / "models", rig
