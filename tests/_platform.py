"""The platform byte-identity references were recorded on, and how this one differs.

Same recipe and seed give the same bytes on one platform. Across platforms the
last bits may move: numpy's and MuJoCo's versions, and the BLAS kernels OpenBLAS
runs (``tests/conftest.py`` pins Haswell ones where the CPU runs them). A check
against recorded bytes skips, naming the difference, where any of these differ.
"""

from __future__ import annotations

import json
import platform

import mujoco
import numpy as np

from uavsim.data.backends import blas_kernels

#: where the committed byte references (the training-set digests, the example session) were made
RECORDED = {"numpy": "2.4.6", "mujoco": "4.0.0", "machine": "x86_64", "blas": "openblas Haswell"}


def platform_differs(recorded: dict[str, str] = RECORDED) -> str | None:
    """None on the recorded platform, else one line naming both."""
    here = {"numpy": np.__version__, "mujoco": mujoco.__version__, "machine": platform.machine(),
            "blas": blas_kernels()}
    if here != recorded:
        return f"reference bytes recorded on {json.dumps(recorded)}, this is {json.dumps(here)}"
    return None
