"""``uavsim sim relay``: one relay episode per loop on the MuJoCo hexarotor.

Prints the limit cycle's period and amplitude next to the exact lumped
prediction, and can save the episode as a session (``--session DIR``).
"""

from __future__ import annotations

import argparse

import numpy as np

from uavsim.cli._common import eprint, print_json, print_table
from uavsim.control.relay import MRFT, NPMRFT
from uavsim.lumped.params import LumpedParams
from uavsim.noise.analysis import cycle_stats
from uavsim.sim.runner import LoopBatch
from uavsim.sim.sessions import DEMO_PARAMS, episode_to_session


def _relay(args: argparse.Namespace) -> int:
    loops = args.loop or list(DEMO_PARAMS)
    rows = []
    for loop in loops:
        kw = dict(DEMO_PARAMS[loop])
        for k in ("K", "T_prop", "T1", "tau"):
            v = getattr(args, k)
            if v is not None:
                kw[k] = v
        p = LumpedParams(loop, **kw).check()
        lb = LoopBatch([p], dt=args.dt, rate_hz=args.rate, y0=np.array([-1e-3]), seed=args.seed)
        if args.tau_obs > 0 or args.a_n > 0:
            ctl = NPMRFT(args.beta, args.h, args.tau_obs, args.a_n, args.rate, 1)
        else:
            ctl = MRFT(args.beta, args.h, args.rate, 1)
        res = lb.run(ctl, args.duration)
        if res.diverged[0]:
            eprint(f"{loop}: diverged: {res.reasons[0]}")
        P, A, nc = cycle_stats(res.t, res.y[0], res.u[0], settle=0.5 * args.duration)
        row = {"loop": loop, **kw, "beta": args.beta, "h": args.h, "period_s": P, "amplitude": A, "cycles": nc}
        try:
            from uavsim.lumped import exact_limit_cycle

            Pe, Ae = exact_limit_cycle(p, args.beta, args.h)
            row.update(period_exact_s=Pe, amplitude_exact=Ae)
        except ImportError:  # pragma: no cover - lumped math not installed
            pass
        rows.append(row)
        if args.session:
            path = episode_to_session(res, 0, loop, args, f"{args.session}/{loop}")
            eprint(f"{loop}: session written to {path}")
    if args.json:
        print_json({"rows": rows})
    else:
        print_table(rows)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="simulate loops of the hexarotor", description="Simulate loops of the MuJoCo hexarotor.")
    ssub = p.add_subparsers(dest="sim_command", metavar="ACTION")
    ssub.required = True
    r = ssub.add_parser("relay", help="one MRFT/NP-MRFT episode per loop", description=__doc__)
    r.add_argument("--loop", action="append", choices=list(DEMO_PARAMS), help="loop (repeatable; default all inner loops)")
    r.add_argument("--K", type=float, help="loop gain")
    r.add_argument("--T-prop", dest="T_prop", type=float, help="propulsion time constant, s")
    r.add_argument("--T1", type=float, help="body time constant, s")
    r.add_argument("--tau", type=float, help="loop delay, s")
    r.add_argument("--beta", type=float, default=-0.73, help="MRFT beta (default -0.73)")
    r.add_argument("--h", type=float, default=1.0, help="relay amplitude, command units")
    r.add_argument("--tau-obs", dest="tau_obs", type=float, default=0.0, help="NP-MRFT observation time, s")
    r.add_argument("--a-n", dest="a_n", type=float, default=0.0, help="NP-MRFT noise amplitude")
    r.add_argument("--rate", type=float, default=200.0, help="control rate, Hz")
    r.add_argument("--dt", type=float, default=0.0005, help="physics step, s")
    r.add_argument("--duration", type=float, default=20.0, help="episode length, s")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--session", help="also save each episode as a session folder under this path")
    r.add_argument("--json", action="store_true", help="print JSON")
    r.set_defaults(func=_relay)
