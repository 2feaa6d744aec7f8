"""``uavsim gap SESSION``: which physical effect does the model lack?

Simulates every run of the session with the session's ``[model]`` (or
``--model FILE``) on the MuJoCo loop, compares with the measured runs on
features that separate effects, fits every candidate effect of the
vocabulary, and names the one that closes the gap (or ``none``). Prints a
table (or the spec's JSON with ``--json``); ``--report DIR`` writes
before/after plots, a Rerun recording and the updated model; ``--write``
adds the winner to the session's ``[[effects]]``.

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
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from uavsim.gap.workflow import format_table, read_model_file, run_gap, updated_session

    session = read_session(args.session)
    model = read_model_file(args.model, session.loop) if args.model else None
    result = run_gap(session, model=model, seed=args.seed, log=eprint)
    if args.report:
        from uavsim.gap.report import write_report

        eprint(f"report: {write_report(session, result, args.report)}")
    if args.write:
        path = session.path or args.session
        write_session(updated_session(session, result), path)
        eprint(f"updated model written to {path}")
    if args.json:
        print_json(result.to_json())
    else:
        print(format_table(result))
    return 0
