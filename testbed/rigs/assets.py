"""Locate the MJCF files in ``models/`` from a checkout or from an installed wheel."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

_CHECKOUT_MODELS = Path(__file__).resolve().parents[2] / "models"


def model_path(file_name: str) -> Path:
    """Path of an MJCF file shipped in ``models/``.

    In a checkout (or an editable install) the top-level ``models/`` directory is used; in
    an installed wheel the files are package data of ``testbed.models``.

    Parameters
    ----------
    file_name : str
        File name such as ``"helicopter_2dof.xml"``.

    Returns
    -------
    Path
        Existing path of the file.
    """
    candidate = _CHECKOUT_MODELS / file_name
    if candidate.is_file():
        return candidate
    packaged = Path(str(resources.files("testbed.models").joinpath(file_name)))
    if packaged.is_file():
        return packaged
    raise FileNotFoundError(f"MJCF model {file_name!r} not found in {_CHECKOUT_MODELS} "
                            "nor in the installed package data testbed.models")
