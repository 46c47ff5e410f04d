"""Display units: angles in degrees at the edges (plots, Rerun, tables), SI inside.

Units come from the rig's declarations (``Trajectory.meta["units"]``, the ``units`` map of
every JSON output); nothing is guessed from a name.
"""

from __future__ import annotations

import math

#: SI angular units and their display form.
_DEGREES = {"rad": "deg", "rad/s": "deg/s", "rad/s^2": "deg/s^2", "rad/s2": "deg/s^2"}


def display(unit: str | None, degrees: bool = True) -> tuple[float, str]:
    """Factor and unit for showing a value given in ``unit``.

    Parameters
    ----------
    unit : str or None
        The declared unit (``""`` or None: dimensionless or unknown).
    degrees : bool
        Show angles (rad, rad/s, rad/s^2) in degrees.

    Returns
    -------
    factor : float
        Multiply the SI value by it.
    shown : str
        The unit to print (``""`` when there is none).
    """
    unit = unit or ""
    if degrees and unit in _DEGREES:
        return math.degrees(1.0), _DEGREES[unit]
    return 1.0, unit


def label(name: str, unit: str) -> str:
    """``"name [unit]"``, or ``name`` alone without a unit."""
    return f"{name} [{unit}]" if unit else name
