"""Exact reference simulation of the lumped loops, independent of MuJoCo.

The inner lumped process ``K e^{-tau s} / (s (T_prop s + 1)(T1 s + 1))`` is
discretized exactly for a piecewise-constant input (zero-order hold at the
step ``dt``), with the delay split into whole steps (a ring buffer) and a
fractional remainder handled by two input matrices (the modified z-transform).
A relay evaluated at every step closes the loop. This is the yardstick the
MuJoCo loops are tested against: no approximation beyond floating point and
the sampling of the relay.

    sim = LumpedDiscrete.inner(K=1.0, T_prop=0.1, T1=0.8, tau=0.02, dt=5e-4, n=4)
    relay = MRFT(beta=-0.73, h=1.0, rate_hz=1 / 5e-4, n=4)
    y = sim.reset()
    for k in range(steps):
        y = sim.step(relay(-y))

Shapes: ``n`` processes stepped together; states ``(n, nx)``.

The lateral loop (``LateralDiscrete``) is the composite of the attitude
process, the sampled attitude PD and the outer drag-integrator, with the
attitude command as the single ZOH input (delayed by ``tau_in``) and ``x``
read through an output delay line of ``tau_out`` (linear interpolation between
physics samples, as the MuJoCo sensor with ``interp="linear"``):

    sim = LateralDiscrete(K=1.0, T_prop=0.05, T1=0.5, tau_in=0.01, T2=1.5, tau_out=0.04,
                          att_kp=3.0, att_kd=0.4, att_filter_hz=20.0, dt=5e-4, rate_hz=200.0)
    y = sim.reset()
    for k in range(samples):          # one call per control sample
        y = sim.step(relay(-y))
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm


def _zoh_pieces(A: np.ndarray, B: np.ndarray, dt: float, frac: float):
    """Phi, Gamma0, Gamma1 for a delay with fractional part ``frac`` in [0, dt).

    Over one step the delayed input equals the older sample for ``frac`` seconds
    and the newer one for ``dt - frac``:
    ``x+ = Phi x + Gamma1 u_old + Gamma0 u_new``.
    """
    nx = A.shape[0]

    def integral(T: float):
        # [[A, B], [0, 0]] exponential gives e^{AT} and int_0^T e^{As} B ds
        M = np.zeros((nx + 1, nx + 1))
        M[:nx, :nx] = A
        M[:nx, nx:] = B
        E = expm(M * T)
        return E[:nx, :nx], E[:nx, nx:]

    Phi, _ = integral(dt)
    Phi_new, Gam_new = integral(dt - frac)
    _, Gam_old = integral(frac)
    return Phi, Gam_new[:, 0], (Phi_new @ Gam_old)[:, 0]


class LumpedDiscrete:
    """``n`` single-input linear processes with input delay, stepped exactly at ``dt``.

    Parameters
    ----------
    A : array (n, nx, nx), B : array (n, nx, 1), C : array (nx,)
        Continuous state space per process (output ``y = C x``).
    tau : array (n,)
        Input delay per process, s.
    dt : float
        Step, s.
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, tau: np.ndarray, dt: float):
        n, nx, _ = A.shape
        self.n, self.nx, self.dt = n, nx, float(dt)
        tau = np.asarray(tau, dtype=np.float64)
        steps = np.floor(tau / dt + 1e-9).astype(np.int64)
        frac = np.clip(tau - steps * dt, 0.0, None)
        frac = np.where(frac < 1e-12, 0.0, frac)
        self.Phi = np.empty((n, nx, nx))
        self.G_new = np.empty((n, nx))
        self.G_old = np.empty((n, nx))
        for i in range(n):
            self.Phi[i], self.G_new[i], self.G_old[i] = _zoh_pieces(A[i], B[i], dt, frac[i])
        self.C = np.asarray(C, dtype=np.float64)
        self.delay_steps = steps
        self.buf_len = int(steps.max()) + 2
        self.reset()

    @classmethod
    def inner(cls, K, T_prop, T1, tau, dt: float, n: int | None = None) -> LumpedDiscrete:
        """Inner loop ``K e^{-tau s}/(s (T_prop s+1)(T1 s+1))``; arguments scalars or (n,).

        States: ``[y, dy/dt, a]`` with ``a`` the lagged propulsion command.
        """
        K, T_prop, T1, tau = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (K, T_prop, T1, tau)))
        if n is not None and K.shape[0] == 1:
            K, T_prop, T1, tau = (np.repeat(v, n) for v in (K, T_prop, T1, tau))
        m = K.shape[0]
        A = np.zeros((m, 3, 3))
        B = np.zeros((m, 3, 1))
        A[:, 0, 1] = 1.0
        A[:, 1, 1] = -1.0 / T1
        A[:, 1, 2] = K / T1
        A[:, 2, 2] = -1.0 / T_prop
        B[:, 2, 0] = 1.0 / T_prop
        return cls(A, B, np.array([1.0, 0.0, 0.0]), tau, dt)

    def reset(self, x0: np.ndarray | None = None, prehistory: str = "zero") -> np.ndarray:
        """Zero state (or ``x0`` (n, nx)); return y (n,).

        ``prehistory``: what the delay line holds before t = 0, ``"zero"`` or
        ``"first"`` (the first input, which is what MuJoCo's history buffers
        return for a read older than their first sample).
        """
        if prehistory not in ("zero", "first"):
            raise ValueError(f"prehistory must be 'zero' or 'first', got {prehistory!r}")
        self.prehistory = prehistory
        self.x = np.zeros((self.n, self.nx)) if x0 is None else np.array(x0, dtype=np.float64)
        self.hist = np.zeros((self.n, self.buf_len))
        self.k = 0
        return self.x @ self.C

    def step(self, u: np.ndarray) -> np.ndarray:
        """Apply input ``u`` (n,) at the current instant, advance ``dt``; return y (n,)."""
        L = self.buf_len
        self.hist[:, self.k % L] = u
        rows = np.arange(self.n)
        u_new = self.hist[rows, (self.k - self.delay_steps) % L]
        u_old = self.hist[rows, (self.k - self.delay_steps - 1) % L]
        # before t = 0 the input is zero, or the first input (as a MuJoCo
        # history buffer answers a read older than its first sample)
        if self.k == 0:
            self.u_first = np.array(u, dtype=np.float64, copy=True)
        pre = self.u_first if self.prehistory == "first" else 0.0
        u_new = np.where(self.k - self.delay_steps >= 0, u_new, pre)
        u_old = np.where(self.k - self.delay_steps - 1 >= 0, u_old, pre)
        self.x = (
            np.einsum("nij,nj->ni", self.Phi, self.x) + self.G_new * u_new[:, None] + self.G_old * u_old[:, None]
        )
        self.k += 1
        return self.x @ self.C


