"""Class selection: the answer of least expected log J under the network's belief.

The network is trained with a cost-sensitive loss over the table's robust
answers, yet its most likely class is not the answer of least cost: many classes
are near-equivalent for a true class while some (answer, truth) pairs are
unstable. The class answered is the minimum-expected-cost (Bayes) decision, the
cost being log J over the bundle's cost matrix ``J`` (``ModelBundle.cost``: the dataset's, rows class
answered, columns true class) with the network's softmax at the bundle's
temperature as the belief
(``uavsim.learning.decision``: the same decision the trainer picks its best
epoch on). ``decision="argmax"`` (the most likely class) is kept for comparison;
it is also what a bundle exported without ``J`` answers, and what the trainer
exports as the decision where it had the lower mean log J on the validation set
(``ModelBundle.decision``).

``decision="fitted"`` judges the candidates on models of the measured process
rather than on the grid's nominal classes: every class fits the one measured
point (``fitted_model``: its lags with the gain and delay that put it on the
cycle's response), so the belief's ``FITTED_BELIEFS`` most likely classes give
as many plausible off-grid processes, and each of the ``FITTED_CANDIDATES``
classes of least expected cost answers its robust table PD with its own gain
estimate. The class answered has the least belief-weighted
``log(ISE / best ISE)`` over those models (exact sampled ISE at the table's rate,
clipped like ``J``). It needs the cycle's response and costs the beliefs' lifted
loops and candidates x beliefs closed ones (a few ms: off the <= 2 ms table path).

``decision="blend"`` (the inner loops' default, ``DEFAULT_DECISION``) adds to each
candidate's fitted cost ``BLEND_GRID_WEIGHT`` times its grid cost (the Bayes decision's
expected log J): the fitted models know the measured point, the grid's J knows how a
class's PD fares over the whole lag structure of the belief's classes, which one
measured point cannot tell apart. On development seeds 11-16, 300 off-grid processes
each (docs/results/identification.md), it lowered the median J on all twelve loop x seed
sets against Bayes and the p95 on seven of them, with 23 unstable answers against
Bayes's 38 (the fitted decision alone: 39). Cost: the fitted decision's (about 3 ms on
one thread).

``decision="stable"`` (the lateral loops' default, ``DEFAULT_DECISION``) chooses a class and
a factor on its PD by stability first: every class's robust table PD over its own gain
estimate, and that PD times each of ``STABLE_SCALES``, is closed on the fitted models
(``fitted_model``) of the belief's ``FITTED_BELIEFS`` most likely classes, each at the
measured phase and ``STABLE_PHASE_DEG`` more and less lag (its delay moved by that phase
at the measured frequency, not below zero; fits with a delay beyond the grid's box are
left out). The candidates of the largest
belief-weighted fraction of stable models are kept; among them the largest factor, then
the least expected cost of the grid's J (Bayes) wins. The lateral optima are fragile (gain margins 1.03-1.3,
about half the class pairs unstable on each other) and lateral cycles under 10-20 %
noise are often classified far from the process: the Bayes answer is then unstable on
its own fitted model in more than half the unstable cases (development seeds 11-12,
docs/results/identification.md), which a check at the measured point sees. The
factor is applied to the answer (``Decision.scale``). Cost: about
``2 n`` x ``3 FITTED_BELIEFS`` closed loops (tens of ms for 20 classes).

Where the relay's cycles disagree with each other (``response_spread``, the spread of each
cycle's own response: ``uavsim.data.preprocess.CycleFeatures``) by more than
``SPREAD_LIMITS``, the measured point itself is suspect: the lateral answers that stayed
unstable under the stable decision had measured gains 0.1-0.8 of the truth's or phases
15-55 degrees off (development seeds 11-12), with cycle spreads mostly above those limits,
which no model fitted to the point with 5 degrees of error foresees. Such a cycle's models
are moved by its measured phase spread (at least ``STABLE_PHASE_DEG``) and also taken with
their gain raised by its log-gain spread, and the factor may go down to ``SPREAD_SCALES``'s
last (about twice the closed loops, on those cycles only).

    from uavsim.ident.select import choose_class, decide_class
    d = decide_class(bundle, bundle.predictor.activations(x))       # Decision: cls, expected_J, p, decision
    cls = choose_class(bundle, bundle.predictor.activations(x), decision="argmax")     # (m,) int
"""

from __future__ import annotations

import numpy as np

