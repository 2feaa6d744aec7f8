"""Refit an identified base model's continuous parameters on every run of the session.

Identification (:func:`uavsim.gap.iterate.identify_base`) reads the model off
one relay cycle: the network's class gives ``T_prop`` and ``T1`` on a grid,
the fit puts ``K`` and ``tau`` on the cycle's amplitude and phase. One cycle
cannot split the loop's lag between ``T_prop`` and ``tau``, and the class grid
is coarse, so the model flies the session's other runs (the second relay, the
steps) worse than the vehicle's own lumped equivalent does: a clean session
keeps a gap that hides the effects the search looks for.

:func:`refit_base` moves ``log K``, ``log T_prop``, ``log T1`` and ``log tau``
by a bounded, batched pattern search on the gap the workflow itself measures
(:class:`uavsim.gap.workflow.GapEvaluator`: the features of every run, the noise
scales of the starting model's seed spread, fixed during the search). Each
iteration flies, in one MuJoCo batch, the current point, its moves along each
parameter and along the two pairs one cycle cannot tell apart (``T_prop``
against ``tau``: the same phase at the cycle; ``K`` with ``T1``: the same
high-frequency gain), each with :data:`SEEDS` noise seeds. A move is taken when
it beats the current point of the same batch; otherwise the steps halve. The
refit is kept only when, flown again with fresh seeds, it beats the start.

One relay cycle also fits every class of the network (each class's lags with its own gain and
delay on the cycle's point), and where the process lies outside the grid's box (a long added
delay) the network's class can be far from the lumped equivalent, beyond the search's reach
(:data:`SPAN`). So the search starts from the best of ``starts`` when one is given: every class
fitted to the identified cycle (:func:`uavsim.gap.iterate.class_starts`), flown in one batch
with the identified model (:data:`SCREEN_SEEDS` noise seeds each) and scored on the same noise
scales; the search then moves around that start, and its result is still kept only when it
beats the identified model.

``ridge`` screens the start with ``K`` and ``T1`` multiplied together (the same gain at the cycle,
which one cycle cannot place along that line) before the search; off by default (:data:`RIDGE`).

A refit also takes in what a linear model can: a delay, a lag, a low-pass or
a gain moves ``tau`` or ``K``. :class:`RefitResult` keeps the moves, and
:func:`uavsim.gap.iterate.absorbed_by` reads them.

    fit = refit_base(session, model, seed=0, log=print)
    fit.model, fit.gap_before, fit.gap_after, fit.moved
    # from the network's best-flying class (ident: identify's answer, uavsim.gap.iterate.identify_base)
    fit = refit_base(session, model, starts=class_starts(ident, model))
    fit.screened["start"], fit.screened["gap"]
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from uavsim.formats.session import ModelSpec, Session
from uavsim.gap.simulate import Episode
from uavsim.gap.workflow import GapEvaluator, base_effects

__all__ = ["PARAMS", "RefitResult", "refit_base"]

#: the model's parameters the refit moves (each in its log)
PARAMS = ("K", "T_prop", "T1", "tau")
#: first step of each parameter, in its log (about x1.35 for K, x1.65 for the time constants, x2 for tau)
STEPS = {"K": 0.3, "T_prop": 0.5, "T1": 0.5, "tau": 0.7}
#: the search stops when every step is below this (a 4% move)
MIN_STEP = 0.04
#: most iterations (one batch each)
ITERATIONS = 8
#: noise seeds per point and iteration
SEEDS = 2
#: fresh seeds for the final comparison of the start and the refit
VERIFY_SEEDS = 3
#: the refit moves each parameter no further than this factor from its start; ``tau`` furthest: a
#: lag or low-pass the identified class lacks lands in it, and on 32 development testbed sessions
#: the search had stopped at x4 on it (clean gaps there 2.6-5.3 -> 2.2-4.8 at x16; answers right
#: 21 -> 23, docs/results/gap-workflow.md)
SPAN = {"K": 4.0, "T_prop": 4.0, "T1": 4.0, "tau": 16.0}
#: noise seeds per screened start (:func:`refit_base`'s ``starts``)
SCREEN_SEEDS = 1
#: factors along the ``K``-``T1`` ridge (both by the same factor: the same high-frequency gain) flown
#: in one batch before the search, which starts from the best; ``()``: none. Off by default: on 24
#: development testbed sessions, (0.5, 0.7, 1.4, 2.0, 2.8) answered 17 right against 16 without it,
#: three gained and two lost (docs/results/gap-workflow.md), and the naming floors were set without it
RIDGE: tuple[float, ...] = ()
#: smallest delay, s (the log needs one; below a control period it is not seen)
TAU_FLOOR = 0.0005


@dataclass
class RefitResult:
    """A base model refitted on the session's runs.

    Attributes
    ----------
    model : ModelSpec
        The refitted model (the start when the refit did not beat it).
    start : ModelSpec
        The model the refit started from.
    gap_before, gap_after : float
        Gap of the start and of the refit, flown with the same fresh seeds (the
        workflow's features and noise scales).
    moved : dict of str to float
        Per parameter, refit over start (1.0: not moved; ``tau``: the same, with the floor).
    accepted : bool
        Whether the refit beat the start (else ``model`` is the start).
    screened : dict or None
        With ``starts``: the index of the start the search began from (-1: the model itself),
        its screening gap and the model's (the same noise draw), and how many were screened.
    iterations, episodes : int
        Batches flown in the search and episodes in all.
    seconds : float
    """

    model: ModelSpec
    start: ModelSpec
    gap_before: float
    gap_after: float
    moved: dict[str, float]
    accepted: bool
    iterations: int
    episodes: int
    seconds: float
    screened: dict | None = None

    @property
    def gap(self) -> float:
        """Gap of ``model``, the model the refit answers: the refit's when kept, else the start's (fresh seeds)."""
        return float(self.gap_after if self.accepted else self.gap_before)

    def to_json(self) -> dict:
        return {
            "model": dataclasses.asdict(self.model),
            "start": dataclasses.asdict(self.start),
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "moved": self.moved,
            "accepted": self.accepted,
            "iterations": self.iterations,
            "episodes": self.episodes,
            "seconds": self.seconds,
            "screened": self.screened,
        }


def _to_x(model: ModelSpec) -> np.ndarray:
    v = {k: float(getattr(model, k)) for k in PARAMS}
    v["tau"] = max(v["tau"], TAU_FLOOR)
    v["K"] = abs(v["K"])
    return np.log(np.array([v[k] for k in PARAMS]))


def _to_model(start: ModelSpec, x: np.ndarray) -> ModelSpec:
    v = dict(zip(PARAMS, np.exp(x).tolist(), strict=True))
    v["K"] = math.copysign(v["K"], float(start.K))
    return dataclasses.replace(start, **v)


def _directions() -> np.ndarray:
    """Unit moves, one row each (in units of each parameter's step): each axis both ways, and the pairs."""
    i = {k: j for j, k in enumerate(PARAMS)}
    rows = []
    for k in PARAMS:
        for s in (1.0, -1.0):
            d = np.zeros(len(PARAMS))
            d[i[k]] = s
            rows.append(d)
    for a, b, sign in (("T_prop", "tau", -1.0), ("K", "T1", 1.0)):
        for s in (1.0, -1.0):
            d = np.zeros(len(PARAMS))
            d[i[a]], d[i[b]] = s, sign * s
            rows.append(d)
    return np.array(rows)


def _gaps(ev: GapEvaluator, points: list[ModelSpec], seeds: int) -> np.ndarray:
    """Mean gap over ``seeds`` noise draws of each model in ``points``, all flown in one batch."""
    plans = [Episode(i, seed=s, model=m) for m in points for s in range(seeds) for i in range(ev.R)]
    g = [ev.gap(ev.features(runs)) for runs in ev.fly(plans)]
    return np.array(g).reshape(len(points), seeds).mean(axis=1)


def _screen(ev: GapEvaluator, points: list[ModelSpec], seeds: int) -> np.ndarray:
    """:func:`_gaps` of ``points`` without using up the evaluator's noise draws.

    The search then draws the noise it would have drawn without the screen: where a screen keeps
    the start, the refit is the one it was.
    """
    calls = ev.calls
    g = _gaps(ev, points, seeds)
    ev.calls = calls
    return g


def refit_base(
    session: Session,
    model: ModelSpec,
    *,
    seed: int = 0,
    nthread: int = 0,
    dt: float = 0.001,
    iterations: int = ITERATIONS,
    starts: list[ModelSpec] | None = None,
    ridge: tuple[float, ...] | None = None,
    log=None,
) -> RefitResult:
    """Refit ``model``'s ``K``, ``T_prop``, ``T1``, ``tau`` on every run of ``session`` (pattern search on the gap).

    Parameters
    ----------
    session : Session
        The runs to fit (each must be analysable: :func:`uavsim.gap.iterate.live_runs`);
        its ``[[effects]]`` are flown on every point.
    model : ModelSpec
        The starting point (an identified base model); its noise std is kept.
    seed : int
        Seed of the simulated noise (same seed, same refit).
    nthread, dt :
        As :func:`uavsim.gap.workflow.run_gap`.
    iterations : int
        Most batches of the search.
    starts : list of ModelSpec, optional
        Other starting points (their ``K``, ``T_prop``, ``T1``, ``tau``): the search begins from
        the one of least gap, ``model`` included (module docstring).
    ridge : tuple of float, optional
        Factors on ``K`` and ``T1`` together screened before the search (default :data:`RIDGE`).
    log : callable(str), optional

    Returns
    -------
    RefitResult
    """
    t0 = time.perf_counter()
    log = log or (lambda msg: None)
    ev = GapEvaluator(session, model, base_effects(session), seed, nthread, dt)
    R = ev.R
    # the noise scales and the sensor's smoothing, from the start's own seed spread, fixed for the search
    first = ev.sims([("none", 0.0)], seeds=3)
    fb = [ev.features(s) for s in first]
    if any(f is None for f in fb[0]):  # the start cannot fly a run: nothing to refit from (the search says so)
        log("refit not run: the identified model cannot fly every run")
        return RefitResult(model=model, start=model, gap_before=math.inf, gap_after=math.inf,
                           moved=dict.fromkeys(PARAMS, 1.0), accepted=False, iterations=0, episodes=3 * R,
                           seconds=time.perf_counter() - t0)  # fmt: skip
    ev.calibrate(fb)
    x0 = _to_x(model)
    episodes = 3 * R
    screened = None
    xs = x0
    if starts:
        pts = [model] + [dataclasses.replace(model, K=s.K, T_prop=s.T_prop, T1=s.T1, tau=s.tau) for s in starts]
        g = _screen(ev, pts, SCREEN_SEEDS)
        episodes += len(pts) * SCREEN_SEEDS * R
        j = int(np.argmin(g))
        screened = {"start": j - 1, "gap": float(g[j]), "model_gap": float(g[0]), "n": len(starts)}
        if j > 0:
            xs = _to_x(pts[j])
            log(f"refit starts from screened start {j - 1} of {len(starts)}: gap {g[0]:.3f} -> {g[j]:.3f} "
                f"(T_prop {pts[j].T_prop:.4g} s, T1 {pts[j].T1:.4g} s, tau {pts[j].tau * 1e3:.1f} ms)")
    ridge = RIDGE if ridge is None else ridge
    if any(f <= 0 for f in ridge):
        raise ValueError(f"ridge factors must be > 0, got {ridge}")
    if ridge:
        d = np.zeros(len(PARAMS))
        d[PARAMS.index("K")] = d[PARAMS.index("T1")] = 1.0
        xr = [xs] + [xs + math.log(f) * d for f in ridge]
        g = _screen(ev, [_to_model(model, x) for x in xr], SEEDS)
        episodes += len(xr) * SEEDS * R
        j = int(np.argmin(g))
        if j > 0:
            xs = xr[j]
            log(f"refit starts on the K-T1 ridge at x{ridge[j - 1]:g}: gap {g[0]:.3f} -> {g[j]:.3f}")
    span = np.log([SPAN[k] for k in PARAMS])
    lo, hi = xs - span, xs + span
    lo[PARAMS.index("tau")] = min(lo[PARAMS.index("tau")], math.log(TAU_FLOOR))
    steps = np.array([STEPS[k] for k in PARAMS])
    dirs = _directions()
    x = xs.copy()
    it = 0
    for it in range(1, iterations + 1):  # noqa: B007 (the count is reported)
        cand = np.clip(x + dirs * steps, lo, hi)
        pts = [_to_model(model, x)] + [_to_model(model, c) for c in cand]
        g = _gaps(ev, pts, SEEDS)
        episodes += len(pts) * SEEDS * R
        j = int(np.argmin(g[1:]))
        if g[1 + j] < g[0]:
            x = cand[j]
            log(f"refit {it}: gap {g[0]:.3f} -> {g[1 + j]:.3f}, "
                + ", ".join(f"{k} {v:.4g}" for k, v in zip(PARAMS, np.exp(x), strict=True)))  # fmt: skip
        else:
            steps = steps / 2
            if np.all(steps < MIN_STEP):
                break
    # the start and the refit with the same fresh seeds: keep the refit only when it is better
    fit = _to_model(model, x)
    moved = dict(zip(PARAMS, np.exp(x - x0).tolist(), strict=True))
    if np.allclose(x, x0):
        g0 = g1 = float(np.mean([ev.gap(f) for f in fb]))
    else:
        g0, g1 = _gaps(ev, [model, fit], VERIFY_SEEDS).tolist()
        episodes += 2 * VERIFY_SEEDS * R
    accepted = bool(g1 < g0)
    res = RefitResult(model=fit if accepted else model, start=model, gap_before=float(g0), gap_after=float(g1),
                      moved=moved if accepted else dict.fromkeys(PARAMS, 1.0), accepted=accepted,
                      iterations=it, episodes=episodes, seconds=time.perf_counter() - t0,
                      screened=screened)  # fmt: skip
    log(f"refit on {R} runs: gap {g0:.3f} -> {g1:.3f} ({'kept' if accepted else 'not kept'}; "
        + ", ".join(f"{k} x{v:.3g}" for k, v in moved.items()) + f"; {it} batches, {res.seconds:.1f} s)")
    return res
