"""A rig's construction options (``--rig-option NAME=VALUE``): their declaration and parsing,
and the call that builds a rig with them (:func:`build_rig`)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np


@dataclasses.dataclass(frozen=True)
class RigOption:
    """A rig's construction option (``--rig-option NAME=VALUE``, the scenario's
    ``rig_options``), e.g. the Aero's ``yaw_locked``.

    Attributes
    ----------
    default : bool, int, float or str
        The value when not given; its type is the option's type.
    help : str
        One line for ``testbed describe`` and ``--help``.
    choices : tuple, optional
        The allowed values (empty: any of the type).
    """

    default: bool | int | float | str
    help: str
    choices: tuple[Any, ...] = ()

    def parse(self, name: str, value: Any) -> Any:
        """``value`` (a Python value, or the text of ``NAME=VALUE``) as this option's type.

        Raises
        ------
        ValueError
            One line naming the option and what was expected.
        """
        kind = type(self.default)
        if isinstance(value, str) and kind is not str:
            text = value.strip().lower()
            try:
                if kind is bool:
                    if text not in ("true", "false", "1", "0", "yes", "no"):
                        raise ValueError
                    value = text in ("true", "1", "yes")
                else:
                    value = kind(text)
            except ValueError:
                raise ValueError(f"rig option {name!r} must be a {kind.__name__}, got "
                                 f"{value!r}") from None
        ok = isinstance(value, kind) and not (kind is not bool and isinstance(value, bool))
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value, ok = float(value), True
        if not ok or (kind is float and not np.isfinite(value)):
            raise ValueError(f"rig option {name!r} must be a {'finite ' if kind is float else ''}"
                             f"{kind.__name__}, got {value!r}")
        if self.choices and value not in self.choices:
            raise ValueError(f"rig option {name!r} must be one of {list(self.choices)}, got "
                             f"{value!r}")
        return value


def build_rig(rig_cls: type, params: Any = None, *, physics_dt_s: float = 0.001,
               profile: str = "paper", options: dict[str, Any] | None = None) -> Any:
    """``rig_cls(params, physics_dt_s=..., profile=...)``, with ``options=`` only when there are
    options (a rig class of a user's that predates rig options keeps working).

    Parameters
    ----------
    rig_cls : type
        A :class:`~testbed.rigs.base.Rig` subclass.
    params : testbed.rigs.params.Params, optional
        Its nominal parameters (default the class's).
    physics_dt_s : float
    profile : str
    options : dict, optional
        :attr:`~testbed.rigs.base.Rig.rig_options` values.
    """
    kwargs = {"options": dict(options)} if options else {}
    return rig_cls(params, physics_dt_s=physics_dt_s, profile=profile, **kwargs)
