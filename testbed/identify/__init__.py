"""Recordings -> a twin of the user's rig: identification, the twin file, comparison.

:func:`identify` fits a rig's declared identifiable parameters (:attr:`Rig.identifiable`)
and its sensor model to a :class:`~testbed.io.recording.Recording`; :func:`write_twin`
keeps the result as a twin file, which :func:`read_twin` reads back for the rest of the
project (:meth:`Twin.params_scales`, :meth:`Twin.params`); :func:`compare` simulates a rig or
a twin with a recording's inputs and scores the fit; :func:`plot_identification` and
:func:`plot_compare` draw them.
"""

from testbed.identify.channels import IdentificationError
from testbed.identify.comparison import compare, compare_json
from testbed.identify.fit import identify
from testbed.identify.plots import plot_compare, plot_identification
from testbed.identify.result import Identification, ParameterEstimate, fit_percent
from testbed.identify.simulate import simulate_recording
from testbed.identify.twin import Twin, TwinError, read_twin, write_twin

__all__ = ["Identification", "IdentificationError", "ParameterEstimate", "Twin", "TwinError",
           "compare", "compare_json", "fit_percent", "identify", "plot_compare",
           "plot_identification", "read_twin", "simulate_recording", "write_twin"]
