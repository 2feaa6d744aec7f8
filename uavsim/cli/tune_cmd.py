"""``uavsim tune``: PD gains for one lumped process: the homogeneous MRFT rule, and with
``--optimal`` the ISE-optimal PD at the control rate beside it.

Gains are for unit gain K = 1 (a process of gain K takes kp/K, kd/K).

    uavsim tune --loop altitude --T-prop 0.3 --T1 0.2 --tau 0.0128 --json
    uavsim tune --loop altitude --T-prop 0.3 --T1 0.2 --tau 0.0128 --optimal --rate 200

With ``--optimal`` the rule's ISE at the rate (sampled, zero-order hold) and its J
against the optimum are shown too; a lateral loop's attitude loop is then closed
by the attitude process's optimal PD at the same rate (as the lateral tables).
"""

from __future__ import annotations

import argparse
import math

from uavsim.cli._common import print_json, print_table
from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams, loop_family
from uavsim.tuning.rule import DEFAULT_BETA, DEFAULT_PM_DEG, TuningRule


def register(subparsers) -> None:
    p = subparsers.add_parser("tune", help="PD gains of the MRFT tuning rule (and the optimum at a rate) for a lumped process (K = 1)")
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
    p.add_argument("--optimal", action="store_true",
                   help="also the ISE-optimal PD at the control rate (--rate), sampled with a zero-order hold")
    p.add_argument("--rate", type=float, default=200.0, help="control rate for --optimal, Hz (default 200)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def run(args: argparse.Namespace) -> int:
    fam = loop_family(args.loop)
    rule = TuningRule(args.beta, args.pm, args.gain_scale)
    if args.optimal and not (math.isfinite(args.rate) and args.rate > 0):
        raise UserError(f"--rate must be > 0 Hz, got {args.rate}")
    attitude = None
    if fam == "lateral":
        if args.T2 is None or args.tau_in is None:
            raise UserError("a lateral loop needs --T2 and --tau-in")
        pa = LumpedParams("roll", 1.0, args.T_prop, args.T1, args.tau_in)
        if args.optimal:
            # the attitude loop flown under the lateral one: the attitude optimum at the same rate
            from uavsim.tuning.optimal import optimal_pd

            ga = optimal_pd(pa, args.rate).row(0)
        else:
            # the attitude loop is closed by the attitude rule's PD (the inner grids' rule)
            ga = TuningRule().gains(pa).as_dict()
        attitude = {"att_kp": ga["kp"], "att_kd": ga["kd"], "att_filter_hz": ga["derivative_filter_hz"]}
        p = LumpedParams(args.loop, 1.0, args.T_prop, args.T1, args.tau, T2=args.T2, tau_in=args.tau_in, **attitude)
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
    if args.optimal:
        from uavsim.tuning.optimal import optimal_pd

        o = optimal_pd(p, args.rate, rule=rule).row(0)
        out.update({"rate_hz": o["rate_hz"], "optimal_kp": o["kp"], "optimal_kd": o["kd"],
                    "optimal_derivative_filter_hz": o["derivative_filter_hz"], "optimal_ise": o["ise"],
                    "rule_ise": _finite(o["rule_ise"]), "rule_J": _finite(o["rule_ise"] / o["ise"]),
                    "optimal_kp_over_rule": o["kp"] / g.kp})
    if attitude is not None and args.optimal:
        out["attitude"] = attitude
    if args.json:
        print_json(out)
    elif args.optimal:
        rows = [{"": "rule", "kp": g.kp, "kd": g.kd, "derivative_filter_hz": g.derivative_filter_hz,
                 f"ISE at {args.rate:g} Hz": "unstable" if out["rule_ise"] is None else out["rule_ise"],
                 "J": "unstable" if out["rule_J"] is None else out["rule_J"]},
                {"": f"optimal at {args.rate:g} Hz", "kp": out["optimal_kp"], "kd": out["optimal_kd"],
                 "derivative_filter_hz": out["optimal_derivative_filter_hz"],
                 f"ISE at {args.rate:g} Hz": out["optimal_ise"], "J": 1.0}]
        print(f"{args.loop}: Omega {g.omega:.4g} rad/s (beta {g.beta:g}), K = 1")
        if attitude is not None:
            print(f"attitude loop closed by its optimal PD at {args.rate:g} Hz: kp {attitude['att_kp']:.4g}, "
                  f"kd {attitude['att_kd']:.4g}, filter {attitude['att_filter_hz']:.4g} Hz")
        print_table(rows)
    else:
        print_table([{k: v for k, v in out.items()}])
    return 0
