"""``uavsim scenario run FILE``: a visual-servoing scenario, end to end in simulation.

NP-MRFT on the scenario's loops through its sensor chain (camera, IMU,
Kalman filter), identification, tuning, then the step or disturbance test.
Prints a table beside the paper's Tables I/II, writes a Rerun recording
(``--save FILE.rrd``; default ``<scenario>.rrd`` in the current folder) with
the run's arrays beside it (``FILE.run.npz``, what ``uavsim replay FILE.rrd``
reads back), and with ``--json`` prints one JSON object on stdout
(``{"loops": {"altitude": {...}, "lateral": {..., "loop": "lateral_y"}}, "test": {...}}``).

    uavsim scenario run scenarios/normal-camera-kf.toml --json --save normal-kf.rrd

``uavsim scenario trends [FILE ...] [--seeds N]`` runs the six camera
scenarios (default: ``scenarios/*-camera-*.toml``) over N seeds each and checks
the paper's Table I trends on the medians and per seed
(``uavsim.scenario.trends``): one flight's identification under camera noise
moves from seed to seed, one seed settles nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from uavsim.cli._common import eprint, print_json
from uavsim.lumped.params import LATERAL_LOOPS


def register(subparsers) -> None:
    p = subparsers.add_parser("scenario", help="visual-servoing scenarios (identify, tune, test)",
                              description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="scenario_cmd", required=True)
    r = sub.add_parser("run", help="run a scenario file", description=__doc__.split("\n\n")[1])
    r.add_argument("file", metavar="FILE", help="scenario TOML (scenarios/*.toml)")
    r.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    r.add_argument("--save", metavar="FILE.rrd", help="Rerun recording path (default: <scenario>.rrd)")
    r.add_argument("--seed", type=int, help="override the scenario's seed")
    r.add_argument("--sessions", metavar="DIR", help="keep the relay sessions in DIR")
    r.set_defaults(func=main)
    t = sub.add_parser("trends", help="the paper's camera trends over several seeds",
                       description=__doc__.split("\n\n")[3])
    t.add_argument("files", nargs="*", metavar="FILE", help="camera scenarios (default: scenarios/*-camera-*.toml)")
    t.add_argument("--seeds", type=int, default=5, help="seeds per scenario (default 5)")
    t.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    t.set_defaults(func=trends_main)


def main(args: argparse.Namespace) -> int:
    from uavsim.errors import UserError
    from uavsim.scenario.config import load_scenario
    from uavsim.scenario.flow import run_scenario
    from uavsim.scenario.record import write_recording
    from uavsim.scenario.table import format_table, table_rows

    if args.seed is not None and args.seed < 0:
        raise UserError(f"--seed must be >= 0, got {args.seed}")
    scn = load_scenario(args.file)
    save = Path(args.save) if args.save else Path(f"{scn.name}.rrd")
    if save.suffix != ".rrd":
        raise UserError(f"--save {save}: expected a .rrd file name")
    result = run_scenario(scn, seed=args.seed, workdir=args.sessions)
    md = "\n\n".join(f"{loop}:\n" + format_table(table_rows([result], loop), loop) for loop in result["loops"])
    write_recording(result, save, md)
    public = {k: v for k, v in result.items() if not k.startswith("_")}
    # the JSON names the lateral loop "lateral" (the contract), with its axis inside
    public["loops"] = {("lateral" if k in LATERAL_LOOPS else k): ({**v, "loop": k} if k in LATERAL_LOOPS else v)
                       for k, v in result["loops"].items()}
    public["recording"] = str(save)
    if args.json:
        print_json(public)
    else:
        print(md)
        if "test" in public:
            print("test:", ", ".join(f"{k}={v}" for k, v in public["test"].items()))
        print(f"recording: {save}")
    eprint(f"recording written to {save}")
    sys.stdout.flush()
    return 0


def trends_main(args: argparse.Namespace) -> int:
    from uavsim.errors import UserError
    from uavsim.scenario.trends import camera_trends, format_trends

    files = list(args.files)
    if not files:
        root = Path(__file__).resolve().parents[2] / "scenarios"
        files = sorted(str(f) for f in root.glob("*-camera-*.toml"))
        if not files:
            raise UserError(f"no camera scenarios under {root}; pass FILE arguments")
    res = camera_trends(files, args.seeds)
    if args.json:
        print_json(res)
    else:
        print(format_trends(res))
    sys.stdout.flush()
    return 0
