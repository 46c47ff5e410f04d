"""The parameter mismatch of a matched (augmented) design: derivatives of its discrete model.

A paper design's mismatch is the derivative of the rig's linearization ``A`` (continuous,
the rig's own states; :class:`testbed.rigs.params.ParameterMismatch`). A matched design
(:func:`testbed.design.build_matched_design`) has states the linearization does not have
(rotor lags, sensor biases, whole-sample delays) and a discrete model that is not the ZOH
of its continuous one on the delay rows. Its mismatch is therefore taken on the discrete
model itself: the rig rebuilt at ``params.scaled({p_i: 1 +- step})`` (its profile and rig
options), its design model rebuilt for the same sensors and period, and ``dF/ds_i`` by
central differences of the rebuilt designs' ``F``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: Relative agreement of the design rebuilt at the nominal parameters with the design
#: (the rebuild must be the same model, not one with other design options).
REBUILD_RTOL = 1e-9


@dataclass(frozen=True, eq=False)
class MatchedMismatch:
    """A matched design's declared parameter-mismatch range and how to rebuild the design.

    Kept in ``DesignModel.extras["matched_mismatch"]`` by
    :func:`testbed.design.build_matched_design` (the rig class, its nominal parameters and
    the sensors: no MuJoCo model).

    Attributes
    ----------
    mismatch : testbed.rigs.params.ParameterMismatch
        The rig's range (fields and relative half-ranges ``r_i``), nominal parameters,
        profile and options.
    sensors : testbed.sensors.Sensor
        The design's sensors (the rebuilt designs have the same channels and states).
    dt_s : float
        Control period, s.
    """

    mismatch: Any
    sensors: Any
    dt_s: float

    @property
    def ranges(self) -> dict[str, float]:
        """``{field: r_i}``, the rig's declared range."""
        return dict(self.mismatch.ranges)

    def rebuilt_F(self, scales: dict[str, float] | None = None) -> np.ndarray:
        """``F`` of the design model rebuilt with the fields scaled by ``scales``.

        Parameters
        ----------
        scales : dict, optional
            ``{field: factor}`` (None: the nominal parameters).

        Returns
        -------
        ndarray, shape (n, n)
        """
        rig = self.mismatch.rebuilt(scales)
        return np.asarray(rig.design_model(self.sensors, self.dt_s).discrete.F, float)

    def discrete_derivatives(self, F: np.ndarray, step: float = 1e-3
                             ) -> dict[str, np.ndarray]:
        """``dF/ds_i`` at ``s = 1`` for each field of the range, central differences.

        Parameters
        ----------
        F : ndarray, shape (n, n)
            The design's discrete state matrix: the design rebuilt at the nominal parameters
            must reproduce it (to :data:`REBUILD_RTOL`).
        step : float
            Relative step of the scale factors, in (0, 0.5).

        Returns
        -------
        dict
            ``{field: ndarray (n, n)}`` in the order of the range.

        Raises
        ------
        ValueError
            A bad step, or the rebuilt nominal design differs from ``F`` (other design
            options than the defaults the rebuild uses).
        """
        if not (np.isfinite(step) and 0 < step < 0.5):
            raise ValueError(f"step must be in (0, 0.5), got {step}")
        F = np.asarray(F, float)
        nominal = self.rebuilt_F()
        if nominal.shape != F.shape or not np.allclose(nominal, F, rtol=REBUILD_RTOL,
                                                       atol=REBUILD_RTOL * np.abs(F).max()):
            raise ValueError("the matched design rebuilt at the nominal parameters differs "
                             "from this design (design options the rebuild does not know): "
                             "its mismatch derivatives would be of another model")
        out = {}
        for name in self.mismatch.ranges:
            plus, minus = (self.rebuilt_F({name: 1.0 + sign * step}) for sign in (1.0, -1.0))
            out[name] = (plus - minus) / (2.0 * step)
        return out
