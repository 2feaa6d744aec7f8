"""The relay cycle identification uses, and the checks that refuse what is not one.

``extract_cycle`` runs THE preprocessing (``uavsim.data.preprocess.features``:
same resampling, edges, normalization and input length as the training sets,
with the bundle's settings) and then refuses, with ``NoOscillation`` (one line,
never a guess):

* a clipped output (``SATURATION_FRACTION`` of the cycle at its top or bottom level);
* a period no class of the network comes near (``ModelBundle.period_bounds``): the
  relay switching on noise, or a process outside the grid's box;
* a phase the relay cannot have put the loop at (``phase_lead`` above
  ``PHASE_LEAD_MAX_DEG``): switched early, on noise, and then the "response"
  ``Y1 / (h U1)`` is partly the noise's correlation with the relay;
* for a network trained on relay runs that trim their bias (``ModelBundle.bias_trim``),
  a cycle whose duty is further from a half than ``DUTY_LIMIT`` (``duty_refusal``): a
  relay bias (or disturbance) the training cycles never had.
* for the loops in ``POINT_PHASE_SE_LIMIT_DEG`` (attitude), a measured point whose phase
  scatters from cycle to cycle beyond that standard error (``scatter_refusal``): under heavy
  noise such a point gives gains far from the optimum or unstable ones.

When the run's last cycles are refused, the steady cycles before them are
tried, up to ``MAX_CYCLES_DROPPED`` cycles back (``IDENT_CYCLES_DROPPED`` per loop: a
burst of noise can break the last cycle of a run whose earlier ones are fine); the
answer's ``oscillation`` ``start``/``stop`` say which samples were used. The fundamental
response is averaged over up to ``IDENT_RESPONSE_CYCLES`` steady cycles of the loop's run
where it has them (a longer lateral run measures its point better: its standard error
falls with the root of the cycles, ``uavsim.ident.family``). When none of those cuts has two
cycles of steady length (the preprocessing's 25 %: a noisy run whose relay switches
unevenly), identification does not refuse outright: the cut whose last two cycles
agree best is used, up to ``IDENT_STEADY_TOL`` apart, for the loops in
``UNEVEN_CYCLE_LOOPS`` (lateral: its decision backs its PD off on the response's
per-cycle spread, ``CycleFeatures.response_spread``, measured over those uneven
cycles; the inner loops' decision has no such back-off, and there such answers were
unstable more often than the others). The training sets never take such a cycle
(their preprocessing keeps its own tolerance); the other checks still apply.

    from uavsim.ident.cycle import extract_cycle
    f = extract_cycle(y, u, rate_hz=200.0, h=1.0, bias=0.0, bundle=b)
    f.x, f.period, f.response
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.data.preprocess import (
    MIN_CYCLE_SAMPLES,
    RESPONSE_CYCLES,
    STEADY_TOL,
    CycleFeatures,
    features,
    held_response,
)
from uavsim.errors import NoOscillation, UserError
from uavsim.ident.bundle import ModelBundle
from uavsim.ident.response import phase_se_deg

__all__ = ["SATURATION_FRACTION", "PHASE_LEAD_MAX_DEG", "PHASE_LAG_MAX_DEG", "DUTY_LIMIT", "MAX_CYCLES_DROPPED",
           "IDENT_CYCLES_DROPPED", "IDENT_RESPONSE_CYCLES", "IDENT_STEADY_TOL",
           "UNEVEN_CYCLE_LOOPS", "IDENT_INPUTS",
           "extract_cycle", "response_cycles", "phase_lead", "phase_lost", "phase_refusal", "period_refusal",
           "saturation_refusal",
           "duty_refusal", "DUTY_REFUSAL_PREFIX", "scatter_refusal", "POINT_PHASE_SE_LIMIT_DEG"]

#: a cycle whose output sits at its top or bottom level this fraction of the time is clipped, not a relay cycle
SATURATION_FRACTION = 0.35
_SAT_BAND = 0.005  # of the peak-to-peak: "at the extreme level"
#: a cycle lagging more than this (deg) less than the relay's phase was switched by noise (``phase_lead``);
#: NP-MRFT's own cycles lead by up to ~55 deg with a user's settings (a long observation window and a
#: relay bias of half h, even without noise: ``uavsim evaluate``), and identify as well as the others
PHASE_LEAD_MAX_DEG = 70.0
#: a cycle lagging more than this (deg) beyond the relay's phase is no limit cycle of the relay either
#: (``phase_lost``): on the altitude episodes of development seeds 11-20 the first runs' points lag at most
#: 54 deg beyond it (all but one at most 31), but for one at 20 % noise, 120 deg (a two-cycle "cycle" of noise)
PHASE_LAG_MAX_DEG = 70.0
#: a network trained on bias-trimmed relays refuses a cycle whose duty error ``|2 d - 1|`` (about the relay
#: bias over h on these loops) is above this: 0.3 % of the trimmed training cycles are (a trim not settled under
#: 10-20 % noise; development seeds 11-13: 8 of 1800 trimmed runs refused so, which answered had J 1.13-2.3 and
#: one unstable), and untrimmed runs beyond it failed (unstable or refused) 1 in 10 to 3 in 10 (development seed 11)
DUTY_LIMIT = 0.2
#: when the last cycles are refused, the steady cycles up to this many cycles before the end are tried
MAX_CYCLES_DROPPED = 3
#: the same per loop where a run has more cycles to go back over (a loop not named: ``MAX_CYCLES_DROPPED``);
#: lateral runs of 13 cycles under 0-20 % noise (development seeds 11-12, identified on the whole trace before
#: ``uavsim evaluate`` cut it to the final run): 10 back refuse 1 and 12 of 480 where 3 back refuse 5 and 19
IDENT_CYCLES_DROPPED: dict[str, int] = {"lateral": 10}
#: most steady cycles each loop's fundamental response is averaged over, where the run has them
#: (``uavsim.data.preprocess.features``' ``response_cycles``; a loop not named: ``RESPONSE_CYCLES``)
IDENT_RESPONSE_CYCLES: dict[str, int] = {"lateral": 12, "attitude": 12}
#: identification refuses a loop's cycle whose measured point's phase standard error (its cycles' phase spread
#: over the root of their count, ``uavsim.ident.response.point_sigmas``) is above this, degrees (a loop not
#: named: never). Attitude runs of 13 cycles, development seeds 11-20 (3,000 processes, 0-20 % noise): of the 7
#: answers beyond 20 degrees (all at 15-20 % noise) one was unstable and five had J 1.26-2.03; refusing them took
#: the max 2.03 -> 1.38 at 27 refusals in all (docs/results/identification.md)
POINT_PHASE_SE_LIMIT_DEG: dict[str, float] = {"attitude": 20.0}
#: identification only: where no cut has two cycles within the preprocessing's steady tolerance, the cut whose
#: two last cycles agree best is used if their lengths differ by at most this fraction of the longer
#: (development seeds 11-12, lateral: every such answer stable, the spread back-off engaged on most)
IDENT_STEADY_TOL = 0.75
#: the loops whose identification takes such uneven cycles (module docstring)
UNEVEN_CYCLE_LOOPS = ("lateral",)
#: what the network sees of a loop's run (``uavsim.data.preprocess.features``'s ``inputs``; a loop not
#: named, or a network of several cycles: the last cycle, as in training)
IDENT_INPUTS: dict[str, str] = {}
_RESAMPLE_MARGIN = 0.02


def saturation_refusal(y: np.ndarray) -> str | None:
    """Why a cycle's output ``y`` is clipped (sits at its extreme level for long), or None."""
    y = np.asarray(y, dtype=np.float64)
    if y.size < 4:
        return None
    hi, lo = float(y.max()), float(y.min())
    band = _SAT_BAND * (hi - lo)
    for name, frac in (("top", np.mean(y >= hi - band)), ("bottom", np.mean(y <= lo + band))):
        if frac > SATURATION_FRACTION:
            return f"output saturated: the cycle sits at its {name} level {100 * frac:.0f}% of the time"
    return None


