"""``uavsim grid``: build and report the class grids and their tables of optimal gains.

    uavsim grid build --loop altitude [--out PATH]
    uavsim grid table --loop altitude [--rate 200] [--out PATH]
    uavsim grid report --loop altitude [--json] [--points 2000] [--rate 200] [--table-points 300]
"""

from __future__ import annotations

import argparse

from uavsim.cli._common import eprint, print_json, print_table
from uavsim.lumped.params import loop_family


def register(subparsers) -> None:
    p = subparsers.add_parser("grid", help="build or report the lumped-model class grids")
    sub = p.add_subparsers(dest="grid_command", metavar="ACTION")
    sub.required = True
    b = sub.add_parser("build", help="build a grid and write it (atomically)")
    b.add_argument("--loop", required=True, help="attitude | altitude | lateral (lateral needs the attitude grid)")
    b.add_argument("--out", help="output path (default: the packaged grids/LOOP.json)")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--beta", type=float, help="MRFT beta (default: the rule default)")
    b.add_argument("--pm", type=float, help="phase margin, deg (default: the rule default)")
    b.set_defaults(func=run_build)
    t = sub.add_parser("table", help="the ISE-optimal PD of every class at a control rate, and its J")
    t.add_argument("--loop", required=True, help="attitude | altitude | lateral (lateral needs the attitude table)")
    t.add_argument("--rate", type=float, default=200.0, help="control rate, Hz (default 200)")
    t.add_argument("--out", help="output path (default: package data at 200 Hz, else the user cache)")
    t.set_defaults(func=run_table)
    r = sub.add_parser("report", help="class counts, neighbour J, coverage, build time")
    r.add_argument("--loop", required=True)
    r.add_argument("--path", help="grid file (default: the packaged one)")
    r.add_argument("--points", type=int, default=2000, help="random box points for coverage (default 2000)")
    r.add_argument("--seed", type=int, default=1, help="seed of the random box points (default 1)")
    r.add_argument("--rate", type=float, default=200.0, help="control rate of the table figures, Hz (default 200)")
    r.add_argument("--table-points", dest="table_points", type=int, default=300,
                   help="random box points of the table figures (default 300; 0: no table figures)")
    r.add_argument("--json", action="store_true")
    r.set_defaults(func=run_report)


def run_build(args: argparse.Namespace) -> int:
    from uavsim.tuning.grid import build_grid, save_grid
    from uavsim.tuning.rule import DEFAULT_BETA, DEFAULT_PM_DEG

    g = build_grid(args.loop, beta=DEFAULT_BETA if args.beta is None else args.beta,
                   pm_deg=DEFAULT_PM_DEG if args.pm is None else args.pm, seed=args.seed, log=eprint)
    path = save_grid(g, args.out)
    n = sum(s.n for s in g.sub) if g.sub else g.n
    eprint(f"wrote {path}: {n} classes in {g.built['build_time_s']} s")
    return 0


def run_table(args: argparse.Namespace) -> int:
    from uavsim.tuning.table import build_table, save_table

    t = build_table(args.loop, args.rate, log=eprint)
    path = save_table(t, args.out)
    n = sum(s.n for s in t.sub) if t.sub else t.n
    eprint(f"wrote {path}: {n} classes at {t.rate_hz:g} Hz in {t.built['build_time_s']} s")
    return 0


def _flat(prefix: str, d: dict, rows: list[dict]) -> None:
    for k, v in d.items():
        if isinstance(v, dict):
            _flat(f"{prefix}{k}.", v, rows)
        elif not isinstance(v, list):
            rows.append({"figure": f"{prefix}{k}", "value": v})


def run_report(args: argparse.Namespace) -> int:
    from uavsim.tuning.grid import grid_report, load_grid

    g = load_grid(args.loop, args.path)
    rep = grid_report(g, n_points=args.points, seed=args.seed)
    if args.table_points > 0:
        from uavsim.tuning.table import load_table
        from uavsim.tuning.table_report import table_figures

        rep["table"] = table_figures(g, load_table(args.loop, args.rate, grid=g, log=eprint),
                                     n_points=args.table_points, seed=args.seed)
    if args.json:
        print_json(rep)
        return 0
    fam = loop_family(args.loop)
    rows = [{"figure": k, "value": v} for k, v in rep.items() if not isinstance(v, dict)]
    for key in ("neighbour_J_across_levels", "neighbour_J_within_level", "coverage"):
        if key in rep:
            rows += [{"figure": f"{key}.{k}", "value": v} for k, v in rep[key].items()]
    if "table" in rep:
        _flat("table.", rep["table"], rows)
    print(f"{fam} grid")
    print_table(rows)
    return 0
