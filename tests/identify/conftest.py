"""Puts this folder on ``sys.path``: the tests import their unit makers from
``identify_units``."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
