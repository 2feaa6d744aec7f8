"""PBVS/IBVS schedule switch and the scheduled PD."""

import numpy as np
import pytest

from uavsim.errors import UserError
from uavsim.vision.schedules import Schedule, ScheduledPD, ScheduleSwitch, SwitchParams


def test_switch_on_large_innovation_and_back_when_settled():
    sw = ScheduleSwitch(SwitchParams(gate_m=0.1, gate_sigma=3.0, settle_tol_m=0.05, settle_s=0.5), 200.0, 2)
    small = np.array([0.01, 0.01])
    std = np.full(2, 0.005)
    a = sw.update(small, std, np.array([True, True]), np.zeros(2))
    assert (a == 1).all()
    a = sw.update(np.array([0.5, 0.01]), std, np.array([True, True]), np.array([0.5, 0.0]))
    assert list(a) == [2, 1] and sw.to_ibvs[0]
    # not settled yet: the error is outside the band
    for _ in range(200):
        a = sw.update(np.zeros(2), std, np.zeros(2, bool), np.array([0.2, 0.0]))
    assert a[0] == 2
    n_back = None
    for k in range(200):
        a = sw.update(np.zeros(2), std, np.zeros(2, bool), np.array([0.01, 0.0]))
        if a[0] == 1 and n_back is None:
            n_back = k + 1
    assert n_back == 100  # settle_s * rate


def test_innovation_between_frames_does_not_switch():
    sw = ScheduleSwitch(SwitchParams(), 200.0, 1)
    a = sw.update(np.array([1.0]), np.array([0.01]), np.array([False]), np.zeros(1))
    assert a[0] == 1


def test_scheduled_pd_uses_active_schedule():
    pd = ScheduledPD(Schedule(2.0, 0.0, 10.0), Schedule(0.5, 0.0, 10.0), 200.0, 2)
    u = pd(np.ones(2), np.ones(2) * 2, np.array([1, 2]))
    np.testing.assert_allclose(u, [2.0, 1.0])


def test_bad_switch_params():
    with pytest.raises(UserError):
        SwitchParams(gate_m=0.0).check()
