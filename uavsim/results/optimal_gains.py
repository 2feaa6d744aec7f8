"""Figures of docs/results/optimal-gains.md that ``uavsim grid table`` / ``grid report`` do not print.

Each section is one function and one flag; the output is one JSON object.

* ``--kick``: the ISE-optimal PDs of a grid's classes with the derivative kick
  (``kick=True`` of ``uavsim.lumped.sampled``): their ``kp`` over the rule's, the
  first sample's derivative command ``kd a / Ts`` over the proportional one
  ``kp`` (unit step, ``a = Ts N / (1 + Ts N)``), and the rule's J against that
  optimum; beside them the table's (no kick) ``kp`` over the rule's.
* ``--free-filter``: the derivative filter ``N`` left free. From each chosen
  class's table optimum, Nelder-Mead over ``(log kp, log kd, log N)`` on the
  exact sampled ISE (``N`` capped at ``1e15`` rad/s, the raw difference to
  rounding): the filter it ends at and the ISE it gains over the fixed filter.
  ``--classes`` evenly spaced classes of each inner grid.
* ``--margins``: gain margins of the tables' answers at the control rate: the
  largest factor ``k`` for which ``(k kp, k kd)`` (same filter) still gives a
  stable sampled loop, by bisection; inner grids and every lateral sub-grid.
* ``--latency``: wall time of one ISE optimum (``uavsim.tuning.optimal``) for
  random processes of each box (``--n`` inner, ``--n-lateral`` lateral, seeded),
  and of one robust answer (``uavsim.tuning.robust.robust_gains``) over a class
  and its grid neighbours, as the table builds it. Run it with
  ``OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1``; times depend on the machine's load.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m uavsim.results.optimal_gains --kick --free-filter --margins
    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python -m uavsim.results.optimal_gains --latency --seed 0
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from uavsim.errors import UserError
from uavsim.lumped.sampled import lift, sampled_ise
from uavsim.tuning.grid import BOX_AXES, box_sample, class_process_params, load_grid
from uavsim.tuning.optimal import DEFAULT_RATE_HZ, optimal_gains
from uavsim.tuning.table import load_table, neighbourhoods

INNER = ("attitude", "altitude")
#: the free filter's cap, rad/s: beyond it the filtered derivative is the raw difference to rounding
N_CAP = 1e15


def _stats(x) -> dict[str, float]:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"n": 0}
    return {"n": int(x.size), "min": float(x.min()), "median": float(np.median(x)),
            "p95": float(np.percentile(x, 95)), "max": float(x.max())}


def _inner_params(grid) -> dict[str, np.ndarray]:
    return {k: np.asarray(grid.params[k], float) for k in ("T_prop", "T1", "tau")}


def kick_figures(loop: str = "altitude", rate_hz: float = DEFAULT_RATE_HZ) -> dict:
    """The ISE optimum of every class of ``loop``'s grid with the derivative kick (module docstring)."""
    g = load_grid(loop)
    o = optimal_gains(loop, rate_hz, rule=g.rule, kick=True, K=1.0, **_inner_params(g))
    t = load_table(loop, rate_hz, grid=g)
    Ts = 1.0 / rate_hz
    N = 2 * np.pi * o.derivative_filter_hz
    a = Ts * N / (1.0 + Ts * N)
    ok = np.isfinite(o.ise)
    return {"loop": loop, "rate_hz": rate_hz, "classes": g.n, "stable_optimum": int(ok.sum()),
            "kick_kp_over_rule_kp": _stats((o.kp / o.rule_kp)[ok]),
            "kick_first_derivative_over_proportional": _stats((o.kd * a / Ts / o.kp)[ok]),
            "rule_J_against_kick_optimum": _stats((o.rule_ise / o.ise)[ok]),
            "rule_unstable_with_kick": int(np.sum(~np.isfinite(o.rule_ise))),
            "no_kick_table_kp_over_rule_kp": _stats(t.kp / o.rule_kp)}


def _free_filter_one(proc, kp: float, kd: float, N: float, maxfev: int) -> tuple[float, float, float, float]:
    from scipy.optimize import minimize

    cap = np.log(N_CAP)

    def f(th):
        q = sampled_ise(proc, np.exp(th[0]), np.exp(th[1]), np.exp(min(th[2], cap)))[0]
        return float(np.log(q)) if np.isfinite(q) else 1e3

    r = minimize(f, np.log([kp, kd, N]), method="Nelder-Mead",
                 options={"xatol": 1e-5, "fatol": 1e-10, "maxfev": maxfev, "maxiter": maxfev})
    th = r.x
    return float(np.exp(th[0])), float(np.exp(th[1])), float(np.exp(min(th[2], cap))), float(np.exp(r.fun))


