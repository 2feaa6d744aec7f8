"""The ISE-optimal PD of a lumped process at the control rate.

The PD the vehicle flies is sampled at the control rate with a zero-order hold
(``uavsim.lumped.sampled``); its step ISE is computed exactly there, and this
module minimizes it over ``(kp, kd)``:

* the derivative filter is fixed by the rule, not optimized:
  ``N = 10 Omega`` (``Omega`` the process's describing-function MRFT frequency at
  ``beta = -0.73``, as the homogeneous rule), capped at a quarter of the control
  rate (``N <= 2 pi rate / 4``: the filter of a sampled derivative cannot cut
  above the Nyquist frequency, and half of it keeps the derivative's noise down).
  The ISE alone would drive the filter open (a noise-free criterion favours the
  raw difference), so optimizing it is no answer a vehicle can fly. The filter
  is part of the answer's gains (``derivative_filter_hz``);
* the step is taken with the PD started at it (``kick=False`` of
  ``uavsim.lumped.sampled``: no derivative kick). With the kick the ISE optimum
  is another kind of controller, ``kp`` a tenth of the rule's and the step
  driven by the derivative impulse (hundreds of times the steady command,
  which a vehicle saturates), and the rule would sit at J ~ 2 from it; without
  it the optimum lies near the rule (optimal ``kp`` 0.5-1.9 x the rule's);
* the search runs in ``(log kp, log kd)`` from the best stable node of a scan
  around the rule's gains (the rule itself is unstable at the control rate for
  the fastest processes), then a batched trust-region Newton method on
  ``log ISE`` with finite-difference derivatives on a 3 x 3 stencil; every
  accepted step lowers the ISE, so the answer is never worse than the start
  and never unstable.

All of it is batched: B processes are optimized together, each iteration
evaluating every stencil in one ``sampled_ise`` call.

Gains are for the process as given; for unit-gain processes (K = 1, the grids'
normalization) a process of gain K takes ``kp / K``, ``kd / K`` and the same
filter: the loop depends on ``K kp`` and ``K kd`` only (``scale_gains``).

    from uavsim.tuning.optimal import optimal_pd, optimal_gains
    g = optimal_pd(LumpedParams("altitude", 1.0, 0.1, 0.8, 0.02), rate_hz=200.0)
    g.kp, g.kd, g.derivative_filter_hz, g.ise
    G = optimal_gains("altitude", 200.0, K=1.0, T_prop=[0.1, 0.2], T1=0.8, tau=0.02)   # arrays
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.frequency import batch_args, mrft_prediction_batch
from uavsim.lumped.lateral import DERIVATIVE_FILTER_RATIO
from uavsim.lumped.params import LumpedParams, loop_family
from uavsim.lumped.sampled import SampledProcess, lift, sampled_ise
from uavsim.tuning.rule import TuningRule

__all__ = ["DEFAULT_RATE_HZ", "FILTER_CAP_FRACTION", "OptimalGains", "derivative_filter", "minimize_ise", "minimize_log",
           "optimal_gains", "optimal_pd", "scale_gains"]

#: the control rate of the vehicle (paper: 200 Hz loop)
DEFAULT_RATE_HZ = 200.0
#: the derivative filter's cut-off is at most this fraction of the control rate
FILTER_CAP_FRACTION = 0.25

# scan of the start: kp and Td = kd/kp as multiples of the rule's
_SCAN_KP = np.array([0.15, 0.25, 0.4, 0.6, 0.8, 1.0, 1.25, 1.6])
_SCAN_TD = np.array([0.35, 0.6, 1.0, 1.6, 2.5])
# the finite-difference stencil of the Newton step (offsets in units of the step h)
_STENCIL = np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [1, -1], [-1, 1], [-1, -1]], dtype=float)


def derivative_filter(omega, rate_hz: float) -> np.ndarray:
    """The derivative filter (rad/s): ``min(10 omega, 2 pi FILTER_CAP_FRACTION rate_hz)``, (B,).

    ``omega``: the process's DF MRFT frequency at the rule's beta, rad/s.
    """
    return np.minimum(DERIVATIVE_FILTER_RATIO * np.asarray(omega, dtype=np.float64),
                      2.0 * math.pi * FILTER_CAP_FRACTION * float(rate_hz))


def scale_gains(kp, kd, K) -> tuple[np.ndarray, np.ndarray]:
    """Unit-gain (K = 1) gains for a process of gain ``K``: ``(kp / K, kd / K)``; the filter is unchanged."""
    K = np.asarray(K, dtype=np.float64)
    if np.any(~np.isfinite(K)) or np.any(K == 0):
        raise UserError(f"process gain K must be finite and non-zero, got {K!r}")
    return np.asarray(kp, dtype=np.float64) / K, np.asarray(kd, dtype=np.float64) / K


@dataclass(frozen=True)
class OptimalGains:
    """ISE-optimal PDs of B processes at one control rate (arrays (B,)).

    Attributes
    ----------
    kp, kd : PD gains for the processes as given (command/output, command s/output)
    derivative_filter_hz : the filter (Hz), ``N / (2 pi)``
    ise : the optimal step ISE, output^2 s (inf: no stable PD found)
    rate_hz : control rate, Hz
    omega : DF MRFT frequency at the rule's beta, rad/s (the filter's reference)
    rule_kp, rule_kd : the homogeneous rule's gains (continuous-time design, same filter)
    rule_ise : the rule's ISE at the control rate with its own filter ``10 omega`` (inf: unstable)
    iterations : Newton iterations used
    converged : whether the step fell below the tolerance
    """

    kp: np.ndarray
    kd: np.ndarray
    derivative_filter_hz: np.ndarray
    ise: np.ndarray
    rate_hz: float
    omega: np.ndarray
    rule_kp: np.ndarray
    rule_kd: np.ndarray
    rule_ise: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray

    @property
    def N(self) -> np.ndarray:
        """Derivative filter, rad/s."""
        return 2.0 * math.pi * self.derivative_filter_hz

    @property
    def n(self) -> int:
        return int(self.kp.shape[0])

    def row(self, i: int) -> dict[str, float]:
        """Process ``i`` as plain floats."""
        return {"kp": float(self.kp[i]), "kd": float(self.kd[i]), "derivative_filter_hz": float(self.derivative_filter_hz[i]),
                "ise": float(self.ise[i]), "rate_hz": self.rate_hz, "omega": float(self.omega[i]),
                "rule_kp": float(self.rule_kp[i]), "rule_kd": float(self.rule_kd[i]), "rule_ise": float(self.rule_ise[i]),
                "iterations": int(self.iterations[i]), "converged": bool(self.converged[i])}


def _log_ise(proc: SampledProcess, idx: np.ndarray, th: np.ndarray, N: np.ndarray, kick: bool = False) -> np.ndarray:
    """``log ISE`` of processes ``idx`` at log-gains ``th`` (m, 2); inf where unstable."""
    if len(idx) == 0:
        return np.zeros(0)
    with np.errstate(over="ignore"):
        q = sampled_ise(proc.take(idx), np.exp(th[:, 0]), np.exp(th[:, 1]), N[idx], kick=kick)
    with np.errstate(divide="ignore"):
        return np.where(np.isfinite(q) & (q > 0), np.log(q), np.inf)


def minimize_log(logf, th0: np.ndarray, *, max_iter: int = 60, tol: float = 1e-7,
                 h0: float = 0.02) -> dict[str, np.ndarray]:
    """Batched trust-region Newton on a smooth objective of ``(log kp, log kd)``.

    Parameters
    ----------
    logf : callable (idx (m,), th (m, 2)) -> (m,)
        The objective of problems ``idx`` at points ``th`` (e.g. ``log ISE``); ``inf`` where not
        admissible (an unstable loop). One call per iteration evaluates all active problems.
    th0 : ndarray (B, 2)
        Admissible starting points.
    max_iter, tol, h0 : see ``minimize_ise``.

    Returns
    -------
    dict: ``th`` (B, 2), ``f`` (B,), ``iterations`` (B,), ``converged`` (B,).

    Derivatives come from a 3 x 3 finite-difference stencil of step ``h``; a stencil that
    touches an inadmissible point is shrunk and retried. Only decreasing steps are
    accepted, so the answer is admissible and never worse than the start.
    """
    th = np.array(th0, dtype=np.float64).reshape(-1, 2)
    B = th.shape[0]
    f = logf(np.arange(B), th)
    if not np.all(np.isfinite(f)):
        raise UserError("the optimization needs admissible (stable) starting gains")
    delta = np.full(B, 0.5)  # trust radius
    h = np.full(B, h0)
    iters = np.zeros(B, dtype=np.int64)
    conv = np.zeros(B, dtype=bool)
    active = np.arange(B)
    for _ in range(max_iter):
        if active.size == 0:
            break
        m = active.size
        pts = th[active][:, None, :] + h[active][:, None, None] * _STENCIL[None]  # (m, 8, 2)
        fs = logf(np.repeat(active, 8), pts.reshape(-1, 2)).reshape(m, 8)
        f0 = f[active]
        hh = h[active]
        fin = np.all(np.isfinite(fs), axis=1)
        fs = np.where(fin[:, None], fs, 0.0)  # a stencil touching instability is not used (below)
        g = np.column_stack([fs[:, 0] - fs[:, 1], fs[:, 2] - fs[:, 3]]) / (2 * hh[:, None])
        Hxx = (fs[:, 0] - 2 * f0 + fs[:, 1]) / hh**2
        Hyy = (fs[:, 2] - 2 * f0 + fs[:, 3]) / hh**2
        Hxy = (fs[:, 4] - fs[:, 5] - fs[:, 6] + fs[:, 7]) / (4 * hh**2)
        H = np.stack([np.stack([Hxx, Hxy], -1), np.stack([Hxy, Hyy], -1)], -2)
        H = np.where(fin[:, None, None], H, np.eye(2))
        g = np.where(fin[:, None], g, 0.0)
        # Levenberg-regularized Newton step inside the trust radius
        lam_min = np.linalg.eigvalsh(H)[:, 0]
        dl = delta[active]
        lam = np.maximum(0.0, -lam_min + 1e-6 * np.maximum(1.0, np.abs(lam_min)))
        s = np.zeros((m, 2))
        for _k in range(30):
            Hl = H + lam[:, None, None] * np.eye(2)
            s = -np.linalg.solve(Hl, g[:, :, None])[:, :, 0]
            too_long = np.hypot(s[:, 0], s[:, 1]) > dl
            if not too_long.any():
                break
            lam = np.where(too_long, np.maximum(2.0 * lam, 1e-3 * np.maximum(1.0, np.abs(np.diagonal(H, axis1=1, axis2=2)).max(1))), lam)
        sl = np.hypot(s[:, 0], s[:, 1])
        over = sl > dl
        s = np.where(over[:, None], s * (dl / np.maximum(sl, 1e-300))[:, None], s)
        sl = np.minimum(sl, dl)
        # a stencil touching instability: shrink it and retry from the same point
        s = np.where(fin[:, None], s, 0.0)
        f_new = logf(active, th[active] + s)
        pred = -(np.einsum("mi,mi->m", g, s) + 0.5 * np.einsum("mi,mij,mj->m", s, H, s))
        better = fin & (f_new < f0)
        ratio = np.where(pred > 0, (f0 - f_new) / np.maximum(pred, 1e-300), 0.0)
        th[active] = np.where(better[:, None], th[active] + s, th[active])
        f[active] = np.where(better, f_new, f0)
        grow = better & (ratio > 0.75) & (sl >= 0.99 * dl)
        shrink = fin & (~better | (ratio < 0.25))
        delta[active] = np.where(grow, 2.0 * dl, np.where(shrink, 0.25 * np.maximum(sl, 1e-12), dl))
        # the stencil follows the step (at least 1e-4: below it rounding of the ISE takes over)
        h[active] = np.where(fin, np.clip(np.minimum(hh, 0.5 * np.maximum(sl, 1e-4)), 1e-4, h0), 0.25 * hh)
        iters[active] += 1
        done = (fin & (sl < tol)) | (delta[active] < tol) | (hh < 1e-8)
        conv[active] = done & fin
        active = active[~done]
    return {"th": th, "f": f, "iterations": iters, "converged": conv}


def minimize_ise(proc: SampledProcess, N, kp0, kd0, *, max_iter: int = 60, tol: float = 1e-7,
                 h0: float = 0.02, kick: bool = False) -> dict[str, np.ndarray]:
    """Minimize the sampled ISE over ``(kp, kd)`` from stable starts, batched (``minimize_log``).

    Parameters
    ----------
    proc : SampledProcess
        B processes (``uavsim.lumped.sampled.lift``).
    N : float or ndarray (B,)
        Fixed derivative filters, rad/s.
    kp0, kd0 : ndarray (B,)
        Starting gains; each must give a stable loop (finite ISE).
    max_iter : int
        Newton iterations at most.
    tol : float
        Convergence: a step shorter than ``tol`` in ``(log kp, log kd)``.
    h0 : float
        First finite-difference step, in log units.
    kick : bool
        Step semantics of the ISE (``uavsim.lumped.sampled``).

    Returns
    -------
    dict of (B,) arrays: ``kp``, ``kd``, ``ise``, ``iterations``, ``converged``.
    """
    B = proc.B
    N = np.broadcast_to(np.asarray(N, dtype=np.float64), (B,)).copy()
    th0 = np.column_stack([np.log(np.broadcast_to(kp0, (B,))), np.log(np.broadcast_to(kd0, (B,)))])
    r = minimize_log(lambda idx, th: _log_ise(proc, idx, th, N, kick), th0, max_iter=max_iter, tol=tol, h0=h0)
    return {"kp": np.exp(r["th"][:, 0]), "kd": np.exp(r["th"][:, 1]), "ise": np.exp(r["f"]),
            "iterations": r["iterations"], "converged": r["converged"]}


def _start(proc: SampledProcess, N: np.ndarray, kp_r: np.ndarray, kd_r: np.ndarray,
           kick: bool) -> tuple[np.ndarray, np.ndarray]:
    """Best stable node of the scan around the rule (``_SCAN_KP`` x ``_SCAN_TD``), widened downwards if none."""
    B = proc.B
    kp0 = np.full(B, np.nan)
    kd0 = np.full(B, np.nan)
    todo = np.arange(B)
    scale = 1.0
    for _ in range(4):
        if todo.size == 0:
            break
        ck, ct = (a.ravel() for a in np.meshgrid(_SCAN_KP * scale, _SCAN_TD, indexing="ij"))
        m = ck.size
        idx = np.repeat(todo, m)
        kp = kp_r[idx] * np.tile(ck, todo.size)
        kd = kd_r[idx] * np.tile(ck * ct, todo.size)
        th = np.column_stack([np.log(kp), np.log(kd)])
        f = _log_ise(proc, idx, th, N, kick).reshape(todo.size, m)
        j = np.argmin(f, axis=1)
        ok = np.isfinite(f[np.arange(todo.size), j])
        sel = np.arange(todo.size) * m + j
        kp0[todo[ok]] = kp[sel[ok]]
        kd0[todo[ok]] = kd[sel[ok]]
        todo = todo[~ok]
        scale *= 0.1
    return kp0, kd0


def optimal_gains(family: str, rate_hz: float = DEFAULT_RATE_HZ, *, rule: TuningRule | None = None,
                  kick: bool = False, start: tuple | None = None, **params) -> OptimalGains:
    """ISE-optimal PDs at ``rate_hz`` of B processes of one family (batched).

    Parameters
    ----------
    family : str
        Loop or family name.
    rate_hz : float
        Control rate, Hz.
    rule : TuningRule or None
        The rule whose gains start the search and are reported beside the optimum; its
        ``beta`` sets the DF frequency ``omega`` of the filter (``derivative_filter``).
        Default: the inner loops' ``TuningRule()`` (beta -0.73, pm 20 deg); a lateral
        sub-grid passes its own.
    kick : bool
        Step semantics of the ISE (``uavsim.lumped.sampled``); default: the PD starts at the step.
    start : (kp, kd) arrays (B,) or None
        Known starting gains (e.g. a nearby class's table gains scaled by K); where they are
        stable the scan around the rule is skipped (identification's latency), elsewhere it runs.
    **params
        Process parameters as ``uavsim.lumped.sampled.lift`` (lateral: ``att_N`` in rad/s).

    Returns
    -------
    OptimalGains
        Processes no scanned PD stabilizes get ``ise = inf`` and NaN gains.
    """
    fam = loop_family(family)
    proc = lift(fam, rate_hz, **params)
    B = proc.B
    rule = TuningRule() if rule is None else rule
    full = {k: np.broadcast_to(np.asarray(v, dtype=np.float64).reshape(-1), (B,)) if np.size(v) > 1 else v
            for k, v in params.items() if v is not None}
    w, _ = mrft_prediction_batch(fam, rule.beta, 1.0, **full)
    if not np.all(np.isfinite(w)):
        raise UserError(f"{fam}: no MRFT oscillation at beta={rule.beta} for some processes (the filter needs its frequency)")
    g = rule.gains_batch(fam, **full)
    kp_r, kd_r = np.asarray(g["kp"], float), np.asarray(g["kd"], float)
    N = derivative_filter(w, rate_hz)
    rule_ise = sampled_ise(proc, kp_r, kd_r, np.asarray(g["N"], float), kick=kick)
    kp0, kd0 = np.full(B, np.nan), np.full(B, np.nan)
    if start is not None:
        k0, d0 = (np.broadcast_to(np.asarray(v, dtype=np.float64), (B,)) for v in start)
        good = np.isfinite(k0) & np.isfinite(d0) & (k0 > 0) & (d0 > 0)
        good[good] = np.isfinite(_log_ise(proc, np.flatnonzero(good), np.log(np.column_stack([k0, d0])[good]), N, kick))
        kp0[good], kd0[good] = k0[good], d0[good]
    todo = np.flatnonzero(~np.isfinite(kp0))
    if todo.size:
        kp0[todo], kd0[todo] = _start(proc.take(todo), N[todo], kp_r[todo], kd_r[todo], kick)
    ok = np.isfinite(kp0)
    out = {"kp": np.full(B, np.nan), "kd": np.full(B, np.nan), "ise": np.full(B, np.inf),
           "iterations": np.zeros(B, dtype=np.int64), "converged": np.zeros(B, dtype=bool)}
    if ok.any():
        idx = np.flatnonzero(ok)
        r = minimize_ise(proc.take(idx), N[idx], kp0[idx], kd0[idx], kick=kick)
        for k, v in r.items():
            out[k][idx] = v
    return OptimalGains(kp=out["kp"], kd=out["kd"], derivative_filter_hz=N / (2 * math.pi), ise=out["ise"],
                        rate_hz=float(rate_hz), omega=w, rule_kp=kp_r, rule_kd=kd_r, rule_ise=rule_ise,
                        iterations=out["iterations"], converged=out["converged"])


def optimal_pd(p: LumpedParams, rate_hz: float = DEFAULT_RATE_HZ, rule: TuningRule | None = None) -> OptimalGains:
    """``optimal_gains`` of one process (``OptimalGains`` of length 1; ``.row(0)`` for floats).

    Raises ``UserError`` if no PD stabilizes it.
    """
    p.check()
    g = optimal_gains(p.family, rate_hz, rule=rule, **batch_args(p))
    if not np.isfinite(g.ise[0]):
        raise UserError(f"{p.loop}: no stable PD found at {rate_hz:g} Hz")
    return g
