"""Recordings -> a twin of the user's rig: identification, the twin file, comparison.

:func:`identify` fits a rig's declared identifiable parameters (:attr:`Rig.identifiable`)
and its sensor model to a :class:`~testbed.io.recording.Recording`;
:func:`~testbed.identify.twin.write_twin` keeps the result as a twin file, which
:func:`~testbed.identify.twin.read_twin` reads back for the rest of the project;
:func:`~testbed.identify.compare.compare` simulates a rig or a twin with a recording's
inputs and scores the fit.
"""

from testbed.identify.channels import IdentificationError
from testbed.identify.fit import Identification, ParameterEstimate, fit_percent, identify
from testbed.identify.simulate import simulate_recording

__all__ = ["Identification", "IdentificationError", "ParameterEstimate", "fit_percent",
           "identify", "simulate_recording"]