def free_filter_figures(n_classes: int = 10, rate_hz: float = DEFAULT_RATE_HZ, maxfev: int = 4000) -> dict:
    """The ISE optimum with the filter free on ``n_classes`` evenly spaced classes of each inner grid."""
    rows = []
    for loop in INNER:
        g = load_grid(loop)
        t = load_table(loop, rate_hz, grid=g)
        proc = lift(loop, rate_hz, K=1.0, **_inner_params(g))
        for c in np.unique(np.linspace(0, g.n - 1, n_classes).round().astype(int)):
            p = proc.take(np.array([c]))
            q_fixed = float(sampled_ise(p, t.kp[c], t.kd[c], t.N[c])[0])
            kp, kd, N, q = _free_filter_one(p, float(t.kp[c]), float(t.kd[c]), float(t.N[c]), maxfev)
            rows.append({"loop": loop, "class": int(c), "N_fixed": float(t.N[c]), "N_free": N,
                         "N_at_cap": bool(N >= 0.999 * N_CAP), "kp_free_over_fixed": kp / float(t.kp[c]),
                         "kd_free_over_fixed": kd / float(t.kd[c]), "ise_fixed": q_fixed, "ise_free": q,
                         "ise_gain": 1.0 - q / q_fixed})
    return {"rate_hz": rate_hz, "N_cap": N_CAP, "rows": rows, "ise_gain": _stats([r["ise_gain"] for r in rows]),
            "N_free_over_fixed": _stats([r["N_free"] / r["N_fixed"] for r in rows]),
            "at_cap": sum(r["N_at_cap"] for r in rows)}


def gain_margin(proc, kp, kd, N, k_max: float = 10.0, steps: int = 30) -> np.ndarray:
    """Largest ``k`` in ``[1, k_max]`` with ``(k kp, k kd, N)`` stable on ``proc``, (B,), by bisection in log k.

    NaN where the answer is unstable as given; ``k_max`` where it is still stable there.
    """
    kp, kd, N = (np.asarray(v, float) for v in (kp, kd, N))

    def stable(k):
        return sampled_ise(proc, k * kp, k * kd, N, return_stable=True)[1]

    lo, hi = np.zeros(kp.size), np.full(kp.size, np.log(k_max))
    ok1, okmax = stable(np.ones(kp.size)), stable(np.full(kp.size, k_max))
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        s = stable(np.exp(mid))
        lo, hi = np.where(s, mid, lo), np.where(s, hi, mid)
    return np.where(~ok1, np.nan, np.where(okmax, k_max, np.exp(lo)))


def margin_figures(rate_hz: float = DEFAULT_RATE_HZ) -> dict:
    """Gain margins of the optimal and robust answers of every table (module docstring)."""
    out: dict = {"rate_hz": rate_hz}
    for loop in INNER:
        g = load_grid(loop)
        t = load_table(loop, rate_hz, grid=g)
        proc = lift(loop, rate_hz, K=1.0, **_inner_params(g))
        out[loop] = {"optimum": _stats(gain_margin(proc, t.kp, t.kd, t.N)),
                     "robust": _stats(gain_margin(proc, t.robust_kp, t.robust_kd, t.N))}
    g = load_grid("lateral")
    t = load_table("lateral", rate_hz, grid=g)
    per, opt, rob = [], [], []
    for a, (s, st) in enumerate(zip(g.sub, t.sub, strict=True)):
        xc = np.column_stack([np.asarray(s.params[k], float) for k in BOX_AXES["lateral"]])
        proc = lift("lateral", rate_hz, K=1.0, **class_process_params("lateral", xc, st.attitude))
        mo, mr = gain_margin(proc, st.kp, st.kd, st.N), gain_margin(proc, st.robust_kp, st.robust_kd, st.N)
        opt.append(mo)
        rob.append(mr)
        per.append({"att_class": a, "classes": s.n, "optimum_min": float(np.nanmin(mo)),
                    "optimum_max": float(np.nanmax(mo)), "robust_min": float(np.nanmin(mr))})
    out["lateral"] = {"optimum": _stats(np.concatenate(opt)), "robust": _stats(np.concatenate(rob)),
                      "per_attitude_class": per}
    return out


