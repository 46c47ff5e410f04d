"""Old names kept for one release: a call warns and runs the renamed function."""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import Any


def deprecated_alias(new: Callable[..., Any], old_name: str) -> Callable[..., Any]:
    """``new`` under its old name ``old_name``: each call warns (``DeprecationWarning``).

    Parameters
    ----------
    new : callable
        The renamed function.
    old_name : str
        The name it had (kept for one release).

    Returns
    -------
    callable
        A function of ``new``'s signature that warns, then returns ``new(...)``.
    """
    target = f"{new.__module__}.{new.__qualname__}"

    @functools.wraps(new)
    def alias(*args: Any, **kwargs: Any) -> Any:
        warnings.warn(f"{old_name} is deprecated (removed in the next release); use {target}",
                      DeprecationWarning, stacklevel=2)
        return new(*args, **kwargs)

    alias.__name__ = alias.__qualname__ = old_name
    alias.__doc__ = f"Deprecated alias of :func:`{target}` (removed in the next release)."
    return alias
