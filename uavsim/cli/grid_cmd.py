"""``uavsim grid``: build and report the class grids.

    uavsim grid build --loop altitude [--out PATH]
    uavsim grid report --loop altitude [--json] [--points 2000]
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
    r = sub.add_parser("report", help="class counts, neighbour J, coverage, build time")
    r.add_argument("--loop", required=True)
    r.add_argument("--path", help="grid file (default: the packaged one)")
    r.add_argument("--points", type=int, default=2000, help="random box points for coverage (default 2000)")
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


def run_report(args: argparse.Namespace) -> int:
    from uavsim.tuning.grid import grid_report, load_grid

    g = load_grid(args.loop, args.path)
    rep = grid_report(g, n_points=args.points)
    if args.json:
        print_json(rep)
        return 0
    fam = loop_family(args.loop)
    rows = [{"figure": k, "value": v} for k, v in rep.items() if not isinstance(v, dict)]
    for key in ("neighbour_J_across_levels", "neighbour_J_within_level", "coverage"):
        if key in rep:
            rows += [{"figure": f"{key}.{k}", "value": v} for k, v in rep[key].items()]
    print(f"{fam} grid")
    print_table(rows)
    return 0
