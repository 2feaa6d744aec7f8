"""``uavsim export-gains SOURCE``: identified PD gains as PX4 or ArduPilot parameters.

SOURCE is a session (identified here, as ``uavsim identify`` does) or the JSON
``uavsim identify --json`` printed. The PD maps onto the autopilot's cascade as
outer P = kp / kd and rate P = kd * S, where S converts the session's command
units into the autopilot's (``--cmd-scale S``; for an altitude session whose u
is normalized thrust, ``--hover-thrust H`` gives S = g / H). Without S, or for
gains a P-P cascade cannot take, it refuses. The file's comments state the
mapping, the units and the identified model (``uavsim.autopilot``).

    uavsim export-gains flights/roll --models training/runs --autopilot px4 --cmd-scale 1 --out roll.params
    uavsim identify flights/alt --json > alt.json
    uavsim export-gains alt.json --autopilot ardupilot --hover-thrust 0.39 --out alt.parm
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from uavsim.cli._common import eprint, print_json


def register(subparsers) -> None:
    p = subparsers.add_parser("export-gains", help="write identified gains as PX4 or ArduPilot parameters",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("source", metavar="SOURCE", help="session folder, or the JSON of `uavsim identify --json`")
    p.add_argument("--autopilot", required=True, choices=["px4", "ardupilot"])
    p.add_argument("--out", required=True, metavar="FILE", help="parameter file (.params for PX4, .parm for "
                                                                 "ArduPilot)")
    p.add_argument("--cmd-scale", type=float, metavar="S", help="autopilot output units per session command unit")
    p.add_argument("--hover-thrust", type=float, metavar="H", help="altitude: normalized hover thrust (S = g / H)")
    p.add_argument("--gains", default="gains", choices=["gains", "gains_table", "gains_optimum", "gains_measured_point"],
                   help="which gains of the identification (default: gains)")
    p.add_argument("--models", help="with a session: exported model folder or root (as uavsim identify)")
    p.add_argument("--attitude-class", type=int, metavar="N", help="with a lateral session (as uavsim identify)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def _answer(source: str, models: str | None, attitude_class: int | None) -> dict:
    from uavsim.errors import UserError

    p = Path(source)
    if p.suffix == ".json" and p.is_file():
        try:
            ans = json.loads(p.read_text())
        except (ValueError, UnicodeDecodeError) as exc:
            raise UserError(f"{p}: not the JSON of `uavsim identify --json` ({exc})") from None
        if not isinstance(ans, dict):
            raise UserError(f"{p}: not the JSON of `uavsim identify --json` (not an object)")
        return ans
    from uavsim.ident.session import identify_session

    return identify_session(source, models=models, attitude_class=attitude_class)


def run(args: argparse.Namespace) -> int:
    from uavsim.autopilot import export_gains, write_params

    ans = _answer(args.source, args.models, args.attitude_class)
    exp = export_gains(ans, args.autopilot, cmd_scale=args.cmd_scale, hover_thrust=args.hover_thrust,
                       gains_key=args.gains)
    path = write_params(exp, args.out)
    if args.json:
        print_json({"file": str(path), "autopilot": exp.autopilot, "loop": exp.loop, "cmd_scale": exp.cmd_scale,
                    "params": exp.as_dict(), "units": {p.name: p.unit for p in exp.params}})
    else:
        eprint(f"wrote {path}")
        for p in exp.params:
            print(f"{p.name:18s} {p.value:<12.6g} {p.unit}")
    return 0
