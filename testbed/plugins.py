"""User plug-ins (``--filter mod:make``, ``--rig mod:Class``, ``--estimator``): loading them and
naming their failures.

A plug-in is ``package.module:attribute`` (imported) or ``path/to/file.py:attribute`` (a file
loaded under a private module name). Whatever a plug-in raises while it is loaded or built,
including ``SystemExit``, becomes a :class:`PluginError` (a ``ValueError``: bad input, nothing
ran) naming the plug-in and the exception in one line; what an estimator raises while it runs
becomes :class:`EstimatorFailed` (a ``filters.FilterError``: a failure of the filter).
``KeyboardInterrupt`` and the CLI's SIGTERM pass through untouched.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import os
import sys
from typing import Any

from filters import FilterError

#: Exceptions of plug-in code that are failures of the plug-in (not interrupts).
PLUGIN_FAILURES = (Exception, SystemExit)


def describe(exc: BaseException) -> str:
    """``TypeName: message`` of an exception, on one line."""
    if isinstance(exc, SystemExit):
        text = f"SystemExit({exc.code!r})"
    else:
        message = " ".join(str(exc).split())
        text = f"{type(exc).__name__}: {message}" if message else type(exc).__name__
    return text


def factory_name(factory: Any) -> str:
    """How messages and results name an estimator or other plug-in given by name or object:
    the name itself (a string), a factory's ``__name__`` (a :class:`LabelledFactory`'s
    label), else its ``repr``."""
    if isinstance(factory, str):
        return factory
    return getattr(factory, "__name__", repr(factory))


class PluginError(ValueError):
    """A plug-in failed to load or to build (nothing ran): ``what`` names it (``--filter
    'mod:make'``), ``stage`` is ``"load"`` or ``"build"``."""

    def __init__(self, what: str, stage: str, cause: BaseException | str):
        self.what, self.stage = what, stage
        detail = cause if isinstance(cause, str) else describe(cause)
        super().__init__(f"{what} failed while {'loading' if stage == 'load' else 'building'}: "
                         f"{detail}")

    def __reduce__(self) -> tuple[Any, ...]:
        return (_rebuild_plugin_error, (self.what, self.stage, str(self)))


def _rebuild_plugin_error(what: str, stage: str, message: str) -> PluginError:
    err = PluginError.__new__(PluginError)
    ValueError.__init__(err, message)
    err.what, err.stage = what, stage
    return err


class EstimatorFailed(FilterError):
    """An estimator raised something other than a ``FilterError`` while it ran (a
    ``LinAlgError`` in its ``step``, a ``SystemExit``...): a failure of the filter, exit 3."""

    def __init__(self, message: str, time_s: float | None = None):
        self.time_s = time_s
        super().__init__(message)

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (str(self), self.time_s))


def is_file_spec(module: str) -> bool:
    """Whether the module part of ``module:attribute`` names a file (``x.py`` or a path)."""
    return module.endswith(".py") or os.sep in module or "/" in module


def _load_file(path: str) -> Any:
    """Import ``path`` (a ``.py`` file) under a private name; the same file gives the same
    module."""
    full = os.path.abspath(os.path.expanduser(path))
    if not os.path.isfile(full):
        raise ImportError(f"no such file {path!r}")
    digest = hashlib.sha1(full.encode()).hexdigest()[:12]
    name = f"testbed_plugin_{os.path.splitext(os.path.basename(full))[0]}_{digest}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, full)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path!r} as Python")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look the module up by name
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def load(spec: str, what: str) -> Any:
    """The object named by ``module:attribute`` or ``path/to/file.py:attribute``.

    Parameters
    ----------
    spec : str
    what : str
        How messages name it (``"--filter 'mod:make'"``).

    Raises
    ------
    PluginError
        The module does not import (any exception of its code, ``SystemExit`` included), or
        it has no such attribute.
    """
    module_name, sep, attr = spec.rpartition(":")
    if not sep or not module_name or not attr:
        raise PluginError(what, "load", f"expected 'module:attribute', got {spec!r}")
    try:
        if is_file_spec(module_name):
            module = _load_file(module_name)
        else:
            module = importlib.import_module(module_name)
    except ImportError as err:
        raise PluginError(what, "load", f"cannot import {module_name!r} ({err})") from None
    except PLUGIN_FAILURES as err:
        raise PluginError(what, "load", err) from None
    try:
        return getattr(module, attr)
    except AttributeError:
        raise PluginError(what, "load", f"module {module_name!r} has no {attr!r}") from None


def split_label(spec: str) -> tuple[str | None, str]:
    """``"LABEL=spec"`` -> ``("LABEL", "spec")``; a spec without a label -> ``(None, spec)``.

    Raises
    ------
    ValueError
        An empty label or spec (``"=x"``, ``"x="``).
    """
    label, sep, rest = spec.partition("=")
    if not sep:
        return None, spec
    label, rest = label.strip(), rest.strip()
    if not label or not rest:
        raise ValueError(f"expected LABEL=NAME_OR_MODULE:FACTORY, got {spec!r}")
    return label, rest


def default_label(spec: str, obj: Any) -> str:
    """A plug-in's short label: its ``name`` attribute (a string; a class's ``name`` class
    attribute counts), else ``file:attribute`` without the file's directories and ``.py``
    for a file plug-in, else the spec itself (``package.module:attribute``)."""
    name = getattr(obj, "name", None)
    if isinstance(name, str) and name.strip():
        return name.strip()
    module, sep, attr = spec.rpartition(":")
    if sep and is_file_spec(module):
        return f"{os.path.splitext(os.path.basename(module))[0]}:{attr}"
    return spec


class LabelledFactory:
    """A plug-in factory named by its spec, carrying a label (its ``__name__``).

    Calls, attributes (``paper_design_only``...) and the signature are the plug-in's (loaded
    on first use, :func:`load`); it pickles as its spec and label, so that worker processes
    load the plug-in themselves.

    Parameters
    ----------
    spec : str
        ``package.module:attribute`` or ``path/to/file.py:attribute``.
    label : str
    resolve : callable ``spec -> object``, optional
        How the spec is loaded (a module-level function, pickled by reference; default
        :func:`load`, naming failures as a filter's).
    """

    def __init__(self, spec: str, label: str, resolve: Any = None):
        self.spec, self.label, self.resolve = spec, label, resolve

    @property
    def __name__(self) -> str:  # noqa: PLW3201 - what the harness and messages read
        return self.label

    def target(self) -> Any:
        """The factory the spec names, loaded on first use (and kept)."""
        target = self.__dict__.get("_loaded")
        if target is None:
            target = (load(self.spec, f"filter {self.spec!r}") if self.resolve is None
                      else self.resolve(self.spec))
            self.__dict__["_loaded"] = target
        return target

    @property
    def __signature__(self) -> Any:  # noqa: PLW3201 - inspect.signature reads it
        import inspect

        try:
            return inspect.signature(self.target())
        except (TypeError, ValueError):
            return None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.target()(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("spec", "label", "resolve", "_loaded"):
            raise AttributeError(name)
        return getattr(self.target(), name)

    def __reduce__(self) -> tuple[Any, ...]:
        return (LabelledFactory, (self.spec, self.label, self.resolve))

    def __repr__(self) -> str:
        return f"{self.label}={self.spec}"
