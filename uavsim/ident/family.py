"""The lateral PD chosen over the family of models the measured point allows.

A lateral process over a known attitude loop has three unknowns: its gain ``K``, drag
time constant ``T2`` and outer delay ``tau``. One relay cycle measures ``G(j w)`` at one
frequency, two real numbers, so every ``T2`` fixes the ``K`` and ``tau`` that put the
model on the measured point (``uavsim.ident.response.fit_response_lateral``): the models
consistent with the measurement form a one-parameter **family**. The grid's classes sit
on it only at their own ``T2``, and a class's table PD is the optimum of its nominal
model, not of the family member that matches the flight; the lateral optima are fragile
(gain margins 1.03-1.3), so the distance costs much.

``family_gains`` answers instead the ISE-optimal PD at the control rate of one family
member, times one of ``FAMILY_SCALES``:

1. the family: ``T2`` on ``FAMILY_T2_POINTS`` log-spaced points of the box and every
   class's own, each fitted to the point; members whose delay is not in ``(0, tau_max]``
   of the box are no process the measurement allows;
2. the belief on the family: the network's softmax at each class's own member
   (``1 - FAMILY_FLAT`` of it), the rest spread flat over the members;
3. the candidates: each member's own optimum (``uavsim.tuning.optimal``) times each factor;
4. the measurement's own error: the family fitted again to the point moved by the
   cycle's phase spread (at least ``FAMILY_PHASE_DEG``) both ways, and with the gain
   raised by its log-gain spread, alone and with either phase;
5. the answer: the largest factor whose candidates keep the largest share of all those
   models stable (a smaller factor only where it keeps more), and among those candidates
   the one of least belief-weighted ``log(ISE / best ISE)`` over the nominal family
   (clipped like ``J``).

The answer must hold every member stable, so with one point it is the optimum of about the
most cautious member, whatever the network believes. **A second relay run at another
frequency** (``other``: ``uavsim.ident.twopoint.SECOND_BETA``) tells the members apart:
each predicts that run's point too, and the family is kept to the members whose miss
(``other_point_chi2``, over the point's standard errors with
``uavsim.ident.twopoint.EXTRAPOLATION_SIGMA``) is within ``FAMILY_OTHER_CHI2`` of the
best's, ``FAMILY_UNSTEADY_CHI2`` where the other point's own cycles disagree (its error
is then not its spread's), the moved families likewise; the belief is weighed by
``exp(-chi2 / 2)``. Identification anchors the family on the network's run where its
cycle is steady, else on the second run's (``uavsim.ident.session.identify_cycle``), and
answers from the second run alone where the network's run was refused
(``identify_second_point``). On development seeds 11-13 (480 off-grid processes each,
0-20 % noise) the lateral p95 went from 1.429 / 1.559 / 1.463 with one run to 1.075 /
1.080 / 1.083 (docs/results/identification.md); the two limits were set there (the
family's tail fell as the first narrowed, 6 -> 2 -> 1 -> 0.5, and flattened at 0.25; the
second was 0.5 until a noisy first point ruled out the true member on seed 13).

Only a **steady cycle** is answered so (``family_applies``): at least
``FAMILY_MIN_CYCLES`` response cycles, whose own responses spread less than
``FAMILY_SPREAD_LIMITS``, as a run of ``FAMILY_REFERENCE_CYCLES`` response cycles would
(``point_spread``: a longer run's spread is scaled to the one that four cycles need for
the same 95 % confidence half-width of the mean point, Student's t; a run of 12 response
cycles passes with a spread about 2.8 times as large). Under 10-20 % noise the measured
phase is off by several degrees even where the cycles agree (development seed 12: six answers of J 1.4-13
or unstable at phase spreads of 1.7-2.9 degrees, where the table's answers were
1.00-1.05); the limits were set on development seeds 11-12 as the widest that added no
unstable answer and raised no p95 there (runs at the network's beta, one run). A second run's
cycle is steady within twice those limits (``SECOND_SPREAD_LIMITS``): its cycle is several times
larger for the same sensor, and its point the more accurate at the same spread (development seed 12:
the two unstable table answers had second points within 1.4 % and 0.8 degrees of the exact response
at spreads the first limits refused; twice the limits took development seeds 11-13 from p95 1.075 /
1.080 / 1.083 and 0 / 2 / 0 unstable to 1.063 / 1.069 / 1.081 and none, with 1.5 and 3 times the same
or within 0.003). Elsewhere the class decision's table answer (``decide_stable``) stays.

Cost: ``optimal_gains`` on 10-35 members and ``6 x members^2`` closed loops per factor
tried: whole identifications of 71-88 ms median and 0.46-0.66 s p95 on one thread of the
2-core development machine (``uavsim evaluate``'s clock; the answer's ``latency_ms``), off
the table's real-time path, as the fitted optimum is.

    from uavsim.ident.family import family_applies, family_gains
    if family_applies(f.response_spread, f.response_cycles):
        g = family_gains(bundle, p, f.response, f.response_period,
                         spread=point_spread(f.response_spread, f.response_cycles), other=f2)
        g.kp, g.kd, g.derivative_filter_hz, g.scale, g.T2_s, g.tau_s     # FamilyAnswer (None: no member)
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from uavsim.errors import UserError
from uavsim.ident.bundle import ModelBundle
from uavsim.ident.gains import flight_attitude, lateral_model, model_loop_params
from uavsim.learning.decision import COST_CLIP

__all__ = ["FAMILY_T2_POINTS", "FAMILY_FLAT", "FAMILY_SCALES", "FAMILY_PHASE_DEG", "FAMILY_SPREAD_LIMITS",
           "FAMILY_OTHER_CHI2", "FAMILY_UNSTEADY_CHI2",
           "FAMILY_MIN_CYCLES", "FAMILY_REFERENCE_CYCLES", "DEFAULT_FAMILY", "FamilyAnswer", "default_family",
           "SECOND_SPREAD_LIMITS", "point_spread", "unsteady_spread", "other_point_chi2", "family_applies",
           "family_members", "family_gains"]

#: log-spaced drag time constants of the box the family is taken at (beside every class's own)
FAMILY_T2_POINTS = 12
#: share of the belief spread flat over the family's members
FAMILY_FLAT = 0.2
#: factors on a member's optimum the answer may take, largest first
FAMILY_SCALES = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5)
#: least phase error (deg) the family is moved by, both ways
FAMILY_PHASE_DEG = 2.0
#: a cycle whose response cycles spread by more than (std of log |G|, std of phase in deg) keeps the table answer
FAMILY_SPREAD_LIMITS = (0.1, 1.5)
#: another point's ``chi2`` above the best member's by more than this rules a member out
FAMILY_OTHER_CHI2 = 0.5
#: the spread limits a second relay run's cycle is steady within (``family_applies``'s ``limits``): the second
#: point is measured on a cycle several times larger, over up to 12 cycles, and is the more accurate of the two
#: at the same spread (module docstring)
SECOND_SPREAD_LIMITS = (2.0 * FAMILY_SPREAD_LIMITS[0], 2.0 * FAMILY_SPREAD_LIMITS[1])
#: ``FAMILY_OTHER_CHI2`` for another point whose own cycles are not steady (``family_applies``)
FAMILY_UNSTEADY_CHI2 = 4.0
#: fewest response cycles a family answer is made from
FAMILY_MIN_CYCLES = 3
#: the response cycles ``FAMILY_SPREAD_LIMITS`` hold for (the runs of 5 cycles they were set on)
FAMILY_REFERENCE_CYCLES = 4
#: loops whose steady cycles answer the family's PD where identification is not told otherwise
DEFAULT_FAMILY = {"lateral": True}


@dataclass(frozen=True)
class FamilyAnswer:
    """The family's PD and the member it is the optimum of.

    Attributes
    ----------
    kp, kd : PD gains (command per output unit, command s per output unit)
    derivative_filter_hz : the PD's derivative filter, Hz
    scale : the factor on the member's optimum
    K, T2_s, tau_s : the member (gain, drag time constant and outer delay, s)
    members : models of the nominal family
    stable_share : share of the nominal and moved models the answer keeps stable
    expected_log_ratio : its belief-weighted ``log(ISE / best ISE)`` over the nominal family
    """

    kp: float
    kd: float
    derivative_filter_hz: float
    scale: float
    K: float
    T2_s: float
    tau_s: float
    members: int
    stable_share: float
    expected_log_ratio: float


def default_family(loop: str, family: bool | None) -> bool:
    """Whether ``loop`` answers the family's PD: ``family``, or None for ``DEFAULT_FAMILY``; a one-line error
    where it is asked of an inner loop."""
    if family is None:
        return DEFAULT_FAMILY.get(loop, False)
    if family and loop != "lateral":
        raise UserError(f"the family answer is the lateral loop's, not the {loop} loop's")
    return bool(family)


def point_spread(spread, response_cycles: int, *, reference_cycles: int = FAMILY_REFERENCE_CYCLES
                 ) -> tuple[float, float]:
    """The per-cycle spread ``reference_cycles`` response cycles would need for the 95 % confidence
    half-width of their mean point that ``response_cycles`` cycles of ``spread`` give.

    ``spread`` is ``CycleFeatures.response_spread`` (std of log |G| and of the phase in rad over the
    cycles, ``ddof=0``); the half-width is ``t(0.975, m - 1) spread / sqrt(m - 1)`` for ``m`` cycles
    (Student's t: a spread measured on few cycles is itself uncertain). Unchanged at the reference.
    """
    k = _half_width(max(int(response_cycles), 2)) / _half_width(int(reference_cycles))
    return tuple(float(float(v) * k) for v in spread)


@functools.lru_cache(maxsize=64)
def _half_width(m: int) -> float:
    """``t(0.975, m - 1) / sqrt(m - 1)``: the 95 % half-width of ``m`` cycles' mean per unit of their spread
    (cached: every lateral identification asks for it, and the quantile costs about 0.05 ms)."""
    from scipy.stats import t

    return float(t.ppf(0.975, m - 1) / math.sqrt(m - 1))


def unsteady_spread(f) -> float:
    """How unsteady a measured point is: its cycles' spread over ``FAMILY_SPREAD_LIMITS`` (the larger of the
    gain's and the phase's parts), as ``point_spread`` scales it; ``f``: a ``CycleFeatures``."""
    sg, sp = point_spread(f.response_spread, f.response_cycles)
    return max(sg / FAMILY_SPREAD_LIMITS[0], math.degrees(sp) / FAMILY_SPREAD_LIMITS[1])


def family_applies(spread, response_cycles: int, *, limits=FAMILY_SPREAD_LIMITS,
                   min_cycles: int = FAMILY_MIN_CYCLES) -> bool:
    """Whether a cycle is steady enough for the family answer: ``spread`` (std of log |G|, of the phase in rad,
    over ``response_cycles`` cycles; compared as ``point_spread`` makes it)."""
    sg, sp = point_spread(spread, response_cycles)
    return response_cycles >= min_cycles and sg < limits[0] and math.degrees(sp) < limits[1]


def family_members(bundle: ModelBundle, response: complex, response_period: float, *,
                   attitude: dict[str, float] | None = None, gain_factor: float = 1.0) -> dict[str, np.ndarray]:
    """The models (B,) the measured point allows, as ``fitted_model`` gives them (``K``, ``T2``, ``tau``, the
    attitude loop's keys), and ``cls``: the class whose ``T2`` each member has (-1: none).

    ``T2`` on ``FAMILY_T2_POINTS`` log-spaced points of the box and at every class's own; ``K`` and
    ``tau`` fitted to the point (times ``gain_factor`` on ``K``); members with a delay outside
    ``(0, tau_max]`` of the box left out.
    """
    from uavsim.lumped.params import RANGES

    lo, hi = RANGES["lateral"]["T2"]
    tau_max = RANGES["lateral"]["tau"][1]
    cT2 = np.asarray(bundle.column("T2"), dtype=np.float64)
    grid = np.geomspace(lo, hi, FAMILY_T2_POINTS)
    grid = grid[~np.isclose(grid[:, None], cT2[None, :], rtol=1e-6).any(axis=1)]  # a class's own T2 is there already
    T2 = np.concatenate([cT2, grid])
    n = T2.size
    # the branch nearest the box's middle delay: the one in [0, tau_max] at lateral cycle frequencies
    m = lateral_model(bundle, np.full(n, complex(response)), np.full(n, float(response_period)), T2=T2,
                      tau_class=np.full(n, 0.5 * tau_max), attitude=attitude)
    m["cls"] = np.concatenate([np.arange(cT2.size), np.full(grid.size, -1)])
    m["K"] = m["K"] * gain_factor
    ok = np.isfinite(m["K"]) & (m["K"] > 0) & (m["tau"] > 0) & (m["tau"] <= tau_max)
    return {k: v[ok] for k, v in m.items()}


def other_point_chi2(bundle: ModelBundle, members: dict[str, np.ndarray], other, *,
                     attitude: dict[str, float] | None = None) -> np.ndarray:
    """How far each member (``family_members``) misses another relay run's measured point, (B,).

    ``other``: that run's ``CycleFeatures`` (its ``response`` at its own frequency, the hold removed
    as for the family's). The squared misses of ``log |G|`` and of the phase over the point's uncertainty
    (``uavsim.ident.twopoint.point_uncertainty`` with ``EXTRAPOLATION_SIGMA``: the members are the
    lumped model, the flight is not exactly one).
    """
    from uavsim.data.preprocess import process_response
    from uavsim.ident.response import attitude_loop_response, unit_response_lateral
    from uavsim.ident.twopoint import EXTRAPOLATION_SIGMA, point_uncertainty

    att = flight_attitude(bundle, attitude)
    w2 = 2.0 * math.pi / float(other.response_period)
    G2 = complex(process_response(other.response, other.response_period, rate_hz=bundle.input_rate_hz))
    mag0, ph0 = unit_response_lateral(w2, members["T2"], attitude_loop_response(w2, att)[0])
    pred = members["K"] * mag0 * np.exp(1j * (ph0 - w2 * members["tau"]))
    sg, sp = point_uncertainty(other, EXTRAPOLATION_SIGMA)
    return (np.log(abs(G2) / np.abs(pred)) / sg) ** 2 + (np.angle(G2 / pred) / sp) ** 2


def family_gains(bundle: ModelBundle, p: np.ndarray, response: complex, response_period: float, *,
                 spread=(0.0, 0.0), attitude: dict[str, float] | None = None, scales=FAMILY_SCALES,
                 phase_deg: float = FAMILY_PHASE_DEG, flat: float = FAMILY_FLAT, other=None,
                 other_chi2: float = FAMILY_OTHER_CHI2) -> FamilyAnswer | None:
    """The PD of the measured point's family (module docstring); None where no member holds a stable optimum.

    Parameters
    ----------
    bundle : ModelBundle
        A lateral bundle (its attitude loop, classes' ``T2``, rule and control rate).
    p : (n,) float
        The network's belief over the bundle's classes.
    response, response_period : complex, float
        The cycle's fundamental response (``CycleFeatures.response``) and its period, s.
    spread : (float, float)
        The cycle's ``response_spread`` (std of log |G|, std of the phase in rad) as ``point_spread`` scales
        it to ``FAMILY_REFERENCE_CYCLES`` cycles.
    attitude : dict or None
        The flight's attitude loop where known better than the bundle's (``fitted_model``'s).
    scales, phase_deg, flat
        ``FAMILY_SCALES``, ``FAMILY_PHASE_DEG``, ``FAMILY_FLAT``.
    other : CycleFeatures or None
        Another relay run's cycle at another ``beta``: the family is kept to the members that meet its
        point too (``other_point_chi2`` within ``other_chi2`` of the best), each weighed by how well,
        which tells the members apart where the network does not.
    other_chi2 : float
        ``FAMILY_OTHER_CHI2``; identification passes ``FAMILY_UNSTEADY_CHI2`` for a point whose own
        cycles are not steady.
    """
    from uavsim.lumped.sampled import lift, sampled_ise
    from uavsim.tuning.optimal import optimal_gains

    if bundle.loop != "lateral":
        raise ValueError("the family answer is the lateral loop's")
    nom = family_members(bundle, response, response_period, attitude=attitude)
    if nom["K"].size == 0:
        return None
    chi2, allowed = None, np.inf
    if other is not None:  # the family is the members both points allow
        chi2 = other_point_chi2(bundle, nom, other, attitude=attitude)
        allowed = float(chi2.min()) + other_chi2
        keep = chi2 <= allowed
        nom, chi2 = {k: v[keep] for k, v in nom.items()}, chi2[keep]
    B = nom["K"].size
    if B == 0:  # no member predicts the other point at all (not a number)
        return None
    w = np.full(B, flat / B)
    p = np.asarray(p, dtype=np.float64).ravel()
    on = nom["cls"] >= 0
    w[on] += (1.0 - flat) * p[nom["cls"][on]]
    if chi2 is not None:
        with np.errstate(divide="ignore"):
            lw = np.log(w) - 0.5 * chi2
        w = np.exp(lw - lw.max())
    w /= w.sum()
    pn = model_loop_params(bundle, nom)
    with np.errstate(all="ignore"):
        opt = optimal_gains(bundle.loop, bundle.rate_hz, rule=bundle.rule, **pn)
    good = np.isfinite(opt.ise) & (opt.ise > 0) & np.isfinite(opt.kp) & (opt.kp > 0)
    if not good.any():
        return None
    # the measurement's own error: the point moved by its phase spread and its gain raised by its gain spread,
    # alone and together (less lag with more gain: a PD near a member's optimum can lose a process of almost no
    # delay and a little more gain that holds it at a few ms)
    d = math.radians(max(phase_deg, math.degrees(float(spread[1]))))
    kg = math.exp(min(float(spread[0]), 1.0))
    moved = [family_members(bundle, complex(response) * np.exp(1j * dph), response_period, attitude=attitude,
                            gain_factor=gf) for dph, gf in ((-d, 1.0), (d, 1.0), (0.0, kg), (-d, kg), (d, kg))]
    if other is not None:
        moved = [{k: v[other_point_chi2(bundle, m, other, attitude=attitude) <= allowed] for k, v in m.items()}
                 for m in moved]
    allm = [pn] + [model_loop_params(bundle, m) for m in moved if m["K"].size]
    every = {k: (np.concatenate([q[k] for q in allm]) if isinstance(v, np.ndarray) else v) for k, v in pn.items()}
    M = every["K"].size
    gi = np.flatnonzero(good)
    ci, mi = np.repeat(np.arange(gi.size), M), np.tile(np.arange(M), gi.size)
    with np.errstate(all="ignore"):
        proc = lift(bundle.loop, bundle.rate_hz, **every).take(mi)
    best = (-1.0, np.inf, 0, 1.0)  # (stable share, cost, member, factor)
    for f in scales:  # largest factor first: a smaller one answers only where it holds more of the models
        with np.errstate(all="ignore"):
            q = sampled_ise(proc, f * opt.kp[gi][ci], f * opt.kd[gi][ci],
                            2.0 * math.pi * opt.derivative_filter_hz[gi][ci]).reshape(gi.size, M)
        stable = np.isfinite(q) & (q > 0)
        share = stable.mean(axis=1)
        # the nominal members without an optimum of their own weigh nothing on the cost
        ratio = np.where(stable[:, :B], q[:, :B], np.inf) / np.where(good, opt.ise, np.inf)[None, :]
        cost = np.log(np.clip(np.where(good[None, :], ratio, 1.0), *COST_CLIP)) @ w
        keep = np.flatnonzero(share >= share.max() - 1e-9)
        k = int(keep[np.argmin(cost[keep])])
        if share[k] > best[0] + 1e-9:
            best = (float(share[k]), float(cost[k]), int(gi[k]), float(f))
        if best[0] >= 1.0 - 1e-9:  # every model held: no smaller factor can do better
            break
    share, cost, j, f = best
    return FamilyAnswer(kp=f * float(opt.kp[j]), kd=f * float(opt.kd[j]),
                        derivative_filter_hz=float(opt.derivative_filter_hz[j]), scale=f, K=float(nom["K"][j]),
                        T2_s=float(nom["T2"][j]), tau_s=float(nom["tau"][j]), members=int(B), stable_share=share,
                        expected_log_ratio=cost)
