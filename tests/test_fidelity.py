"""The MuJoCo loops reproduce the lumped models' relay limit cycles.

For random points of each inner loop's parameter box, the hexarotor closed by
the plain MRFT of the session spec is compared with an independent exact
simulation of the lumped transfer function (``uavsim.lumped.reference``), both
closed by the same relay. At the physics rate (2 kHz) the period must agree
within 1% and the amplitude within 2%; at a 200 Hz controller switching is
quantized to 5 ms, so the period must agree within one control sample and the
amplitude within 5%.

At 200 Hz the relay's switching instant is quantized, and a sampled relay
loop can have several stable limit cycles (a fast cycle that switches one
sample later, near its peak, carries a few percent more amplitude). Two
simulations that agree to 1e-6 (the open-loop test below shows how closely
the physics matches) can settle on different ones. So at 200 Hz every point
must meet the spec against the reference started like MuJoCo, or against
another orbit of the exact reference (started from other initial outputs):
MuJoCo's cycle must be one of the lumped model's cycles
(``_fidelity.in_spec_or_other_orbit``).
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from _fidelity import cycle_rows, in_spec_or_other_orbit, relay_pair

from uavsim.lumped.params import RANGES, LumpedParams, loop_family
from uavsim.lumped.reference import LumpedDiscrete
from uavsim.sim.runner import LoopBatch


def random_params(loop: str, n: int, rng: np.random.Generator) -> list[LumpedParams]:
    box = RANGES[loop_family(loop)]
    out = []
    for _ in range(n):
        # log-uniform over the box, as the grids are spaced
        v = {k: float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) for k, (lo, hi) in box.items()}
        out.append(LumpedParams(loop, K=float(np.exp(rng.uniform(np.log(0.2), np.log(5.0)))), **v))
    return out


def compare(params, beta, dt, rate_hz, duration, orbits=None):
    """Cycle rows of MuJoCo against the reference; with ``orbits`` (a ``within`` predicate), also the
    per-point verdicts of ``in_spec_or_other_orbit`` and the count that needed another orbit."""
    n = len(params)
    # a definite start: the first sample's sign must not hinge on round-off
    y0 = np.array([-1e-3 * p.K for p in params])
    # relay amplitude scaled by 1/K keeps every cycle small (attitude in radians)
    h = np.array([0.2 / p.K for p in params])
    ref = LumpedDiscrete.inner(
        [p.K for p in params], [p.T_prop for p in params], [p.T1 for p in params], [p.tau for p in params], 1 / rate_hz
    )
    x0 = np.zeros((n, 3))
    x0[:, 0] = y0  # the delay line starts empty (prehistory zero), as MuJoCo's history buffer
    res, Y, U = relay_pair(params, beta, h, y0, ref, x0, dt, rate_hz, duration)
    rows = cycle_rows(params, res, Y, U, rate_hz)
    if orbits is None:
        return rows
    return rows, *in_spec_or_other_orbit(rows, orbits, ref, x0, 0, beta, h, rate_hz, Y.shape[1])


@pytest.mark.parametrize("loop", ["altitude", "roll", "pitch"])
def test_open_loop_matches_lumped(loop):
    """A square wave through the MuJoCo loop and through the exact lumped model."""
    rng = np.random.default_rng(zlib.crc32(loop.encode()))
    params = random_params(loop, 10, rng)
    n, half = len(params), 37
    lb = LoopBatch(params, dt=0.0005, rate_hz=200.0)
    count = [0]

    def square(e):
        k = count[0]
        count[0] += 1
        return np.full(n, 1.0 if (k // half) % 2 == 0 else -1.0)

    res = lb.run(square, 6.0)
    ref = LumpedDiscrete.inner(
        [p.K for p in params], [p.T_prop for p in params], [p.T1 for p in params], [p.tau for p in params], 1 / 200
    )
    y = ref.reset(prehistory="zero")
    Y = np.empty_like(res.y)
    for k in range(res.t.size):
        Y[:, k] = y
        y = ref.step(np.full(n, 1.0 if (k // half) % 2 == 0 else -1.0))
    a, b = res.y[:, -4 * half :], Y[:, -4 * half :]
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    err = np.abs(a - b).max(axis=1) / np.ptp(b, axis=1)
    assert err.max() < 2e-3, err


@pytest.mark.parametrize("loop", ["altitude", "roll", "pitch"])
@pytest.mark.parametrize("beta", [-0.73, -0.3, 0.0])
def test_fidelity_200hz(loop, beta):
    """Every point within one control sample and 5% amplitude of a cycle of the exact model."""
    rng = np.random.default_rng(zlib.crc32(f"{loop}{beta}".encode()))
    params = random_params(loop, 30, rng)
    Ts = 1 / 200
    rows, ok, _ = compare(params, beta, dt=0.0005, rate_hz=200.0, duration=40.0, orbits=lambda r: within_200hz(r, Ts))
    assert all(ok), [r for r, good in zip(rows, ok, strict=True) if not good]


def within_200hz(r: tuple, Ts: float) -> bool:
    """A cycle row within one control sample in period and 5% in amplitude."""
    return abs(r[1] - r[2]) <= Ts + 1e-9 and abs(r[3] / r[4] - 1) <= 0.05


@pytest.mark.slow
@pytest.mark.parametrize("loop", ["altitude", "roll", "pitch"])
@pytest.mark.parametrize("beta", [-0.73, -0.3, 0.0])
def test_fidelity_physics_rate(loop, beta):
    rng = np.random.default_rng(1 + zlib.crc32(f"{loop}{beta}".encode()))
    params = random_params(loop, 30, rng)
    rows = compare(params, beta, dt=0.0005, rate_hz=2000.0, duration=40.0)
    bad = [r for r in rows if abs(r[1] / r[2] - 1) > 0.01 or abs(r[3] / r[4] - 1) > 0.02]
    assert not bad, bad


def test_sub_step_actuator_delay():
    """Delays shorter than one physics step (MuJoCo's history would round them up to dt) are kept.

    At dt = 1 ms (the datasets' step) a square wave through the altitude loop
    with tau in (0, dt) matches the exact lumped model to the Euler step's
    1.3e-3 of the peak-to-peak; rounded up to 1 ms the mismatch would be
    several times that.
    """
    taus = [0.0002, 0.0005, 0.0007, 0.00095]
    params = [LumpedParams("altitude", K=2.0, T_prop=0.03, T1=0.4, tau=t) for t in taus]
    n, half, T = len(params), 7, 400
    wave = lambda k: np.full(n, 1.0 if (k // half) % 2 == 0 else -1.0)  # noqa: E731
    count = [0]

    def square(e):
        count[0] += 1
        return wave(count[0] - 1)

    res = LoopBatch(params, dt=0.001, rate_hz=200.0).run(square, T / 200)
    ref = LumpedDiscrete.inner([2.0] * n, [0.03] * n, [0.4] * n, taus, 1 / 200)
    y = ref.reset(prehistory="zero")
    Y = np.empty((n, T))
    for k in range(T):
        Y[:, k] = y
        y = ref.step(wave(k))
    a, b = res.y[:, -100:], Y[:, -100:]
    err = np.abs((a - a.mean(1, keepdims=True)) - (b - b.mean(1, keepdims=True))).max(1) / np.ptp(b, axis=1)
    assert err.max() < 2e-3, err