from uavsim.errors import UserError
from uavsim.ident.bundle import ModelBundle
from uavsim.learning.decision import COST_CLIP, DECISIONS, Decision, decide, expected_cost, softmax

__all__ = ["DECISIONS", "IDENT_DECISIONS", "DEFAULT_DECISION", "FITTED_BELIEFS", "FITTED_CANDIDATES",
           "STABLE_PHASE_DEG", "STABLE_SCALES", "SPREAD_LIMITS", "SPREAD_SCALES", "BLEND_GRID_WEIGHT", "Decision",
           "LOOK_COMBINE", "DEFAULT_LOOK_COMBINE", "cycle_activations", "decide_class", "decide_fitted", "decide_blend",
           "decide_stable", "choose_class"]

#: decisions identification answers: the trainer's two, the one over fitted models, stability first,
#: the fitted models' cost plus the grid's
IDENT_DECISIONS = DECISIONS + ("fitted", "stable", "blend")
#: the decision a loop answers when none is asked for (a loop not named: the bundle's, the trainer's choice)
DEFAULT_DECISION = {"lateral": "stable", "altitude": "blend", "attitude": "blend"}
#: most likely classes whose fitted models the ``fitted`` decision judges on
FITTED_BELIEFS = 8
#: classes of least expected cost it chooses among
FITTED_CANDIDATES = 10
#: phase (deg) the ``stable`` decision moves each fitted model by, both ways
STABLE_PHASE_DEG = 5.0
#: factors on ``kp`` and ``kd`` the ``stable`` decision may answer, largest first
STABLE_SCALES = (1.0, 0.9)
#: weight of the grid's expected log J beside the fitted models' expected log ISE ratio (``blend``)
BLEND_GRID_WEIGHT = 1.0
#: a cycle whose response cycles spread by more than (std of log |G|, std of phase in deg) is suspect
SPREAD_LIMITS = (0.4, 15.0)
#: factors the ``stable`` decision may answer on a suspect cycle, largest first
SPREAD_SCALES = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5)
#: how the beliefs of several looks at a run combine (``cycle_activations``)
LOOK_COMBINE = ("logsum", "logmean", "mean")
#: the default: their mean, the one of the three that never added unstable answers on the inner loops'
#: development seeds 11-14 (the product, over-confident, added 10 on attitude: docs/results/identification.md)
DEFAULT_LOOK_COMBINE = "mean"


def cycle_activations(bundle: ModelBundle, f, *, combine: str | None = None) -> np.ndarray:
    """The network's activations (1, n) for an extracted cycle ``f`` (``CycleFeatures``).

    One input (``f.x``): its activations. Several looks (``f.looks``, each response cycle as its own
    input): the looks' beliefs ``p_i = softmax(a_i / T)`` combined by ``combine`` (``LOOK_COMBINE``;
    None: ``DEFAULT_LOOK_COMBINE``) and returned as activations ``T log p`` of that belief, so every
    decision takes it as it takes one input's: ``"logsum"`` the normalized product of the ``p_i``
    (independent looks), ``"logmean"`` their normalized geometric mean (one look's sharpness),
    ``"mean"`` their mean.
    """
    looks = getattr(f, "looks", None)
    if looks is None or len(looks) < 2:
        return bundle.predictor.activations(f.x)
    combine = DEFAULT_LOOK_COMBINE if combine is None else combine
    if combine not in LOOK_COMBINE:
        raise UserError(f"combine must be one of {', '.join(LOOK_COMBINE)}, got {combine!r}")
    T = bundle.temperature
    p = softmax(bundle.predictor.activations(looks), T)
    with np.errstate(divide="ignore"):
        if combine == "mean":
            lp = np.log(p.mean(axis=0))
        else:
            lp = np.log(np.maximum(p, 1e-300)).sum(axis=0) / (p.shape[0] if combine == "logmean" else 1.0)
    return (T * (lp - lp.max()))[None, :]


