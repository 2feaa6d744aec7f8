"""Shared by the fidelity tests: close MuJoCo and an exact reference by the same relay, measure cycles."""

from __future__ import annotations

import numpy as np

from uavsim.control.relay import MRFT
from uavsim.lumped.params import LumpedParams
from uavsim.sim.runner import LoopBatch


def cycle(y: np.ndarray, u: np.ndarray, Ts: float) -> tuple[float, float]:
    """Mean period and half peak-to-peak over the second half of a relay run."""
    rising = np.flatnonzero(np.diff(np.sign(u)) > 0)
    rising = rising[rising >= y.size // 2]
    assert rising.size >= 3, "no sustained oscillation"
    period = (rising[-1] - rising[0]) / (rising.size - 1) * Ts
    seg = y[rising[0] : rising[-1]]
    return period, (seg.max() - seg.min()) / 2


def relay_pair(params: list[LumpedParams], beta: float, h: np.ndarray, y0: np.ndarray, ref, x0: np.ndarray,
               dt: float, rate_hz: float, duration: float):
    """The MuJoCo loops (initial output ``y0``) and ``ref`` (reset to ``x0``), each closed by an MRFT.

    Returns ``(res, Y, U)``: the MuJoCo ``EpisodeResult`` and the reference's (n, T) output and command.
    """
    n = len(params)
    lb = LoopBatch(params, dt=dt, rate_hz=rate_hz, y0=y0)
    res = lb.run(MRFT(beta, h, rate_hz, n), duration)
    assert not res.diverged.any(), res.reasons
    y = ref.reset(x0)
    relay = MRFT(beta, h, rate_hz, n)
    T = res.t.size
    Y, U = np.empty((n, T)), np.empty((n, T))
    for k in range(T):
        u = relay(-y)
        Y[:, k], U[:, k] = y, u
        y = ref.step(u)
    return res, Y, U


def cycle_rows(params: list[LumpedParams], res, Y: np.ndarray, U: np.ndarray, rate_hz: float) -> list[tuple]:
    """``(params, period_mujoco, period_ref, amplitude_mujoco, amplitude_ref)`` per episode."""
    rows = []
    for i, p in enumerate(params):
        P1, A1 = cycle(res.y[i], res.u[i], 1 / rate_hz)
        P2, A2 = cycle(Y[i], U[i], 1 / rate_hz)
        rows.append((p, P1, P2, A1, A2))
    return rows
