"""Figures of docs/results/lateral-grid.md: the lateral grid and its 200 Hz table.

    python -m uavsim.results.lateral_grid --seed 2026 --per-class 10 > figures.json

Coverage: ``--per-class`` seeded random box points per attitude class (seed + attitude class,
``uavsim.tuning.table_report``), each judged against its own ISE-optimal PD at 200 Hz, answered by
the best class of its sub-grid (what a perfect J-trained classifier answers) and by the class
nearest in the log box, with the table's optimal and robust gains scaled by the gain identification
estimates. ``--grid``/``--table`` read other files (the old grid and its table, from git): they are
judged with this code, on the loop as flown (the attitude table PD sampled at 200 Hz, the table's
``attitude``), like the new ones.

    git show 3feb740:uavsim/tuning/grids/lateral.json > /tmp/old/lateral.json   # and its table
    python -m uavsim.results.lateral_grid --seed 2026 --per-class 10 \
        --grid /tmp/old/lateral.json --table /tmp/old/optimal-lateral-200hz.json > old.json
    python -m uavsim.results.lateral_grid --render figures.json old.json      # the page's markdown tables
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from uavsim.errors import UserError
from uavsim.tuning.grid import box_sample, load_grid
from uavsim.tuning.table import load_table
from uavsim.tuning.table_report import j_stats, neighbour_j, point_j

KINDS = ("best", "robust_best", "nearest", "robust_nearest", "rule")


def continuous_check(g) -> list[dict]:
    """Per attitude class, over its classes: the DF MRFT frequency with the continuous attitude loop
    against the sampled one, the continuous loop's magnitude and phase error at the sampled MRFT
    frequency, and what a response fit with the continuous loop reads for K and the outer delay from
    the exact 200 Hz response at the class's exact cycle."""
    from uavsim.lumped.frequency import mrft_prediction_batch
    from uavsim.lumped.lateral import attitude_closed_loop_batch, lateral_response_sampled

    rows = []
    for a, s in enumerate(g.sub):
        att = s.attitude
        pa = {"T_prop": att["T_prop"], "T1": att["T1"], "tau_in": att["tau_in"], "att_kp": att["att_kp"],
              "att_kd": att["att_kd"], "att_N": 2 * np.pi * att["att_filter_hz"]}
        pp = {"K": 1.0, "T2": s.params["T2"], "tau": s.params["tau"], **pa}
        w_c = mrft_prediction_batch("lateral", s.beta, 1.0, **pp)[0]
        w_s = s.omega_df
        Tc = attitude_closed_loop_batch(w_s[:, None], **pa)[:, 0]
        Ts = attitude_closed_loop_batch(w_s[:, None], **pa, rate_hz=200.0)[:, 0]
        w = s.omega  # the exact cycle's frequency
        H = np.array([lateral_response_sampled(np.array([w[i]]), 200.0, K=1.0, T2=s.params["T2"][i],
                                               tau=s.params["tau"][i], **pa)[0, 0] for i in range(s.n)])
        x = w / 400.0
        G = H / (np.sinc(x / np.pi) * np.exp(-1j * x))
        T0 = attitude_closed_loop_batch(w[:, None], **pa)[:, 0]
        G0 = T0 / (1j * w * (1j * w * s.params["T2"] + 1))
        K_fit = np.abs(G) / np.abs(G0)
        dtau = ((np.angle(G0) - np.angle(G)) % (2 * np.pi)) / w - s.params["tau"]
        dtau = (dtau + np.pi / w) % (2 * np.pi / w) - np.pi / w
        rows.append({"att_class": a, "omega_cont_over_sampled": [float(np.min(w_c / w_s)), float(np.max(w_c / w_s))],
                     "T_att_mag_err_max": float(np.max(np.abs(np.abs(Tc / Ts) - 1))),
                     "T_att_phase_err_deg_max": float(np.max(np.abs(np.degrees(np.angle(Tc / Ts))))),
                     "K_fit_err_max": float(np.max(np.abs(K_fit - 1))),
                     "tau_fit_err_ms_max": float(1e3 * np.max(np.abs(dtau)))})
    return rows


def _f(st: dict) -> str:
    """median / p95 / max, unstable of ``j_stats`` (1000: an unstable answer)."""
    def v(x):
        return "-" if x >= 1e3 else f"{x:.3f}"
    return f"{v(st['median'])} / {v(st['p95'])} / {v(st['max'])}, {st['unstable']}"


def _read_json(path: str) -> dict:
    try:
        with open(path) as fh:
            return json.load(fh)
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: not the JSON this module prints ({exc})") from None


