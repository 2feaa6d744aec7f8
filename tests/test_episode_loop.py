"""LoopBatch's stepping API is the episode loop: run() is start/measure/actuate/step, a measurement stage plugs in."""

import numpy as np

from uavsim.control.relay import MRFT
from uavsim.lumped.params import LumpedParams
from uavsim.model.effects import make_effect
from uavsim.sim.runner import LoopBatch

RATE = 200.0
P = [LumpedParams("altitude", K=1.0, T_prop=0.1, T1=0.8, tau=0.02), LumpedParams("altitude", K=2.0, T_prop=0.05,
                                                                                   T1=0.5, tau=0.01)]


def _batch(**kw) -> LoopBatch:
    return LoopBatch(P, dt=0.001, rate_hz=RATE, seed=4, effects=[make_effect("noise", std=0.01)], **kw)


class Offset:
    """A measurement stage: the true output plus a constant, counting its calls."""

    def __init__(self, c: float) -> None:
        self.c, self.calls = c, 0

    def reset(self, n, rate_hz, rng) -> None:
        self.calls = 0

    def __call__(self, y_true, k):
        self.calls += 1
        return y_true + self.c


def test_run_is_the_stepping_api():
    T = 120
    res = _batch().run(MRFT(-0.5, 1.0, RATE, 2), T / RATE)
    lb, relay = _batch(), MRFT(-0.5, 1.0, RATE, 2)
    lb.start(T)
    Y = np.empty((2, T))
    for k in range(T):
        _, Y[:, k] = lb.measure(k)
        lb.actuate(relay(-Y[:, k]), k)
        lb.step(k)
    np.testing.assert_array_equal(Y, res.y)  # same draws, same physics, bit for bit
    assert not lb.diverged.any() and np.ptp(res.y_true) > 0


def test_a_measurement_stage_replaces_the_measurement_effects():
    stage = Offset(0.25)
    res = _batch().run(MRFT(-0.5, 1.0, RATE, 2), 0.3, measurement=stage)
    assert stage.calls == res.t.size
    np.testing.assert_array_equal(res.y, res.y_true + 0.25)  # no noise: the stage took the effects' place


def test_step_flags_and_parks_a_runaway_episode():
    lb = _batch()
    lb.start(10)
    lb.qpos[1, 3] = 1.5  # tilted beyond 1.2 rad
    new = lb.step(0)
    assert new.tolist() == [False, True] and lb.diverged.tolist() == [False, True]
    assert "runaway" in lb.reasons[1] and lb.qpos[1, 3] == 0.0
    assert not lb.step(1).any()  # flagged once
