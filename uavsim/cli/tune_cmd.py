"""``uavsim tune``: the homogeneous MRFT rule's PD gains for one lumped process.

Gains are for unit gain K = 1 (a process of gain K takes kp/K, kd/K).

    uavsim tune --loop altitude --T-prop 0.3 --T1 0.2 --tau 0.0128 --json
"""

from __future__ import annotations

import argparse

from uavsim.cli._common import print_json, print_table
from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams, loop_family
from uavsim.tuning.rule import DEFAULT_BETA, DEFAULT_PM_DEG, TuningRule


def register(subparsers) -> None:
    p = subparsers.add_parser("tune", help="PD gains of the MRFT tuning rule for a lumped process (K = 1)")
    p.add_argument("--loop", required=True, help="altitude | roll | pitch | lateral_x | lateral_y")
    p.add_argument("--T-prop", dest="T_prop", type=float, required=True, help="propulsion time constant, s")
    p.add_argument("--T1", type=float, required=True, help="body time constant, s")
    p.add_argument("--tau", type=float, required=True, help="loop delay, s (lateral: tau_out)")
    p.add_argument("--T2", type=float, help="lateral drag time constant, s (lateral only)")
    p.add_argument("--tau-in", dest="tau_in", type=float, help="attitude delay, s (lateral only)")
    p.add_argument("--beta", type=float, default=DEFAULT_BETA, help=f"MRFT beta (default {DEFAULT_BETA})")
    p.add_argument("--pm", type=float, default=DEFAULT_PM_DEG, help=f"phase margin, deg (default {DEFAULT_PM_DEG})")
    p.add_argument("--gain-scale", dest="gain_scale", type=float, default=1.0,
                   help="loop gain |C G| at Omega, in (0, 1] (default 1; the lateral grids use 0.59-0.7, "
                        "see `uavsim grid report --loop lateral`)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    fam = loop_family(args.loop)
    rule = TuningRule(args.beta, args.pm, args.gain_scale)
    if fam == "lateral":
        if args.T2 is None or args.tau_in is None:
            raise UserError("a lateral loop needs --T2 and --tau-in")
        # the attitude loop is closed by the attitude rule's PD (the inner grids' rule)
        ga = TuningRule().gains(LumpedParams("roll", 1.0, args.T_prop, args.T1, args.tau_in))
        p = LumpedParams(args.loop, 1.0, args.T_prop, args.T1, args.tau, T2=args.T2, tau_in=args.tau_in,
                         att_kp=ga.kp, att_kd=ga.kd, att_filter_hz=ga.derivative_filter_hz)
    else:
        if args.T2 is not None or args.tau_in is not None:
            raise UserError("--T2 and --tau-in are only for lateral loops")
        p = LumpedParams(args.loop, 1.0, args.T_prop, args.T1, args.tau)
    p.check()
    g = rule.gains(p)
    out = {"loop": args.loop, "beta": g.beta, "pm_deg": g.pm_deg, "gain_scale": g.gain_scale, "c1": g.c1, "c3": g.c3,
           "omega": g.omega,
           "period": 2 * 3.141592653589793 / g.omega, "amplitude_df": g.amplitude_df, "kp": g.kp, "kd": g.kd,
           "derivative_filter_hz": g.derivative_filter_hz, "K": 1.0}
    if args.json:
        print_json(out)
    else:
        print_table([{k: v for k, v in out.items()}])
    return 0
