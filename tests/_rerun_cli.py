"""Shared by the replay tests: Rerun's own command-line tool, analytics off, and its time format."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

RERUN = Path(sys.executable).with_name("rerun")
ENV = {**os.environ, "RERUN_ANALYTICS": "0"}
_ISO = re.compile(r"^P(?:T(?:(\d+)H)?(?:(\d+)M)?(?:([\d.]+)S)?|0D)$")


def rerun(*args: str) -> subprocess.CompletedProcess:
    """``rerun ARGS...`` from the venv, output captured, never raising on a non-zero exit."""
    return subprocess.run([str(RERUN), *args], capture_output=True, text=True, env=ENV, timeout=60, check=False)


def iso_seconds(text: str) -> float:
    """Seconds of an ISO 8601 duration as ``rerun rrd print`` writes timeline values (``PT1.25S``)."""
    m = _ISO.match(text)
    assert m, text
    h, mi, s = (float(g) if g else 0.0 for g in m.groups())
    return 3600.0 * h + 60.0 * mi + s
