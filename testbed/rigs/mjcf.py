"""Where a rig's MJCF comes from: the built-in models' folder and the file read once per
process (a copy per rig: :meth:`testbed.rigs.base.Rig.__init__`)."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import mujoco


@functools.lru_cache(maxsize=16)
def read_mjcf(path: str, modified_ns: int, first_profile: bool) -> Any:
    """The MJCF file read once per process (and again when it changes on disk).

    A run builds several rigs of one class (the simulated rig, the designer's, the
    controller's); each gets a copy: ``first_profile`` the compiled model (deep-copied: the
    same bits as :meth:`mujoco.MjModel.from_xml_path`), otherwise the parsed spec, which the
    profile edits (:meth:`testbed.rigs.base.Rig.edit_spec`) before compiling.
    """
    del modified_ns  # part of the cache key only
    if first_profile:
        return mujoco.MjModel.from_xml_path(path)
    return mujoco.MjSpec.from_file(path)


def models_dir() -> Path:
    """The folder of the built-in rigs' MJCF models: the checkout's top-level ``models/``
    (``testbed/models`` links to it: the wheel ships it as ``testbed/models``), or
    ``testbed/models`` inside an installed wheel."""
    package = Path(__file__).resolve().parents[1]
    installed = package / "models"
    return installed.resolve() if installed.is_dir() else package.parent / "models"
