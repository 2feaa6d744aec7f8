"""``uavsim session``: inspect flight sessions (format ``uavsim-session/2``, or 1).

``check`` reads a session with every check of :mod:`uavsim.formats.session`
and prints what it found, so a user can validate a folder from the field before
feeding it to ``uavsim identify`` or ``uavsim gap``. An invalid session is a
``SessionError``: one line on stderr, exit status 2.

``import`` turns a flight log (PX4 ULog, ArduPilot DataFlash, ROS 2 bag) into a
session with one relay run (``uavsim.logs``): name r, y, u (``--r/--y/--u
TOPIC.FIELD``) or a ``--preset``, and the relay's settings; the relay's levels
and segment are detected in u when not given (and said so on stderr).

    uavsim session check flights/2024-05-01
    uavsim session check flights/2024-05-01/session.toml --json
    uavsim session import flight.ulg --preset px4-altitude --beta -0.73 --tau-obs 0.02 --a-n 0.002 --out s1
    uavsim session import 00000042.BIN --preset ardupilot-roll --kind mrft --beta -0.73 --out s2
"""

from __future__ import annotations

import argparse
from typing import Any

from uavsim.cli._common import print_json, print_table
from uavsim.formats.session import NP_MRFT_RUN, RELAY_KINDS, read_session, session_summary


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``session`` command and its actions to the top-level parser."""
    parser = subparsers.add_parser(
        "session",
        help="inspect flight sessions (uavsim-session/2, or 1) and import flight logs",
        description="Inspect flight sessions: a folder with session.toml and one CSV per run.",
    )
    actions = parser.add_subparsers(dest="session_command", metavar="ACTION")
    actions.required = True
    check = actions.add_parser(
        "check",
        help="validate a session and print a summary",
        description="Validate a session (every key, value and CSV row) and summarize it.",
    )
    check.add_argument("path", metavar="PATH", help="the session folder or its session.toml")
    check.add_argument(
        "--json", action="store_true", help="print one JSON object on stdout instead of text"
    )
    check.set_defaults(func=_check)
    _register_import(actions)


def _register_import(actions) -> None:
    from uavsim.logs.importer import FORMATS, PRESETS

    presets = "; ".join(f"{k}: r={p.r}, y={p.y}, u={p.u}" for k, p in PRESETS.items())
    imp = actions.add_parser(
        "import", help="a flight log (ULog, DataFlash, ROS 2 bag) as a session",
        description="Write a session with one relay run from a flight log. Fields: TOPIC.FIELD, -X, rad(X), "
                    f"roll(TOPIC.q), pitch(TOPIC.q) or a number. Presets: {presets}.")
    imp.add_argument("log", metavar="LOG", help=".ulg, DataFlash .bin, or a ROS 2 bag folder")
    imp.add_argument("--out", required=True, metavar="DIR", help="session folder to write")
    imp.add_argument("--preset", choices=list(PRESETS), help="where the loop's r, y, u are")
    imp.add_argument("--r", metavar="FIELD", help="reference (overrides the preset's)")
    imp.add_argument("--y", metavar="FIELD", help="measurement (overrides the preset's)")
    imp.add_argument("--u", metavar="FIELD", help="relay command (overrides the preset's)")
    imp.add_argument("--loop", help="session loop (default: the preset's)")
    imp.add_argument("--format", choices=FORMATS, help="log format (default: from the file)")
    imp.add_argument("--kind", default=NP_MRFT_RUN, choices=list(RELAY_KINDS), help="relay run kind")
    imp.add_argument("--beta", type=float, help="the relay's beta (required)")
    imp.add_argument("--h", type=float, help="relay amplitude, command units (default: detected in u)")
    imp.add_argument("--bias", type=float, help="relay bias, command units (default: detected in u)")
    imp.add_argument("--bias-trim", choices=["off", "duty"], default="off",
                     help="duty: the flight's relay trimmed its bias from each cycle's duty (then give --h, --bias, "
                          "--start and --stop: its u has more than two levels)")
    imp.add_argument("--tau-obs", type=float, help="NP-MRFT observation time, s (np-mrft)")
    imp.add_argument("--a-n", type=float, help="NP-MRFT noise amplitude, output units (np-mrft)")
    imp.add_argument("--rate", type=float, help="control rate, Hz (default: u's logging rate)")
    imp.add_argument("--start", type=float, help="window start, s of log time (default: detected)")
    imp.add_argument("--stop", type=float, help="window end, s of log time (default: detected)")
    imp.add_argument("--json", action="store_true", help="print one JSON object")
    imp.set_defaults(func=_import)


def _import(args: argparse.Namespace) -> int:
    from uavsim.cli._common import eprint
    from uavsim.logs import import_log

    ans = import_log(args.log, args.out, preset=args.preset, r=args.r, y=args.y, u=args.u, loop=args.loop,
                     fmt=args.format, kind=args.kind, beta=args.beta, h=args.h, bias=args.bias,
                     tau_obs=args.tau_obs, a_n=args.a_n, rate_hz=args.rate, start=args.start, stop=args.stop,
                     bias_trim=args.bias_trim, log_fn=lambda s: eprint(f"session import: {s}"))
    if args.json:
        print_json(ans)
    else:
        print(f"wrote {ans['session']}: {ans['loop']} {ans['run']['kind']}, {ans['samples']} samples at "
              f"{ans['rate_hz']:g} Hz from {ans['format']} t = {ans['start']:.6g}..{ans['stop']:.6g} s")
    return 0


def _check(args: argparse.Namespace) -> int:
    # read_session raises SessionError (a UserError) on any problem; main
    # turns it into one line on stderr and exit status 2.
    session = read_session(args.path)
    summary = session_summary(session)
    if args.json:
        print_json(summary)
        return 0
    _print_text(summary)
    return 0


def _params_text(params: dict[str, Any]) -> str:
    return " ".join(f"{k}={v}" if isinstance(v, str) else f"{k}={v:.6g}" for k, v in params.items() if v is not None)


def _print_text(summary: dict[str, Any]) -> None:
    rate = summary["control_rate_hz"]
    print(f"session  {summary['path']}  (ok)")
    print(f"loop     {summary['loop']}")
    print(f"rate     {rate:.6g} Hz (Ts = {1000.0 / rate:.6g} ms)")
    model = summary["model"]
    print(f"model    {_params_text(model) if model else 'none (identification case)'}")
    actuator = summary["actuator"]
    if actuator is not None:
        print(f"actuator {_params_text(actuator)} (command units about the hover trim)")
    effects = summary["effects"]
    names = ", ".join(
        f"{e['name']}({_params_text(e['params'])})" if e["params"] else e["name"] for e in effects
    )
    print(f"effects  {names or 'none'}")
    print()
    rows = []
    for run in summary["runs"]:
        params = {
            k: v for k, v in run.items() if k not in ("file", "kind", "samples", "duration_s")
        }
        rows.append(
            {
                "file": run["file"],
                "kind": run["kind"],
                "samples": run["samples"],
                "duration_s": run["duration_s"],
                "params": _params_text(params),
            }
        )
    print_table(rows, ["file", "kind", "samples", "duration_s", "params"])
