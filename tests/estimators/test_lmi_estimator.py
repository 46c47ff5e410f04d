"""The generic lmi-hinf design (testbed.estimators.stochastic_system): the error-block form's
assumption, detectability, named when it fails."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from filters.lmi_hinf import StochasticLinearSystem
from testbed.estimators.stochastic_system import undetectable_modes, verified_estimator


def test_an_undetectable_unstable_mode_is_named():
    """The error block's assumption: (A, C_y) detectable. An integrator the measurement does
    not see is refused with the mode named (the skip reason of testbed score)."""
    A = np.array([[1.0, 0.0], [0.0, 0.5]])
    s = StochasticLinearSystem(A=A, B=np.eye(2), C_y=np.array([[0.0, 1.0]]),
                               C_z=np.eye(1, 2), D_y=np.ones((1, 2)))
    assert undetectable_modes(A, s.C_y) == [1.0]
    assert undetectable_modes(A, np.array([[1.0, 0.0]])) == []
    design = SimpleNamespace(x0=np.zeros(2), dt_s=0.01)
    with pytest.raises(ValueError, match=r"needs \(F, H\) detectable.*'1'"):
        verified_estimator(s, design, gamma=None, gamma_factor=5.0, objective="h2-unique",
                           input_matrix=None, feedthrough=None, plant_block=False)
