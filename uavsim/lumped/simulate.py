"""Time-domain simulation of the lumped loops: MRFT limit cycles and PD steps.

Inner loops are simulated *exactly* at the sample instants: the plant
``K/(s (T_prop s + 1)(T1 s + 1))`` is discretized with a zero-order hold by the
matrix exponential, and the delay ``tau = (d + f) dt`` (integer ``d``,
fraction ``0 <= f < 1``) is handled exactly by splitting each hold interval
(modified z-transform):

    x[k+1] = Phi x[k] + Gamma_a u[k-d-1] + Gamma_b u[k-d]
    Gamma_b = int_0^{(1-f) dt} e^{A s} ds B,   Gamma_a = e^{A (1-f) dt} int_0^{f dt} e^{A s} ds B

The controller (relay or PD) is evaluated at every step on the sampled error;
the only approximation is that sampling (dt is chosen small against the period).
Lateral loops (two delays, the inner one inside the attitude feedback) are
simulated at a fine step with the attitude PD sampled at the same step.

``exact_limit_cycle`` has two independent methods: ``"sim"`` (relay simulation
to a settled cycle, measured on the last cycles) and ``"fourier"`` (the exact
periodic solution of the loop under a square wave, from the harmonic series of
the exact frequency response, solved for the MRFT switching condition; this is
an LPRS-style exact method with no sinusoidal assumption and no time step).

    from uavsim.lumped import LumpedParams, exact_limit_cycle, step_ise
    p = LumpedParams("altitude", 1.0, 0.3, 0.2, 0.0128)
    period, amp = exact_limit_cycle(p, beta=-0.73, h=1.0)
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm
from scipy.optimize import brentq

from uavsim.errors import UserError
from uavsim.lumped.frequency import (
    attitude_filter,
    batch_args,
    check_beta,
    freq_response_batch,
    mrft_prediction,
)
from uavsim.lumped.params import LumpedParams

__all__ = [
    "inner_state_space",
    "discretize_delayed",
    "simulate_relay_batch",
    "simulate_pd_step_batch",
    "simulate",
    "exact_limit_cycle",
    "fourier_limit_cycle",
    "step_ise",
    "step_ise_time",
]


def inner_state_space(K: float, T_prop: float, T1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C) of ``K / (s (T_prop s + 1)(T1 s + 1))``; state [y, y', thrust-lag]."""
    A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / T1, 1.0 / T1], [0.0, 0.0, -1.0 / T_prop]])
    B = np.array([0.0, 0.0, K / T_prop])
    C = np.array([1.0, 0.0, 0.0])
    return A, B, C


def _gamma(A: np.ndarray, B: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{A t}, int_0^t e^{A s} ds B) by one augmented matrix exponential."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A
    M[:n, n] = B
    E = expm(M * t)
    return E[:n, :n], E[:n, n]


def discretize_delayed(A: np.ndarray, B: np.ndarray, dt: float, tau: float):
    """Exact ZOH discretization with an input delay.

    Returns
    -------
    Phi : ndarray (n, n)
    Gamma_a, Gamma_b : ndarray (n,)
        Weights of ``u[k-d-1]`` and ``u[k-d]``.
    d : int
        Whole samples of delay.
    """
    q = tau / dt
    d = int(math.floor(q + 1e-9))
    f = max(q - d, 0.0)
    if f < 1e-9:
        f = 0.0
    Phi, _ = _gamma(A, B, dt)
    Eb, Gb = _gamma(A, B, (1.0 - f) * dt)
    _, Gf = _gamma(A, B, f * dt)
    Ga = Eb @ Gf
    return Phi, Ga, Gb, d


class _InnerBatch:
    """Exact-discretized inner plants for a batch (same dt, per-process delays)."""

    def __init__(self, K, T_prop, T1, tau, dt: float):
        K, T_prop, T1, tau = (np.atleast_1d(np.asarray(v, float)) for v in (K, T_prop, T1, tau))
        self.B = n = max(map(len, (K, T_prop, T1, tau)))
        K, T_prop, T1, tau = (np.broadcast_to(v, (n,)) for v in (K, T_prop, T1, tau))
        self.Phi = np.zeros((n, 3, 3))
        self.Ga = np.zeros((n, 3))
        self.Gb = np.zeros((n, 3))
        self.d = np.zeros(n, dtype=int)
        for i in range(n):
            if T_prop[i] > 0:
                A, Bv, _ = inner_state_space(K[i], T_prop[i], T1[i])
            else:  # K / (s (T1 s + 1)) padded to 3 states (third state unused)
                A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0 / T1[i], 0.0], [0.0, 0.0, 0.0]])
                Bv = np.array([0.0, K[i] / T1[i], 0.0])
            self.Phi[i], self.Ga[i], self.Gb[i], self.d[i] = discretize_delayed(A, Bv, dt, tau[i])
        self.x = np.zeros((n, 3))
        self.L = int(self.d.max()) + 2
        self.hist = np.zeros((n, self.L))  # ring buffer of past inputs
        self.k = 0
        self.rows = np.arange(n)

    @property
    def y(self) -> np.ndarray:
        return self.x[:, 0]

    def step(self, u: np.ndarray) -> None:
        k = self.k
        self.hist[:, k % self.L] = u
        ub = self.hist[self.rows, (k - self.d) % self.L]
        ua = self.hist[self.rows, (k - self.d - 1) % self.L]
        ub = np.where(self.d > k, 0.0, ub)
        ua = np.where(self.d + 1 > k, 0.0, ua)
        self.x = np.einsum("bij,bj->bi", self.Phi, self.x) + self.Ga * ua[:, None] + self.Gb * ub[:, None]
        self.k += 1


