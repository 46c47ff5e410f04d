"""An estimator's optional parts, read in one place (:mod:`testbed.estimators.optional`):
what it has, else the table's default; the members it lacks; and the typed checks that
replaced other probes (a rig class for the nonlinear family, a rig to register)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from filters import DiscreteLinearSystem, KalmanFilter
from filters.kalman import CovarianceMemo
from testbed.estimators import ChannelSelect, PerMember, optional
from testbed.estimators.nonlinear import MujocoRigType, nominal_rig
from testbed.rigs import RIGS, register_rig
from testbed.rigs.base import Rig
from testbed.rigs.helicopter.rig import HelicopterRig


class _Minimal:
    """x, reset and step only."""

    x = np.zeros(2)

    def reset(self, x0, P0):
        self.x = np.asarray(x0, float)

    def step(self, y, u=None):
        return self.x


class _Everything(_Minimal):
    P = np.eye(2)
    batched = True
    innovation, innovation_cov = np.ones(1), np.eye(1)
    design_meta = {"gamma": 2.0}
    channels = "all"
    shared_P = np.eye(2) * 3

    def __init__(self):
        self.primed, self.memo = [], None

    def prime(self, y):
        self.primed.append(y)

    def share_covariance_memo(self, memo):
        self.memo = memo


def test_an_estimator_without_the_optional_parts_gets_the_defaults():
    est = _Minimal()
    assert optional.covariance(est) is None and optional.is_batched(est) is False
    assert optional.innovations(est) == (None, None)
    assert optional.design_facts(est) is None and optional.requested_channels(est) is None
    assert optional.primer(est) is None and optional.shared_covariance(est) is None
    assert optional.share_covariance_memo(est, object()) is False
    assert optional.lacks(est) == []
    # every default is what the table says
    assert {k: v for k, v in optional.DEFAULTS.items() if k != "inner"} == {
        "P": None, "batched": False, "innovation": None, "innovation_cov": None,
        "design_meta": None, "channels": None, "prime": None, "shared_P": None,
        "share_covariance_memo": None}


def test_an_estimator_with_them_gets_its_own():
    est = _Everything()
    assert optional.covariance(est) is est.P and optional.is_batched(est) is True
    nu, S = optional.innovations(est)
    assert nu is est.innovation and S is est.innovation_cov
    assert optional.design_facts(est) == {"gamma": 2.0}
    assert optional.requested_channels(est) == "all"
    optional.primer(est)(np.ones(1))
    assert len(est.primed) == 1
    assert optional.shared_covariance(est) is est.shared_P
    memo = object()
    assert optional.share_covariance_memo(est, memo) is True and est.memo is memo


def test_a_wrapper_gives_its_inner_design_facts_and_shared_covariance():
    inner = _Everything()
    wrapped = ChannelSelect(inner, np.array([0]), 2)
    assert optional.design_facts(wrapped) == {"gamma": 2.0}
    assert optional.shared_covariance(wrapped) is inner.shared_P
    assert optional.shared_covariance(ChannelSelect(_Minimal(), np.array([0]), 2)) is None
    assert optional.is_batched(wrapped) is True


def test_lacks_names_the_missing_members_in_order():
    class NoStep:
        x = np.zeros(1)

    assert optional.lacks(NoStep()) == ["reset", "step"]
    assert optional.lacks(NoStep(), ("step",)) == ["step"]
    assert optional.lacks(lambda d: d, ("step",)) == ["step"]  # a factory, not an estimator
    assert optional.lacks(_Minimal, ("step",)) == []  # a class has its methods


def test_per_member_covariance_and_kalman_memo():
    system = DiscreteLinearSystem(F=np.eye(1), B=np.zeros((1, 1)), H=np.eye(1), D=np.zeros((1, 1)),
                                  Q=np.eye(1), R=np.eye(1), dt_s=0.1)
    kf = KalmanFilter(system, np.zeros(1), np.eye(1))
    assert optional.share_covariance_memo(kf, CovarianceMemo()) is True
    many = PerMember([_Minimal(), _Minimal()])
    assert optional.covariance(many) is None  # its members have none
    assert optional.is_batched(many) is True


def test_the_nonlinear_family_asks_for_a_mujoco_rig_class():
    assert issubclass(HelicopterRig, MujocoRigType)
    assert not issubclass(int, MujocoRigType)
    for rig_type in (None, int, "helicopter"):
        with pytest.raises(ValueError, match="names no rig"):
            nominal_rig(SimpleNamespace(extras={"rig_type": rig_type}))


def test_register_rig_takes_rig_subclasses_with_a_name():
    with pytest.raises(ValueError, match="expected a Rig subclass"):
        register_rig(int)
    with pytest.raises(ValueError, match="expected a Rig subclass"):
        register_rig("helicopter")

    class Nameless(Rig):
        pass

    with pytest.raises(ValueError, match=r"Nameless\.name must be a non-empty string"):
        register_rig(Nameless)
    assert "helicopter" in RIGS
