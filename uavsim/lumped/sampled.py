"""Exact step ISE of a lumped loop closed by the PD sampled at the control rate.

On the vehicle the PD runs at the session's control rate ``1/Ts`` with a
zero-order hold (``uavsim.control.pd``, the "step" semantics of the session
format): at each sample ``t_k = k Ts`` the controller reads the output,
``raw_k = (e_k - e_{k-1})/Ts``, ``d_k = d_{k-1} + a (raw_k - d_{k-1})`` with
``a = Ts N / (1 + Ts N)``, ``u_k = kp e_k + kd d_k``, and ``u_k`` acts at once
over ``[t_k, t_k + Ts)`` (``uavsim.sim.runner.LoopBatch.run`` reads the state,
computes the command and then advances the physics), delayed by the process's
input delay. The step is a unit reference step at ``t_0 = 0`` from rest, in one
of two semantics (``kick``):

* ``kick=False`` (default): the PDs start at the step, ``raw_0 = 0`` (the first
  sample of ``uavsim.control.pd.PD``, what ``LoopBatch.run`` with a unit reference
  does). For this step it is the same as a derivative on the measurement;
* ``kick=True``: the PDs ran at rest before it (``e_{-1} = 0``), so the jump enters
  the derivative (a session's step run, whose reference steps at ``step_time``).

The ISE optimum differs in kind between them: with the kick the ISE-optimal PD
drives the step with the derivative impulse (``kd a / Ts``, hundreds of times
the steady command) and a proportional gain a tenth of the rule's; without it
the optimum lies near the homogeneous rule (``uavsim.tuning.optimal``).

The loop is linear and periodic with period ``Ts``, so it is lifted over one
period: with the state at the samples in coordinates relative to the final
steady state (output 1, everything else 0), ``z_{k+1} = M z_k`` and the
integral of the squared error over ``[t_k, t_{k+1})`` is ``z_k' Q z_k``.
``M`` is the exact zero-order-hold discretization, the delay split into whole
periods (shift states of the held command) and a fraction ``f`` (the period
cut at ``f Ts``: the older command before, the newer after, as
``uavsim.lumped.simulate.discretize_delayed``); ``Q`` is the intersample integral
of ``e(t)^2`` over the two pieces, by Van Loan's matrix exponential. Then

    ISE = integral_0^inf e(t)^2 dt = z_0' P z_0,     P = M' P M + Q

a discrete Lyapunov equation, solved by doubling (``P <- P + A' P A``,
``A <- A^2``: the sum of the first ``2^j`` terms after ``j`` steps, batched over
many loops). No time step, no horizon: exact to rounding. The loop is stable iff
the spectral radius of ``M`` is below 1, i.e. iff ``M^(2^j) -> 0``, which the
doubling tests as it goes; an unstable loop has ISE ``inf``.

Loops (the lumped models of ``uavsim.lumped.params``):

* inner (altitude, attitude): ``K e^{-tau s} / (s (T_prop s + 1)(T1 s + 1))``,
  the error ``e = 1 - y``;
* lateral: the unit-gain attitude process ``e^{-tau_in s}/(s (T_prop s+1)(T1 s+1))``
  closed by its own PD (``att_kp``, ``att_kd``, ``att_N``) sampled at the same
  instants on the true attitude, the outer ``x'' = (K/T2) theta - x'/T2``, and the
  measurement ``y(t) = x(t - tau)`` (the outer delay): the MuJoCo lateral loop
  (``uavsim.model.mapping``). The outer PD's output is the attitude reference.
  The error is ``e(t) = 1 - x(t - tau)``, the lumped model's own output as in the
  frequency-domain ISE (``uavsim.lumped.ise``): for ``t < tau`` it is 1, so the
  ISE is ``tau`` plus the integral of ``(1 - x)^2``.

As ``Ts -> 0`` the ISE tends to the continuous one of ``uavsim.lumped.ise``.

    from uavsim.lumped.sampled import lift, sampled_ise, step_ise_sampled
    proc = lift("altitude", 200.0, K=1.0, T_prop=0.1, T1=0.8, tau=0.0213)   # controller-free part
    Q = sampled_ise(proc, kp=[1.5, 2.0], kd=[0.4, 0.5], N=[80.0, 80.0])      # two PDs on it (broadcast)
    Q = step_ise_sampled("altitude", 1.5, 0.4, 80.0, 200.0, K=1.0, T_prop=0.1, T1=0.8, tau=0.0213)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np
from scipy.linalg import expm

from uavsim.errors import UserError
from uavsim.lumped.params import loop_family

__all__ = ["SampledProcess", "lift", "loop_matrices", "open_loop", "lyapunov_sum", "sampled_ise", "step_ise_sampled",
           "pd_step_ise", "delay_split"]

#: doubling steps at most: 2^64 periods (a loop this close to marginal stability counts as unstable)
_MAX_DOUBLING = 64
#: stop doubling once |M^(2^j)| (max entry) is below this: the tail left is of order its square
_DOUBLING_TOL = 1e-10


def delay_split(tau, Ts: float) -> tuple[np.ndarray, np.ndarray]:
    """Whole control periods ``d`` and fraction ``f`` in [0, 1) of delays ``tau`` (s), arrays (B,).

    As ``uavsim.lumped.simulate.discretize_delayed``: ``tau = (d + f) Ts``, a fraction
    under 1e-9 counts as 0.
    """
    q = np.asarray(tau, dtype=np.float64) / Ts
    d = np.floor(q + 1e-9).astype(np.int64)
    f = np.maximum(q - d, 0.0)
    return d, np.where(f < 1e-9, 0.0, f)


@dataclass(frozen=True)
class SampledProcess:
    """The controller-free part of B lifted loops (``lift``); arrays over the batch.

    Attributes
    ----------
    family : str
        ``altitude``, ``attitude`` or ``lateral``.
    rate_hz : float
        Control rate, Hz.
    Px : ndarray (B, nx, nx + 2)
        ``X_{k+1} = Px [X_k; v_old; v_new]``: the plant state over one period under the
        older held command (for ``f Ts``) then the newer one.
    W : ndarray (B, nx + 2, nx + 2)
        Integral of ``e(t)^2`` over one period, a quadratic form in ``[X_k; v_old; v_new]``.
    d_in : ndarray (B,) int
        Whole periods of the input delay (``tau`` inner, ``tau_in`` lateral).
    X0 : ndarray (B, nx)
        Plant state at the step relative to the final steady state.
    m_row : ndarray (B, nx + 2) or None
        Lateral: ``x(t_k + (1 - f_out) Ts) - 1`` as a row on ``[X_k; v_old; v_new]``.
    d_out : ndarray (B,) int or None
        Lateral: whole periods of the outer delay.
    att : ndarray (B, 3) or None
        Lateral: the attitude PD's ``kp``, ``kd`` and ``a = Ts N / (1 + Ts N)``.
    offset : ndarray (B,)
        ISE accumulated before the lifted sum starts (lateral: ``tau``, the output delay).
    """

    family: str
    rate_hz: float
    Px: np.ndarray
    W: np.ndarray
    d_in: np.ndarray
    X0: np.ndarray
    offset: np.ndarray
    m_row: np.ndarray | None = None
    d_out: np.ndarray | None = None
    att: np.ndarray | None = None

    @property
    def B(self) -> int:
        return self.Px.shape[0]

    @property
    def Ts(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def nx(self) -> int:
        return self.Px.shape[1]

    def take(self, idx) -> SampledProcess:
        """The loops ``idx`` (int array) of the batch, e.g. one process repeated for many controllers."""
        idx = np.asarray(idx, dtype=np.int64)
        kw = {f.name: getattr(self, f.name)[idx] for f in fields(self)
              if isinstance(getattr(self, f.name), np.ndarray)}
        return replace(self, **kw)


def _broadcast(*vals) -> tuple[int, list[np.ndarray]]:
    arrs = [np.atleast_1d(np.asarray(v, dtype=np.float64)).reshape(-1) for v in vals]
    B = max(a.size for a in arrs)
    for a in arrs:
        if a.size not in (1, B):
            raise UserError(f"parameter arrays of sizes {sorted({x.size for x in arrs})} do not broadcast")
    return B, [np.broadcast_to(a, (B,)).copy() for a in arrs]


def _van_loan(F: np.ndarray, Qw: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(e^{F h}, int_0^h e^{F' s} Qw e^{F s} ds)`` for batches F (B, n, n), h (B,)."""
    B, n, _ = F.shape
    C = np.zeros((B, 2 * n, 2 * n))
    C[:, :n, :n] = -np.swapaxes(F, 1, 2)
    C[:, :n, n:] = Qw
    C[:, n:, n:] = F
    E = expm(C * h[:, None, None])
    Phi = E[:, n:, n:]
    return Phi, np.swapaxes(Phi, 1, 2) @ E[:, :n, n:]


