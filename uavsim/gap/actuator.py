"""The actuator's own limits, fitted on the steps so that the effect search does not take them for an effect.

A step test's PD differentiates the error, so the step's first sample sends a
command many times the relay's amplitude (a 0.18 rad pitch step with ``kd``
9.3 and a 19 Hz derivative filter: 134 command units, against a relay ``h``
of 5.7). A real aircraft's actuators clip and slew that kick (the ESCs' PWM
range and slew); a lumped model passes it whole, overshoots more and starts
sooner. That difference is in every session, clean or not, and the effect
search reads it as a ``saturation`` or a ``rate_limit`` (on clean testbed
sessions they removed 40-55% of the gap the base model left).

:func:`fit_actuator` gives the base model the actuator's limits, each only in
the range where it leaves the relay runs alone, so that an effect which acts on
the relay's cycle is still the search's to find:

* a ``saturation`` no lower than the largest relay amplitude (the user chose
  ``h`` inside the actuator's range, so the relay itself never clips);
* a ``rate_limit`` no slower than the largest relay switch (``2 h``) in
  :data:`SLEW_SHARE` of the shortest measured period (an effect slower than
  that shapes the cycle and is the search's).

A grid of both (and neither) is flown in one batch with the session's runs;
the best is kept when it beats no limit. The search's candidates of the same
name still run: an episode's own ``saturation`` or ``rate_limit`` replaces the
actuator's (a tighter limit in series hides the looser one).

    act = fit_actuator(session, model, seed=0)
    act.limits          # {"saturation": ..., "rate_limit": ...} (either may be absent)
    act.gap_none, act.gap
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from uavsim.formats.session import STEP_RUN, ModelSpec, Session
from uavsim.gap.features import noise_offsets, noise_scales
from uavsim.gap.workflow import GapEvaluator, base_effects

__all__ = ["ActuatorFit", "fit_actuator", "actuator_floors", "SAT_FACTORS", "SLEW_FACTORS", "SLEW_SHARE"]

#: saturation limits tried, in multiples of the largest relay amplitude
SAT_FACTORS = (1.0, 1.5, 2.2, 3.2)
#: slew rates tried, in multiples of the slowest allowed (:func:`actuator_floors`)
SLEW_FACTORS = (1.0, 2.0, 4.0)
#: the slowest actuator slew: the largest relay switch (2 h) within this share of the shortest period
SLEW_SHARE = 0.05
#: noise seeds per grid point
SEEDS = 2


@dataclass
class ActuatorFit:
    """The actuator limits of the base model.

    Attributes
    ----------
    limits : dict of str to float
        ``saturation`` (command units) and/or ``rate_limit`` (command units/s); empty when
        no limit beat none (or the session has no step run).
    gap_none, gap : float
        Gap of the base model without and with ``limits`` (the grid's seeds).
    floors : dict of str to float
        The lowest ``saturation`` and ``rate_limit`` allowed (:func:`actuator_floors`).
    episodes : int
    seconds : float
    """

    limits: dict[str, float] = field(default_factory=dict)
    gap_none: float = math.nan
    gap: float = math.nan
    floors: dict[str, float] = field(default_factory=dict)
    episodes: int = 0
    seconds: float = 0.0

    def to_json(self) -> dict:
        return {"limits": dict(self.limits), "gap_none": self.gap_none, "gap": self.gap, "floors": dict(self.floors),
                "episodes": self.episodes, "seconds": self.seconds}  # fmt: skip


def actuator_floors(session: Session, meas: list[dict | None]) -> dict[str, float]:
    """Lowest actuator ``saturation`` and ``rate_limit`` that leave the session's relay runs alone.

    ``saturation``: the largest relay amplitude ``h``; ``rate_limit``: ``2 h`` over
    :data:`SLEW_SHARE` of the shortest measured relay period (``meas``: the runs' features).
    """
    relays = [(abs(float(r.spec.h)), f) for r, f in zip(session.runs, meas, strict=True)
              if r.spec.kind != STEP_RUN and r.spec.h is not None and f is not None and "period" in f]  # fmt: skip
    if not relays:
        return {}
    hmax = max(h for h, _ in relays)
    pmin = min(math.exp(f["period"]) for _, f in relays)
    return {"saturation": hmax, "rate_limit": 2.0 * hmax / (SLEW_SHARE * pmin)}


def fit_actuator(
    session: Session,
    model: ModelSpec,
    *,
    seed: int = 0,
    nthread: int = 0,
    dt: float = 0.001,
    log=None,
) -> ActuatorFit:
    """The actuator limits (:data:`SAT_FACTORS` x :data:`SLEW_FACTORS` above the floors, and none) that fit best.

    Parameters
    ----------
    session : Session
        The live runs (each analysable); nothing is fitted without a step run.
    model : ModelSpec
        The base model (its noise std is flown).
    seed, nthread, dt :
        As :func:`uavsim.gap.workflow.run_gap`.
    log : callable(str), optional

    Returns
    -------
    ActuatorFit
    """
    t0 = time.perf_counter()
    log = log or (lambda msg: None)
    base = base_effects(session)
    ev = GapEvaluator(session, model, base, seed, nthread, dt)
    floors = actuator_floors(session, ev.meas)
    if not floors or not any(r.spec.kind == STEP_RUN for r in session.runs):
        return ActuatorFit(floors=floors, seconds=time.perf_counter() - t0)
    sats = [None] + [floors["saturation"] * f for f in SAT_FACTORS if "saturation" not in base]
    slews = [None] + [floors["rate_limit"] * f for f in SLEW_FACTORS if "rate_limit" not in base]
    first = ev.sims([("none", 0.0)], seeds=3)
    fb = [ev.features(s) for s in first]
    if any(f is None for f in fb[0]):
        return ActuatorFit(floors=floors, episodes=3 * ev.R, seconds=time.perf_counter() - t0)
    ev.scales = noise_scales(fb)
    ev.offsets = noise_offsets(ev.meas, fb, ev.scales)
    # one batch per slew, the saturations as its episodes' own effect
    grid, gaps = [], []
    for slew in slews:
        ev.base = dict(base) if slew is None else {**base, "rate_limit": slew}
        sims = ev.sims([("none", 0.0) if sat is None else ("saturation", sat) for sat in sats], seeds=SEEDS)
        for j, sat in enumerate(sats):
            grid.append((sat, slew))
            gaps.append(float(np.mean([ev.gap(ev.features(s)) for s in sims[j * SEEDS:(j + 1) * SEEDS]])))
    ev.base = dict(base)
    k = int(np.argmin(gaps))
    sat, slew = grid[k]
    limits = {}
    if sat is not None:
        limits["saturation"] = float(sat)
    if slew is not None:
        limits["rate_limit"] = float(slew)
    res = ActuatorFit(limits=limits, gap_none=gaps[0], gap=gaps[k], floors=floors,
                      episodes=(3 + SEEDS * len(grid)) * ev.R, seconds=time.perf_counter() - t0)  # fmt: skip
    log("actuator limits on the steps: " + (", ".join(f"{n} {v:.4g}" for n, v in limits.items()) or "none")
        + f" (gap {res.gap_none:.3f} -> {res.gap:.3f}; {res.seconds:.1f} s)")  # fmt: skip
    return res