class LateralDiscrete:
    """``n`` lateral loops ``K e^{-tau_out s} T_att(s) / (s (T2 s + 1))``, stepped exactly.

    The state is the composite ``[theta, theta', a, x, x']`` of a unit-gain
    attitude process ``e^{-tau_in s} / (s (T_prop s + 1)(T1 s + 1))`` (``a`` the
    lagged propulsion command) and the outer ``x'' = (K / T2) theta - x' / T2``;
    ``theta`` is in lumped units (one unit of ``u`` is one unit of attitude
    reference), so ``x / u = K T_att / (s (T2 s + 1))`` with ``T_att`` the
    attitude loop closed by the sampled PD of ``uavsim.control.pd`` at
    ``rate_hz`` on the true ``theta``. The PD output is the only input of the
    continuous state: it is held for a control period and discretized exactly
    at the physics step ``dt`` with the input delay ``tau_in``
    (``LumpedDiscrete``). The measurement is ``x(t - tau_out)`` from a delay
    line at ``dt``, linearly interpolated between samples and zero before
    ``t = 0`` (a MuJoCo sensor history with ``interp="linear"`` answers so).

    Parameters
    ----------
    K, T_prop, T1, tau_in, T2, tau_out, att_kp, att_kd, att_filter_hz : float or array (n,)
        Lateral gain (output units per command unit per s), attitude time
        constants (s), attitude delay (s), drag time constant (s), output delay
        (s, >= dt), attitude PD gains for the unit-gain attitude process and its
        derivative filter (Hz).
    dt : float
        Physics step, s; ``1 / (rate_hz dt)`` must be a whole number.
    rate_hz : float
        Controller rate (attitude PD and the caller's outer controller), Hz.
    """

    def __init__(self, K, T_prop, T1, tau_in, T2, tau_out, att_kp, att_kd, att_filter_hz, dt: float, rate_hz: float):
        from uavsim.control.pd import PD

        vals = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float))
                                     for v in (K, T_prop, T1, tau_in, T2, tau_out, att_kp, att_kd, att_filter_hz)))
        K, T_prop, T1, tau_in, T2, tau_out, kp, kd, fhz = (v.copy() for v in vals)
        n = K.shape[0]
        steps = 1.0 / (rate_hz * dt)
        if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise ValueError(f"control period 1/{rate_hz} Hz is not a whole number of {dt} s steps")
        if np.any(tau_out < dt - 1e-12):
            raise ValueError("tau_out must be >= dt (the measurement is at least one physics step old)")
        self.n, self.dt, self.rate_steps = n, float(dt), int(round(steps))
        A = np.zeros((n, 5, 5))
        B = np.zeros((n, 5, 1))
        A[:, 0, 1] = 1.0
        A[:, 1, 1] = -1.0 / T1
        A[:, 1, 2] = 1.0 / T1
        A[:, 2, 2] = -1.0 / T_prop
        B[:, 2, 0] = 1.0 / T_prop
        A[:, 3, 4] = 1.0
        A[:, 4, 0] = K / T2
        A[:, 4, 4] = -1.0 / T2
        self.plant = LumpedDiscrete(A, B, np.array([0.0, 0.0, 0.0, 1.0, 0.0]), tau_in, dt)
        self.pd = PD(kp, kd, fhz, rate_hz, n)
        self.tau_out = tau_out
        self.out_len = int(np.ceil(tau_out.max() / dt)) + 3
        self.reset()

    @property
    def theta(self) -> np.ndarray:
        """Attitude in lumped units (n,): tilt / (tilt per command unit)."""
        return self.plant.x[:, 0].copy()

    def _measure(self) -> np.ndarray:
        # x at t_now - tau_out on the physics grid, linear between samples
        s = self.plant.k - self.tau_out / self.dt  # fractional sample index
        j0 = np.floor(s + 1e-9).astype(np.int64)
        f = np.clip(s - j0, 0.0, 1.0)
        f = np.where(f < 1e-9, 0.0, f)
        L = self.out_len
        rows = np.arange(self.n)
        x0 = np.where(j0 >= 0, self.xhist[rows, j0 % L], 0.0)
        x1 = np.where(j0 + 1 >= 0, self.xhist[rows, (j0 + 1) % L], 0.0)
        return np.where(f > 0, (1 - f) * x0 + f * x1, x0)

    def reset(self, x0: np.ndarray | None = None) -> np.ndarray:
        """Zero state (or ``x0`` (n, 5): theta, theta', a, x, x'); return the first measurement (n,)."""
        self.plant.reset(x0, prehistory="zero")
        self.pd.reset()
        self.xhist = np.zeros((self.n, self.out_len))
        self.xhist[:, 0] = self.plant.x[:, 3]
        return self._measure()

    def step(self, u: np.ndarray) -> np.ndarray:
        """Apply the lateral command ``u`` (n,) for one control period; return the measurement (n,).

        The attitude PD acts on ``u - theta`` at this instant and its output is
        held for ``rate_steps`` physics steps.
        """
        att_u = self.pd(np.asarray(u, float) - self.plant.x[:, 0])
        for _ in range(self.rate_steps):
            self.plant.step(att_u)
            self.xhist[:, self.plant.k % self.out_len] = self.plant.x[:, 3]
        return self._measure()
