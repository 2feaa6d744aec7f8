"""Make the example NP-MRFT altitude session of ``make demo`` (``scenarios/sessions/altitude-npmrft``).

An off-grid altitude process (not a grid class) flown in the MuJoCo hexarotor
under NP-MRFT at the grid's beta, with white measurement noise of 5% of the
oscillation amplitude, recorded at the 200 Hz control rate and saved as a
session (format ``uavsim-session/2``) **without** ``[model]``: the
identification case. The NP-MRFT settings are a user's: a hover segment gives
the first run's, each run is refined for the next (``uavsim noise``), and the
third run is the session's. The true process is written beside it
(``altitude-npmrft.truth.json``) so the demo can compare.

    python -m uavsim.sim.example_session                       # rewrites scenarios/sessions/ (seeded, deterministic)
    python -m uavsim.sim.example_session --out /tmp/sessions   # the same bytes elsewhere
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from uavsim.control.relay import NPMRFT
from uavsim.formats.session import write_session
from uavsim.lumped.params import LumpedParams
from uavsim.lumped.simulate import exact_limit_cycle
from uavsim.noise.estimate import estimate_noise, recommend, refine, synthetic_hover
from uavsim.noise.models import make_noise
from uavsim.sim.runner import LoopBatch
from uavsim.sim.sessions import relay_session
from uavsim.tuning.grid import load_grid
from uavsim.tuning.rule import TuningRule

#: the folder ``make demo`` reads, relative to the repository root
DEFAULT_OUT = Path("scenarios") / "sessions"
NAME = "altitude-npmrft"
SEED = 2024
# off-grid: between the grid's classes; a 3.38 kg hexarotor's altitude loop in PWM-us command units
TRUE = LumpedParams("altitude", K=2.4, T_prop=0.11, T1=0.74, tau=0.021)
H = 0.5           # relay amplitude, command units
NOISE = 0.05      # white noise amplitude (2 std) / oscillation amplitude
SECONDS = 10.0
REFINEMENTS = 2   # relay runs refined from the one before


def make_example_session(out: str | Path = DEFAULT_OUT) -> Path:
    """Fly the example session and write ``out/altitude-npmrft/`` and ``out/altitude-npmrft.truth.json``.

    Returns the session folder. Same code and seed, same bytes.
    """
    out = Path(out)
    grid = load_grid("altitude")
    beta = grid.beta
    _, a0 = exact_limit_cycle(TRUE, beta, H)
    rng = np.random.default_rng(SEED)
    hover = synthetic_hover(1, 10.0, 200.0, np.array([a0]), make_noise("white", NOISE, a0), rng)[0]
    est = estimate_noise(hover, 200.0)
    tau_obs, a_n = recommend(est, beta)
    settings = [(tau_obs, a_n)]
    for run in range(REFINEMENTS + 1):
        lb = LoopBatch([TRUE], dt=0.0005, rate_hz=200.0, effects=[make_noise("white", NOISE, a0)], seed=SEED + run,
                       y0=np.array([-0.3 * a0]))
        res = lb.run(NPMRFT(beta, H, tau_obs, a_n, 200.0, 1), duration_s=SECONDS)
        if run < REFINEMENTS:
            ref = refine(res.t, res.r[0] - res.y[0], res.u[0], beta=beta, tau_obs=tau_obs, a_n=a_n, rate_hz=200.0,
                         hover=est)
            tau_obs, a_n = ref.tau_obs, ref.a_n
            settings.append((tau_obs, a_n))
    s = relay_session(res, 0, TRUE, beta=beta, h=H, rate_hz=200.0, tau_obs=tau_obs, a_n=a_n, with_model=False,
                      file="npmrft_b073.csv")
    path = write_session(s, out / NAME)
    g = TuningRule(beta, grid.pm_deg).gains(TRUE)
    truth = {"params": TRUE.as_dict(), "rule_gains": {"kp": g.kp, "kd": g.kd,
                                                      "derivative_filter_hz": g.derivative_filter_hz},
             "beta": beta, "h": H, "noise": {"kind": "white", "level": NOISE, "amplitude": NOISE * a0},
             "relay_settings": [{"tau_obs": t, "a_n": a} for t, a in settings], "seed": SEED,
             "oscillation_amplitude": a0}
    (out / f"{NAME}.truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uavsim.sim.example_session", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(DEFAULT_OUT), metavar="DIR",
                    help=f"folder for {NAME}/ and {NAME}.truth.json (default: {DEFAULT_OUT}, run from the repository root)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        print(f"{out}: exists and is not a folder", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    print(make_example_session(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