#: how :func:`duty_refusal`'s reason begins (the gap workflow tells a refusal for the duty alone by it)
DUTY_REFUSAL_PREFIX = "relay duty "


def duty_refusal(s: np.ndarray, bias_trim: str) -> str | None:
    """Why a cycle is not one a network trained on relays with ``bias_trim`` knows, or None.

    ``s``: the relay's state at each sample of whole cycles (> 0 at ``+h``). A trimmed relay's
    cycle is symmetric: a duty error ``|2 d - 1|`` above ``DUTY_LIMIT`` is refused.
    """
    s = np.asarray(s, dtype=np.float64)
    if bias_trim == "off" or s.size == 0:
        return None
    duty = float(np.mean(s > 0))
    err = abs(2.0 * duty - 1.0)
    if err <= DUTY_LIMIT:
        return None
    return (f"{DUTY_REFUSAL_PREFIX}{duty:.2f} over the cycle (a bias of about {err:.2f} h): the network was "
            "trained on relay runs that trim their bias to a symmetric cycle; fly the run with bias_trim = \"duty\" "
            "and long enough for the trim to settle")


def scatter_refusal(loop: str, response_spread: tuple[float, float], cycles: int) -> str | None:
    """Why a cycle's measured point scatters too much to identify ``loop`` from, or None.

    ``response_spread``: std of log |G| and of the phase (rad) over the ``cycles`` steady cycles the
    point averages (``CycleFeatures.response_spread``); refused where the phase's standard error is
    above the loop's ``POINT_PHASE_SE_LIMIT_DEG``.
    """
    limit = POINT_PHASE_SE_LIMIT_DEG.get(loop)
    if limit is None:
        return None
    se = phase_se_deg(float(response_spread[1]), cycles)
    if not se > limit:
        return None
    return (f"the measured point's phase scatters from cycle to cycle (standard error {se:.0f} deg over {cycles} "
            f"cycles, beyond {limit:g}): noise or a disturbance moves the cycle; fly a longer run or with less noise")


