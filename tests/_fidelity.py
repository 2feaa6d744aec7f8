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


def reference_relay(ref, x0: np.ndarray, beta: float, h: np.ndarray, rate_hz: float, T: int):
    """``ref`` reset to ``x0`` and closed by an MRFT for ``T`` samples: its (n, T) output and command."""
    n = x0.shape[0]
    y = ref.reset(x0)
    relay = MRFT(beta, h, rate_hz, n)
    Y, U = np.empty((n, T)), np.empty((n, T))
    for k in range(T):
        u = relay(-y)
        Y[:, k], U[:, k] = y, u
        y = ref.step(u)
    return Y, U


def relay_pair(params: list[LumpedParams], beta: float, h: np.ndarray, y0: np.ndarray, ref, x0: np.ndarray,
               dt: float, rate_hz: float, duration: float):
    """The MuJoCo loops (initial output ``y0``) and ``ref`` (reset to ``x0``), each closed by an MRFT.

    Returns ``(res, Y, U)``: the MuJoCo ``EpisodeResult`` and the reference's (n, T) output and command.
    """
    n = len(params)
    lb = LoopBatch(params, dt=dt, rate_hz=rate_hz, y0=y0)
    res = lb.run(MRFT(beta, h, rate_hz, n), duration)
    assert not res.diverged.any(), res.reasons
    return (res, *reference_relay(ref, x0, beta, h, rate_hz, res.t.size))


def _cycle_or_nan(y: np.ndarray, u: np.ndarray, Ts: float) -> tuple[float, float]:
    try:
        return cycle(y, u, Ts)
    except AssertionError:  # that start did not settle on a cycle
        return float("nan"), float("nan")


def in_spec_or_other_orbit(rows: list[tuple], within, ref, x0: np.ndarray, out_index: int, beta: float,
                           h: np.ndarray, rate_hz: float, T: int,
                           factors=(0.3, 3.0, 10.0, -1.0, -3.0, 30.0)) -> tuple[list[bool], int]:
    """Per point: does MuJoCo's cycle meet ``within`` against the reference, or against another orbit of it?

    A sampled relay loop can have several stable limit cycles (switching one
    sample earlier or later), and two simulations that agree to 1e-6 can settle
    on different ones. Where MuJoCo's cycle misses the reference started like
    it, the reference is started again from other initial outputs (``x0``'s
    state ``out_index`` times each factor) and the point passes if MuJoCo's
    cycle is, within spec, one of the orbits the exact model reaches.

    Returns the per-point verdicts and how many points needed another orbit.
    """
    ok = [bool(within(r)) for r in rows]
    if all(ok):
        return ok, 0
    others = []
    for f in factors:
        x = x0.copy()
        x[:, out_index] *= f
        Y, U = reference_relay(ref, x, beta, h, rate_hz, T)
        others.append([_cycle_or_nan(Y[i], U[i], 1 / rate_hz) for i in range(len(rows))])
    n_other = 0
    for i, r in enumerate(rows):
        if not ok[i] and any(within((r[0], r[1], P, r[3], A)) for P, A in (o[i] for o in others)):
            ok[i] = True
            n_other += 1
    return ok, n_other


def cycle_rows(params: list[LumpedParams], res, Y: np.ndarray, U: np.ndarray, rate_hz: float) -> list[tuple]:
    """``(params, period_mujoco, period_ref, amplitude_mujoco, amplitude_ref)`` per episode."""
    rows = []
    for i, p in enumerate(params):
        P1, A1 = cycle(res.y[i], res.u[i], 1 / rate_hz)
        P2, A2 = cycle(Y[i], U[i], 1 / rate_hz)
        rows.append((p, P1, P2, A1, A2))
    return rows
