"""Limit-cycle measurement on recorded relay runs.

The steady cycle is measured between rising edges of the relay output ``u``
(the DNN input uses the same edges): the mean period over the last half of the
run, and the amplitude as half the peak-to-peak of ``y`` over those cycles.

    period, amplitude, ncycles = relay_cycle(y, u, rate_hz=200.0)
"""

from __future__ import annotations

import numpy as np


def rising_edges(u: np.ndarray) -> np.ndarray:
    """Sample indices (m,) where ``u`` (T,) switches from below to above its mid level."""
    mid = 0.5 * (np.nanmax(u) + np.nanmin(u))
    s = u > mid
    return np.flatnonzero(~s[:-1] & s[1:]) + 1


def relay_cycle(y: np.ndarray, u: np.ndarray, rate_hz: float, settle_fraction: float = 0.5) -> tuple[float, float, int]:
    """Period (s), amplitude (output units) and cycle count of the settled oscillation.

    Parameters
    ----------
    y, u : (T,) output and relay command at ``rate_hz``.
    settle_fraction : float
        Fraction of the run skipped as transient.

    Returns ``(nan, nan, 0)`` when fewer than two settled cycles exist.
    """
    edges = rising_edges(u)
    edges = edges[edges >= int(settle_fraction * y.size)]
    if edges.size < 3:
        return float("nan"), float("nan"), 0
    ncyc = edges.size - 1
    period = (edges[-1] - edges[0]) / ncyc / rate_hz
    seg = y[edges[0] : edges[-1]]
    return float(period), float((seg.max() - seg.min()) / 2), int(ncyc)
