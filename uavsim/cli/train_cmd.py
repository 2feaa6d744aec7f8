"""``uavsim train RECIPE``: train the classifier(s) of a training recipe.

Progress bars and per-epoch lines go to stderr; the summary (or, with
``--json``, one JSON object: ``{"reports": [...]}``) to stdout. A checkpoint is
written every epoch; ``--resume`` continues an interrupted run.

    uavsim train training/altitude.toml
    uavsim train training/small.toml --resume --json
"""

from __future__ import annotations

import argparse

from uavsim.cli._common import print_json, print_table


def register(subparsers) -> None:
    p = subparsers.add_parser("train", help="train DNN-NP-MRFT networks from a recipe (training/*.toml)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recipe", help="training recipe (TOML)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    p.add_argument("--epochs", type=int, help="override the recipe's maximum epochs")
    p.add_argument("--quiet", action="store_true", help="no progress bars or per-epoch lines")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    try:
        import torch  # noqa: F401
    except ImportError:
        from uavsim.errors import UserError

        raise UserError("training needs torch: pip install 'uavsim[train]' (identification does not)") from None
    from uavsim.learning.train import train_from_recipe

    overrides = {"epochs": args.epochs} if args.epochs else None
    reports = train_from_recipe(args.recipe, resume=args.resume, quiet=args.quiet, overrides=overrides)
    if args.json:
        print_json({"reports": reports})
        return 0
    rows = []
    for r in reports:
        row = {"name": r["name"], "classes": r["n_classes"], "epochs": r["epochs_run"], "best": r["best_epoch"],
               "time_s": r["train_time_s"], "val_top1": r["val"]["top1"], "val_mean_J": r["val"]["mean_J"]}
        if "test" in r:
            row.update({"test_top1": r["test"]["top1"], "test_mean_J": r["test"]["mean_J"],
                        "test_p95_J": r["test"]["p95_J"]})
        row["out"] = r["out"]
        rows.append(row)
    print_table(rows)
    return 0