def decide_class(bundle: ModelBundle, activations: np.ndarray, *, decision: str | None = None,
                 response=None, response_period=None, response_spread=None) -> Decision:
    """The class decision for the network's activations (m, n) or (n,).

    ``decision``: ``"bayes"``, ``"argmax"``, ``"fitted"``, ``"stable"`` or ``"blend"`` (the last three
    need ``response`` and ``response_period``, (m,) each: ``decide_fitted``, ``decide_stable``,
    ``decide_blend``; ``response_spread`` (m, 2), where known, is the stable decision's), or None for the
    loop's ``DEFAULT_DECISION``, else the bundle's (``ModelBundle.decision``). ``expected_J`` is
    that of the class answered (nan without a cost matrix).
    """
    if decision is not None and decision not in IDENT_DECISIONS:
        raise UserError(f"decision must be one of {', '.join(IDENT_DECISIONS)}, got {decision!r}")
    if decision is None and bundle.cost is not None:
        decision = DEFAULT_DECISION.get(bundle.loop)
    if decision in ("fitted", "stable", "blend"):
        if response is None or response_period is None:
            raise UserError(f"the {decision} decision needs the cycle's response and its period")
        if decision == "stable":
            return decide_stable(bundle, activations, response, response_period, spread=response_spread)
        fn = decide_fitted if decision == "fitted" else decide_blend
        return fn(bundle, activations, response, response_period)
    if decision == "bayes" and bundle.cost is None:
        raise UserError(f"{bundle.dir}: exported without the cost matrix J (weights.npz) the Bayes decision "
                        "needs: retrain, or decide by argmax")
    return decide(activations, bundle.cost, decision=decision or bundle.decision, temperature=bundle.temperature,
                  log_J=bundle.log_cost)


def _belief(bundle: ModelBundle, activations, response, response_period, name: str):
    """The softmax (m, n), responses (m,), periods (m,) and expected costs (m, n) a decision over
    fitted models starts from; a one-line error without the cost matrix or with mismatched inputs."""
    if bundle.cost is None:
        raise UserError(f"{bundle.dir}: exported without the cost matrix J (weights.npz) the {name} decision "
                        "needs: retrain, or decide by argmax")
    p = softmax(activations, bundle.temperature)
    resp = np.atleast_1d(np.asarray(response, dtype=np.complex128))
    per = np.atleast_1d(np.asarray(response_period, dtype=np.float64))
    if resp.shape != (p.shape[0],) or per.shape != (p.shape[0],):
        raise UserError(f"{p.shape[0]} inputs, {resp.size} responses and {per.size} periods")
    ec = expected_cost(p, log_J=bundle.log_cost)
    return p, resp, per, ec


def decide_fitted(bundle: ModelBundle, activations: np.ndarray, response, response_period, *,
                  beliefs: int = FITTED_BELIEFS, candidates: int = FITTED_CANDIDATES,
                  grid_weight: float = 0.0) -> Decision:
    """The class of least expected log ISE ratio over the belief's fitted models (module docstring).

    Parameters
    ----------
    activations : (m, n) or (n,)
        The network's activations.
    response, response_period : (m,) complex, (m,) float
        Each cycle's fundamental response and its period, s (``CycleFeatures``).
    beliefs, candidates : int
        Most likely classes judged on, classes of least expected cost chosen among.
    grid_weight : float
        Weight of the grid's expected cost (Bayes's) added to each candidate's (``decide_blend``).

    Returns
    -------
    Decision
        ``decision`` ``"fitted"``; ``expected_J`` the exp of the chosen class's expected log
        ratio to the best candidate on each fitted model (plus ``grid_weight`` times its grid cost).
    """
    cls, score, p, _ = _fitted(bundle, activations, response, response_period, beliefs, candidates, grid_weight,
                               "fitted")
    return Decision(cls=cls, expected_J=np.exp(score), p=p, decision="fitted")


