"""Phase-margin back-off: scale the answer's PD down where a little more lag would ruin it.

The answer (``uavsim.ident.session.identify_cycle``) is the table's robust PD of
the class decided, over the gain fitted at the measured point. Where the class is
wrong or the measured phase is off (relay cycles at 15-20 % noise measure the
phase of ``G(j w)`` a few to 15 degrees off), that PD can be near the stability
limit of the true process. The guard asks the answer's own fitted model
(``uavsim.ident.gains.fitted_model``: the class's lags, the fitted gain and
delay) with ``GUARD_PHASE_DEG`` more phase lag at the measured frequency (its
delay longer by ``radians(GUARD_PHASE_DEG) / w``) which of the factors
``GUARD_SCALES`` of ``kp`` and ``kd`` (the filter kept) still gives an ISE within
``GUARD_RATIO`` of the best of them there (exact sampled ISE at the table's rate,
``uavsim.lumped.sampled``), and answers the largest. Where the table PD holds the
perturbed model (almost always) the factor is 1 and the answer is unchanged; where
no factor holds it, the answer is kept too (the guard only backs off to a factor it
can show is better). It is a back-off by a margin stated in phase, not a blanket
detuning: ``uavsim evaluate`` scores it (``answer_guarded``) beside the plain
``x0.85`` detuning of the answer.

Measured on development seeds 11 and 12 (docs/results/identification.md) with networks
trained on untrimmed relay runs it removed 13 -> 8 unstable answers of the inner loops at a
median cost under 0.5 %, and 48 -> 39 lateral ones, without a gain at the p95, so it was
opt-in. A relay that trims its bias (``uavsim.control.relay``) measures the point 2-4 times
more precisely (log-gain spread 0.015 against 0.060 at 10 % noise, attitude seed 11), and
with the networks trained on such runs the guard lowered the p95 on all six inner loop x seed
sets of development seeds 11-13 (attitude 1.48 / 2.18 / 1.21 -> 1.15 / 1.27 / 1.12) and the
unstable answers 24 -> 12, for medians up to 0.007 higher: it is on by default for the loops
in ``DEFAULT_GUARD``. Cost: one lifted loop and ``len(GUARD_SCALES)`` ISEs (about 1 ms).

The answer's own model cannot see a wrong class: the tail that remained (attitude, development
seeds 11-13) was answers whose class fits the measured point but not the process, with the
network's belief split over neighbours (softmax 0.3-0.7 on the first). The guard therefore also
closes the answer's PD on the fitted models of the belief's ``GUARD_BELIEFS`` other most likely
classes holding at least ``GUARD_BELIEF_MIN`` (``belief_guard_scale``), each with
``GUARD_BELIEF_PHASE_DEG`` more lag, and answers the least factor (``answer_guard``). Chosen on
development seeds 11-13 (300 processes each, docs/results/identification.md): attitude at 7.5 deg
took the p95 1.153 / 1.270 / 1.122 -> 1.157 / 1.133 / 1.129, the max 2.62 / 2.92 / 1.47 -> 1.46 /
1.42 / 1.38 and the unstable answers 11 -> 5, for medians 1.021 / 1.019 / 1.020 -> 1.026 / 1.023 /
1.029 (5 deg: p95 1.152 / 1.174 / 1.112, 6 unstable; 10 deg: medians 1.046-1.054); altitude at 5
deg left the median and p95 within 0.003 and the max 1.64 -> 1.45 on seed 13 (7.5 deg raised its
medians 0.004-0.007 over the goal's 1.03). Cost: up to ``GUARD_BELIEFS`` more fitted models closed in
the same batch as the answer's own (about 1 ms more).

With a second relay run (``answer_guard``'s ``second``) the guard backs off no further than the
models both measured points allow ask (``uavsim.ident.lagfamily``: the larger of the two factors).
Where the first point measured no phase at all (``measured_no_phase``: its cycles scatter beyond
``GUARD_SECOND_POINT_SPREAD`` times the steadiness limits, or it lags beyond the relay's phase by more than
``uavsim.ident.cycle.PHASE_LAG_MAX_DEG``) and the second run's cycle is steady, the one-point factor is
closed at the second run's point.

    from uavsim.ident.guard import answer_guard, guard_scale
    s = guard_scale(bundle, cls, response, response_period, kp=kp, kd=kd, derivative_filter_hz=fhz)   # (m,)
    g = answer_guard(bundle, p, c, response, period, kp=kp0, kd=kd0, derivative_filter_hz=f0)   # one answer
    g["scale"], g["belief_classes"]
"""

