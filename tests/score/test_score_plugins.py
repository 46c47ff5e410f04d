"""Plug-ins first-class in ``testbed score``: short labels, ANIS and whiteness from the
optional innovation members, ``--filter`` (``--estimator`` its alias), progress lines."""

from __future__ import annotations

import inspect
import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from testbed import estimators, plugins
from testbed.cli import main

EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples"
FP_EKF = f"{EXAMPLES / 'fp_ekf.py'}:make"
USERKF = f"{EXAMPLES / 'userkf.py'}:make"


def test_labels_are_short_names_not_paths():
    assert estimators.label("kalman") == "kalman" and estimators.labelled("kalman") == "kalman"
    pytest.importorskip("filterpy")
    assert estimators.label(FP_EKF) == "fp-ekf"  # the class's name attribute
    assert estimators.label(USERKF) == "userkf:make"  # file:factory, no directories
    assert estimators.label(f"mine={USERKF}") == "mine"
    assert estimators.label("ref=ms-hinf") == "ref"
    with pytest.raises(ValueError, match="LABEL="):
        estimators.labelled(f"={USERKF}")
    with pytest.raises(ValueError, match="unknown filter"):
        estimators.labelled("mine=nope")


def test_a_labelled_factory_is_its_plug_in():
    lab = estimators.labelled(f"mine={USERKF}")
    assert isinstance(lab, plugins.LabelledFactory) and lab.__name__ == "mine"
    copy = pickle.loads(pickle.dumps(lab))  # workers load the plug-in themselves
    assert copy.__name__ == "mine" and copy.spec == lab.spec
    assert list(inspect.signature(lab).parameters) == ["design"]
    ms = estimators.labelled("ref=ms-hinf")
    # the family's declarations come through (the paper design only, its options)
    assert estimators.paper_design_only(ms) == estimators.paper_design_only("ms-hinf")
    with pytest.raises(ValueError, match="no option"):
        estimators.check_options(ms, "ref", {"nope": 1})


def test_per_member_stacks_the_instances_innovations():
    class One:
        def __init__(self, nu, S):
            self.x, self.P = np.zeros(2), np.eye(2)
            self.innovation, self.innovation_cov = nu, S

    nu = [np.array([1.0]), np.array([2.0])]
    S = [np.array([[3.0]]), np.array([[4.0]])]
    both = estimators.PerMember([One(nu[0], S[0]), One(nu[1], S[1])])
    np.testing.assert_array_equal(both.innovation, [[1.0], [2.0]])
    np.testing.assert_array_equal(both.innovation_cov, [[[3.0]], [[4.0]]])
    assert estimators.PerMember([One(None, None), One(nu[1], S[1])]).innovation is None


def test_the_protocol_is_one_place():
    from filters import KalmanFilter
    from filters.base import Batched, Estimator, Innovations, Named

    class Plain:
        x, P = np.zeros(1), None

        def reset(self, x0, P0):
            pass

        def step(self, y, u=None):
            return self.x

    assert isinstance(Plain(), Estimator)
    assert not isinstance(Plain(), Innovations) and not isinstance(Plain(), Named)
    assert not isinstance(object(), Estimator)
    design = _design()
    kf = KalmanFilter(design.discrete, design.x0, design.P0)
    assert isinstance(kf, Estimator) and isinstance(kf, Innovations) and isinstance(kf, Named)
    built = estimators.build("kalman", design)
    assert isinstance(built, Estimator) and isinstance(built, Batched)


def _design():
    from testbed.experiment import runner
    from testbed.experiment.scenario import Scenario

    exp = runner.build(Scenario(rig="vehicle-roll", estimator="kalman", duration_s=1), 1)
    try:
        return exp.design
    finally:
        exp.close()


def test_score_labels_plug_ins_and_reports_their_anis(tmp_path, capsys):
    pytest.importorskip("filterpy")
    out = tmp_path / "s.json"
    assert main(["score", "--filter", "kalman", "--estimator", FP_EKF, "--filter",
                 f"mine={USERKF}", "--suite", "quick", "--scenario", "calibration",
                 "--runs", "3", "--no-worst-case", "--json", str(out)]) == 0
    captured = capsys.readouterr()
    doc = json.loads(out.read_text())
    assert doc["estimators"] == ["kalman", "fp-ekf", "mine"]
    rows = {r["estimator"]: r for r in doc["results"]}
    # the plug-in with innovation members is scored like the built-in (the same filter)
    assert rows["fp-ekf"]["anis"] == pytest.approx(rows["kalman"]["anis"], rel=1e-6)
    assert rows["fp-ekf"]["whiteness"] is not None
    assert rows["mine"]["anis"] is None  # userkf has no innovation members
    assert str(EXAMPLES) not in captured.out  # no file paths in the table
    assert "fp-ekf" in captured.out
    # not a terminal: one line per entry with the count and the time left
    assert "scored calibration (1/1 entries" in captured.err and "left)" in captured.err
    assert "note: fp-ekf has no batched = True" in captured.err


def test_score_without_estimators_says_what_to_type(capsys):
    assert main(["score"]) == 2
    err = capsys.readouterr().err
    assert "--filter NAME" in err and "--estimator" in err and "kalman" in err
