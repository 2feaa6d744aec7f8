"""``uavsim replay``: look at a session, a dataset episode or a scenario run in the Rerun viewer.

Logs r, y (as the controller saw it), y_true (noise-free, simulations), e =
r - y and u over time, the switching instants, and for relay runs the
accepted extrema and ``tau_obs`` inhibition windows recomputed with the
project's NP-MRFT, a check that the recomputed relay output matches the
logged u, the phase portrait (e, de/dt) and, for simulations, the vehicle's
3D pose with its rotor thrust arrows. See :mod:`uavsim.viz.replay`.

PATH is a session folder, a dataset file (``--class C --episode E``: the
E-th kept episode of label C, simulated again exactly from the recipe the
file records), or a scenario run (the ``.rrd`` of ``uavsim scenario run``
with the ``.run.npz`` written beside it, or that ``.run.npz``).

Without ``--save`` or ``--spawn`` (or when no viewer can be started) the
recording is written beside the source (``<session>/replay.rrd``,
``<dataset>-class<C>-episode<E>.replay.rrd``, ``<run>.replay.rrd``); open it
with ``rerun FILE.rrd``.

    uavsim replay flights/2024-05-01 --save replay.rrd
    uavsim replay flights/2024-05-01 --run mrft_b073_h1.csv --spawn
    uavsim replay datasets/small.h5 --class 2 --episode 0 --save ep.rrd
    uavsim replay normal-camera-kf.rrd --save run-replay.rrd --json
"""

from __future__ import annotations

import argparse

from uavsim.cli._common import print_json


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``replay`` command to the top-level parser."""
    parser = subparsers.add_parser(
        "replay",
        help="replay a session, dataset episode or scenario run in Rerun (signals, relay switches, "
             "phase portrait, vehicle)",
        description=(
            "Log a session, a dataset episode or a scenario run to Rerun with the relay's extrema and "
            "tau_obs windows recomputed; write an .rrd file and/or open the viewer."
        ),
    )  # fmt: skip
    parser.add_argument(
        "path", metavar="PATH",
        help="a session folder (or its session.toml), a dataset .h5, or a scenario run (.rrd or .run.npz)",
    )  # fmt: skip
    parser.add_argument(
        "--save", metavar="FILE.rrd", default=None,
        help="write the recording to this file (default without --spawn: beside PATH)",
    )  # fmt: skip
    parser.add_argument("--spawn", action="store_true", help="open the Rerun viewer if available")
    parser.add_argument(
        "--run", metavar="NAME", default=None,
        help="sessions: replay only this run (CSV name or stem); scenario runs: only this episode "
             "(e.g. altitude/relay)",
    )  # fmt: skip
    parser.add_argument("--class", dest="cls", type=int, default=None, metavar="C",
                        help="datasets: the label (row of the class table, default 0)")
    parser.add_argument("--episode", type=int, default=None, metavar="E",
                        help="datasets: the index among the label's kept episodes (default 0)")
    parser.add_argument("--no-resim", dest="resimulate", action="store_false",
                        help="do not simulate again (no noise-free output or vehicle pose)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.set_defaults(func=_replay)


def _replay(args: argparse.Namespace) -> int:
    from uavsim.viz.replay import replay

    summary = replay(args.path, args.save, run=args.run, cls=args.cls, episode=args.episode, spawn=args.spawn,
                     resimulate=args.resimulate)
    if args.json:
        print_json(summary)
        return 0
    where = summary["rrd"] or "viewer"
    print(
        f"replay  {summary['source']}  {args.path}  -> {where}"
        + ("  (viewer spawned)" if summary["spawned"] else "")
    )
    for info in summary["runs"]:
        line = f"  runs/{info['stem']}  {info['kind']:<8} {info['rows']} samples  {info['switches']} switches"
        if "u_mismatch" in info:
            line += f"  {info['extrema']} extrema  u mismatch {info['u_mismatch']}"
        if info.get("vehicle"):
            line += "  vehicle pose"
        print(line)
        for msg in info["messages"][1:-1]:
            print(f"    {msg}")
    return 0
