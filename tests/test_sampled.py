"""The exact sampled-PD step ISE against brute-force time simulation and other references.

The brute force is independent of the lifted model: the exact reference
discretizations of ``uavsim.lumped.reference`` stepped at a tenth of the control
period (the fractional delays on that fine grid), the PD of the session format
evaluated at every control sample, and the squared error integrated by
Simpson's rule over the fine samples, to a horizon where the error has died out.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import simpson
from scipy.linalg import solve_discrete_lyapunov

from uavsim.errors import UserError
from uavsim.lumped.ise import step_ise_batch
from uavsim.lumped.reference import LateralDiscrete, LumpedDiscrete
from uavsim.lumped.sampled import delay_split, lift, lyapunov_sum, sampled_ise, step_ise_sampled

RATE = 200.0
SUB = 10  # fine steps per control period


class OuterPD:
    """The session format's PD on ``n`` errors, started at the step (``kick=False``) or at rest before it."""

    def __init__(self, kp, kd, N, n: int, kick: bool):
        self.Ts = 1.0 / RATE
        self.kp, self.kd, self.a = kp, kd, self.Ts * N / (1 + self.Ts * N)
        self.e_prev = np.zeros(n) if kick else np.ones(n)  # e_0 = 1: the first difference is 0
        self.d = np.zeros(n)

    def __call__(self, e):
        self.d = self.d + self.a * ((e - self.e_prev) / self.Ts - self.d)
        self.e_prev = e
        return self.kp * e + self.kd * self.d


def ise_and_tail(err: np.ndarray, offset=0.0):
    """Simpson ISE over the fine samples (n, S) and the largest |e| of the last 100 control periods."""
    return offset + simpson(err**2, dx=1.0 / (RATE * SUB), axis=1), np.abs(err[:, -SUB * 100:]).max(axis=1)


def brute_inner(K, T_prop, T1, tau, kp, kd, N, kick: bool, t_end: float):
    """ISE and the tail of |e| of n inner loops, by fine simulation, arrays (n,)."""
    sim = LumpedDiscrete.inner(K, T_prop, T1, tau, 1.0 / (RATE * SUB))
    y = sim.reset()
    pd = OuterPD(kp, kd, N, y.size, kick)
    steps = int(round(t_end * RATE))
    ys = np.empty((y.size, steps * SUB + 1))
    ys[:, 0] = y
    for k in range(steps):
        u = pd(1.0 - y)
        for j in range(SUB):
            y = sim.step(u)
            ys[:, k * SUB + j + 1] = y
    return ise_and_tail(1.0 - ys)


def brute_lateral(p: dict, kp, kd, N, kick: bool, t_end: float):
    """Same for lateral loops (``LateralDiscrete`` with the outer PD and the measurement delay)."""
    sim = LateralDiscrete(p["K"], p["T_prop"], p["T1"], p["tau_in"], p["T2"], p["tau"], p["att_kp"], p["att_kd"],
                          p["att_N"] / (2 * np.pi), 1.0 / (RATE * SUB), RATE)
    y = sim.reset()
    if kick:
        sim.pd.k = 1  # the attitude PD ran at rest before the step: the jump enters its derivative
    pd = OuterPD(kp, kd, N, y.size, kick)
    steps = int(round(t_end * RATE))
    xs = np.zeros((y.size, steps * SUB + 1))
    for k in range(steps):
        att_u = sim.pd(pd(1.0 - y) - sim.plant.x[:, 0])
        for j in range(SUB):
            sim.plant.step(att_u)
            sim.xhist[:, sim.plant.k % sim.out_len] = sim.plant.x[:, 3]
            xs[:, k * SUB + j + 1] = sim.plant.x[:, 3]
        y = sim._measure()
    # e(t) = 1 - x(t - tau) is 1 until tau: the ISE of the measured error is tau + that of 1 - x
    return ise_and_tail(1.0 - xs, p["tau"])


# K, T_prop, T1, tau (fractions of the control period: 0, 0.3, 0.5, 0.9, multiples of the fine step), kp, kd, N
INNER = np.array([
    [1.0, 0.10, 0.80, 0.0215, 30.0, 8.0, 60.0],
    [2.0, 0.30, 0.20, 0.0125, 8.0, 2.0, 40.0],
    [0.5, 0.05, 0.50, 0.0500, 8.0, 1.5, 30.0],
    [1.0, 0.02, 1.50, 0.0000, 150.0, 30.0, 300.0],
    [3.0, 0.015, 0.3, 0.0045, 25.0, 2.5, 500.0],
])


