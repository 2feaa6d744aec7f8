"""``uavsim session``: inspect flight sessions (format ``uavsim-session/2``, or 1).

``check`` reads a session with every check of :mod:`uavsim.formats.session`
and prints what it found, so a user can validate a folder from the field before
feeding it to ``uavsim identify`` or ``uavsim gap``. An invalid session is a
``SessionError``: one line on stderr, exit status 2.

    uavsim session check flights/2024-05-01
    uavsim session check flights/2024-05-01/session.toml --json
"""

from __future__ import annotations

import argparse
from typing import Any

from uavsim.cli._common import print_json, print_table
from uavsim.formats.session import read_session, session_summary


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``session`` command and its actions to the top-level parser."""
    parser = subparsers.add_parser(
        "session",
        help="inspect flight sessions (uavsim-session/2, or 1)",
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
    return " ".join(f"{k}={v:.6g}" for k, v in params.items() if v is not None)


def _print_text(summary: dict[str, Any]) -> None:
    rate = summary["control_rate_hz"]
    print(f"session  {summary['path']}  (ok)")
    print(f"loop     {summary['loop']}")
    print(f"rate     {rate:.6g} Hz (Ts = {1000.0 / rate:.6g} ms)")
    model = summary["model"]
    print(f"model    {_params_text(model) if model else 'none (identification case)'}")
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
