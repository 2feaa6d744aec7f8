"""``uavsim bench sim``: batched closed-loop stepping against raw MuJoCo stepping.

Measured in one run on the same altitude-loop model, so that the ratios do not
depend on how busy the machine is:

- ``raw_steps_per_s``: ``Batch.step`` on ``nsim`` simulations, no controller;
- ``closed_loop_steps_per_s``: ``LoopBatch`` with a numpy MRFT at 200 Hz;
- ``python_loop_steps_per_s``: a plain Python loop over ``MjData`` with the
  same relay, simulations split over as many processes as the batch has
  threads (Python threads would share one interpreter lock), each one
  simulation after another (measured on fewer simulations and reported per
  simulated step);
- ``ratio_closed_loop_to_raw`` and ``ratio_closed_loop_to_python``.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import time

import mujoco
import numpy as np

from uavsim.cli._common import eprint, print_result
from uavsim.control.relay import MRFT
from uavsim.lumped.params import LumpedParams
from uavsim.sim.runner import LoopBatch


def _params(n: int, rng: np.random.Generator) -> list[LumpedParams]:
    return [
        LumpedParams("altitude", K=float(rng.uniform(0.5, 2)), T_prop=float(rng.uniform(0.02, 0.3)),
                     T1=float(rng.uniform(0.2, 2)), tau=float(rng.uniform(0.001, 0.06)))
        for _ in range(n)
    ]


def _python_loop(params: list[LumpedParams], dt: float, rate_hz: float, T: int) -> tuple[int, float]:
    """A plain Python loop over MjData, one simulation after another: (physics steps made, seconds taken)."""
    lb = LoopBatch(params, dt=dt, rate_hz=rate_hz, y0=np.full(len(params), -1e-3))
    mix = lb.vehicle.mixer()[:, 0] / lb.vehicle.thrust_per_us
    done = 0
    t0 = time.perf_counter()
    for i in range(len(params)):
        model = lb.batch.get_model(i)
        d = mujoco.MjData(model)
        d.qpos[2] = -1e-3
        relay = MRFT(-0.73, 1.0, rate_hz, 1)
        scale = lb.map.cmd_scale[i]
        for _ in range(T):
            u = relay(np.array([-d.qpos[2]]))[0]
            d.ctrl[:] = scale * u * mix
            for _ in range(lb.rate_steps):
                mujoco.mj_step(model, d)
        done += T * lb.rate_steps
    return done, time.perf_counter() - t0


def bench_sim(nsim: int = 1024, duration_s: float = 2.0, dt: float = 0.001, rate_hz: float = 200.0,
              python_sims: int = 8, seed: int = 0, rounds: int = 3) -> dict:
    """Run the three measurements; return the figures (steps are physics steps).

    Raw and closed-loop stepping are measured ``rounds`` times, alternating,
    and the medians are reported.
    """
    rng = np.random.default_rng(seed)
    params = _params(nsim, rng)
    lb = LoopBatch(params, dt=dt, rate_hz=rate_hz, y0=np.full(nsim, -1e-3))
    T = int(round(duration_s * rate_hz))
    steps = T * lb.rate_steps * nsim
    raws, closeds = [], []
    # alternate the two measurements so that a change in machine load hits both
    for _ in range(rounds):
        b = lb.batch  # raw: the same batch, the same substeps, no controller
        t0 = time.perf_counter()
        for _ in range(T):
            b.step(nstep=lb.rate_steps)
        raws.append(steps / (time.perf_counter() - t0))
        lb2 = LoopBatch(params, dt=dt, rate_hz=rate_hz, y0=np.full(nsim, -1e-3))
        t0 = time.perf_counter()
        lb2.run(MRFT(-0.73, 1.0, rate_hz, nsim), duration_s)
        closeds.append(steps / (time.perf_counter() - t0))
    raw, closed = float(np.median(raws)), float(np.median(closeds))
    # a plain Python loop over MjData with the same relay and mapping, on the batch's thread count
    nthread = int(lb.batch.nthread)
    python_sims = max(python_sims, nthread)
    shares = [[params[i] for i in range(k, python_sims, nthread)] for k in range(nthread)]
    with cf.ProcessPoolExecutor(max_workers=nthread) as ex:
        done = list(ex.map(_python_loop, shares, [dt] * nthread, [rate_hz] * nthread, [T] * nthread))
    # the processes ran side by side: their steps over the longest one's loop time (start-up excluded)
    py = sum(n for n, _ in done) / max(s for _, s in done)
    return {
        "nsim": nsim, "nthread": lb.batch.nthread, "python_loop_processes": nthread, "dt": dt, "rate_hz": rate_hz, "rounds": rounds,
        "raw_steps_per_s": raw, "closed_loop_steps_per_s": closed, "python_loop_steps_per_s": py,
        "ratio_closed_loop_to_raw": closed / raw, "ratio_closed_loop_to_python": closed / py,
    }


def _run(args: argparse.Namespace) -> int:
    eprint(f"bench sim: {args.nsim} simulations, {args.duration} s each ...")
    r = bench_sim(args.nsim, args.duration, args.dt, python_sims=args.python_sims, seed=args.seed, rounds=args.rounds)
    print_result(r, args.json)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="batched closed loop vs raw MuJoCo vs Python loop", description=__doc__)
    p.add_argument("--nsim", type=int, default=1024)
    p.add_argument("--duration", type=float, default=2.0, help="simulated seconds per episode")
    p.add_argument("--dt", type=float, default=0.001)
    p.add_argument("--python-sims", dest="python_sims", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rounds", type=int, default=3, help="alternating raw/closed-loop repetitions")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_run)
