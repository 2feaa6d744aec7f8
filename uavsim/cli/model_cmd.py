"""``uavsim model export``: write the hexarotor MJCF so it opens in MuJoCo's viewer."""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import mujoco

from uavsim.cli._common import eprint
from uavsim.errors import UserError
from uavsim.model.vehicle import Vehicle, hexarotor_mjcf


def _export(args: argparse.Namespace) -> int:
    xml = hexarotor_mjcf(Vehicle(), timestep=args.timestep, saturation=args.saturation)
    mujoco.MjModel.from_xml_string(xml)  # refuse to write a model MuJoCo cannot load
    out = Path(args.out)
    if out.parent and not out.parent.exists():
        raise UserError(f"{out.parent}: folder does not exist")
    fd, tmp = tempfile.mkstemp(dir=out.parent or ".", prefix=out.name, suffix=".partial")
    with os.fdopen(fd, "w") as f:
        f.write(xml)
    os.replace(tmp, out)
    eprint(f"wrote {out} (open it with: python -m mujoco.viewer --mjcf={out})")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("model", help="the hexarotor model", description="The MuJoCo hexarotor model.")
    msub = p.add_subparsers(dest="model_command", metavar="ACTION")
    msub.required = True
    e = msub.add_parser("export", help="write the MJCF", description="Write the hexarotor MJCF (the paper's vehicle).")
    e.add_argument("--out", default="hexarotor.xml", help="output file (default: hexarotor.xml)")
    e.add_argument("--timestep", type=float, default=0.001, help="physics step, s (default 0.001)")
    e.add_argument("--saturation", action="store_true", help="clip rotor PWM to 1165..1878 us")
    e.set_defaults(func=_export)