from __future__ import annotations

import numpy as np

from uavsim.ident.bundle import ModelBundle
from uavsim.ident.cycle import phase_lost
from uavsim.ident.family import SECOND_SPREAD_LIMITS, family_applies, unsteady_spread
from uavsim.ident.lagfamily import LAG_GUARD_LOOPS, lag_family_scale

__all__ = ["DEFAULT_GUARD", "GUARD_PHASE_DEG", "GUARD_RATIO", "GUARD_SCALES", "GUARD_BELIEFS", "GUARD_BELIEF_MIN",
           "GUARD_BELIEF_PHASE_DEG", "GUARD_SECOND_POINT_SPREAD", "default_guard", "measured_no_phase", "guard_scale",
           "belief_guard_scale", "answer_guard"]

#: the loops whose identification applies the guard unless told otherwise (module docstring)
DEFAULT_GUARD: dict[str, bool] = {"altitude": True, "attitude": True, "lateral": False}

#: extra phase lag at the measured frequency the answer must tolerate, degrees
GUARD_PHASE_DEG = 5.0
#: a factor holds the perturbed model when its ISE is within this ratio of the best factor's
GUARD_RATIO = 2.0
#: factors of ``kp`` and ``kd`` tried, largest first (1: the answer unchanged)
GUARD_SCALES = (1.0, 0.97, 0.94, 0.91, 0.88, 0.85, 0.82, 0.79, 0.76, 0.73, 0.7, 0.65, 0.6, 0.55, 0.5)
#: the belief's most likely classes besides the answer's whose fitted models the answer must also hold
GUARD_BELIEFS = 4
#: ... those of them with at least this softmax
GUARD_BELIEF_MIN = 0.05
#: extra phase lag those models are taken with, degrees, per loop (a loop not named: no belief check;
#: the lateral ``stable`` decision closes its PDs on the belief's models itself)
#: attitude 6.25: with the point averaged over up to 12 cycles (``uavsim.ident.cycle.IDENT_RESPONSE_CYCLES``)
#: the 7.5 chosen over 4 backed off well-measured answers too far (development seeds 11-20, runs of 13 cycles:
#: p95 1.102 -> 1.094, max 2.15 -> 2.03; 5.0: p95 1.096, max 2.56; docs/results/identification.md)
GUARD_BELIEF_PHASE_DEG: dict[str, float] = {"altitude": 5.0, "attitude": 6.25}
#: a first point whose spread is beyond this many times the family's steadiness limits
#: (``uavsim.ident.family.unsteady_spread``) measured no phase: with a second run whose cycle is steady,
#: the one-point guard closes the answer's PD on models fitted to that run's point instead. Development seeds
#: 11-20 (altitude, with the second run's network; 21 of 3,000 points are that loose): unstable answers
#: 3 -> 1, pooled p95 1.0755 -> 1.0753; 16 and 25 gave 1 unstable at p95 1.0790 and 1.0766, and every
#: unsteady point (8 times) 1 at 1.0870 (docs/results/identification.md). Attitude: no point so loose
#: passes its scatter refusal
GUARD_SECOND_POINT_SPREAD = 40.0


def default_guard(loop: str, guard: bool | None) -> bool:
    """``guard`` where given, else the loop's ``DEFAULT_GUARD``."""
    return DEFAULT_GUARD.get(loop, False) if guard is None else bool(guard)


def measured_no_phase(bundle: ModelBundle, f) -> bool:
    """Whether the network's run's point (``f``, a ``CycleFeatures``) measured no phase of the process: its
    cycles' spread beyond ``GUARD_SECOND_POINT_SPREAD`` times the steadiness limits
    (``uavsim.ident.family.unsteady_spread``), or a lag beyond the relay's phase at the bundle's ``beta``
    over ``uavsim.ident.cycle.PHASE_LAG_MAX_DEG`` (``phase_lost``)."""
    return unsteady_spread(f) >= GUARD_SECOND_POINT_SPREAD or phase_lost(f.response, f.response_period,
                                                                          bundle.rule.beta, bundle.input_rate_hz)


