"""``uavsim evaluate``: identification on off-grid processes against each process's optimum.

Random processes of the loop's box (seeded), simulated in MuJoCo through the
datasets' episode path with every noise kind at 0-20% of the cycle amplitude
and the relay's settings found as a user finds them (hover segment, refined
runs), are identified as sessions are. Each answer is scored by
``J = ISE(answer) / ISE(optimal PD of the true process)`` at the control rate;
refusals are failures. Rows per noise level, with the same run's controls: the
table on the J-best class (an oracle classifier) and on the nearest class, the
rule on the true process, and the answer detuned x0.85
(``uavsim.ident.evaluate``).

    uavsim evaluate --loop altitude --models training/runs --n 300 --seed 2 --json > altitude.json
    uavsim evaluate --loop attitude --models training/runs --markdown attitude.md
    uavsim evaluate --loop lateral --models training/runs --att-classes 0,17,40 --n 20
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from uavsim.cli._common import eprint, print_json


def register(subparsers) -> None:
    p = subparsers.add_parser("evaluate", help="identification on off-grid processes, J against the optimum",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--loop", required=True, choices=["altitude", "attitude", "lateral"])
    p.add_argument("--models", default=None, help="model root (altitude/, attitude/, lateral/aNN/) or a model "
                                                  "folder (default: $UAVSIM_MODELS or training/runs)")
    p.add_argument("--recipe", help="dataset recipe of the relay, randomization and preprocessing "
                                    "(default: datasets/LOOP.toml)")
    p.add_argument("--n", type=int, default=300, help="processes (lateral: per attitude class; default 300)")
    p.add_argument("--seed", type=int, default=2, help="seed of the draw and the simulation (default 2)")
    p.add_argument("--K", type=float, nargs=2, default=(0.5, 2.0), metavar=("LO", "HI"),
                   help="process gain range, log-uniform (default 0.5 2)")
    p.add_argument("--att-classes", help="lateral: comma-separated attitude classes (default: every network)")
    p.add_argument("--optimum", choices=["never", "auto", "always"], default="never",
                   help="identification's fitted-model optimum mode (default never: the table path)")
    p.add_argument("--decision", choices=["bayes", "argmax", "fitted", "stable", "blend"], default=None,
                   help="identification's class decision (default: stable on lateral loops, blend on the inner ones); the "
                        "rows answer_bayes, answer_argmax, answer_fitted and answer_blend score those in the same run")
    p.add_argument("--guard", action=argparse.BooleanOptionalAction, default=None,
                   help="identification backs its PD off by the phase-margin guard (uavsim.ident.guard; default: "
                        "identification's, on for the inner loops); the row answer_guarded scores the guard in "
                        "every run")
    p.add_argument("--family", action=argparse.BooleanOptionalAction, default=None,
                   help="lateral: steady cycles answer the PD chosen over the family of models the measured point "
                        "allows (uavsim.ident.family, under a second each; default on); the row answer_table scores "
                        "the table's answer in every run")
    p.add_argument("--inputs", choices=["last", "mean", "each"], default=None,
                   help="what the network sees of each relay run: the last cycle (as in training), the mean of the "
                        "steady cycles, each steady cycle as its own input (default: the loop's, "
                        "uavsim.ident.cycle.IDENT_INPUTS)")
    p.add_argument("--combine", choices=["logsum", "logmean", "mean"], default=None,
                   help="with --inputs each: how the cycles' beliefs combine (default mean: their mean probabilities)")
    p.add_argument("--second-beta", default="auto", metavar="BETA",
                   help="also fly a second relay run at this beta on every process and weigh the network's belief "
                        "by how each class fits both measured points (uavsim.ident.twopoint; lateral: the family of "
                        "models too, uavsim.ident.family); default auto: -0.3 on every loop; none: one run (the "
                        "paper's method)")
    p.add_argument("--no-second-network", dest="second_network", action="store_false",
                   help="with a second run, weigh by its point alone, not also by the network of its beta that the "
                        "model root holds (uavsim.ident.secondnet: altitude-second)")
    p.add_argument("--bias-trim", choices=["off", "duty"], default=None,
                   help="the relay trims its bias from each cycle's duty (duty) or keeps it (off); default: the "
                        "network's dataset recipe's [test] bias_trim")
    p.add_argument("--cycles", type=int, default=None,
                   help="relay cycles each run flies, the first a transient (default: 13 on attitude and lateral "
                        "loops, which average their point over up to 12; else the recipe's [episodes] cycles, the "
                        "training sets' 5)")
    p.add_argument("--chunk", type=int, default=60, help="episodes per MuJoCo batch (default 60)")
    p.add_argument("--markdown", metavar="FILE", help="also write the rows as a markdown table")
    p.add_argument("--out", metavar="FILE", help="write the full result (with every episode) as JSON")
    p.add_argument("--json", action="store_true", help="print the result (without episodes) as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # numpy's BLAS on one thread unless the user says otherwise: the lifted loops are small
    # matrices, and BLAS threads only contend with MuJoCo's and each other (lateral, 2 cores:
    # 9.1 s -> 5.1 s at low load, 680-2070 s -> 75-96 s under load; the same rows). It must be
    # set before numpy is first imported, which this command's imports below do.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from uavsim.errors import UserError
    from uavsim.ident.bundle import default_model_root
    from uavsim.ident.evaluate import EvalSpec, evaluate, markdown, second_beta_for

    if args.n < 1 or args.chunk < 1:
        raise UserError("--n and --chunk must be >= 1")
    if not 0 < args.K[0] <= args.K[1]:
        raise UserError(f"--K needs 0 < LO <= HI, got {args.K[0]} {args.K[1]}")
    second_beta = None if args.second_beta == "none" else args.second_beta
    if second_beta not in (None, "auto"):
        try:
            second_beta = float(second_beta)
        except ValueError:
            raise UserError(f"--second-beta takes a beta, auto or none, got {second_beta!r}") from None
    second_beta_for(args.loop, second_beta)  # a beta outside (-1, 1): the one-line error before any flight
    recipe = Path(args.recipe) if args.recipe else Path("datasets") / f"{args.loop}.toml"
    if not recipe.is_file():
        raise UserError(f"recipe {recipe} not found (pass --recipe)")
    att = None
    if args.att_classes:
        try:
            att = tuple(int(a) for a in args.att_classes.split(",") if a.strip())
        except ValueError:
            raise UserError(f"--att-classes: not a comma-separated list of integers: {args.att_classes!r}") from None
    spec = EvalSpec(loop=args.loop, n=args.n, seed=args.seed, K=tuple(args.K), chunk=args.chunk, att_classes=att,
                    optimum=args.optimum, decision=args.decision, guard=args.guard, inputs=args.inputs,
                    combine=args.combine, second_beta=second_beta, bias_trim=args.bias_trim,
                    family=args.family, cycles=args.cycles, second_network=args.second_network)
    res = evaluate(spec, models=args.models or default_model_root(), recipe=recipe)
    md = markdown(res)
    if args.markdown:
        Path(args.markdown).write_text(md)
        eprint(f"wrote {args.markdown}")
    if args.out:
        Path(args.out).write_text(json.dumps(res, default=float))
        eprint(f"wrote {args.out}")
    if args.json:
        print_json({k: v for k, v in res.items() if k != "episodes"})
    else:
        print(md, end="")
    return 0
