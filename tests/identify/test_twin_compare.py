"""The twin file and the comparison: round trip, validation, and the twin compared on its
own recording giving the identification's fit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from identify_units import VEHICLE_FREE, vehicle_unit

from testbed.identify import (
    TwinError,
    compare,
    compare_json,
    identify,
    plot_compare,
    plot_identification,
    read_twin,
    write_twin,
)
from testbed.rigs.vehicle_roll.model import VehicleRollParams
from testbed.rigs.vehicle_roll.rig import VehicleRollRig


@pytest.fixture(scope="module")
def identified():
    rec, scales = vehicle_unit(4, duration_s=6.0)
    rec = dataclasses.replace(rec, sha256="ab" * 32, source="unit4.csv")
    return rec, scales, identify(VehicleRollRig, rec, free=list(VEHICLE_FREE), holdout=0.25)


def test_twin_round_trip(tmp_path, identified):
    rec, scales, res = identified
    path = write_twin(tmp_path / "twin.toml", res)
    assert not list(tmp_path.glob(".*.tmp"))  # written atomically
    twin = read_twin(path)
    assert twin.rig == "vehicle-roll" and twin.profile == "hardware"
    assert twin.recording_sha256 == "ab" * 32 and twin.method == res.method
    assert twin.fit_percent == pytest.approx(res.fit_percent)
    for name in VEHICLE_FREE:
        assert twin.parameters[name].value == res.parameters[name].value
        assert twin.parameters[name].ci95 == pytest.approx(res.parameters[name].ci95)
    # scales relative to the rig's nominal parameters, and the Params themselves
    assert twin.params_scales() == pytest.approx(res.params_scales())
    params = twin.params()
    assert isinstance(params, VehicleRollParams)
    assert params.roll_stiffness == res.parameters["roll_stiffness"].value
    assert params.sprung_mass_kg == VehicleRollParams().sprung_mass_kg  # not free: nominal
    assert twin.sensors["lateral_accel"]["delay_samples"] == \
        res.sensors["lateral_accel"]["delay_samples"]


def test_compare_of_the_twin_on_its_recording_gives_the_identify_fit(tmp_path, identified):
    rec, _, res = identified
    twin = read_twin(write_twin(tmp_path / "twin.toml", res))
    out = compare(twin, rec)
    assert out["source"] == "twin" and out["method"] == res.method
    for name, value in res.fit_percent.items():
        assert out["fit_percent"][name] == pytest.approx(value, abs=1e-9)
    for name, value in res.holdout_fit_percent.items():
        assert out["holdout_fit_percent"][name] == pytest.approx(value, abs=1e-9)
    nominal = compare("vehicle-roll", rec, holdout=0.25)
    assert nominal["source"] == "nominal"
    assert nominal["fit_percent"]["roll_rate"] < out["fit_percent"]["roll_rate"]
    doc = compare_json(out)
    assert "series" not in doc and doc["recording_sha256"] == rec.sha256
    a = plot_compare(out, tmp_path / "compare.png")
    b = plot_identification(res, tmp_path / "ident.png")
    for p in (a, b):
        assert p.stat().st_size > 10_000 and p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _write(tmp_path, text):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("edit, match", [
    (lambda s: s.replace('rig = "vehicle-roll"', 'rig = "submarine"'), "key 'rig'"),
    (lambda s: s.replace('profile = "hardware"', 'profile = "space"'), "key 'profile'"),
    (lambda s: s.replace("[parameters.roll_stiffness]", "[parameters.stiffness]"),
     "key 'parameters.stiffness' is not a parameter"),
    (lambda s: s.replace('format = "testbed-twin"', 'format = "other"'), "key 'format'"),
    (lambda s: s.replace('method = "', 'method = "x'), "key 'method'"),
    (lambda s: "\n".join(line for line in s.splitlines()
                         if not line.startswith("dt_s")), "missing key 'dt_s'"),
    (lambda s: s + "\n[[[", "not a readable TOML"),
])
def test_twin_errors_name_the_file_and_key(tmp_path, identified, edit, match):
    _, _, res = identified
    good = write_twin(tmp_path / "good.toml", res).read_text()
    path = _write(tmp_path, edit(good))
    with pytest.raises(TwinError, match=match) as info:
        read_twin(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_twin_needs_toml_and_an_existing_file(tmp_path, identified):
    _, _, res = identified
    with pytest.raises(TwinError, match=r"\.toml"):
        write_twin(tmp_path / "twin.json", res)
    with pytest.raises(TwinError, match="no such twin file"):
        read_twin(tmp_path / "missing.toml")
    assert np.isfinite(list(res.fit_percent.values())).all()
