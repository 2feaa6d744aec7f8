"""``uavsim noise SESSION``: measure the noise of a flight segment and recommend NP-MRFT settings.

Reads the session, takes one run (``--run FILE``, default the first), forms
the error ``e = r - y`` and estimates the noise period ``T_n``, the noise
amplitude ``a_n`` and ``sigma`` (``uavsim.noise.estimate``):

- a step run: only the settled part (the last half after the step) is used;
- a relay run (mrft / np-mrft): the oscillation is high-passed above its
  harmonics, and its measured period gives ``T0`` for ``beta_min``.

It prints the recommended ``tau_obs`` and ``a_n`` and the resulting
``beta_min`` for the run's beta (``--beta`` overrides it).

    uavsim noise flights/2024-05-01 --run mrft_b073_h1.csv --json
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from uavsim.cli._common import print_json, print_table
from uavsim.errors import UserError
from uavsim.noise.analysis import cycle_stats
from uavsim.noise.estimate import estimate_noise, recommend, recommended_beta_min


def register(subparsers) -> None:
    p = subparsers.add_parser("noise", help="estimate measurement noise and recommend NP-MRFT tau_obs and a_n",
                              description=__doc__.split("\n\n")[0])
    p.add_argument("session", metavar="SESSION", help="session folder or its session.toml")
    p.add_argument("--run", metavar="FILE", help="the run's CSV file name (default: the first run)")
    p.add_argument("--beta", type=float, help="planned MRFT beta (default: the run's, else -0.73)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=main)


def analyse(session, run_file: str | None = None, beta: float | None = None) -> dict:
    """Noise estimate and recommendation for one run of a ``Session``; returns a JSON-ready dict."""
    runs = session.runs
    if run_file is None:
        run = runs[0]
    else:
        match = [r for r in runs if r.spec.file == run_file]
        if not match:
            raise UserError(f"no run {run_file!r} in the session (runs: {', '.join(r.spec.file for r in runs)})")
        run = match[0]
    d = run.data
    rate = float(session.control_rate_hz)
    e = np.asarray(d.r, dtype=float) - np.asarray(d.y, dtype=float)
    period = None
    segment = e
    if run.spec.kind == "step":
        t_step = run.spec.step_time or 0.0
        # settled part: the second half of what follows the step
        start = t_step + 0.5 * (d.t[-1] - t_step)
        segment = e[d.t >= start]
        how = f"settled part of the step run (t >= {start:.3g} s)"
    else:
        period, _, ncyc = cycle_stats(d.t, e, d.u)
        if ncyc >= 2 and math.isfinite(period):
            how = f"oscillation of period {period:.4g} s, high-passed above its harmonics"
        else:
            period = None
            how = "relay run without a steady cycle: treated as a hover segment"
    b = beta if beta is not None else (run.spec.beta if run.spec.beta is not None else -0.73)
    est = estimate_noise(segment, rate, period=period)
    tau_obs, a_n = recommend(est, b, period)
    return {
        "session": str(session.path) if session.path is not None else None,
        "run": run.spec.file, "kind": run.spec.kind, "segment": how,
        "T_n": est.T_n, "a_n": a_n, "a_n_mean": est.a_n_mean, "sigma": est.sigma,
        "cutoff_hz": est.cutoff_hz, "period": period, "beta": b,
        "tau_obs": tau_obs, "beta_min": recommended_beta_min(tau_obs, period),
        "notes": est.notes,
    }


def main(args: argparse.Namespace) -> int:
    from uavsim.formats.session import read_session

    if args.beta is not None and not -1 < args.beta < 1:
        raise UserError(f"--beta must lie in (-1, 1), got {args.beta}")
    out = analyse(read_session(args.session), args.run, args.beta)
    if args.json:
        print_json(out)
        return 0
    rows = [{"quantity": k, "value": out[k], "unit": u} for k, u in (
        ("T_n", "s"), ("a_n", "output units"), ("a_n_mean", "output units"), ("sigma", "output units"),
        ("cutoff_hz", "Hz"), ("period", "s"), ("tau_obs", "s"), ("beta", ""), ("beta_min", ""))]
    print(f"run {out['run']} ({out['kind']}): {out['segment']}")
    print_table(rows, ["quantity", "value", "unit"])
    for note in out["notes"]:
        print(f"note: {note}")
    return 0
