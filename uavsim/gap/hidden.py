"""Hidden-effect sessions: simulated flights with one secret effect, to test the gap workflow.

``hidden_session(seed)`` draws a base model from the paper's box (loop
altitude, roll or pitch; ``T_prop``, ``T1``, ``tau`` uniform in the box, ``K``
log-uniform in [0.2, 5]), a measurement noise of 0.5-2% of the predicted
oscillation amplitude, and one effect of the vocabulary (or ``none``) with a
random magnitude chosen relative to the loop's own scales (period, relay
amplitude, oscillation amplitude) so that the effect is observable while the
loop still oscillates. It then flies four runs on the MuJoCo loop with the
registry effects of :mod:`uavsim.model.effects` at one scalar value
(the workflow fits with the same effects at per-episode values): NP-MRFT at beta = -0.73 with h and 2 h (amplitude
dependence), NP-MRFT at beta = -0.3 (frequency dependence) and a PD step with
half the tuning rule's gains (so that a hidden delay cannot destabilize it).
Attitude relays use ``h`` such that the cycle stays near 0.1 rad. The session carries the base ``[model]`` and no
``[[effects]]``: the truth is returned separately (``write_hidden`` puts it in
``<folder>.truth.json`` beside the session folder, never inside it).

    session, truth = hidden_session(seed=4)
    write_hidden(session, truth, "out/hidden_004")   # out/hidden_004/ + out/hidden_004.truth.json
    truth.effect, truth.params                       # e.g. "lag", {"T": 0.043}
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from uavsim.errors import UserError
from uavsim.formats.session import (
    NP_MRFT_RUN,
    STEP_RUN,
    ModelSpec,
    Run,
    RunData,
    RunSpec,
    Session,
    write_session,
)
from uavsim.gap.simulate import Episode, SessionController, run_reference
from uavsim.lumped.params import RANGES, LumpedParams, loop_family
from uavsim.model.effects import make_effect, vocabulary
from uavsim.noise.analysis import rising_edges
from uavsim.sim.runner import LoopBatch
from uavsim.tuning.rule import TuningRule

__all__ = ["HIDDEN_EFFECTS", "Truth", "hidden_session", "write_hidden", "draw_effect"]

# The vocabulary the suite draws from, ``none`` included (uniformly): a live view of the
# registered vocabulary effects, in the format's table order.
HIDDEN_EFFECTS = vocabulary.WITH_NONE
RATE_HZ = 200.0


@dataclass
class Truth:
    """What the generator hid.

    Attributes
    ----------
    effect : str
        Vocabulary name (``"none"`` for no effect).
    params : dict of str to float
        The effect's parameters (empty for none).
    seed : int
        Seed of the draw and the simulation.
    loop : str
    model : dict
        The base model's lumped parameters and noise std (also in the session).
    """

    effect: str
    params: dict[str, float]
    seed: int
    loop: str
    model: dict


def _scales(p: LumpedParams, h: float) -> tuple[float, float]:
    """Predicted MRFT (beta = -0.73) period, s, and amplitude at relay ``h``, output units."""
    g = TuningRule().gains(p)
    return 2 * math.pi / g.omega, g.amplitude_df * h


def draw_effect(name: str, rng: np.random.Generator, period: float, h: float, amp: float, noise_std: float,
                rate_hz: float = RATE_HZ) -> dict[str, float]:
    """A random observable magnitude of effect ``name`` for a loop with these scales.

    Parameters
    ----------
    name : str
        Vocabulary name.
    rng : numpy Generator
    period : float
        MRFT period of the base loop, s.
    h : float
        Smallest relay amplitude of the session, command units.
    amp : float
        Oscillation amplitude at ``h``, output units.
    noise_std : float
        The model's measurement noise std, output units.
    rate_hz : float
        Control rate, Hz.
    """
    if name == "none":
        return {}
    try:
        term = vocabulary.term(name)
    except UserError:
        raise ValueError(f"unknown effect {name!r}") from None
    return term.draw(rng, period, h, amp, noise_std, rate_hz)


def _oscillates(t: np.ndarray, u: np.ndarray) -> bool:
    e = rising_edges(u)
    return e.size >= 6 and not np.isnan(u).any()


def hidden_session(seed: int, effect: str | None = None, loop: str | None = None) -> tuple[Session, Truth]:
    """Draw and fly one hidden-effect session.

    Parameters
    ----------
    seed : int
        Seeds the draws and the simulation's noise.
    effect : str, optional
        Force this effect (default: drawn uniformly from :data:`HIDDEN_EFFECTS`).
    loop : str, optional
        Force the loop (default: altitude, roll or pitch at random).

    Returns
    -------
    (Session, Truth)
        The session (base model, no effects) and what was hidden.
    """
    rng = np.random.default_rng([seed, 9])
    loop = loop or str(rng.choice(["altitude", "roll", "pitch"]))
    effect = effect or str(rng.choice(tuple(HIDDEN_EFFECTS)))
    box = RANGES[loop_family(loop)]
    for _attempt in range(20):
        p = LumpedParams(
            loop,
            K=float(math.exp(rng.uniform(math.log(0.2), math.log(5.0)))),
            T_prop=float(rng.uniform(*box["T_prop"])),
            T1=float(rng.uniform(*box["T1"])),
            tau=float(rng.uniform(*box["tau"])),
        )
        period, amp = _scales(p, 1.0)
        # attitude amplitudes stay small angles (the runner stops at 1.2 rad)
        h = 1.0 if loop == "altitude" else min(1.0, 0.1 / amp)
        amp *= h
        if period > 1.0:  # keep sessions short (the 2-minute budget); the box has slower loops
            continue
        noise_std = float(rng.uniform(0.005, 0.02) * amp)
        params = draw_effect(effect, rng, period, h, amp, noise_std)
        session = _fly(p, h, period, amp, noise_std, effect, params, seed)
        if session is not None:
            break
    else:  # pragma: no cover - the box always has points that oscillate
        raise RuntimeError(f"no oscillating session for seed {seed}")
    model = session.model
    truth = Truth(effect, params, int(seed), loop, asdict(model))
    return session, truth


def _fly(p: LumpedParams, h: float, period: float, amp: float, noise_std: float, effect: str,
         params: dict[str, float], seed: int) -> Session | None:
    duration = float(np.clip(14 * period, 5.0, 14.0))
    tau_obs, a_n = 0.015, 2.0 * noise_std
    g = TuningRule().gains(p)
    specs = [
        RunSpec("np_b073_h1.csv", NP_MRFT_RUN, beta=-0.73, h=h, tau_obs=tau_obs, a_n=a_n),
        RunSpec("np_b073_h2.csv", NP_MRFT_RUN, beta=-0.73, h=2 * h, tau_obs=tau_obs, a_n=a_n),
        RunSpec("np_b030_h1.csv", NP_MRFT_RUN, beta=-0.3, h=h, tau_obs=tau_obs, a_n=a_n),
        # half the rule's gains: the rule leaves 20 deg of phase margin, which a
        # hidden delay or lag would eat; the step run must stay stable
        RunSpec("step.csv", STEP_RUN, kp=0.5 * g.kp, kd=0.5 * g.kd, derivative_filter_hz=g.derivative_filter_hz,
                step=round(2.0 * amp, 12), step_time=0.5),
    ]
    T = int(round(duration * RATE_HZ))
    t = np.arange(T) / RATE_HZ
    zero = RunData(t, np.zeros(T), np.zeros(T), np.zeros(T))
    runs = [Run(s, zero) for s in specs]
    fx = [make_effect("noise", std=noise_std)]
    if effect != "none":
        fx.append(make_effect(effect, **params))
    lb = LoopBatch([p] * len(runs), rate_hz=RATE_HZ, effects=fx, seed=seed, nthread=0)
    ref = np.stack([run_reference(r, T, RATE_HZ) for r in runs])
    res = lb.run(SessionController(runs, [Episode(i) for i in range(len(runs))], RATE_HZ), duration, reference=ref)
    if res.diverged.any():
        return None
    for i in range(3):
        if not _oscillates(t, res.u[i]):
            return None
    if not np.isfinite(res.y[3]).all() or np.abs(res.y[3]).max() > 20 * abs(specs[3].step):
        return None
    out = [Run(s, RunData(t.copy(), res.r[i].copy(), res.y[i].copy(), res.u[i].copy())) for i, s in enumerate(specs)]
    model = ModelSpec(K=p.K, T_prop=p.T_prop, T1=p.T1, tau=p.tau, noise_std=noise_std)
    return Session(loop=p.loop, control_rate_hz=RATE_HZ, runs=out, model=model)


def write_hidden(session: Session, truth: Truth, path: str | Path) -> Path:
    """Write the session folder at ``path`` and the truth to ``<path>.truth.json`` beside it."""
    folder = write_session(session, path)
    Path(str(Path(path)) + ".truth.json").write_text(json.dumps(asdict(truth), indent=1) + "\n")
    return folder