def guard_scale(bundle: ModelBundle, cls, response, response_period, *, kp, kd, derivative_filter_hz,
                phase_deg: float | np.ndarray = GUARD_PHASE_DEG, ratio: float = GUARD_RATIO,
                scales=GUARD_SCALES, model: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """The factor of each answer's ``kp`` and ``kd`` (module docstring), (m,) float64 in ``scales``.

    Parameters
    ----------
    cls : (m,) int
        Classes answered.
    response, response_period : (m,) complex, (m,) float
        Each cycle's fundamental response and its period, s (``CycleFeatures``).
    kp, kd, derivative_filter_hz : (m,) float
        The answers' PDs (``table_gains`` of ``cls`` over the fitted gain), filter in Hz.
    phase_deg, ratio, scales
        The margin (a scalar, or one per answer), the ISE ratio a factor must keep, the factors
        (largest first).
    model : dict or None
        The answers' fitted models where the caller has them (``fitted_model`` of ``cls``,
        e.g. with the flight's attitude loop); None: fitted here with the bundle's.
    """
    from uavsim.ident.gains import fitted_model, model_loop_params
    from uavsim.lumped.sampled import lift, sampled_ise

    cls = np.atleast_1d(np.asarray(cls, dtype=np.int64))
    resp = np.atleast_1d(np.asarray(response, dtype=np.complex128))
    per = np.atleast_1d(np.asarray(response_period, dtype=np.float64))
    kp, kd, fhz = (np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in (kp, kd, derivative_filter_hz))
    sc = np.asarray(scales, dtype=np.float64)
    out = np.ones(cls.size)
    if model is None:
        model = fitted_model(bundle, cls, resp, per)
    pk = model_loop_params(bundle, model)
    pk["tau"] = pk["tau"] + np.radians(phase_deg) * per / (2.0 * np.pi)
    ok = (np.isfinite(pk["K"]) & (pk["K"] > 0) & np.isfinite(pk["tau"]) & np.isfinite(kp) & (kp > 0)
          & np.isfinite(kd) & np.isfinite(fhz))
    idx = np.flatnonzero(ok)
    if not idx.size:
        return out
    with np.errstate(all="ignore"):
        proc = lift(bundle.loop, bundle.rate_hz, **{k: (v[idx] if isinstance(v, np.ndarray) else v)
                                                    for k, v in pk.items()})
        rep = np.repeat(np.arange(idx.size), sc.size)
        s = np.tile(sc, idx.size)
        Q = sampled_ise(proc.take(rep), s * kp[idx][rep], s * kd[idx][rep], 2.0 * np.pi * fhz[idx][rep])
    Q = np.where(np.isfinite(Q) & (Q > 0), Q, np.inf).reshape(idx.size, sc.size)
    best = Q.min(axis=1, keepdims=True)
    holds = np.isfinite(best) & (Q <= ratio * best)
    # the largest factor that holds; none (no factor keeps the perturbed loop stable): the answer as it was
    out[idx] = np.where(holds.any(axis=1), sc[np.argmax(holds, axis=1)], 1.0)
    return out


def _belief_classes(bundle: ModelBundle, p, cls: int, beliefs: int, p_min: float) -> list[int]:
    """The ``beliefs`` most likely classes of ``p`` (n,) other than ``cls`` with at least ``p_min``;
    none for a loop without a ``GUARD_BELIEF_PHASE_DEG``."""
    if bundle.loop not in GUARD_BELIEF_PHASE_DEG or beliefs <= 0:
        return []
    p = np.asarray(p, dtype=np.float64).ravel()
    return [int(j) for j in np.argsort(-p, kind="stable")[: beliefs + 1] if j != cls and p[j] >= p_min][:beliefs]


def _scales_on(bundle: ModelBundle, classes: list[int], phases: list[float], response: complex,
               response_period: float, *, kp: float, kd: float, derivative_filter_hz: float,
               attitude: dict[str, float] | None) -> np.ndarray:
    """``guard_scale`` of one PD on the fitted models of ``classes`` (each with its own extra lag), one batch."""
    from uavsim.ident.gains import fitted_model

    k = len(classes)
    resp, per = np.full(k, complex(response)), np.full(k, float(response_period))
    model = fitted_model(bundle, classes, resp, per, attitude=attitude)
    return guard_scale(bundle, classes, resp, per, kp=np.full(k, float(kp)), kd=np.full(k, float(kd)),
                       derivative_filter_hz=np.full(k, float(derivative_filter_hz)), model=model,
                       phase_deg=np.asarray(phases, dtype=np.float64))


def belief_guard_scale(bundle: ModelBundle, p, cls: int, response: complex, response_period: float, *, kp: float,
                       kd: float, derivative_filter_hz: float, attitude: dict[str, float] | None = None,
                       beliefs: int = GUARD_BELIEFS, p_min: float = GUARD_BELIEF_MIN) -> tuple[float, list[int]]:
    """The factor of one answer's PD that the belief's other likely classes' fitted models hold, and those classes.

    ``guard_scale`` of the answer's PD on the fitted models (``fitted_model`` at the measured point)
    of the ``beliefs`` most likely classes of ``p`` (n,) other than ``cls`` with at least ``p_min``,
    each with ``GUARD_BELIEF_PHASE_DEG`` of the loop more lag (a loop without an entry: factor 1,
    no class); the least of their factors.
    """
    top = _belief_classes(bundle, p, cls, beliefs, p_min)
    if not top:
        return 1.0, []
    s = _scales_on(bundle, top, [GUARD_BELIEF_PHASE_DEG[bundle.loop]] * len(top), response, response_period,
                   kp=kp, kd=kd, derivative_filter_hz=derivative_filter_hz, attitude=attitude)
    return float(s.min()), top


def answer_guard(bundle: ModelBundle, p, cls: int, response: complex, response_period: float, *, kp: float,
                 kd: float, derivative_filter_hz: float, attitude: dict[str, float] | None = None,
                 first=None, second=None, p_network=None) -> dict:
    """The guard of one answer (module docstring): the least of its own model's factor and the belief's; with a
    second relay run, on the loops of ``uavsim.ident.lagfamily.LAG_GUARD_LOOPS``, no less than the lag family's.

    The answer's class and the belief's (``belief_guard_scale``) are fitted and closed in one
    batch. Returns the answer's ``guard`` entry: ``scale``, ``phase_deg``, ``own_scale``,
    ``belief_scale``, ``belief_classes``, ``belief_phase_deg``; with the lag family, ``scale_one_point``
    (the factor without it), ``lag_family`` (``lag_family_scale``'s answer) and ``one_point``: the run whose
    point the one-point factor was closed at (``second`` where the first point measured no phase,
    ``measured_no_phase``). ``first``, ``second``: the two runs' cycles; ``p_network``: the network's
    belief before any weighing by the points (the lag family weighs its members by the points itself).
    """
    at_second = (first is not None and second is not None and measured_no_phase(bundle, first)
                 and family_applies(second.response_spread, second.response_cycles, limits=SECOND_SPREAD_LIMITS))
    if at_second:
        response, response_period = second.response, second.response_period
    top = _belief_classes(bundle, p, cls, GUARD_BELIEFS, GUARD_BELIEF_MIN)
    bp = GUARD_BELIEF_PHASE_DEG.get(bundle.loop)
    s = _scales_on(bundle, [int(cls), *top], [GUARD_PHASE_DEG] + [bp] * len(top), response, response_period,
                   kp=kp, kd=kd, derivative_filter_hz=derivative_filter_hz, attitude=attitude)
    own, bel = float(s[0]), (float(s[1:].min()) if top else 1.0)
    out = {"scale": min(own, bel), "phase_deg": GUARD_PHASE_DEG, "own_scale": own, "belief_scale": bel,
           "belief_classes": top, "belief_phase_deg": bp}
    if second is not None and bundle.loop in LAG_GUARD_LOOPS:  # no further back than the lag family asks
        lag = lag_family_scale(bundle, p if p_network is None else p_network, first, second, kp=kp, kd=kd,
                               derivative_filter_hz=derivative_filter_hz, scales=GUARD_SCALES)
        out.update({"scale_one_point": out["scale"], "scale": max(out["scale"], lag["scale"]), "lag_family": lag,
                    "one_point": "second" if at_second else "first"})
    return out
