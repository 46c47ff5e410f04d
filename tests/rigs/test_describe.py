"""describe_rig: a rig's inputs, sensor channels per profile and preset, options, identifiable
parameters and states, checked against the rig itself; format_description's tables."""

from __future__ import annotations

import dataclasses
import json

import pytest

from testbed.rigs.base import RigOption
from testbed.rigs.describe import (
    describe_rig,
    format_description,
    parameter_unit,
    sensor_channels,
)
from testbed.rigs.helicopter.hardware import HelicopterHardware
from testbed.rigs.helicopter.rig import SENSOR_PRESETS, HelicopterParams, HelicopterRig
from testbed.rigs.linear_plant.rig import LinearPlantParams, LinearPlantRig


class OptionPlant(LinearPlantRig):
    """A calibration plant declaring options and identifiable parameters (test only)."""

    name = "option-plant"
    rig_options = {"locked": RigOption(False, "clamp the cart"),
                   "spring": RigOption("soft", "which spring is fitted",
                                       choices=("soft", "hard"))}
    identifiable = {"stiffness_n_m": (0.5, 2.0), "damping_n_s_m": (0.1, 10.0)}


def test_helicopter_inputs_channels_and_states_match_the_rig():
    d = describe_rig("helicopter")
    assert d["name"] == "helicopter" and d["class"].endswith(":HelicopterRig")
    assert [s["name"] for s in d["states"]] == list(HelicopterRig.state_names)
    assert [s["unit"] for s in d["states"]] == list(HelicopterRig.state_units)
    assert list(d["profiles"]) == ["paper", "hardware"]
    limits = {"paper": (24.0, 24.0), "hardware": HelicopterHardware().voltage_limit_v}
    for profile, entry in d["profiles"].items():
        rig = HelicopterRig(profile=profile)
        assert [i["name"] for i in entry["inputs"]] == ["V_pitch", "V_yaw"]
        assert [i["unit"] for i in entry["inputs"]] == ["V", "V"]
        assert [i["high"] for i in entry["inputs"]] == list(limits[profile])
        assert [i["low"] for i in entry["inputs"]] == [-v for v in limits[profile]]
        assert list(entry["sensors"]) == list(SENSOR_PRESETS)
        for preset in SENSOR_PRESETS:
            suite = rig.sensors(preset)
            assert [(c["name"], c["unit"]) for c in entry["sensors"][preset]["channels"]] == \
                list(zip(suite.names, suite.units, strict=True))
    assert d["profiles"]["paper"]["default_sensors"] == "encoders"
    assert d["profiles"]["hardware"]["default_sensors"] == "hardware"
    json.dumps(d, allow_nan=False)  # JSON-ready


def test_one_profile_and_the_union_of_channels():
    d = describe_rig(HelicopterRig, profile="hardware")
    assert list(d["profiles"]) == ["hardware"]
    channels = sensor_channels("helicopter")
    assert {"pitch", "yaw", "pitch_rate", "gyro_pitch", "accel_x"} <= set(channels)
    assert channels["accel_x"] == "m/s^2" and channels["gyro_yaw"] == "rad/s"
    with pytest.raises(ValueError, match="unknown profile 'wind'.*'paper', 'hardware'"):
        describe_rig("helicopter", profile="wind")


def test_options_and_identifiable_parameters():
    d = describe_rig(OptionPlant, options={"spring": "hard"})
    assert d["options"] == [
        {"name": "locked", "type": "bool", "default": False, "help": "clamp the cart",
         "choices": [], "value": False},
        {"name": "spring", "type": "str", "default": "soft", "help": "which spring is fitted",
         "choices": ["soft", "hard"], "value": "hard"}]
    nominal = LinearPlantParams()
    by_field = {p["field"]: p for p in d["identifiable"]}
    assert list(by_field) == ["stiffness_n_m", "damping_n_s_m"]
    k = by_field["stiffness_n_m"]
    assert k["nominal"] == nominal.stiffness_n_m and k["unit"] == "N/m"
    assert (k["low"], k["high"]) == (0.5 * nominal.stiffness_n_m, 2.0 * nominal.stiffness_n_m)
    assert by_field["damping_n_s_m"]["unit"] == "N s/m"
    with pytest.raises(ValueError, match="no option 'colour'"):
        describe_rig(OptionPlant, options={"colour": 1})
    with pytest.raises(ValueError, match="must be one of"):
        describe_rig(OptionPlant, options={"spring": "rubber"})


def test_parameter_units_from_metadata_docstring_or_name():
    assert parameter_unit(HelicopterParams, "pitch_damping") == "N m s/rad"
    assert parameter_unit(HelicopterParams, "K_yp") == "N m/V"  # a grouped entry
    assert parameter_unit(HelicopterParams, "pitch_inertia") == "kg m^2"
    assert parameter_unit(HelicopterParams, "mass_kg") == "kg"  # the name's ending
    assert parameter_unit(LinearPlantParams, "stiffness_n_m") == "N/m"  # the doc wins

    @dataclasses.dataclass(frozen=True)
    class Tagged:
        """Attributes
        ----------
        gain : float
            A gain, furlongs.
        """

        gain: float = dataclasses.field(default=1.0, metadata={"unit": "V/A"})
        other: float = 2.0

    assert parameter_unit(Tagged, "gain") == "V/A"
    assert parameter_unit(Tagged, "other") == ""


def test_format_description_tables():
    text = format_description(describe_rig(OptionPlant))
    lines = text.splitlines()
    assert lines[0].startswith("rig option-plant (") and lines[0].endswith(":OptionPlant)")
    inputs = lines.index("profile paper: inputs")
    header, rule, row = lines[inputs + 1:inputs + 4]
    assert header.split() == ["name", "unit", "low", "high"]
    assert row.split() == ["force", "N", "-100", "100"]
    for word in ("unit", "low", "high"):  # columns aligned under their headers
        assert row[header.index(word)] != " " and row[header.index(word) - 1] == " "
    assert set(rule.replace(" ", "")) == {"-"}
    options = "\n".join(lines[lines.index("options (--rig-option NAME=VALUE)"):])
    assert "locked" in options and "clamp the cart" in options and "soft, hard" in options
    ident = lines[lines.index("identifiable parameters (bounds: low..high, as factors of "
                              "nominal)") + 3]
    assert ident.split()[:3] == ["stiffness_n_m", f"{LinearPlantParams().stiffness_n_m:.6g}",
                                 "N/m"] and ident.endswith("0.5..2")
    heli = format_description(describe_rig("helicopter"))
    assert "accel_x" in heli and "m/s^2" in heli and "none" in heli  # no options declared
