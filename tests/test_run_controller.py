"""run_controller: a session run's RunSpec becomes the controller the format says produced it."""

import numpy as np
import pytest

from uavsim.control.pd import PD
from uavsim.control.relay import MRFT, NPMRFT
from uavsim.control.runs import run_controller
from uavsim.errors import UserError
from uavsim.formats.session import RunSpec


def test_each_kind_and_its_settings():
    r = run_controller(RunSpec("a.csv", "np-mrft", beta=-0.73, h=0.5, tau_obs=0.02, a_n=0.01, bias=0.1), 200.0, n=3)
    assert type(r) is NPMRFT and r.n == 3
    m = run_controller(RunSpec("b.csv", "mrft", beta=-0.3, h=1.0), 200.0, reading=1)
    assert type(m) is MRFT
    p = run_controller(RunSpec("c.csv", "step", kp=2.0, kd=0.5, derivative_filter_hz=10.0, step=1.0, step_time=1.0),
                       200.0)
    assert type(p) is PD and p.kp[0] == 2.0 and p.kd[0] == 0.5
    # the same relay, built directly, switches identically on the same errors
    e = np.sin(np.linspace(0, 20, 400))[:, None] * np.ones(3)
    direct = NPMRFT(-0.73, 0.5, 0.02, 0.01, 200.0, 3, bias=0.1)
    assert np.array_equal([r(x) for x in e], [direct(x) for x in e])


def test_unknown_kind_is_one_line():
    with pytest.raises(UserError, match="x.csv: unknown run kind 'chirp'"):
        run_controller(RunSpec("x.csv", "chirp"), 200.0)