@pytest.mark.parametrize("kick", [False, True])
def test_inner_matches_time_simulation(kick):
    K, Tp, T1, tau, kp, kd, N = INNER.T
    q = step_ise_sampled("altitude", kp, kd, N, RATE, kick=kick, K=K, T_prop=Tp, T1=T1, tau=tau)
    qb, tail = brute_inner(K, Tp, T1, tau, kp, kd, N, kick, t_end=25.0)
    assert tail.max() < 1e-6, tail  # the horizon holds the whole ISE
    assert np.all(np.abs(q / qb - 1) < 1e-6), q / qb - 1


def lateral_cases() -> dict:
    # three attitude processes with their PDs (unit gain), outer delays on the fine grid (0.5 ms)
    return {"K": np.array([1.0, 2.0, 0.7]), "T_prop": np.array([0.1, 0.05, 0.2]), "T1": np.array([0.5, 0.3, 1.2]),
            "tau_in": np.array([0.004, 0.0125, 0.0]), "att_kp": np.array([20.0, 15.0, 30.0]),
            "att_kd": np.array([2.5, 1.2, 10.0]), "att_N": np.array([60.0, 80.0, 40.0]),
            "T2": np.array([1.5, 0.5, 3.0]), "tau": np.array([0.04, 0.0125, 0.1005])}


@pytest.mark.parametrize("kick", [False, True])
def test_lateral_matches_time_simulation(kick):
    p = lateral_cases()
    kp, kd, N = np.array([0.3, 0.2, 1.0]), np.array([0.25, 0.06, 1.5]), np.array([20.0, 30.0, 15.0])
    q = step_ise_sampled("lateral", kp, kd, N, RATE, kick=kick, **p)
    qb, tail = brute_lateral(p, kp, kd, N, kick, t_end=70.0)
    assert tail.max() < 1e-6, tail
    assert np.all(np.abs(q / qb - 1) < 1e-6), q / qb - 1


def test_tends_to_continuous_ise():
    """As the rate grows the sampled ISE tends to the frequency-domain one (its error is O(Ts))."""
    args = {"K": 1.0, "T_prop": 0.1, "T1": 0.8, "tau": 0.0213}
    qc = step_ise_batch("altitude", 30.0, 8.0, 60.0, 8.0, n=20000, **args)  # C(s) on the error: the kick
    errs = [abs(step_ise_sampled("altitude", 30.0, 8.0, 60.0, r, kick=True, **args)[0] / qc[0] - 1)
            for r in (200.0, 2000.0)]
    assert errs[1] < 0.02 and errs[1] < errs[0] / 8, errs


def test_unstable_is_inf_and_stability_flag():
    q, st = step_ise_sampled("altitude", [30.0, 3000.0], [8.0, 8.0], 60.0, RATE, return_stable=True, K=1.0,
                             T_prop=0.1, T1=0.8, tau=0.02)
    assert np.isfinite(q[0]) and q[1] == np.inf
    assert st.tolist() == [True, False]


def test_doubling_matches_scipy_lyapunov():
    rng = np.random.default_rng(0)
    n, B = 7, 5
    M = rng.normal(size=(B, n, n))
    M *= (0.995 / np.abs(np.linalg.eigvals(M)).max(axis=1))[:, None, None]  # slow, non-normal
    L = rng.normal(size=(B, n, n))
    Q = L @ np.swapaxes(L, 1, 2)
    z0 = rng.normal(size=(B, n))
    got = lyapunov_sum(M, Q, z0)
    for b in range(B):
        P = solve_discrete_lyapunov(M[b].T, Q[b])
        assert got[b] == pytest.approx(z0[b] @ P @ z0[b], rel=1e-9)


def test_one_process_many_controllers_broadcast():
    proc = lift("roll", RATE, K=1.0, T_prop=0.05, T1=0.5, tau=0.011)
    kp = np.array([10.0, 20.0, 40.0])
    q = sampled_ise(proc, kp, 2.0, 100.0)
    each = [sampled_ise(proc, k, 2.0, 100.0)[0] for k in kp]
    assert np.allclose(q, each, rtol=1e-12)


def test_delay_split_and_bad_input():
    d, f = delay_split([0.0, 0.0125, 0.015, 0.0149999999999], 1 / 200)
    assert d.tolist() == [0, 2, 3, 3] and f[0] == 0 and f[1] == pytest.approx(0.5) and f[2] == 0 and f[3] == 0
    with pytest.raises(UserError):
        lift("altitude", RATE, K=1.0, T_prop=-0.1, T1=0.5, tau=0.01)
    with pytest.raises(UserError):
        lift("lateral", RATE, K=1.0, T_prop=0.1, T1=0.5, tau=0.01)
    with pytest.raises(UserError):
        lift("altitude", 0.0, K=1.0, T_prop=0.1, T1=0.5, tau=0.01)
