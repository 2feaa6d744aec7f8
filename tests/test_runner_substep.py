"""The sub-step command blend in one rollout call steps exactly as two ``Batch.step`` calls did.

``LoopBatch.advance`` gives episodes whose actuator delay is under one physics
step the blend of the previous and the new command in the first substep. It
did so with ``step(nstep=1)`` then ``step(nstep=rate_steps - 1)``; it now
passes each substep's controls to one ``Batch.rollout``. The reference below is
the two-call version, and every recorded array must match it bit for bit,
also where MuJoCo warns (the rollout stops such an episode, ``Batch.step`` does
not) and on a lateral loop, whose measurement reads the sensors.
"""

import numpy as np
import pytest

from uavsim.control.relay import MRFT
from uavsim.lumped.params import LumpedParams
from uavsim.sim.runner import LoopBatch

RATE = 200.0


def two_calls(lb: LoopBatch) -> None:
    """The former advance: the blend's substep, then the rest."""
    new = lb.ctrl.copy()
    rows = lb._sub_rows
    lb.ctrl[rows] = lb._sub_f * lb._ctrl_prev[rows] + lb._sub_g * new[rows]
    lb.batch.step(nstep=1)
    lb.ctrl[:] = new
    if lb.rate_steps > 1:
        lb.batch.step(nstep=lb.rate_steps - 1)
    lb._ctrl_prev = new


def params(loop: str) -> list[LumpedParams]:
    kw = dict(att_kp=300.0, att_kd=20.0, att_filter_hz=50.0, tau_in=0.0004, T2=0.3) if loop.startswith("lateral") else {}
    return [LumpedParams(loop, K=1.0 + 0.1 * i, T_prop=0.05, T1=0.5, tau=t, **kw)
            for i, t in enumerate(np.linspace(0.0002, 0.03, 6))]


def run(loop: str, reference: bool, dt: float, inject=None, T: int = 300):
    lb = LoopBatch(params(loop), dt=dt, rate_hz=RATE, seed=3, record_state=True)
    assert lb._sub_any
    relay = MRFT(-0.5, 0.3, RATE, lb.n)
    lb.start(T)
    Y, QP, RF, SD = (np.empty((lb.n, T)) for _ in range(4))
    for k in range(T):
        _, Y[:, k] = lb.measure(k)
        lb.actuate(relay(-Y[:, k]), k)
        if inject is not None:
            inject(lb, k)
        if reference:
            lb.advance = lambda lb=lb: two_calls(lb)
        lb.step(k)
        QP[:, k], RF[:, k] = lb.qpos[:, 2], lb.actuator_force[:, 0]
        SD[:, k] = lb.sensordata[:, 0] if lb.lateral else 0.0
    return Y, QP, RF, SD, lb.diverged.copy(), np.array(lb.batch.time)


def bad_velocity(lb, k):
    if k == 40:
        lb.qvel[[0, 3], 2] = np.inf  # a sub-step episode and one without: MuJoCo resets both with a warning


def bad_command(lb, k):
    if k == 60:
        lb._ctrl_prev[lb._sub_rows[0]] = np.nan  # the blend alone is not finite: a warning in the first substep


@pytest.mark.parametrize("loop", ["altitude", "roll", "lateral_x"])
@pytest.mark.parametrize("dt", [0.001, 0.0005])
def test_rollout_blend_matches_two_step_calls(loop, dt):
    ref, new = run(loop, True, dt), run(loop, False, dt)
    for a, b in zip(ref, new, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("inject", [bad_velocity, bad_command])
def test_an_episode_stopped_at_a_warning_is_stepped_on(inject):
    ref, new = run("altitude", True, 0.001, inject), run("altitude", False, 0.001, inject)
    lb = LoopBatch(params("altitude"), dt=0.001, rate_hz=RATE)
    assert lb._sub_any
    for a, b in zip(ref, new, strict=True):
        np.testing.assert_array_equal(a, b)
    control = run("altitude", False, 0.001)  # the injection changed something: the check can fail
    assert not np.array_equal(control[1], new[1], equal_nan=True)
