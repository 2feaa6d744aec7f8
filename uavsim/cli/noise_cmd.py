"""``uavsim noise SESSION``: measure the noise of a flight segment and recommend NP-MRFT settings.

Reads the session, takes one run (``--run FILE``, default the first), forms
the error ``e = r - y`` and recommends ``tau_obs`` and ``a_n`` for the next
relay run (``uavsim.noise.estimate``), from nothing but the session:

- a step run is a hover segment: its settled part (the last half after the
  step) gives the noise period ``T_n`` and amplitude, hence a *first* run's
  settings (``recommend``);
- a relay run (mrft / np-mrft) is refined (``refine``): its measured period
  and amplitude, the time its error takes from an extremum to the switching
  level (what beta allows ``tau_obs`` to be on this cycle) and how early or late
  it switched against the noise-free level give the next run's settings.
  Refine again from that next run until the settings settle (two refinements
  are what ``uavsim bench noise`` measures).

It also prints ``beta_min`` (the paper's formula) for the recommended
``tau_obs`` at the measured period; ``--beta`` overrides the run's beta.

    uavsim noise flights/2024-05-01 --run mrft_b073_h1.csv --json
"""

from __future__ import annotations

import argparse

import numpy as np

from uavsim.cli._common import print_json, print_table
from uavsim.errors import UserError
from uavsim.formats.session import NP_MRFT_RUN, STEP_RUN
from uavsim.noise.estimate import estimate_noise, recommend, recommended_beta_min, refine


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
    b = beta if beta is not None else (run.spec.beta if run.spec.beta is not None else -0.73)
    if run.spec.kind == STEP_RUN:
        t_step = run.spec.step_time or 0.0
        # settled part: the second half of what follows the step
        start = t_step + 0.5 * (d.t[-1] - t_step)
        how = f"settled part of the step run (t >= {start:.3g} s) as a hover segment: a first run's settings"
        est = estimate_noise(e[d.t >= start], rate)
        tau_obs, a_n = recommend(est, b)
        out = {"T_n": est.T_n, "a_n": a_n, "a_n_mean": est.a_n_mean, "sigma": est.sigma,
               "cutoff_hz": est.cutoff_hz, "period": None, "amplitude": None, "level_time": None,
               "switch_error": None, "refined": False, "notes": est.notes}
    else:
        run_tau = float(run.spec.tau_obs or 0.0) if run.spec.kind == NP_MRFT_RUN else 1.0 / rate
        run_a_n = float(run.spec.a_n or 0.0) if run.spec.kind == NP_MRFT_RUN else 0.0
        ref = refine(np.asarray(d.t, dtype=float), e, np.asarray(d.u, dtype=float), beta=b, tau_obs=run_tau,
                     a_n=run_a_n, rate_hz=rate)
        tau_obs, a_n = ref.tau_obs, ref.a_n
        period = ref.period if np.isfinite(ref.period) else None
        how = (f"relay run refined: {ref.half_cycles} half-cycles of period {ref.period:.4g} s"
               if ref.refined else "relay run without enough steady half-cycles: its settings kept")
        est = ref.noise
        out = {"T_n": est.T_n, "a_n": a_n, "a_n_mean": est.a_n_mean, "sigma": est.sigma,
               "cutoff_hz": est.cutoff_hz, "period": period, "amplitude": ref.amplitude,
               "level_time": ref.level_time, "switch_error": ref.switch_error, "refined": ref.refined,
               "notes": ref.notes + est.notes}
    return {
        "session": str(session.path) if session.path is not None else None,
        "run": run.spec.file, "kind": run.spec.kind, "segment": how, **out, "beta": b,
        "tau_obs": tau_obs, "beta_min": recommended_beta_min(tau_obs, out["period"]),
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
        ("tau_obs", "s"), ("a_n", "output units"), ("T_n", "s"), ("a_n_mean", "output units"),
        ("sigma", "output units"), ("cutoff_hz", "Hz"), ("period", "s"), ("amplitude", "output units"),
        ("level_time", "s"), ("switch_error", "output units"), ("beta", ""), ("beta_min", ""))]
    print(f"run {out['run']} ({out['kind']}): {out['segment']}")
    print_table(rows, ["quantity", "value", "unit"])
    for note in out["notes"]:
        print(f"note: {note}")
    return 0
