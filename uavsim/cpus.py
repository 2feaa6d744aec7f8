"""How many CPUs this process may really use.

``os.cpu_count()`` (and ``std::thread::hardware_concurrency`` behind MuJoCo's
``nthread=0`` and torch's default) counts the host's CPUs. In a container
limited by a CPU quota (``docker --cpus=2``, a CI runner) that count can be many
times the two cores the process gets, and a thread pool that size spends its
time switching: every place that would default to "all CPUs" asks here instead.

    from uavsim.cpus import available_cpus
    batch = mujoco.batch.Batch(model, n, available_cpus())
"""

from __future__ import annotations

import math
import os
from functools import cache
from pathlib import Path

__all__ = ["available_cpus", "cgroup_cpu_limit"]


def cgroup_cpu_limit(root: str | os.PathLike = "/sys/fs/cgroup") -> float | None:
    """The cgroup CPU quota in CPUs (v2 ``cpu.max`` or v1 ``cpu.cfs_quota_us``), None when unlimited."""
    root = Path(root)
    try:
        quota, period = (root / "cpu.max").read_text().split()[:2]
        if quota != "max" and float(period) > 0:
            return float(quota) / float(period)
        return None
    except (OSError, ValueError):
        pass
    try:
        quota_us = float((root / "cpu" / "cpu.cfs_quota_us").read_text())
        period_us = float((root / "cpu" / "cpu.cfs_period_us").read_text())
        return quota_us / period_us if quota_us > 0 and period_us > 0 else None
    except (OSError, ValueError):
        return None


@cache
def available_cpus() -> int:
    """CPUs usable by this process: the affinity mask, capped by the cgroup quota (rounded up), >= 1."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    limit = cgroup_cpu_limit()
    if limit is not None:
        n = min(n, max(1, math.ceil(limit)))
    return max(1, n)