def period_refusal(period: float, bounds: tuple[float, float]) -> str | None:
    """Why a cycle of ``period`` (s) is none the classes give (outside ``bounds``), or None."""
    lo, hi = bounds
    if lo <= period <= hi:
        return None
    return (f"cycle period {period:.3g} s is outside what the grid's classes give ({lo:.3g}-{hi:.3g} s): the relay "
            "switched on noise, or the process is outside the grid's box")


def phase_lead(response: complex, response_period: float, beta: float, rate_hz: float = 200.0) -> float:
    """How far (deg) the measured response lags less than a relay at ``beta`` puts it, ``arg G - (-pi + asin beta)``.

    A relay test puts the loop where ``arg G(jw) = -pi + asin(beta)`` (NP-MRFT's
    observation window and ``a_n`` switch later, so more lag; sampling moves it by a
    few degrees). A cycle that lags clearly less was switched early, by noise.
    """
    w = 2.0 * math.pi / float(response_period)
    ph = float(np.angle(complex(response) / held_response(1.0, w, rate_hz)))
    ph = ph - 2.0 * math.pi if ph > 0 else ph  # a relay cycle lags between pi/2 and 2 pi
    return math.degrees(ph - (-math.pi + math.asin(float(beta))))


def phase_lost(response: complex, response_period: float, beta: float, rate_hz: float = 200.0) -> bool:
    """Whether a measured point lags more than ``PHASE_LAG_MAX_DEG`` beyond the phase a relay at ``beta`` puts
    the loop at (``phase_lead``): its cycle measured no phase of the process."""
    return phase_lead(response, response_period, beta, rate_hz) < -PHASE_LAG_MAX_DEG


def phase_refusal(response: complex, response_period: float, beta: float | None, rate_hz: float = 200.0) -> str | None:
    """Why a cycle of this response is not one a relay at ``beta`` produces (``phase_lead`` above
    ``PHASE_LEAD_MAX_DEG``: switched early, on noise), or None; None without a ``beta``."""
    if beta is None:
        return None
    lead = phase_lead(response, response_period, beta, rate_hz)
    if lead > PHASE_LEAD_MAX_DEG:
        return f"the cycle lags {lead:.0f} deg less than a relay at beta={beta:g} puts it: the relay switched early, on noise"
    return None


