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

    from uavsim.ident.guard import guard_scale
    s = guard_scale(bundle, cls, response, response_period, kp=kp, kd=kd, derivative_filter_hz=fhz)   # (m,)
"""

from __future__ import annotations

import numpy as np

from uavsim.ident.bundle import ModelBundle

__all__ = ["DEFAULT_GUARD", "GUARD_PHASE_DEG", "GUARD_RATIO", "GUARD_SCALES", "default_guard", "guard_scale"]

#: the loops whose identification applies the guard unless told otherwise (module docstring)
DEFAULT_GUARD: dict[str, bool] = {"altitude": True, "attitude": True, "lateral": False}

#: extra phase lag at the measured frequency the answer must tolerate, degrees
GUARD_PHASE_DEG = 5.0
#: a factor holds the perturbed model when its ISE is within this ratio of the best factor's
GUARD_RATIO = 2.0
#: factors of ``kp`` and ``kd`` tried, largest first (1: the answer unchanged)
GUARD_SCALES = (1.0, 0.97, 0.94, 0.91, 0.88, 0.85, 0.82, 0.79, 0.76, 0.73, 0.7, 0.65, 0.6, 0.55, 0.5)


def default_guard(loop: str, guard: bool | None) -> bool:
    """``guard`` where given, else the loop's ``DEFAULT_GUARD``."""
    return DEFAULT_GUARD.get(loop, False) if guard is None else bool(guard)


def guard_scale(bundle: ModelBundle, cls, response, response_period, *, kp, kd, derivative_filter_hz,
                phase_deg: float = GUARD_PHASE_DEG, ratio: float = GUARD_RATIO,
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
        The margin, the ISE ratio a factor must keep, the factors (largest first).
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
