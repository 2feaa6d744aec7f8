"""``uavsim generate RECIPE``: build a training set (``uavsim-dataset/1`` HDF5).

Runs every episode of the recipe (NP-MRFT in MuJoCo, noise in the loop),
preprocesses the cycles into network inputs and writes one file (one per
attitude class for lateral recipes). Progress goes to stderr; an interrupted
run leaves ``OUT.resume/`` and running the same command again continues it.

    uavsim generate datasets/small.toml                      # -> datasets/small.h5, local threads
    uavsim generate datasets/altitude.toml --dask local:2    # chunks as Dask tasks
    uavsim generate datasets/altitude.toml --scheduler tcp://10.0.0.5:8786 --json
"""

from __future__ import annotations

import argparse

from uavsim.cli._common import print_json, print_table


def _run(args: argparse.Namespace) -> int:
    from uavsim.data.generate import generate
    from uavsim.data.recipe import load_recipe

    recipe = load_recipe(args.recipe)
    if args.dask and args.scheduler:
        from uavsim.errors import UserError

        raise UserError("give either --dask local:N or --scheduler ADDRESS, not both")
    backend = "threads"
    if args.dask:
        backend = f"dask:{args.dask}"
    elif args.scheduler:
        backend = f"dask:{args.scheduler}"
    s = generate(recipe, args.out, backend=backend, workers=args.workers, progress=not args.quiet)
    if args.json:
        print_json(s)
    else:
        print_table([{"measure": k, "value": v if not isinstance(v, list) else ", ".join(v)} for k, v in s.items()])
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("generate", help="build a training set from a recipe (datasets/*.toml)", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recipe", help="recipe TOML (see datasets/*.toml)")
    p.add_argument("--out", default=None, help="output .h5 (default: the recipe path with .h5)")
    p.add_argument("--dask", default=None, metavar="local:N", help="run chunks on a local Dask cluster of N workers")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="run chunks on this Dask scheduler")
    p.add_argument("--workers", type=int, default=None, help="threads of the local backend (default 2)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.set_defaults(func=_run)