def render(new_path: str, old_path: str) -> None:
    """Markdown tables of lateral-grid.md from the JSON of a new and an old run."""
    new, old = (_read_json(p) for p in (new_path, old_path))
    print("| figure (median / p95 / max, unstable) | old grid | new grid |\n| --- | --- | --- |")
    for k, name in (("best", "best class, optimum"), ("robust_best", "best class, robust"),
                    ("nearest", "nearest class, optimum"), ("robust_nearest", "nearest class, robust"),
                    ("rule", "the sub-grid's rule on the true process")):
        print(f"| {name} | {_f(old['pooled'][k])} | {_f(new['pooled'][k])} |")
    for k, name in (("best", "fast corner, best class, optimum"), ("robust_best", "fast corner, best class, robust")):
        print(f"| {name} (n = {old['fast_corner'][k]['n']} / {new['fast_corner'][k]['n']}) | "
              f"{_f(old['fast_corner'][k])} | {_f(new['fast_corner'][k])} |")
    print()
    print("| att. class | beta (old) | T0 min s | classes (old) | rule pm, scale | neighbour J robust | "
          "neighbour J optimum unstable | robust own J max | best robust | best optimum | old best robust |")
    print("| " + " | ".join(["---"] * 11) + " |")
    for r, o in zip(new["per_class_figures"], old["per_class_figures"], strict=True):
        nb = r["neighbour_J_robust"]
        print(f"| {r['att_class']} | {r['beta']:g} ({o['beta']:g}) | {r.get('T0_min_s', float('nan')):.2f} | "
              f"{r['n_classes']} ({o['n_classes']}) | {r['pm_deg']:g}, {r['gain_scale']:g} | "
              f"{nb['median']:.3f} / {nb['max']:.3f} | {r['neighbour_J_optimum']['unstable']} of "
              f"{r['neighbour_J_optimum']['n']} | {r['robust_own_J']['max']:.3f} | "
              f"{_f(r['coverage_robust_best'])} | {_f(r['coverage_best'])} | {_f(o['coverage_robust_best'])} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uavsim.results.lateral_grid", description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--per-class", type=int, default=10)
    ap.add_argument("--continuous-check", action="store_true",
                    help="also the continuous attitude loop's error at the classes' cycles (new code only)")
    ap.add_argument("--grid", help="lateral grid file (default: the packaged one)")
    ap.add_argument("--table", help="its 200 Hz table file (default: the packaged one)")
    ap.add_argument("--render", nargs=2, metavar=("NEW_JSON", "OLD_JSON"), help="print the markdown tables")
    args = ap.parse_args(argv)
    if args.per_class < 1:
        print(f"python -m uavsim.results.lateral_grid: --per-class must be >= 1, got {args.per_class}", file=sys.stderr)
        return 2
    try:
        if args.render:
            render(*args.render)
        else:
            print(json.dumps(figures(args.seed, args.per_class, grid=args.grid, table=args.table,
                                     continuous=args.continuous_check), indent=1))
    except UserError as exc:
        print(f"python -m uavsim.results.lateral_grid: {exc}", file=sys.stderr)
        return 2
    except KeyError as exc:
        print(f"python -m uavsim.results.lateral_grid: --render: a file lacks {exc} (not this module's JSON)",
              file=sys.stderr)
        return 2
    return 0


def figures(seed: int, per_class: int, *, grid: str | None = None, table: str | None = None,
            continuous: bool = False) -> dict:
    """The figures of the lateral grid (module docstring) as one JSON-able dict."""
    t0 = time.time()
    g = load_grid("lateral", grid)
    t = load_table("lateral", path=table, grid=g)
    groups = [(s, st, st.attitude) for s, st in zip(g.sub, t.sub, strict=True)]
    n = per_class
    pts = point_j("lateral", groups, n, seed)
    X = np.vstack([box_sample("lateral", np.random.default_rng(seed + k), n) for k in range(len(groups))])
    corner = (X[:, 0] < 0.6) & (X[:, 1] <= 0.01) & pts["ok"]  # the old grid's failures were here
    out = {"grid_hash": g.hash, "table_hash": t.hash, "seed": seed, "per_class": n,
           "pooled": {k: j_stats(pts[k][pts["ok"]]) for k in KINDS}, "n_without_optimum": int((~pts["ok"]).sum()),
           "fast_corner": {k: j_stats(pts[k][corner]) for k in KINDS},
           "per_class_figures": []}
    if continuous:
        out["continuous_vs_sampled"] = continuous_check(g)
    for a, (s, st, _) in enumerate(groups):
        sl = slice(a * n, (a + 1) * n)
        nb_r, _w = neighbour_j(s, st.J_robust)
        nb_o, _w = neighbour_j(s, st.J)
        row = {"att_class": a, "beta": s.beta, "pm_deg": s.pm_deg, "gain_scale": s.gain_scale, "n_classes": s.n,
               "period_range_s": [float(s.period.min()), float(s.period.max())],
               "neighbour_J_robust": j_stats(nb_r), "neighbour_J_optimum": j_stats(nb_o),
               "robust_own_J": j_stats(np.diag(st.J_robust)),
               "rule_own_J_unstable": int(np.sum(~np.isfinite(st.rule_ise))),
               **{f"coverage_{k}": j_stats(pts[k][sl][pts["ok"][sl]]) for k in KINDS}}
        if s.built.get("beta_choice"):
            row["T0_min_s"] = s.built["beta_choice"]["T0_min"]
            row["n_neighbour_pairs"] = len(s.neighbours)
        out["per_class_figures"].append(row)
    out["time_s"] = round(time.time() - t0, 1)
    return out


if __name__ == "__main__":
    sys.exit(main())