class _LateralBatch:
    """Fine-step lateral loop: attitude plant + sampled attitude PD + outer lag/integrator."""

    def __init__(self, K, T_prop, T1, tau, T2, tau_in, att_kp, att_kd, att_N, dt: float):
        arrs = [np.atleast_1d(np.asarray(v, float)) for v in (K, T_prop, T1, tau, T2, tau_in, att_kp, att_kd, att_N)]
        n = max(map(len, arrs))
        K, T_prop, T1, tau, T2, tau_in, kp, kd, N = (np.broadcast_to(v, (n,)) for v in arrs)
        self.att = _InnerBatch(1.0, T_prop, T1, tau_in, dt)
        self.kp, self.kd = kp, kd
        self.a = dt * N / (1.0 + dt * N)
        self.dt = dt
        # outer: K / (s (T2 s + 1)) driven by theta(t - tau_out), theta sampled and held
        self.outer = _InnerBatch(K, np.zeros(n), T2, tau, dt)  # T_prop = 0: K/(s(T2 s+1))
        # at rest before t = 0 (reference and attitude 0): a first reference jump enters the
        # attitude derivative, as it enters the continuous C(s) of the frequency-domain ISE
        self.e_prev = np.zeros(n)
        self.dstate = np.zeros(n)

    @property
    def y(self) -> np.ndarray:
        return self.outer.y

    def step(self, u: np.ndarray) -> None:
        e = u - self.att.y  # attitude reference minus attitude
        raw = (e - self.e_prev) / self.dt
        self.dstate = self.dstate + self.a * (raw - self.dstate)
        self.e_prev = e
        ua = self.kp * e + self.kd * self.dstate
        theta = self.att.y.copy()
        self.att.step(ua)
        self.outer.step(theta)


def _make_batch(family: str, dt: float, params: dict):
    if family == "lateral":
        p = dict(params)
        if p.get("att_N") is None:
            p["att_N"] = attitude_filter(p["T_prop"], p["T1"], p["tau_in"])
        return _LateralBatch(p["K"], p["T_prop"], p["T1"], p["tau"], p["T2"], p["tau_in"], p["att_kp"], p["att_kd"], p["att_N"], dt)
    return _InnerBatch(params["K"], params["T_prop"], params["T1"], params["tau"], dt)


def simulate_relay_batch(family: str, beta, h, dt: float, n_steps: int, **params) -> dict[str, np.ndarray]:
    """Plain MRFT (session.md semantics, extremum confirmed one sample after set) on a batch.

    Parameters
    ----------
    family : str
        Loop family.
    beta, h : float or ndarray (B,)
        MRFT parameter and relay amplitude.
    dt : float
        Step = controller sample, s.
    n_steps : int
        Samples to simulate.
    **params
        Process parameters (arrays (B,) or scalars).

    Returns
    -------
    dict with ``t`` (n_steps,), ``e`` and ``u`` (B, n_steps): error (= -y, zero reference)
    and relay output at each sample.
    """
    plant = _make_batch(family, dt, params)
    n = plant.att.B if family == "lateral" else plant.B
    beta = np.broadcast_to(np.asarray(beta, float), (n,))
    h = np.broadcast_to(np.asarray(h, float), (n,))
    E = np.zeros((n, n_steps))
    U = np.zeros((n, n_steps))
    sign = np.ones(n)
    e_ext = np.zeros(n)
    k_ext = np.zeros(n, dtype=int)
    for k in range(n_steps):
        e = -plant.y
        if k == 0:
            sign = np.where(e >= 0, 1.0, -1.0)
            e_ext = e.copy()
        else:
            up = sign > 0
            better = np.where(up, e > e_ext, e < e_ext)
            e_ext = np.where(better, e, e_ext)
            k_ext = np.where(better, k, k_ext)
            conf = (k - k_ext) >= 1
            sw = conf & np.where(up, e <= -beta * e_ext, e >= -beta * e_ext)
            sign = np.where(sw, -sign, sign)
            e_ext = np.where(sw, e, e_ext)
            k_ext = np.where(sw, k, k_ext)
        u = sign * h
        E[:, k] = e
        U[:, k] = u
        plant.step(u)
    return {"t": np.arange(n_steps) * dt, "e": E, "u": U}


