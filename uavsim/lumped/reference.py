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