def extract_cycle(y: np.ndarray, u: np.ndarray, *, rate_hz: float, h: float, bias: float, bundle: ModelBundle,
                  beta: float | None = None, inputs: str | None = None) -> CycleFeatures:
    """The network input and the measured response of a relay run, checked (module docstring).

    Parameters
    ----------
    y, u : (T,) measurement and relay command as the controller saw / computed them
    rate_hz : control rate of the samples, Hz
    h, bias : relay amplitude and bias, command units
    bundle : the network's bundle (preprocessing settings, classes' periods, the relay's beta)
    beta : the run's MRFT parameter; must match the network's when given
    inputs : what the network sees (``features``'s ``inputs``); None: the loop's ``IDENT_INPUTS``

    Raises
    ------
    NoOscillation
        No usable relay oscillation (see module docstring and ``uavsim.data.preprocess``).
    UserError
        A run at another ``beta`` than the network's.
    """
    nb = bundle.rule.beta
    if inputs is None:
        inputs = IDENT_INPUTS.get(bundle.loop, "last") if bundle.cycles == 1 else "last"
    if beta is not None and abs(float(beta) - nb) > 1e-6:
        raise UserError(f"the run used beta={beta} but the {bundle.loop} network was trained at beta={nb:g}")
    y = np.asarray(y, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    pos = (u - bias) > 0
    edges = np.flatnonzero(pos[1:] & ~pos[:-1]) + 1
    # the last cycles, else the last steady ones before them (noise can break a run's last cycle): cut
    # at each rising edge back to MAX_CYCLES_DROPPED typical cycles before the end (a chattering burst
    # has many edges)
    d = np.diff(edges) * (bundle.input_rate_hz / rate_hz)
    d = d[d >= MIN_CYCLE_SAMPLES]
    typical = float(np.median(d)) * rate_hz / bundle.input_rate_hz if d.size else 0.0
    earliest = len(y) - (IDENT_CYCLES_DROPPED.get(bundle.loop, MAX_CYCLES_DROPPED) + 0.5) * typical
    rc = response_cycles(bundle.loop)
    cuts = [len(y)] + [int(e) + 1 for e in edges[::-1][: max(len(edges) - bundle.cycles - 2, 0)] if e >= earliest]

    def checked(stop: int, tol: float | None) -> CycleFeatures:
        f = features(y[:stop], u[:stop], rate_hz, h, bias, bundle.input_length, cycles=bundle.cycles, steady_tol=tol,
                     inputs=inputs, harmonics=False, response_cycles=rc)
        why = (saturation_refusal(y[f.start : f.stop])
               or duty_refusal(pos[f.start : f.stop], bundle.bias_trim)
               or period_refusal(f.period, bundle.period_bounds())
               or phase_refusal(f.response, f.response_period, nb, bundle.input_rate_hz))
        if why:
            raise NoOscillation(why)
        return f

    f = _first_cut(cuts, checked, edges=edges, uneven=bundle.loop in UNEVEN_CYCLE_LOOPS)
    why = scatter_refusal(bundle.loop, f.response_spread, f.response_cycles)
    if why:
        raise NoOscillation(why)
    return f


def _first_cut(cuts: list[int], checked, *, edges: np.ndarray, uneven: bool) -> CycleFeatures:
    """The first cut of ``cuts`` (sample indices) that ``checked(stop, None)`` accepts; else, where
    ``uneven``, the most even pair's (module docstring; ``edges``: the relay's rising edges); else
    the first refusal."""
    first = None
    for stop in cuts:
        try:
            return checked(stop, None)
        except NoOscillation as exc:
            first = first or exc
    if not uneven:
        raise first
    # no cut with a steady pair: the most even pair of cycles, up to IDENT_STEADY_TOL apart (module docstring)
    # (the tolerance passed is the pair's own, so the response cycles are the ones as even as it; the
    # margin covers edges moved by a sample when another control rate is resampled)
    for mismatch, neg_stop in sorted((_pair_mismatch(edges, s), -s) for s in cuts):
        stop = -neg_stop
        if mismatch > IDENT_STEADY_TOL:
            break
        if mismatch <= STEADY_TOL:
            continue  # tried above
        try:
            return checked(stop, mismatch + _RESAMPLE_MARGIN)
        except NoOscillation:
            continue
    raise first


def response_cycles(loop: str) -> int:
    """Most steady cycles identification averages ``loop``'s fundamental response over (``IDENT_RESPONSE_CYCLES``,
    else ``RESPONSE_CYCLES``): ``features``' ``response_cycles`` wherever a run of that loop is read."""
    return IDENT_RESPONSE_CYCLES.get(loop, RESPONSE_CYCLES)


def _pair_mismatch(edges: np.ndarray, stop: int) -> float:
    """The relative length difference of the two last full cycles (between ``edges``) before sample ``stop``."""
    e = edges[edges < stop]
    if e.size < 3:
        return math.inf
    last, before = float(e[-1] - e[-2]), float(e[-2] - e[-3])
    return abs(last - before) / max(last, before)