def simulate_pd_step_batch(family: str, kp, kd, N, dt: float, n_steps: int, **params) -> dict[str, np.ndarray]:
    """Unit reference step at t = 0 under the sampled PD of session.md ("step").

    ``raw_k = (e_k - e_{k-1})/dt`` with ``e_{-1} = 0`` (at rest before the step, so the
    step enters the derivative), ``d_k = d_{k-1} + a (raw_k - d_{k-1})``,
    ``a = dt N/(1 + dt N)``, ``u_k = kp e_k + kd d_k``. At small dt (dt << 1/N) this
    tends to the continuous ``C(s) = kp + kd s/(1 + s/N)``, derivative kick included,
    whose ISE ``uavsim.lumped.ise`` computes in the frequency domain. (Lateral loops:
    the attitude PD inside sees the lateral command's jumps the same way.)

    Returns
    -------
    dict with ``t`` (n_steps,), ``e`` (B, n_steps) the error r - y at each sample.
    """
    plant = _make_batch(family, dt, params)
    n = plant.att.B if family == "lateral" else plant.B
    kp, kd, N = (np.broadcast_to(np.asarray(v, float), (n,)) for v in (kp, kd, N))
    a = dt * N / (1.0 + dt * N)
    E = np.zeros((n, n_steps))
    e_prev = np.zeros(n)  # r = 0 before the step: the step enters the derivative
    dstate = np.zeros(n)
    for k in range(n_steps):
        e = 1.0 - plant.y
        raw = (e - e_prev) / dt
        dstate = dstate + a * (raw - dstate)
        e_prev = e
        u = kp * e + kd * dstate
        E[:, k] = e
        plant.step(u)
    return {"t": np.arange(n_steps) * dt, "e": E}


def simulate(p: LumpedParams, controller: str, dt: float, t_end: float, **kw) -> dict[str, np.ndarray]:
    """Simulate one process: ``controller="mrft"`` (kw: beta, h) or ``"pd_step"`` (kw: kp, kd, N)."""
    p.check()
    n = int(round(t_end / dt))
    if controller == "mrft":
        out = simulate_relay_batch(p.family, kw["beta"], kw.get("h", 1.0), dt, n, **batch_args(p))
    elif controller == "pd_step":
        out = simulate_pd_step_batch(p.family, kw["kp"], kw["kd"], kw["N"], dt, n, **batch_args(p))
    else:
        raise UserError(f"unknown controller {controller!r} (mrft | pd_step)")
    return {k: (v[0] if v.ndim == 2 else v) for k, v in out.items()}


def _cycle_from_sim(t: np.ndarray, e: np.ndarray, u: np.ndarray, n_cycles: int = 4) -> tuple[float, float]:
    rises = np.nonzero((u[1:] > 0) & (u[:-1] < 0))[0] + 1
    if len(rises) < n_cycles + 2:
        raise UserError("relay simulation did not settle into a limit cycle")
    r = rises[-(n_cycles + 1):]
    period = (t[r[-1]] - t[r[0]]) / n_cycles
    seg = e[r[-2]: r[-1]]
    return float(period), float(0.5 * (seg.max() - seg.min()))


def fourier_limit_cycle(p: LumpedParams, beta: float, h: float = 1.0, n_harm: int = 600, n_t: int = 2000) -> tuple[float, float]:
    """Exact symmetric MRFT limit cycle from the harmonic series of ``G`` (no time step).

    Under ``u = h sign(sin(w t))`` the periodic error is
    ``e(t) = -sum_{k odd} 4h/(pi k) |G(jkw)| sin(k w t + arg G(jkw))``; the cycle is the
    ``w`` at which the relay switches down exactly half a period later:
    ``e(T/2) = -beta * max_{[0, T/2]} e``. Solved by bracketing around the DF frequency.

    Returns
    -------
    period : float, s
    amplitude : float
        Half peak-to-peak of the error (output) oscillation.
    """
    p.check()
    beta = check_beta(beta)
    w_df, _ = mrft_prediction(p, beta, h)
    args = batch_args(p)
    k = np.arange(1, 2 * n_harm, 2, dtype=float)
    th = np.linspace(0.0, np.pi, n_t + 1)  # w t over the half-period
    # sin(k th + phi) = sin(k th) cos(phi) + cos(k th) sin(phi): two mat-vecs per frequency
    Sm, Cm = np.sin(np.outer(th, k)), np.cos(np.outer(th, k))

    def wave(w: float) -> np.ndarray:
        G = freq_response_batch(p.family, (k * w)[None, :], **args)[0]
        c = 4 * h / (np.pi * k) * np.abs(G)
        ph = np.angle(G)
        return -(Sm @ (c * np.cos(ph)) + Cm @ (c * np.sin(ph)))

    def F(lw: float) -> float:
        e = wave(math.exp(lw))
        return e[-1] + beta * e.max()

    lw0 = math.log(w_df)
    grid = lw0 + np.linspace(-0.4, 0.4, 17)
    vals = np.array([F(x) for x in grid])
    # root nearest the DF frequency
    idx = np.nonzero(np.sign(vals[:-1]) != np.sign(vals[1:]))[0]
    if len(idx) == 0:
        raise UserError(f"{p.loop}: no exact MRFT cycle found near the DF frequency")
    i = idx[np.argmin(np.abs(grid[idx] - lw0))]
    lw = brentq(F, grid[i], grid[i + 1], xtol=1e-12)
    w = math.exp(lw)
    e = wave(w)
    return 2 * np.pi / w, float(np.abs(e).max())


