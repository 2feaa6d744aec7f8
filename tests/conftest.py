"""Shared pytest setup.

Make the repository importable as ``uavsim`` when the package is not installed
(running ``.venv/bin/pytest`` from a fresh checkout).
"""

import sys
from pathlib import Path

_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)
