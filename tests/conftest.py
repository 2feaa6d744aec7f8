"""Shared pytest setup.

Make the repository importable as ``uavsim`` when the package is not installed
(running ``.venv/bin/pytest`` from a fresh checkout), and keep BLAS to one thread:
the tests' matrices are small, and on a CI runner whose container shows the
host's CPUs an OpenBLAS pool that size makes every product a scheduling storm.

Pin OpenBLAS's kernels to its Haswell ones wherever the CPU runs them (AVX2 and
FMA), unless ``OPENBLAS_CORETYPE`` is set already: OpenBLAS otherwise picks
kernels by CPU model (SkylakeX on an AVX-512 machine), and another kernel moves
LAPACK's last bits. The byte-identity references (``tests/_platform.py``) hold
under Haswell kernels, the ones every x86-64 machine since 2013 can run; with
other kernels those checks skip, naming the difference.
"""

import os
import sys
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

try:
    _flags = set(Path("/proc/cpuinfo").read_text().split())
except OSError:
    _flags = set()
if {"avx2", "fma"} <= _flags:
    os.environ.setdefault("OPENBLAS_CORETYPE", "Haswell")

_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)
