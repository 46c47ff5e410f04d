"""Sphinx configuration of the testbed's documentation (``make docs``).

The pages are the Markdown files of this folder (MyST), the tutorial notebook (MyST-NB), and
an API reference generated from the docstrings (autosummary + autodoc, numpydoc style) of
``filters`` and ``testbed``. ``make docs`` builds with warnings as errors (``-W``).
"""

from __future__ import annotations

import os
import sys
import types
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
# the Gymnasium ids register on import; no display is needed to import the outputs
os.environ.setdefault("MUJOCO_GL", "egl")

project = "testbed"
author = "testbed authors"
copyright = "testbed authors, Apache-2.0"  # noqa: A001 (Sphinx's name)

extensions = [
    "myst_nb",  # Markdown pages (myst-parser) and the notebook
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
]

root_doc = "index"
exclude_patterns = ["_build", "examples", "**.ipynb_checkpoints"]
# anchors for headings down to ###, with GitHub's slugs (the pages link to #sections)
myst_heading_anchors = 3

# API reference: one page per module, generated at build time into docs/api/ (not kept)
autosummary_generate = True
autosummary_imported_members = False
# inherited members too: the filters' documented attributes (x, P, t_s) live on private bases,
# and numpydoc links an Attributes entry to the member of that name; not those of Gymnasium's
# bases, whose docstrings are not numpydoc
autodoc_default_options = {"members": True, "show-inheritance": True,
                           "inherited-members": "Env,Wrapper,VectorEnv"}
autodoc_typehints = "none"  # numpydoc's Parameters sections state the types
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

# the notebook: executed at build time when it has no outputs (they are not committed)
nb_execution_mode = "auto"
nb_execution_timeout = 300
nb_execution_raise_on_error = True
nb_execution_in_temp = True  # what the notebook writes (runs/) stays out of docs/

html_theme = "furo"
html_title = "testbed"


def _skip_type_aliases(app: Any, what: str, name: str, obj: Any, skip: bool, options: Any
                       ) -> bool | None:
    """Leave out module-level type aliases (``X = tuple[...]``): autodoc takes them for
    classes and fails on their signature; the docstrings that use them say what they are."""
    if isinstance(obj, types.GenericAlias):
        return True
    return None


def setup(app: Any) -> None:
    app.connect("autodoc-skip-member", _skip_type_aliases)