def _plant(family: str, B: int, p: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Continuous (A, b, c_err, X_star): state matrices, input column, error row, steady state."""
    if family == "lateral":
        # [theta, theta', a, x, x']: unit-gain attitude process, then x'' = (K/T2) theta - x'/T2
        A = np.zeros((B, 5, 5))
        A[:, 0, 1] = 1.0
        A[:, 1, 1] = -1.0 / p["T1"]
        A[:, 1, 2] = 1.0 / p["T1"]
        A[:, 2, 2] = -1.0 / p["T_prop"]
        A[:, 3, 4] = 1.0
        A[:, 4, 0] = p["K"] / p["T2"]
        A[:, 4, 4] = -1.0 / p["T2"]
        b = np.zeros((B, 5))
        b[:, 2] = 1.0 / p["T_prop"]
        c = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
    else:
        # [y, y', a]: as uavsim.lumped.simulate.inner_state_space
        A = np.zeros((B, 3, 3))
        A[:, 0, 1] = 1.0
        A[:, 1, 1] = -1.0 / p["T1"]
        A[:, 1, 2] = 1.0 / p["T1"]
        A[:, 2, 2] = -1.0 / p["T_prop"]
        b = np.zeros((B, 3))
        b[:, 2] = p["K"] / p["T_prop"]
        c = np.array([1.0, 0.0, 0.0])
    return A, b, c, c.copy()  # the steady state is output 1, the rest 0


def lift(family: str, rate_hz: float, *, K, T_prop, T1, tau, T2=None, tau_in=None, att_kp=None, att_kd=None,
         att_N=None, att_rate_hz=None) -> SampledProcess:
    """Lift B lumped processes over one control period (the part of the loop no controller changes).

    Parameters
    ----------
    family : str
        Loop or family name (``altitude``, ``roll``/``pitch``/``attitude``, ``lateral_x``/``lateral``...).
    rate_hz : float
        Control rate, Hz.
    K, T_prop, T1, tau : float or ndarray (B,)
        Process gain (output units per command unit per s; lateral: per attitude-reference
        unit), time constants (s) and delay (s; lateral: the outer delay).
    T2, tau_in, att_kp, att_kd, att_N : float or ndarray (B,), lateral only
        Drag time constant (s), attitude delay (s), the attitude PD for the unit-gain attitude
        process and its derivative filter (rad/s), sampled at ``rate_hz`` like the outer PD.
    att_rate_hz : float or None, lateral only
        The attitude PD's rate as the process states it (``uavsim.lumped.frequency``); it must be
        ``rate_hz`` (the lifted loop samples both PDs at the same instants). None: ``rate_hz``.

    Returns
    -------
    SampledProcess
    """
    fam = loop_family(family)
    if not (isinstance(rate_hz, (int, float, np.floating)) and math.isfinite(rate_hz) and rate_hz > 0):
        raise UserError(f"control rate must be > 0 Hz, got {rate_hz!r}")
    Ts = 1.0 / float(rate_hz)
    lateral = fam == "lateral"
    names = ["K", "T_prop", "T1", "tau"] + (["T2", "tau_in", "att_kp", "att_kd", "att_N"] if lateral else [])
    vals = [K, T_prop, T1, tau] + ([T2, tau_in, att_kp, att_kd, att_N] if lateral else [])
    if lateral and any(v is None for v in vals):
        raise UserError("a lateral loop needs T2, tau_in, att_kp, att_kd and att_N")
    if att_rate_hz is not None and np.any(np.asarray(att_rate_hz, dtype=np.float64) != float(rate_hz)):
        raise UserError(f"the attitude PD runs at {att_rate_hz} Hz: the lifted loop samples it at {rate_hz:g} Hz")
    B, arrs = _broadcast(*vals)
    p = dict(zip(names, arrs, strict=True))
    if not all(np.all(np.isfinite(a)) for a in arrs):
        raise UserError(f"{fam} process parameters must be finite")
    if np.any(p["T_prop"] <= 0) or np.any(p["T1"] <= 0) or np.any(p["tau"] < 0) or np.any(p["K"] == 0):
        raise UserError(f"{fam} process: need T_prop > 0, T1 > 0, tau >= 0, K != 0")
    if lateral and (np.any(p["T2"] <= 0) or np.any(p["tau_in"] < 0) or np.any(p["att_N"] <= 0)):
        raise UserError("lateral process: need T2 > 0, tau_in >= 0, att_N > 0")
    A, b, c, xs = _plant(fam, B, p)
    nx = A.shape[1]
    d_in, f_in = delay_split(p["tau_in"] if lateral else p["tau"], Ts)
    n = nx + 2
    F1 = np.zeros((B, n, n))  # [X; v_old; v_new] with the older command driving the plant
    F1[:, :nx, :nx] = A
    F1[:, :nx, nx] = b
    F2 = np.zeros((B, n, n))
    F2[:, :nx, :nx] = A
    F2[:, :nx, nx + 1] = b
    Qw = np.zeros((n, n))
    Qw[:nx, :nx] = np.outer(c, c)
    Qw = np.broadcast_to(Qw, (B, n, n))
    h1 = f_in * Ts
    E1, W1 = _van_loan(F1, Qw, h1)
    E2, W2 = _van_loan(F2, Qw, Ts - h1)
    E = E2 @ E1
    W = W1 + np.swapaxes(E1, 1, 2) @ W2 @ E1
    W = 0.5 * (W + np.swapaxes(W, 1, 2))
    X0 = -np.broadcast_to(xs, (B, nx)).copy()
    offset = np.zeros(B)
    kw = {}
    if lateral:
        d_out, f_out = delay_split(p["tau"], Ts)
        t_m = (1.0 - f_out) * Ts  # x(t_{k+1} - f_out Ts) = x(t_k + t_m)
        before = t_m <= h1
        Ea = expm(F1 * np.where(before, t_m, 0.0)[:, None, None])
        Eb = expm(F2 * np.where(before, 0.0, t_m - h1)[:, None, None]) @ E1
        Em = np.where(before[:, None, None], Ea, Eb)
        a_att = Ts * p["att_N"] / (1.0 + Ts * p["att_N"])
        kw = {"m_row": np.einsum("i,bij->bj", c, Em[:, :nx, :]), "d_out": d_out,
              "att": np.column_stack([p["att_kp"], p["att_kd"], a_att])}
        offset = p["tau"].copy()
    return SampledProcess(fam, float(rate_hz), E[:, :nx, :], W, d_in, X0, offset, **kw)


def _pairs(proc: SampledProcess, kp, kd, N) -> tuple[SampledProcess, np.ndarray, np.ndarray, np.ndarray]:
    """Processes and PDs broadcast against each other: ``(proc, kp, kd, N)`` of one batch size."""
    Bp = proc.B
    B, (kp, kd, N) = _broadcast(kp, kd, N)
    if Bp not in (1, B) and B != 1:
        raise UserError(f"{Bp} processes and {B} controllers do not broadcast")
    if Bp == 1 and B > 1:
        proc = proc.take(np.zeros(B, dtype=np.int64))
    B = proc.B
    kp, kd, N = (np.broadcast_to(v, (B,)) for v in (kp, kd, N))
    return proc, kp, kd, N


def lifted_layout(proc: SampledProcess) -> dict[str, int]:
    """Indices of the lifted state's blocks (``loop_matrices``) and its size ``n``."""
    nx = proc.nx
    lateral = proc.family == "lateral"
    H = int(proc.d_in.max()) + 1
    R = int(proc.d_out.max()) + 1 if lateral else 0
    iE = nx + H
    iM = iE + 4 if lateral else iE + 2
    return {"H": H, "R": R, "iH": nx, "iE": iE, "iEa": iE + 2, "iM": iM, "n": iM + R}


def _output_index(proc: SampledProcess) -> np.ndarray:
    """Index of the measured output ``y_k`` in the lifted state, (B,)."""
    if proc.family == "lateral":
        return lifted_layout(proc)["iM"] + proc.d_out
    return np.zeros(proc.B, dtype=np.int64)


def loop_matrices(proc: SampledProcess, kp, kd, N, kick: bool = False,
                  input_state: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lifted closed loop of each (process, PD) pair: ``(M, Q, z0)``.

    Parameters
    ----------
    proc : SampledProcess
        B processes (or 1, broadcast against the gains).
    kp, kd : float or ndarray
        PD gains (command units per output unit, and per output unit/s).
    N : float or ndarray
        Derivative filter, rad/s (> 0).
    kick : bool
        The step semantics (module docstring): False, the PDs start at the step
        (``raw_0 = 0``); True, they ran at rest before it (``e_{-1} = 0``: the jump
        enters the derivatives).
    input_state : bool
        Append a state (last, held constant by nobody: its row of ``M`` is 0) that adds to the
        outer PD's output: its column of ``M`` is the loop's input column (``open_loop``).

    Returns
    -------
    M : ndarray (B, n, n)
        ``z_{k+1} = M z_k``.
    Q : ndarray (B, n, n)
        Integral of ``e^2`` over ``[t_k, t_{k+1})`` is ``z_k' Q z_k``.
    z0 : ndarray (B, n)
        The state at the step.

    The state ``z`` is ``[X (nx) | v_{k-1} .. v_{k-H} (held commands) | e_{k-1}, d_{k-1}`` (outer PD)
    ``| e_att, d_att`` (lateral) ``| m_k .. m_{k-R}`` (lateral: ``x`` at ``t_k - f_out Ts``)``]``.
    """
    proc, kp, kd, N = _pairs(proc, kp, kd, N)
    B = proc.B
    if np.any(N <= 0):
        raise UserError("the derivative filter N must be > 0 rad/s")
    Ts = proc.Ts
    nx = proc.nx
    lateral = proc.family == "lateral"
    lay = lifted_layout(proc)
    H, R, iH, iE, iEa, iM = (lay[k] for k in ("H", "R", "iH", "iE", "iEa", "iM"))
    n = lay["n"] + int(input_state)
    rows = np.arange(B)

    def unit(j) -> np.ndarray:
        r = np.zeros((B, n))
        r[rows, np.broadcast_to(np.asarray(j), (B,))] = 1.0
        return r

    a = (Ts * N / (1.0 + Ts * N))[:, None]
    y = unit(_output_index(proc))
    e = -y
    d = (1.0 - a) * unit(iE + 1) + a * (e - unit(iE)) / Ts
    u = kp[:, None] * e + kd[:, None] * d
    if input_state:
        u = u + unit(n - 1)
    if lateral:
        kpa, kda, aa = (proc.att[:, i:i + 1] for i in range(3))
        ea = u - unit(0)
        da = (1.0 - aa) * unit(iEa + 1) + aa * (ea - unit(iEa)) / Ts
        v = kpa * ea + kda * da
    else:
        v = u
    v_old = unit(iH + proc.d_in)
    v_new = np.where((proc.d_in == 0)[:, None], v, unit(iH + np.maximum(proc.d_in - 1, 0)))
    S = np.concatenate([np.broadcast_to(np.eye(nx, n), (B, nx, n)), v_old[:, None], v_new[:, None]], axis=1)
    M = np.zeros((B, n, n))
    M[:, :nx] = proc.Px @ S
    M[:, iH] = v
    M[:, iH + 1: iH + H] = np.eye(H - 1, n, iH)[None] if H > 1 else 0.0
    M[:, iE] = e
    M[:, iE + 1] = d
    if lateral:
        M[:, iEa] = ea
        M[:, iEa + 1] = da
        M[:, iM] = np.einsum("bj,bjn->bn", proc.m_row, S)
        if R > 1:
            M[:, iM + 1: iM + R] = np.eye(R - 1, n, iM)[None]
    Q = np.swapaxes(S, 1, 2) @ proc.W @ S
    z0 = np.zeros((B, n))
    z0[:, :nx] = proc.X0
    if lateral:
        z0[:, iM:iM + R] = -1.0  # x = 0 before the step: 1 below its final value
    if not kick:
        # e_{-1} = e_0 = 1 (nothing measured yet) and, lateral, e_att,{-1} = e_att,0 = u_0 = kp:
        # both raw differences start at 0
        z0[:, iE] = 1.0
        if lateral:
            z0[:, iEa] = kp
    return M, Q, z0


def open_loop(proc: SampledProcess) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lifted loops with the outer controller taken out: ``(A, b, c)``.

    ``z_{k+1} = A z_k + b u_k`` and ``y_k = c z_k``, with ``u_k`` the outer command at the
    sample ``t_k`` (held over the period; lateral: the attitude reference, which the attitude
    PD inside reads at the same instants) and ``y_k`` the measured output (lateral:
    ``x(t_k - tau)``). Exact at the samples for any input sequence: a relay at the control
    rate (``uavsim.lumped.lateral.sampled_relay_cycle``) or the sampled frequency response
    ``c (z I - A)^{-1} b``. Shapes (B, n, n), (B, n), (B, n); the outer PD's two states are
    kept (and stay 0), so the layout is that of ``loop_matrices``.
    """
    M, _, _ = loop_matrices(proc, 0.0, 0.0, 1.0, input_state=True)
    n = M.shape[1] - 1
    c = np.zeros((proc.B, n))
    c[np.arange(proc.B), _output_index(proc)] = 1.0
    return M[:, :n, :n].copy(), M[:, :n, n].copy(), c


def lyapunov_sum(M: np.ndarray, Q: np.ndarray, z0: np.ndarray, return_rho: bool = False):
    """``z0' P z0`` with ``P = sum_k (M^k)' Q M^k`` for batches; ``inf`` where ``rho(M) >= 1``.

    Doubling: after ``j`` steps ``A = M^(2^j)`` and ``P`` holds the first ``2^j`` terms. The
    spectral radius is below 1 exactly when ``M^k -> 0``, which the same iteration tests: a
    stable loop's ``A`` falls below ``_DOUBLING_TOL`` (the tail left is of order its square),
    an unstable one's overflows or never falls within ``2^64`` periods (no eigenvalue
    decomposition: it would cost more than the sum, and is ill-conditioned on the delay
    line's nilpotent blocks).

    Parameters
    ----------
    M, Q : ndarray (B, n, n)
    z0 : ndarray (B, n)
    return_rho : bool
        Also return the spectral radius of each ``M`` (eigenvalues; for diagnostics).

    Returns
    -------
    J : ndarray (B,)
    rho : ndarray (B,), only with ``return_rho``
    """
    B = M.shape[0]
    out = np.full(B, np.inf)
    act = np.arange(B)
    P = Q.copy()
    A = M.copy()
    with np.errstate(all="ignore"):
        for _ in range(_MAX_DOUBLING):
            if act.size == 0:
                break
            P = P + np.swapaxes(A, 1, 2) @ P @ A
            A = A @ A
            big = np.abs(A).reshape(A.shape[0], -1).max(axis=1)
            done = big < _DOUBLING_TOL
            bad = ~np.isfinite(big) | ~np.isfinite(P.reshape(P.shape[0], -1).max(axis=1))
            done &= ~bad
            if done.any():
                i = act[done]
                out[i] = np.einsum("bi,bij,bj->b", z0[i], P[done], z0[i])
            keep = ~(done | bad)
            act, P, A = act[keep], P[keep], A[keep]
        if not return_rho:
            return out
        rho = np.abs(np.linalg.eigvals(M)).max(axis=-1) if B else np.zeros(0)
    return out, rho


def sampled_ise(proc: SampledProcess, kp, kd, N, return_stable: bool = False, kick: bool = False):
    """Exact unit-step ISE of each (process, sampled PD) pair, (B,); ``inf`` where unstable.

    Parameters
    ----------
    proc : SampledProcess
        From ``lift`` (B processes, or 1 broadcast against the gains).
    kp, kd, N : float or ndarray (B,)
        PD gains and derivative filter (rad/s).
    return_stable : bool
        Also return whether each loop is stable (spectral radius below 1).
    kick : bool
        Step semantics (``loop_matrices``): default False, the PDs start at the step.

    Returns
    -------
    Q : ndarray (B,)
        ISE, output-units^2 s.
    stable : ndarray of bool (B,), only with ``return_stable``
    """
    proc, kp, kd, N = _pairs(proc, kp, kd, N)
    J = np.empty(proc.B)
    # the state holds the delay lines of the longest delays in the batch: loops of like delays
    # together (the doubling's cost grows as the cube of the state size)
    size = proc.d_in + (proc.d_out if proc.d_out is not None else 0)
    for n in np.unique(np.minimum(size, np.maximum(4, size) // 4 * 4)):
        idx = np.flatnonzero(np.minimum(size, np.maximum(4, size) // 4 * 4) == n)
        M, Qm, z0 = loop_matrices(proc.take(idx), kp[idx], kd[idx], N[idx], kick=kick)
        J[idx] = lyapunov_sum(M, Qm, z0)
    Q = np.where(np.isfinite(J), J + proc.offset, np.inf)
    return (Q, np.isfinite(Q)) if return_stable else Q


def step_ise_sampled(family: str, kp, kd, N, rate_hz: float, return_stable: bool = False, kick: bool = False,
                     **params):
    """``sampled_ise`` of B (controller, process) pairs given by their parameters (as ``lift``)."""
    proc = lift(family, rate_hz, **params)
    return sampled_ise(proc, kp, kd, N, return_stable=return_stable, kick=kick)


def pd_step_ise(family: str, rate_hz: float, kp, kd, N, *, batch: int | None = None, **params) -> np.ndarray:
    """``step_ise_sampled`` of B (PD, process) pairs where a PD may be no PD at all, (B,).

    A pair whose ``kp``, ``kd`` or ``N`` is not finite, or with ``kp <= 0`` or ``kd < 0`` (an
    answer that could not be computed), and a pair whose loop is unstable, get ``inf``; only
    the others are lifted. ``params`` are ``lift``'s, (B,) arrays or scalars; ``batch``: pairs
    per ``sampled_ise`` call (memory), None for one call.
    """
    kp, kd, N = (np.asarray(v, dtype=np.float64) for v in (kp, kd, N))
    B = kp.size
    out = np.full(B, np.inf)
    step = B if batch is None else int(batch)
    for a in range(0, B, max(step, 1)):
        s = slice(a, min(a + step, B))
        good = np.isfinite(kp[s]) & np.isfinite(kd[s]) & np.isfinite(N[s]) & (kp[s] > 0) & (kd[s] >= 0)
        if not good.any():
            continue
        idx = np.arange(a, s.stop)[good]
        proc = lift(family, rate_hz, **{k: (np.asarray(v, dtype=np.float64)[idx] if np.ndim(v) else v)
                                        for k, v in params.items()})
        with np.errstate(all="ignore"):
            q = sampled_ise(proc, kp[idx], kd[idx], N[idx])
        out[idx] = np.where(np.isfinite(q), q, np.inf)
    return out
