"""Deprecated (removed in the next release): :mod:`testbed.estimators.stochastic_system`.

The old module path, kept for one release because ``docs/scoring.md`` names the plug-in
``testbed.estimators.lmi:ms_hinf_sampled``; importing it warns.
"""

from __future__ import annotations

import warnings

from testbed.estimators.stochastic_system import *  # noqa: F403

warnings.warn("testbed.estimators.lmi is deprecated (removed in the next release); use "
              "testbed.estimators.stochastic_system", DeprecationWarning, stacklevel=2)
