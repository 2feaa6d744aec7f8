"""Shared pytest setup.

Make the repository importable as ``uavsim`` when the package is not installed
(running ``.venv/bin/pytest`` from a fresh checkout), and keep BLAS to one thread:
the tests' matrices are small, and on a CI runner whose container shows the
host's CPUs an OpenBLAS pool that size makes every product a scheduling storm.
"""

import os
import sys
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)
