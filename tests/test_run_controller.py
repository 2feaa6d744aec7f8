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


def _pd_pair(n=1):
    kw = dict(kp=2.0, kd=0.5, derivative_filter_hz=10.0, rate_hz=200.0, n=n)
    return PD(**kw), PD(**kw, derivative="measurement")


def test_measurement_derivative_gives_no_kick_on_a_step():
    # a step of 1 at sample 5 with the output at rest: the error form kicks by kd a / Ts,
    # the measurement form's command is kp e alone
    err, meas = _pd_pair()
    assert meas.reads_reference and not err.reads_reference
    r = np.where(np.arange(40) >= 5, 1.0, 0.0)
    y = np.zeros(40)
    ue = np.array([err(np.array([ri - yi]))[0] for ri, yi in zip(r, y, strict=True)])
    um = np.array([meas(np.array([ri - yi]), np.array([ri]))[0] for ri, yi in zip(r, y, strict=True)])
    assert np.array_equal(um, 2.0 * r)
    kick = 0.5 * err.a[0] / err.Ts * (1 - err.a[0]) ** np.arange(35)
    assert ue[5] > 10 * um[5]
    np.testing.assert_allclose(ue[5:] - um[5:], kick, rtol=1e-12)


def test_measurement_derivative_equals_error_form_on_a_constant_reference():
    # after the step (reference constant, both started there) the two forms are one controller
    rng = np.random.default_rng(3)
    err, meas = _pd_pair(n=4)
    r = np.full(4, 0.7)
    for _ in range(200):
        y = rng.normal(0.5, 0.2, 4)
        np.testing.assert_allclose(meas(r - y, r), err(r - y), rtol=1e-12, atol=1e-12)


def test_measurement_pd_per_controller_and_checked():
    pd = PD(1.0, 1.0, 10.0, 200.0, 2, derivative=["error", "measurement"])
    pd(np.zeros(2), np.zeros(2))
    u = pd(np.ones(2), np.ones(2))  # the reference stepped to 1, the output stayed at 0
    assert u[0] > 1.0 and u[1] == 1.0
    with pytest.raises(UserError, match="needs the reference"):
        PD(1.0, 1.0, 10.0, 200.0, 1, derivative="measurement")(np.ones(1))
    with pytest.raises(UserError, match="derivative must be one of error, measurement, got setpoint"):
        PD(1.0, 1.0, 10.0, 200.0, 1, derivative="setpoint")


def test_step_run_builds_its_derivative():
    spec = RunSpec("c.csv", "step", kp=2.0, kd=0.5, derivative_filter_hz=10.0, step=1.0, step_time=1.0,
                   derivative="measurement")
    assert run_controller(spec, 200.0).reads_reference