def latency_figures(seed: int = 0, n: int = 30, n_lateral: int = 10, rate_hz: float = DEFAULT_RATE_HZ) -> dict:
    """Wall time (ms) of one ISE optimum per random process, and of one robust answer (module docstring)."""
    from uavsim.lumped.params import RANGES, LumpedParams
    from uavsim.tuning.optimal import optimal_pd
    from uavsim.tuning.robust import robust_gains
    from uavsim.tuning.sensitivity import estimated_gain

    rng = np.random.default_rng(seed)
    out: dict = {"seed": seed, "rate_hz": rate_hz}
    for loop in ("roll", "altitude"):  # the snippet this page once showed, same draws
        box = RANGES["attitude" if loop == "roll" else loop]
        ms = []
        for _ in range(n):
            v = {k: float(np.exp(rng.uniform(np.log(lo), np.log(hi)))) for k, (lo, hi) in box.items()}
            t0 = time.perf_counter()
            optimal_pd(LumpedParams(loop, K=1.0, **v), rate_hz)
            ms.append(1e3 * (time.perf_counter() - t0))
        out[f"optimal_pd_{loop}_ms"] = _stats(ms)
    g = load_grid("lateral")
    t = load_table("lateral", rate_hz, grid=g)
    ms = []
    for _ in range(n_lateral):
        a = int(rng.integers(len(g.sub)))
        x = box_sample("lateral", rng, 1)
        p = class_process_params("lateral", x, t.sub[a].attitude)
        t0 = time.perf_counter()
        o = optimal_gains("lateral", rate_hz, rule=g.sub[a].rule, K=1.0, **p)
        ms.append(1e3 * (time.perf_counter() - t0))
        if not np.isfinite(o.ise[0]):
            ms[-1] = np.nan
    out["optimal_lateral_ms"] = _stats(ms)
    out["optimal_lateral_unstable"] = int(np.sum(~np.isfinite(ms)))
    for loop in INNER:
        g = load_grid(loop)
        t = load_table(loop, rate_hz, grid=g)
        cp = _inner_params(g)
        ans, mod = neighbourhoods(g)
        ms, sizes = [], []
        for c in rng.choice(g.n, size=min(n, g.n), replace=False):
            m = mod[ans == c]
            pick = {k: v[m] for k, v in cp.items()}
            ansp = {k: np.full(m.size, v[c]) for k, v in cp.items()}
            K_hat = estimated_gain(loop, t.omega[m], {"K": 1.0, **pick}, ansp, t.omega[np.full(m.size, c)], t.scaling)
            t0 = time.perf_counter()
            robust_gains(loop, rate_hz, models={"K": 1.0, **pick}, group=np.zeros(m.size, int), N=t.N[c],
                         scale=1.0 / K_hat, q_opt=t.ise[m], kp_opt=t.kp[m], kd_opt=t.kd[m])
            ms.append(1e3 * (time.perf_counter() - t0))
            sizes.append(int(m.size))
        out[f"robust_{loop}_ms"] = {**_stats(ms), "models_per_answer": _stats(sizes)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uavsim.results.optimal_gains", description=__doc__.split("\n\n")[0])
    ap.add_argument("--kick", action="store_true", help="the optimum with the derivative kick (altitude grid)")
    ap.add_argument("--kick-loop", default="altitude", choices=INNER, help="grid of --kick (default altitude)")
    ap.add_argument("--free-filter", action="store_true", help="the optimum with the filter free")
    ap.add_argument("--classes", type=int, default=10, help="classes per inner grid for --free-filter (default 10)")
    ap.add_argument("--margins", action="store_true", help="gain margins of the tables' answers")
    ap.add_argument("--latency", action="store_true", help="latency of the optimum and of the robust answer")
    ap.add_argument("--seed", type=int, default=0, help="draws of --latency (default 0)")
    ap.add_argument("--n", type=int, default=30, help="inner processes (and robust answers) of --latency (default 30)")
    ap.add_argument("--n-lateral", type=int, default=10, help="lateral processes of --latency (default 10)")
    args = ap.parse_args(argv)
    prog = "python -m uavsim.results.optimal_gains"
    if not (args.kick or args.free_filter or args.margins or args.latency):
        print(f"{prog}: nothing to do: give --kick, --free-filter, --margins and/or --latency", file=sys.stderr)
        return 2
    if args.classes < 1 or args.n < 1 or args.n_lateral < 1:
        print(f"{prog}: --classes, --n and --n-lateral must be >= 1", file=sys.stderr)
        return 2
    out: dict = {}
    try:
        if args.kick:
            out["kick"] = kick_figures(args.kick_loop)
        if args.free_filter:
            out["free_filter"] = free_filter_figures(args.classes)
        if args.margins:
            out["margins"] = margin_figures()
        if args.latency:
            out["latency"] = latency_figures(args.seed, args.n, args.n_lateral)
    except UserError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