def exact_limit_cycle(
    p: LumpedParams, beta: float, h: float = 1.0, dt: float | None = None, method: str = "sim", n_periods: int = 30
) -> tuple[float, float]:
    """Period and amplitude of the settled MRFT limit cycle.

    Parameters
    ----------
    p : LumpedParams
        The process.
    beta, h : float
        MRFT parameter in (-1, 1) and relay amplitude > 0.
    dt : float or None
        Step for ``method="sim"``, s; default ``min(1e-4, T_DF/4000)``.
    method : str
        ``"sim"`` (relay simulation, exact discretization, measured over the last
        4 cycles) or ``"fourier"`` (exact periodic solution, see ``fourier_limit_cycle``).
    n_periods : int
        Simulated length in DF periods (``"sim"``).

    Returns
    -------
    period : float
        s.
    amplitude : float
        Half peak-to-peak of the error over the last cycle, output units.
    """
    p.check()
    beta = check_beta(beta)
    if not h > 0:
        raise UserError(f"relay amplitude h must be > 0, got {h!r}")
    if method == "fourier":
        return fourier_limit_cycle(p, beta, h)
    if method != "sim":
        raise UserError(f"unknown limit-cycle method {method!r} (sim | fourier)")
    w_df, _ = mrft_prediction(p, beta, h)
    T = 2 * np.pi / w_df
    if dt is None:
        dt = min(1e-4, T / 4000)
    n = int(n_periods * T / dt)
    out = simulate_relay_batch(p.family, beta, h, dt, n, **batch_args(p))
    return _cycle_from_sim(out["t"], out["e"][0], out["u"][0])


def step_ise_time(p: LumpedParams, kp: float, kd: float, N: float, dt: float | None = None, t_end: float | None = None) -> float:
    """Step ISE by time simulation (sampled PD at small dt, rectangle rule); inf if diverging."""
    p.check()
    if t_end is None or dt is None:
        w, _ = mrft_prediction(p, -0.73, 1.0)
        T = 2 * np.pi / w
        t_end = t_end or 40 * T
        dt = dt or min(1e-4, 0.02 / N)
    n = int(round(t_end / dt))
    e = simulate_pd_step_batch(p.family, kp, kd, N, dt, n, **batch_args(p))["e"][0]
    if not np.all(np.isfinite(e)) or np.abs(e[-n // 10:]).max() > 1.0:
        return math.inf
    return float(np.sum(e**2) * dt)


def step_ise(p: LumpedParams, kp: float, kd: float, N: float, method: str = "freq") -> float:
    """Infinite-horizon unit-step ISE of the loop closed by ``C(s) = kp + kd s/(1 + s/N)``.

    Parameters
    ----------
    p : LumpedParams
        Process (K > 0).
    kp, kd : float
        PD gains, kp > 0, kd >= 0.
    N : float
        Derivative filter, rad/s, > 0.
    method : str
        ``"freq"`` (Parseval on the exact frequency response, default) or ``"time"``.

    Returns
    -------
    float
        ISE, output-units^2 s; ``inf`` if the closed loop is unstable.
    """
    p.check()
    for name, v, ok in (("kp", kp, kp > 0), ("kd", kd, kd >= 0), ("N", N, N > 0)):
        if not math.isfinite(v) or not ok:
            raise UserError(f"PD parameter {name} invalid: {v!r}")
    if method == "time":
        return step_ise_time(p, kp, kd, N)
    from uavsim.lumped.ise import step_ise_batch

    w, _ = mrft_prediction(p, -0.73, 1.0)
    return float(step_ise_batch(p.family, kp, kd, N, w, **batch_args(p))[0])
