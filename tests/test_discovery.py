"""Rigs, estimators and suites of installed packages through entry points
(:mod:`testbed.discovery`): a fake distribution (a ``*.dist-info`` with ``entry_points.txt``
on ``sys.path``) adds a rig, an estimator and a suite that are listed and usable by name."""

from __future__ import annotations

import shutil
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from testbed import discovery, estimators, plugins
from testbed.cli import main
from testbed.experiment import runner
from testbed.experiment.scenario import Scenario
from testbed.rigs import RIGS, resolve_rig, rig_names
from testbed.score import suite

PENDULUM_XML = Path(__file__).resolve().parents[1] / "docs" / "examples" / "pendulum" / \
    "pendulum.xml"
MODULE = "fake_testbed_plugin"

PLUGIN = '''
from dataclasses import dataclass

from testbed.estimators import kalman
from testbed.rigs.base import Params, Rig
from testbed.score.suite import calibration_entry
from testbed.sensors import StateChannel, Suite, WhiteNoise


@dataclass(frozen=True)
class SwingParams(Params):
    mass_kg: float = 1.0
    damping: float = 0.05


class SwingRig(Rig):
    name = "fake-swing"
    xml_path = "pendulum.xml"
    params_type = SwingParams
    joints = ("hinge",)
    state_names = ("angle", "angle_rate")
    state_units = ("rad", "rad/s")
    action_names = ("torque",)
    action_units = ("N m",)
    action_low, action_high = (-5.0,), (5.0,)
    tracked_states = ("angle",)

    def apply_params(self, model, params):
        model.body_mass[self.body_id("arm")] = params.mass_kg
        model.dof_damping[self.dof_adr[0]] = params.damping

    def sensors(self, preset=None, *, dt_s=0.01):
        return Suite(WhiteNoise(StateChannel(0, 2, 1, "angle", "rad"), std=1e-3))


calls = []


def make(design, **options):
    calls.append(options)
    return kalman(design, **options)


def tiny():
    return [calibration_entry(runs=4, duration_s=0.5, worst_case=None)]


tiny.version = 3
'''

ENTRY_POINTS = f'''
[testbed.rigs]
fake-swing = {MODULE}:SwingRig
misnamed = {MODULE}:SwingRig

[testbed.estimators]
fake-kf = {MODULE}:make
broken-kf = fake_testbed_missing_module:make
kalman = {MODULE}:make

[testbed.suites]
fake-suite = {MODULE}:tiny
'''


@pytest.fixture
def installed(tmp_path, monkeypatch):
    """The fake distribution ``fake-testbed-plugin`` on ``sys.path`` (the module, its MJCF
    and its ``.dist-info``), removed after the test."""
    (tmp_path / f"{MODULE}.py").write_text(textwrap.dedent(PLUGIN))
    shutil.copy(PENDULUM_XML, tmp_path / "pendulum.xml")
    info = tmp_path / "fake_testbed_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-testbed-plugin\n"
                                   "Version: 0.1\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(discovery, "_loaded", {})
    yield tmp_path
    sys.modules.pop(MODULE, None)


def test_listed_without_importing(installed):
    assert discovery.names("rig") == ["fake-swing", "misnamed"]
    assert "fake-swing" in rig_names() and rig_names()[:len(RIGS)] == list(RIGS)
    assert estimators.names()[:len(estimators.ESTIMATORS)] == list(estimators.ESTIMATORS)
    assert {"fake-kf", "broken-kf"} <= set(estimators.names())
    assert estimators.names().count("kalman") == 1  # the built-in name wins
    assert suite.suite_names() == ["quick", "standard", "fake-suite"]
    assert MODULE not in sys.modules  # listing imports nothing


def test_rig_and_estimator_usable_by_name(installed):
    rig = resolve_rig("fake-swing")
    assert rig.__name__ == "SwingRig" and rig.__module__ == MODULE
    assert estimators.resolve("kalman") is estimators.ESTIMATORS["kalman"]
    sc = Scenario(rig="fake-swing", estimator="fake-kf", duration_s=0.5, seed=1)
    traj, summary = runner.run(sc, progress=False)
    calls = sys.modules[MODULE].calls
    assert len(calls) == 1
    # the same numbers as the built-in Kalman filter on the same rig and seed
    ref, ref_summary = runner.run(sc.replace(estimator="kalman"), progress=False)
    np.testing.assert_array_equal(traj.estimate, ref.estimate)
    assert summary["rmse"] == ref_summary["rmse"]
    assert main(["run", "fake-swing", "--filter", "fake-kf", "--duration", "0.2",
                 "--no-progress"]) == 0


def test_suite_usable_by_name(installed, capsys):
    entries = suite.get_suite("fake-suite")
    assert [e.name for e in entries] == ["calibration"] and entries[0].runs == 4
    identity = suite.suite_identity("fake-suite")
    assert identity["version"] == 3 and len(identity["hash"]) == 64
    assert main(["score", "--suite", "fake-suite", "--filter", "fake-kf", "--no-worst-case",
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "fake-kf" in out and "calibration" in out


def test_failures_name_the_entry_point(installed):
    with pytest.raises(plugins.PluginError) as err:
        estimators.resolve("broken-kf")
    message = str(err.value)
    assert "\n" not in message
    assert "entry point 'broken-kf = fake_testbed_missing_module:make' (group " \
        "testbed.estimators) failed while loading: ModuleNotFoundError" in message
    with pytest.raises(ValueError, match=r"entry point 'misnamed = .*the class's name is "
                                         r"'fake-swing'"):
        resolve_rig("misnamed")
    with pytest.raises(ValueError, match=r"unknown rig 'nope'; expected one of .*fake-swing"):
        resolve_rig("nope")
    with pytest.raises(ValueError, match=r"unknown filter 'nope'; expected one of .*fake-kf"):
        estimators.resolve("nope")
    with pytest.raises(ValueError, match=r"unknown suite 'nope'; expected one of .*fake-suite"):
        suite.get_suite("nope")
    assert main(["run", "fake-swing", "--filter", "broken-kf", "--duration", "0.2",
                 "--no-progress"]) == 2


def test_nothing_installed_changes_nothing():
    """Without the fake distribution the names are the built-in ones only."""
    assert "fake-swing" not in rig_names() and "fake-kf" not in estimators.names()
    assert suite.suite_names() == ["quick", "standard"]
    with pytest.raises(ValueError, match="kind must be one of"):
        discovery.names("sensor")
