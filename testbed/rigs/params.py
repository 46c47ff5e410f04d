"""A rig's physical parameters: the :class:`Params` base (a frozen dataclass) and its scaling
for model-mismatch studies."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import numpy as np

from filters import real_array
from testbed.records import field_items, field_values
from testbed.rigs.options import build_rig

__all__ = ["ParameterMismatch", "Params", "scaled_copy"]

P = TypeVar("P")


def scaled_copy(params: P, scales: dict[str, Any]) -> P:
    """Copy of a parameter dataclass with fields multiplied by factors, then validated.

    Parameters
    ----------
    params : dataclass instance with a ``validate()`` method
    scales : dict
        ``{field_name: factor}``; factors must be finite and non-negative (0 only where the
        parameter may vanish: ``validate()`` decides).

    Raises
    ------
    ValueError
        Unknown field name (the valid ones are listed), a factor that is not a finite
        non-negative number, or an unphysical result (named by ``validate()``).
    """
    if not isinstance(scales, dict):
        raise ValueError(f"params must be a dict {{field: scale factor}}, got "
                         f"{type(scales).__name__}")
    values = field_values(params)
    names = set(values)
    changes = {}
    for key, factor in scales.items():
        if key not in names:
            raise ValueError(f"unknown params key {key!r}; expected one of {sorted(names)}")
        factor = float(real_array(factor, f"params[{key!r}] (scale factor)", shape=(),
                                  finite=False))
        if not np.isfinite(factor) or factor < 0.0:
            raise ValueError(f"params[{key!r}] must be a finite non-negative scale factor, "
                             f"got {factor}")
        value = values[key] * factor
        if not np.isfinite(value):
            raise ValueError(f"params[{key!r}] = {factor!r} scales {key} out of range "
                             f"({values[key]!r} x {factor!r} is not finite)")
        changes[key] = value
    out = dataclasses.replace(params, **changes)
    with np.errstate(over="raise", invalid="raise"):
        try:
            out.validate()
        except (OverflowError, FloatingPointError) as exc:
            given = ", ".join(f"{k}={v!r}" for k, v in scales.items())
            raise ValueError(f"params {given}: the scaled parameters are out of range "
                             f"({exc})") from None
    return out


@dataclasses.dataclass(frozen=True)
class Params:
    """Base of a rig's physical parameters: a frozen dataclass with scaling and validation."""

    def scaled(self, scales: dict[str, float] | None):
        """Copy with fields multiplied by factors (model-mismatch studies), validated.

        Raises
        ------
        ValueError
            Unknown field (the valid ones listed), a bad factor, or an unphysical result.
        """
        return scaled_copy(self, scales or {})

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first unphysical parameter (all must be finite)."""
        for f, value in field_items(self):
            if not np.isfinite(value):
                raise ValueError(f"{type(self).__name__}.{f.name} must be finite, got {value}")


@dataclasses.dataclass(frozen=True)
class ParameterMismatch:
    """A rig's declared parameter-mismatch range and the derivative of its linearization.

    Kept in ``DesignModel.extras["parameter_mismatch"]`` (picklable: the rig class and its
    nominal parameters, not a MuJoCo model); robust designs (``vc-discrete``,
    :mod:`testbed.estimators.vc`) turn it into a norm-bounded uncertainty.

    Attributes
    ----------
    rig_type : type
        The :class:`~testbed.rigs.base.Rig` subclass.
    params : Params
        The nominal parameters the designer knows.
    ranges : dict
        ``{Params field: relative half-range r}``: the truth may have the field scaled by
        any factor in ``[1 - r, 1 + r]`` (:attr:`testbed.rigs.base.Rig.mismatch_range`).
    physics_dt_s : float
    profile : str
    """

    rig_type: type
    params: Params
    ranges: dict[str, float]
    physics_dt_s: float = 0.001
    profile: str = "paper"
    options: dict[str, Any] = dataclasses.field(default_factory=dict)

    def rebuilt(self, scales: dict[str, float] | None = None) -> Any:
        """The rig rebuilt with its nominal parameters' fields scaled by ``scales`` (None: at
        the nominal parameters), of the same profile, options and physics step."""
        return build_rig(self.rig_type, self.params.scaled(scales or {}),
                         physics_dt_s=self.physics_dt_s, profile=self.profile,
                         options=self.options)

    def derivatives(self, step: float = 1e-3) -> dict[str, np.ndarray]:
        """``dA/ds_i`` of :meth:`testbed.rigs.base.Rig.linearize` with respect to the scale
        factor ``s_i`` of each field in :attr:`ranges`, at ``s = 1``.

        Central differences: rigs built at ``params.scaled({field: 1 +- step})``, each
        linearized at its own operating point and input (the scaled truth's equilibrium).

        Returns
        -------
        dict
            ``{field: ndarray (n, n)}`` in the order of :attr:`ranges`.
        """
        if not (np.isfinite(step) and 0 < step < 0.5):
            raise ValueError(f"step must be in (0, 0.5), got {step}")
        out = {}
        for name in self.ranges:
            A = [self.rebuilt({name: 1.0 + sign * step}).linearize()[0]
                 for sign in (1.0, -1.0)]
            out[name] = (A[0] - A[1]) / (2.0 * step)
        return out
