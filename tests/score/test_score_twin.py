"""``testbed score --twin``: the suite's entries of the twin's rig with its parameters, or a
one-line refusal naming the entries of another rig."""

from __future__ import annotations

import pytest

from testbed.cli import main
from testbed.rigs.aero.rig import AeroParams
from testbed.score import harness
from testbed.score.suite import get_suite

STIFFNESS = 2.2 * AeroParams().pitch_stiffness


def _twin(path, identifiable: bool = True):
    nominal = AeroParams().pitch_stiffness
    path.write_text(f"""format = "testbed-twin"
format_version = 1
rig = "aero"
profile = "hardware"
method = "output-error"
segment_s = 30.0
dt_s = 0.01

[options]
yaw_locked = true

[parameters.pitch_stiffness]
value = {STIFFNESS!r}
nominal = {nominal!r}
identifiable = {str(identifiable).lower()}
ci95 = [{0.99 * STIFFNESS!r}, {1.01 * STIFFNESS!r}]
""")
    return path


def test_the_entries_of_the_twin_rig_with_its_parameters_and_options(tmp_path):
    twin = _twin(tmp_path / "twin.toml")
    suite = get_suite("standard")
    aero = [e for e in suite if e.scenario.rig == "aero"]
    assert aero and len(aero) < len(suite)
    entries = harness.twin_entries(suite, twin, "standard")
    assert [e.name for e in entries] == [e.name for e in aero]
    for before, after in zip(aero, entries, strict=True):
        assert after.scenario.nominal_params == {**before.scenario.nominal_params,
                                                 "pitch_stiffness": STIFFNESS}
        assert after.scenario.rig_options == before.scenario.rig_options  # its own setting
        assert after.scenario.params == before.scenario.params  # an entry's mismatch on top
        assert str(twin) in after.description
        after.scenario.check()  # a valid scenario
    # a parameter the recording did not determine stays at nominal
    held = harness.twin_entries(suite, _twin(tmp_path / "held.toml", False), "standard")
    assert all(e.scenario.nominal_params == a.scenario.nominal_params
               for e, a in zip(held, aero, strict=True))


def test_refused_in_one_line_naming_the_entries_of_another_rig(tmp_path, capsys):
    twin = _twin(tmp_path / "twin.toml")
    suite = get_suite("standard")
    chosen = [e for e in suite if e.name in ("aero", "helicopter", "vehicle-dlc")]
    with pytest.raises(ValueError, match=r"the entries \['helicopter', 'vehicle-dlc'\] are "
                                         "of another rig"):
        harness.twin_entries(chosen, twin, "standard", selected=True)
    with pytest.raises(ValueError, match="suite 'quick' has no entry of rig 'aero'"):
        harness.twin_entries(get_suite("quick"), twin, "quick")
    assert main(["score", "--estimator", "kalman", "--suite", "standard", "--twin", str(twin),
                 "--scenario", "aero", "--scenario", "helicopter", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "['helicopter']" in err and "rig 'aero'" in err
    assert main(["score", "--estimator", "kalman", "--twin", str(tmp_path / "none.toml")]) == 2
    assert "no such twin file" in capsys.readouterr().err


def test_score_on_a_twin_simulates_and_designs_with_its_parameters(tmp_path):
    from testbed.score import report

    twin = _twin(tmp_path / "twin.toml")
    run = harness.score(["kalman"], "standard", scenarios=["aero"], runs=2, worst_case=False,
                        twin=twin)
    summary = report.results(run)
    (block,) = summary["scenarios"]
    assert block["scenario"]["nominal_params"] == {"pitch_stiffness": STIFFNESS}
    assert str(twin) in block["description"]
    (row,) = summary["results"]
    assert row["scenario"] == "aero" and row["rmse"]["pitch"] > 0
