"""``uavsim replay``: look at a flight session in the Rerun viewer.

Logs every run of a session (or one, ``--run``) to Rerun: r, y, e = r - y and
u over time, the switching instants, and for relay runs the accepted extrema
and ``tau_obs`` inhibition windows recomputed with the project's NP-MRFT, a
check that the recomputed relay output matches the logged u, and the phase
portrait (e, de/dt). See :mod:`uavsim.viz.replay`.

Without ``--save`` or ``--spawn`` (or when no viewer can be started) the
recording is written to ``<session>/replay.rrd``; open it with
``rerun FILE.rrd``.

    uavsim replay flights/2024-05-01 --save replay.rrd
    uavsim replay flights/2024-05-01 --run mrft_b073_h1.csv --spawn
    uavsim replay flights/2024-05-01 --json
"""

from __future__ import annotations

import argparse

from uavsim.cli._common import print_json


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``replay`` command to the top-level parser."""
    parser = subparsers.add_parser(
        "replay",
        help="replay a flight session in Rerun (signals, relay switches, phase portrait)",
        description=(
            "Log a session to Rerun with the relay's extrema and tau_obs windows recomputed; "
            "write an .rrd file and/or open the viewer."
        ),
    )
    parser.add_argument("path", metavar="PATH", help="the session folder or its session.toml")
    parser.add_argument(
        "--save", metavar="FILE.rrd", default=None,
        help="write the recording to this file (default without --spawn: PATH/replay.rrd)",
    )  # fmt: skip
    parser.add_argument("--spawn", action="store_true", help="open the Rerun viewer if available")
    parser.add_argument(
        "--run", metavar="FILE", default=None, help="replay only this run (CSV name or stem)"
    )
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.set_defaults(func=_replay)


def _replay(args: argparse.Namespace) -> int:
    from uavsim.viz.replay import replay_session

    summary = replay_session(args.path, args.save, run=args.run, spawn=args.spawn)
    if args.json:
        print_json(summary)
        return 0
    where = summary["rrd"] or "viewer"
    print(
        f"replay  {summary['session']}  -> {where}"
        + ("  (viewer spawned)" if summary["spawned"] else "")
    )
    for info in summary["runs"]:
        line = f"  runs/{info['stem']}  {info['kind']:<8} {info['rows']} samples  {info['switches']} switches"
        if "u_mismatch" in info:
            line += f"  {info['extrema']} extrema  u mismatch {info['u_mismatch']}"
        print(line)
    return 0