def _fitted(bundle: ModelBundle, activations, response, response_period, beliefs: int, candidates: int,
            grid_weight: float, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``decide_fitted``'s search: the classes (m,), their costs (m,), the softmax and the grid's expected
    log J (m, n) it started from."""
    from uavsim.ident.gains import fitted_model, model_loop_params, table_gains
    from uavsim.lumped.sampled import lift, sampled_ise

    p, resp, per, ec = _belief(bundle, activations, response, response_period, name)
    cls = np.argmin(ec, axis=1)
    score = np.zeros(p.shape[0])
    for m in range(p.shape[0]):
        bel = np.argsort(-p[m])[:beliefs]
        cand = np.unique(np.concatenate([np.argsort(ec[m])[:candidates], [cls[m]]]))
        # one fit for every class involved: a belief's model, a candidate's gain estimate
        both = np.union1d(bel, cand)
        model = fitted_model(bundle, both, np.full(both.size, resp[m]), np.full(both.size, per[m]))
        g = table_gains(bundle, cand, model["K"][np.searchsorted(both, cand)])
        ci, bj = np.repeat(np.arange(cand.size), bel.size), np.tile(np.arange(bel.size), cand.size)
        # the belief's models lifted once, then repeated for every candidate's PD
        pk = {k: (v[np.searchsorted(both, bel)] if isinstance(v, np.ndarray) else v)
              for k, v in model_loop_params(bundle, model).items()}
        ok_m = np.isfinite(pk["K"]) & (pk["K"] > 0)
        ok = ok_m[bj] & np.isfinite(g["kp"][ci]) & (g["kp"][ci] > 0)
        Q = np.full(ci.size, np.inf)
        if ok.any():
            with np.errstate(all="ignore"):
                proc = lift(bundle.loop, bundle.rate_hz,
                            **{k: (v[ok_m] if isinstance(v, np.ndarray) else v) for k, v in pk.items()})
                row = np.cumsum(ok_m) - 1  # a model's row among the lifted ones
                Q[ok] = sampled_ise(proc.take(row[bj[ok]]), g["kp"][ci][ok], g["kd"][ci][ok],
                                    2.0 * np.pi * g["derivative_filter_hz"][ci][ok])
        Q = np.where(np.isfinite(Q) & (Q > 0), Q, np.inf).reshape(cand.size, bel.size)
        best = Q.min(axis=0)
        seen = np.isfinite(best)
        if not (seen.any() and p[m, bel][seen].sum() > 0):
            # no candidate holds any fitted model the belief weighs (all its weight on models none holds,
            # as a belief sure of one class can put it): keep the grid's decision
            score[m] = ec[m, cls[m]]
            continue
        w = p[m, bel][seen] / p[m, bel][seen].sum()
        cost = np.log(np.clip(Q[:, seen] / best[seen], *COST_CLIP)) @ w + grid_weight * ec[m, cand]
        k = int(np.argmin(cost))
        cls[m], score[m] = cand[k], cost[k]
    return cls.astype(np.int64), score, p, ec


def decide_blend(bundle: ModelBundle, activations: np.ndarray, response, response_period, *,
                 grid_weight: float = BLEND_GRID_WEIGHT) -> Decision:
    """The class of least fitted-model cost plus ``grid_weight`` times its grid cost (module docstring).

    ``decide_fitted`` with the grid's expected log J (the Bayes decision's cost) added to each
    candidate's expected log ISE ratio over the belief's fitted models. Parameters as
    ``decide_fitted``'s; ``decision`` ``"blend"``, ``expected_J`` the chosen class's under the
    grid's J (as Bayes's).
    """
    cls, _, p, ec = _fitted(bundle, activations, response, response_period, FITTED_BELIEFS, FITTED_CANDIDATES,
                            grid_weight, "blend")
    return Decision(cls=cls, expected_J=np.exp(ec[np.arange(cls.size), cls]), p=p, decision="blend")


def decide_stable(bundle: ModelBundle, activations: np.ndarray, response, response_period, *,
                  beliefs: int = FITTED_BELIEFS, phase_deg: float = STABLE_PHASE_DEG,
                  scales=STABLE_SCALES, spread=None, spread_limits=SPREAD_LIMITS,
                  spread_scales=SPREAD_SCALES) -> Decision:
    """The class and factor whose PD keeps the most of the belief's fitted models stable (module docstring).

    Parameters
    ----------
    activations, response, response_period
        As ``decide_fitted``'s.
    beliefs : int
        Most likely classes whose fitted models the candidates are closed on.
    phase_deg : float
        Phase lag (deg) each model is also moved by, both ways.
    scales : sequence of float
        Factors on ``kp`` and ``kd`` the answer may take, largest first.
    spread : (m, 2) or None
        Each cycle's ``response_spread`` (std of log |G| and of the phase in rad over its
        response cycles); None: every cycle taken as consistent.
    spread_limits, spread_scales
        Above either limit (log gain, deg) a cycle is suspect: its models are moved by its
        phase spread (at least ``phase_deg``) and also taken at its gain times ``exp`` of its
        log-gain spread, and the factors are ``spread_scales`` (module docstring).

    Returns
    -------
    Decision
        ``decision`` ``"stable"``; ``expected_J`` the chosen class's under the grid's J (as
        Bayes's); ``scale`` the factor answered.
    """
    from uavsim.ident.gains import fitted_model, model_loop_params, table_gains
    from uavsim.lumped.params import RANGES
    from uavsim.lumped.sampled import lift, sampled_ise

    p, resp, per, ec = _belief(bundle, activations, response, response_period, "stable")
    n = p.shape[1]
    sp = np.zeros((p.shape[0], 2)) if spread is None else np.asarray(spread, dtype=np.float64).reshape(p.shape[0], 2)
    suspect = (sp[:, 0] > spread_limits[0]) | (np.degrees(sp[:, 1]) > spread_limits[1])
    cls = np.argmin(ec, axis=1)
    scale = np.ones(p.shape[0])
    allc = np.arange(n)
    tau_max = RANGES[bundle.loop]["tau"][1]
    for m in range(p.shape[0]):
        model = fitted_model(bundle, allc, np.full(n, resp[m]), np.full(n, per[m]))
        g = table_gains(bundle, allc, model["K"])
        bel = np.argsort(-p[m])[:beliefs]
        w = p[m, bel] / p[m, bel].sum()
        # the models: each belief's fit, at the measured phase and moved both ways (a suspect cycle: by
        # its phase spread, and also at its gain raised by its gain spread)
        if suspect[m]:
            ph, gf, sc = max(phase_deg, float(np.degrees(sp[m, 1]))), np.unique(np.exp([0.0, sp[m, 0]])), spread_scales
        else:
            ph, gf, sc = phase_deg, np.ones(1), scales
        sc = np.asarray(sc, dtype=np.float64)
        offsets = np.radians([0.0, -ph, ph])
        nv = offsets.size * gf.size
        mb = np.repeat(bel, nv)
        mo, mg = np.tile(np.repeat(offsets, gf.size), bel.size), np.tile(gf, offsets.size * bel.size)
        pk = {k: (v[mb] if isinstance(v, np.ndarray) else v) for k, v in model_loop_params(bundle, model).items()}
        pk["tau"] = np.maximum(pk["tau"] + mo * per[m] / (2.0 * np.pi), 0.0)
        pk["K"] = pk["K"] * mg
        # a fit with a delay beyond the grid's box is no process the grid covers (and its delay line
        # would make the loop's state, so the cost, large)
        ok_m = (np.isfinite(pk["K"]) & (pk["K"] > 0) & np.isfinite(pk["tau"])
                & (np.asarray(model["tau"])[mb] <= tau_max))
        g_ok = np.isfinite(g["kp"]) & (g["kp"] > 0) & np.isfinite(g["kd"])
        if not (ok_m.any() and g_ok.any()):
            continue  # nothing to close a loop on: the grid's Bayes decision
        im, ic = np.flatnonzero(ok_m), np.flatnonzero(g_ok)
        wm = np.repeat(w, nv)[im]
        with np.errstate(all="ignore"):
            proc = lift(bundle.loop, bundle.rate_hz, **{k: (v[im] if isinstance(v, np.ndarray) else v)
                                                        for k, v in pk.items()})
        A, M = np.repeat(ic, im.size), np.tile(np.arange(im.size), ic.size)
        pairs, kp, kd, wf = proc.take(M), g["kp"][A], g["kd"][A], 2.0 * np.pi * g["derivative_filter_hz"][A]
        best = (-1.0, 0, 1.0)  # (stable weight, class, factor)
        for f in sc:  # largest factor first: a smaller one answers only where it holds more of the models
            with np.errstate(all="ignore"):
                q = sampled_ise(pairs, f * kp, f * kd, wf)
            frac = (np.isfinite(q) & (q > 0)).reshape(ic.size, im.size) @ wm
            top = ic[frac >= frac.max() - 1e-9]
            if frac.max() > best[0] + 1e-9:
                best = (float(frac.max()), int(top[np.argmin(ec[m, top])]), float(f))
            if best[0] >= wm.sum() - 1e-9:  # every model held: no smaller factor can do better
                break
        cls[m], scale[m] = best[1], best[2]
    return Decision(cls=cls.astype(np.int64), expected_J=np.exp(ec[np.arange(p.shape[0]), cls]), p=p,
                          decision="stable", scale=scale)


def choose_class(bundle: ModelBundle, activations: np.ndarray, *, decision: str | None = None) -> np.ndarray:
    """The class of each input, (m,) int64 (``decide_class``)."""
    return decide_class(bundle, activations, decision=decision).cls
