"""``uavsim gap SESSION``: which physical effect does the model lack?

Simulates every run of the session with the session's ``[model]`` (or
``--model FILE``; with neither, the model ``uavsim identify`` gives from the
relay run, saying so) on the MuJoCo loop, compares with the measured runs on
features that separate effects, fits every candidate effect of the
vocabulary, adds the one that closes most of the gap and searches again (two
effects at most; from an identified model, one by the search beside those read
off the runs or the noise's level); answers ``named``, ``none``, ``absorbed`` (a
linear effect the identified model took in) or ``unexplained`` (with what the
residual looks like). Prints a table (or JSON with ``--json``); ``--report DIR`` writes
before/after overlays for every run, the ranking, the residual, a Rerun
recording and the updated model; ``--write`` adds the effects to the
session's ``[[effects]]``.

    uavsim gap flights/thermal_kf --report reports/thermal_kf --json
"""

from __future__ import annotations

import argparse

from uavsim.cli._common import eprint, print_json
from uavsim.formats.session import read_session, write_session


def register(subparsers) -> None:
    p = subparsers.add_parser("gap", help="sim-vs-measured gap: name the effect the model lacks",
                              description=__doc__.split("\n\n")[0])  # fmt: skip
    p.add_argument("session", metavar="SESSION", help="session folder or its session.toml")
    p.add_argument("--model", metavar="FILE", help="TOML with a [model] table to test instead of the session's")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--report", metavar="DIR", help="write plots, gap.rrd, gap.json and model.toml here")
    p.add_argument("--write", action="store_true", help="write the updated model and effects into the session")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated noise (default 0)")
    p.add_argument("--models", metavar="DIR", help="networks for identifying the base model when the session has "
                   "no [model] (default: uavsim identify's)")
    p.add_argument("--max-effects", type=int, default=2, help="most effects added one after the other (default 2)")
    p.add_argument("--screen-classes", action="store_true",
                   help="identified base model: start its refit from the network class whose model, fitted to the "
                        "same cycle, flies the runs best (lower base gaps; the naming thresholds were set without it)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from uavsim.gap.iterate import analyse, format_flow
    from uavsim.gap.workflow import read_model_file, updated_session

    session = read_session(args.session)
    model = read_model_file(args.model, session.loop) if args.model else None
    flow = analyse(session, model, models=args.models, seed=args.seed, max_effects=args.max_effects,
                   screen=args.screen_classes, log=eprint)
    if args.report:
        from uavsim.gap.overlay import write_flow_report

        eprint(f"report: {write_flow_report(flow, args.report)}")
    if args.write:
        path = session.path or args.session
        write_session(updated_session(session, flow.final), path)
        eprint(f"updated model written to {path}")
    if args.json:
        print_json(flow.to_json())
    else:
        print(format_flow(flow))
    return 0
