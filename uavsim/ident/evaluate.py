"""Off-grid evaluation of identification against each process's optimum (``uavsim evaluate``).

Random processes (seeded, log-uniform in the loop's box, ``K`` log-uniform)
are simulated in MuJoCo through the datasets' episode path
(``uavsim.data.generate.simulate_features``) with the network's dataset recipe
for the relay, randomization and preprocessing, and every noise kind at levels
``LEVELS`` of the cycle amplitude. The relay's settings are a user's: a hover
segment of the episode's own noise gives the first run's ``tau_obs`` and ``a_n``
(``uavsim.noise.estimate.recommend``), refined from the runs before
(``refine_batch``); the relay is never handed the true period or amplitude. The
recipe must say ``settings = "recommended"``. The relays start at the recipe's drawn
bias (a hover-command error) and trim it where the recipe says (``[test] bias_trim``,
``--bias-trim``), as a user's relay does.

Each episode is identified exactly as a session is (``extract_cycle`` then
``identify_cycle`` on its raw traces), from the start of its final relay run: the
refinement runs before it flew other settings, and a session holds each run on its
own. The figure is

    J = ISE(answer) / ISE(optimal PD of the true process at the control rate)

both exact sampled step ISEs at the table's rate (``uavsim.lumped.sampled``;
optimum from ``uavsim.tuning.optimal.optimal_gains``, the answer with its own
derivative filter). A refusal (no usable oscillation, a period or phase no
class gives, an attitude PD the models of both runs reject at every back-off) is
a failure: ``J = inf`` in the median and p95, counted apart; an unstable answer
is ``inf`` and counted. ``max`` is over the answers given.

In the same run, on the same episodes (controls and alternatives):

* ``table_best_class``: the table's robust answer of the class of least J
  for each process, with the gain estimate for that class (an oracle classifier);
* ``table_nearest_class``: the same for the class nearest in the log box;
* ``rule_on_truth``: the grid's rule applied to the true process (its 10 Omega filter);
* ``answer_x0.85``: the answer's ``kp`` and ``kd`` times 0.85 (a plain detuning,
  which a metric that cannot tell must not pass);
* ``answer_guarded``: the answer's table PD backed off by the phase-margin guard
  (``uavsim.ident.guard``: a factor in 0.5-1 only where the answer's fitted model with
  5 degrees more lag needs it), to be judged against that detuning;
* ``answer_table``: the class's table PD (with the decision's own factor), unguarded: on
  lateral loops what the answer was before the family answer (``uavsim.ident.family``)
  replaced it on steady cycles;
* the class decisions (``uavsim.ident.select``), each scored like the answer (refusals
  are failures): ``answer_bayes`` (least expected J under the network's softmax over
  the bundle's cost matrix, at the bundle's temperature) and ``answer_argmax`` (the most likely class), both with the
  answer's gain estimate; the one identification made equals ``answer``; ``answer_fitted`` and
  ``answer_blend`` (the candidates judged on the belief's fitted models, blend with the grid's
  cost added: ``uavsim.ident.select``);
* alternatives on the network's class: ``table_K_mrft`` (the gain estimated at the
  class's MRFT point, ``K = |G(jw)| / table_gain_at_omega``, instead of fitted at the
  measured frequency), ``table_optimum`` (the class's ISE optimum instead of the
  robust answer), ``fitted_optimum`` (the optimum of the fitted model),
  ``optimum_when_off_grid`` (that optimum only where the fitted delay is off the
  class's: ``optimum="auto"``), ``K_true`` (the true ``K``); and the oracle rows with
  the MRFT-point estimate (``*_K_mrft``).

On every loop (``uavsim.ident.twopoint.SECOND_RUN_LOOPS``) every process also flies a
second relay run at ``SECOND_BETA`` (-0.3; ``second_beta``, ``uavsim evaluate --second-beta``:
another beta, or ``none`` for the paper's one run), with its own settings from the same hover and
the same sensor noise in output units, and the answer weighs its belief by both measured points
(``uavsim.ident.twopoint``), as identification of a session holding such a run does; the
controls are then those of that answer. A lateral process whose first run is refused but whose second
holds a steady cycle is answered from that run alone (``identify_second_point``): its answer counts,
and the class decision's controls (``answer_table`` and the like) count it as refused by them.

Lateral loops: ``n`` processes per attitude class ``a`` (``T2``, outer delay, ``K``
in the lateral box) over that class's attitude loop as the bundle of
``lateral/aNN`` closes it (the attitude table's PD at the control rate). Their
relay runs fly ``RUN_CYCLES`` (13) cycles, and their steady cycles answer the family's
PD (``family``; ``family=False``: the table's).

Attitude relay runs fly ``RUN_CYCLES`` (13) cycles as well, and identification averages their
point over up to 12 (``uavsim.ident.cycle.IDENT_RESPONSE_CYCLES``); altitude runs fly the
recipe's 5.

    from uavsim.ident.evaluate import EvalSpec, evaluate
    res = evaluate(EvalSpec(loop="altitude", n=300, seed=2), models="training/runs", recipe="datasets/altitude.toml")
    res["rows"]                    # per noise level and all: one summary per answer / control
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from uavsim.control.relay import check_bias_trim, relay_command
from uavsim.data.preprocess import process_response
from uavsim.errors import NoOscillation, UserError
from uavsim.ident.bundle import ModelBundle, load_bundle, resolve_model_dir
from uavsim.ident.consistent import consistent_activations
from uavsim.ident.cycle import extract_cycle, phase_lead, response_cycles
from uavsim.ident.family import default_family
from uavsim.ident.gains import fitted_model, gain_estimate, model_optimum, table_gains
from uavsim.ident.guard import answer_guard
from uavsim.ident.secondnet import load_second_bundle, second_reading
from uavsim.ident.select import cycle_activations, decide_blend, decide_fitted
from uavsim.ident.session import identify_cycle, identify_second_point, second_cycle
from uavsim.ident.twopoint import SECOND_BETA, SECOND_RUN_AUTO, SECOND_RUN_LOOPS
from uavsim.learning.decision import decide, softmax
from uavsim.lumped.params import BOX_KEYS, RANGES, LumpedParams, box_coordinates, nearest_centre

__all__ = ["LEVELS", "DETUNE", "GOALS", "RUN_CYCLES", "EvalSpec", "second_beta_for", "draw_processes", "noise_plan",
           "evaluate", "summarize", "markdown"]

#: noise levels (noise amplitude / cycle amplitude); level 0 is noise-free
LEVELS = (0.0, 0.05, 0.10, 0.15, 0.20)
#: the detuning control: the answer's gains times this
DETUNE = 0.85
#: the belief's most likely classes (with their softmax) recorded per episode: the network's, kept to the
#: classes the measured point allows (``uavsim.ident.consistent``), as the decisions see it
TOP_RECORDED = 8
#: the goals: inner loops (median, p95, max of J, unstable, refused fraction), lateral (p95, unstable)
GOALS = {"inner": {"median": 1.03, "p95": 1.10, "max": 1.5, "unstable": 0, "refused_fraction": 0.02},
         "lateral": {"p95": 1.20, "unstable": 0}}
_FAIL = np.inf
#: the second run's simulation seeds: this plus the first run's
SECOND_SEED_OFFSET = 10_000_000
#: relay cycles a loop's identification run flies where not told (``EvalSpec.cycles``; a loop not named: the
#: recipe's ``[episodes] cycles``, the training sets' 5): a lateral run of 13 measures its point over up to 12
#: steady cycles (development seeds 11-12: refusals 9 and 17 of 480 -> 3 and 14, p95 1.694 / 1.881 -> 1.355 / 1.559);
#: an attitude run of 13 too (development seeds 11-20, its point over 12 cycles: p95 1.118 -> 1.102 before the
#: belief guard's margin was re-set)
RUN_CYCLES: dict[str, int] = {"lateral": 13, "attitude": 13}


@dataclass(frozen=True)
class EvalSpec:
    """One evaluation run.

    Attributes
    ----------
    loop : ``altitude``, ``attitude`` or ``lateral``
    n : processes (lateral: per attitude class)
    seed : seed of the draw and of the simulation (recorded)
    K : gain range, log-uniform
    levels : noise levels, each process at one (balanced), kinds cycling over the recipe's
    chunk : episodes per MuJoCo batch (sorted by expected period)
    att_classes : lateral: the attitude classes (default: every one with a network)
    optimum : identification's ``optimum`` mode (``uavsim.ident.session``)
    decision : identification's class decision (``uavsim.ident.select``; None: the bundle's)
    guard : identification backs its PD off by the phase-margin guard (``uavsim.ident.guard``); None:
        identification's default (``DEFAULT_GUARD``)
    inputs : what the network sees of each run (``extract_cycle``'s ``inputs``; None: the loop's ``IDENT_INPUTS``)
    combine : how several looks' beliefs combine (``uavsim.ident.select.cycle_activations``; None: the default)
    second_beta : a second relay run at this ``beta`` on every process (its own settings from the hover,
        the same sensor noise in output units), whose measured point weighs the belief
        (``uavsim.ident.twopoint``); None: one run, the paper's method; ``"auto"`` (default):
        ``SECOND_BETA`` on the loops of ``SECOND_RUN_LOOPS`` (what identification of a session holding
        that run does), one run elsewhere (``second_beta_for``)
    bias_trim : the relays' bias trim (``uavsim.formats.session.RELAY_BIAS_TRIMS``); None: the recipe's
    family : lateral: steady cycles answer the PD of the measured point's model family
        (``uavsim.ident.family``); None: identification's default (on); the row ``answer_table``
        scores the table's answer beside it
    cycles : relay cycles each run flies (the first is the transient); None: the loop's ``RUN_CYCLES``,
        else the recipe's ``[episodes] cycles`` (the training sets' length). The run's length is a
        user's choice: its point's standard error falls with the root of the steady cycles it
        averages (``uavsim.ident.cycle.response_cycles``)
    second_network : with a second run, the network of its ``beta`` beside the model folder reads it where
        the model root holds one (``uavsim.ident.secondnet``: ``altitude-second``), as identification of a
        session does; False: the point alone
    """

    loop: str = "altitude"
    n: int = 300
    seed: int = 2
    K: tuple[float, float] = (0.5, 2.0)
    levels: tuple[float, ...] = LEVELS
    chunk: int = 60
    att_classes: tuple[int, ...] | None = None
    optimum: str = "never"
    decision: str | None = None
    guard: bool | None = None
    inputs: str | None = None
    combine: str | None = None
    second_beta: float | str | None = SECOND_RUN_AUTO
    bias_trim: str | None = None
    family: bool | None = None
    cycles: int | None = None
    second_network: bool = True


def second_beta_for(loop: str, second_beta: float | str | None) -> float | None:
    """The second run's ``beta`` an evaluation flies (``EvalSpec.second_beta``), None for one run."""
    if second_beta == SECOND_RUN_AUTO:
        return SECOND_BETA if loop in SECOND_RUN_LOOPS else None
    if second_beta is None:
        return None
    if isinstance(second_beta, str) or not -1 < float(second_beta) < 1:
        raise UserError(f"second_beta must be \"auto\", None or a beta in (-1, 1), got {second_beta!r}")
    return float(second_beta)


def draw_processes(loop: str, n: int, rng: np.random.Generator, *, K: tuple[float, float],
                   attitude: dict[str, float] | None = None) -> list[LumpedParams]:
    """``n`` processes log-uniform in the box of ``loop`` (lateral: over ``attitude``), ``K`` log-uniform."""
    fam = "lateral" if loop == "lateral" else loop
    box = RANGES[fam]

    def lu(lo: float, hi: float) -> np.ndarray:
        return np.exp(rng.uniform(math.log(lo), math.log(hi), n))

    draw = {k: lu(*v) for k, v in box.items()}
    Ks = lu(*K)
    if fam == "lateral":
        a = attitude or {}
        return [LumpedParams("lateral_x", float(Ks[i]), a["T_prop"], a["T1"], float(draw["tau"][i]),
                             T2=float(draw["T2"][i]), tau_in=a["tau_in"], att_kp=a["att_kp"], att_kd=a["att_kd"],
                             att_filter_hz=a["att_filter_hz"]) for i in range(n)]
    name = "altitude" if fam == "altitude" else "roll"
    return [LumpedParams(name, float(Ks[i]), float(draw["T_prop"][i]), float(draw["T1"][i]), float(draw["tau"][i]))
            for i in range(n)]


def noise_plan(n: int, kinds: tuple[str, ...], levels: tuple[float, ...], rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray]:
    """Each episode's noise kind (index into ``kinds``) and level: levels balanced, kinds cycling.

    Level 0 is the kind ``none`` (or noise at level 0); the other levels cycle over the
    other kinds, so every kind meets every level.
    """
    noisy = [i for i, k in enumerate(kinds) if k != "none"]
    none = kinds.index("none") if "none" in kinds else (noisy[0] if noisy else 0)
    level = np.array([levels[i % len(levels)] for i in range(n)], dtype=np.float64)
    kind = np.full(n, none, dtype=np.int8)
    pos = np.flatnonzero(level > 0)
    if noisy:
        kind[pos] = np.array([noisy[j % len(noisy)] for j in range(pos.size)], dtype=np.int8)
    perm = rng.permutation(n)
    return kind[perm], level[perm]


def _truth(params: list[LumpedParams], att_rate_hz: float | None = None) -> dict[str, np.ndarray]:
    """The processes as arrays; lateral: ``att_rate_hz`` the attitude PD's rate (None: continuous)."""
    keys = ["K", "T_prop", "T1", "tau"]
    if params[0].family == "lateral":
        keys += ["T2", "tau_in", "att_kp", "att_kd"]
    t = {k: np.array([getattr(p, k) for p in params], dtype=np.float64) for k in keys}
    if params[0].family == "lateral":
        t["att_N"] = 2 * math.pi * np.array([p.att_filter_hz for p in params], dtype=np.float64)
        if att_rate_hz is not None:
            t["att_rate_hz"] = np.full(len(params), float(att_rate_hz))
    return t


def _simulate(params: list[LumpedParams], recipe, seed: int, noise: tuple[np.ndarray, np.ndarray], chunk: int,
              log) -> dict[str, Any]:
    """The episodes in chunks of similar expected period; raw traces (ragged: one array per episode)."""
    from uavsim.data.generate import simulate_features
    from uavsim.lumped.frequency import mrft_prediction_batch

    n = len(params)
    fam = params[0].family
    t = _truth(params)
    beta = recipe.test.beta if recipe.test.beta is not None else -0.73
    w, _ = mrft_prediction_batch(fam, beta, 1.0, **{k: v for k, v in t.items()})
    order = np.argsort(-w, kind="stable")  # fastest first: a chunk's episode length follows its slowest
    out = {"y": [None] * n, "u": [None] * n, "bias": np.zeros(n), "diverged": np.zeros(n, bool),
           "tau_obs": np.zeros(n), "a_n": np.zeros(n), "start": np.zeros(n, np.int64)}
    rec = replace(recipe, preprocess=replace(recipe.preprocess, keep_raw=True))
    t0 = time.perf_counter()
    for j, i0 in enumerate(range(0, n, chunk)):
        idx = order[i0 : i0 + chunk]
        _, _, _, _, m = simulate_features([params[i] for i in idx], rec, seed * 1000 + j,
                                          noise=(noise[0][idx], noise[1][idx]))
        for k, i in enumerate(idx):
            out["y"][i] = np.nan_to_num(m["y"][k].astype(np.float64))
            # a trimmed run is read by its relay states at the drawn bias, as a session's is
            out["u"][i] = relay_command(m["u"][k].astype(np.float64), recipe.test.h, m["bias"][k], recipe.test.bias_trim)
        for key in ("bias", "diverged", "tau_obs", "a_n"):
            out[key][idx] = m[key]
        out["start"][idx] = int(round(float(m["run_start_s"]) * recipe.episodes.rate_hz))
        log(f"simulated {min(i0 + chunk, n)}/{n} episodes ({time.perf_counter() - t0:.0f} s)")
    return out


def _simulate_second(params: list[LumpedParams], recipe, seed: int, noise: tuple[np.ndarray, np.ndarray],
                     beta: float, chunk: int, log) -> dict[str, Any]:
    """The same processes' second run at ``beta``: its own settings and draws (seed stream
    ``SECOND_SEED_OFFSET + seed``), the same noise kind and the same noise in output units (the
    level, a fraction of each run's exact cycle amplitude, rescaled from the first run's to this one's)."""
    from uavsim.lumped.simulate import fourier_limit_cycle

    beta1 = recipe.test.beta if recipe.test.beta is not None else -0.73
    h = recipe.test.h
    a1 = np.array([fourier_limit_cycle(p, beta1, h)[1] for p in params])
    a2 = np.array([fourier_limit_cycle(p, beta, h)[1] for p in params])
    level = np.asarray(noise[1], dtype=np.float64) * a1 / a2
    rec = replace(recipe, test=replace(recipe.test, beta=float(beta)))
    log(f"second run at beta {beta:g}")
    return _simulate(params, rec, SECOND_SEED_OFFSET + seed, (noise[0], level), chunk, log)


def _score(fam: str, rate_hz: float, truth: dict[str, np.ndarray], q_opt: np.ndarray, idx: np.ndarray,
           kp, kd, fhz) -> np.ndarray:
    """``J`` of PDs on processes ``idx`` (repeats allowed) against their optima; inf where unstable."""
    from uavsim.lumped.sampled import pd_step_ise

    idx = np.asarray(idx, dtype=np.int64)
    kp, kd, fhz = (np.broadcast_to(np.asarray(v, dtype=np.float64), idx.shape) for v in (kp, kd, fhz))
    q = pd_step_ise(fam, rate_hz, kp, kd, 2 * math.pi * fhz, **{k: v[idx] for k, v in truth.items()})
    return np.where(np.isfinite(q), q / q_opt[idx], _FAIL)


def summarize(J: np.ndarray, refused: np.ndarray | None = None) -> dict[str, Any]:
    """Median, p95 (refusals and unstable answers as failures, ``inf``), max over stable answers, counts."""
    J = np.asarray(J, dtype=np.float64)
    ref = np.zeros(J.shape, bool) if refused is None else np.asarray(refused, bool)
    n = int(J.size)
    if n == 0:
        return {"n": 0}
    full = np.where(ref, np.inf, J)
    stable = full[np.isfinite(full)]

    def p(q: float) -> float:
        # the order statistics on either side: inf where either is a failure (no inf - inf interpolation)
        s = np.sort(full)
        x = q / 100.0 * (n - 1)
        lo, hi = s[int(math.floor(x))], s[int(math.ceil(x))]
        return float(lo + (x - math.floor(x)) * (hi - lo)) if np.isfinite(hi) else float("inf")

    return {"n": n, "refused": int(ref.sum()), "unstable": int(np.sum(~ref & ~np.isfinite(J))),
            "median": p(50), "p95": p(95), "max": float(stable.max()) if stable.size else float("nan")}


def _goal_check(row: dict[str, Any], lateral: bool) -> dict[str, bool]:
    g = GOALS["lateral" if lateral else "inner"]
    out = {k: bool(row.get(k, np.inf) <= v) for k, v in g.items() if k in ("median", "p95", "max", "unstable")}
    if "refused_fraction" in g:
        out["refused_fraction"] = bool(row["refused"] <= g["refused_fraction"] * row["n"])
    return out


def _identify_all(bundle: ModelBundle, sim: dict[str, Any], recipe, optimum: str, decision: str | None,
                  guard: bool | None = None, inputs: str | None = None, combine: str | None = None,
                  sim2: dict[str, Any] | None = None, family: bool | None = None,
                  bundle2: ModelBundle | None = None) -> dict[str, Any]:
    """Identify every episode as a session; the cycles' responses for the controls (also of refused ones).

    ``sim2``: a second run of every episode at another ``beta``; where it holds a cycle, it weighs the
    belief (``identify_cycle``'s ``second``), else the episode is identified from its first run alone.
    ``bundle2``: that run's network (``uavsim.ident.secondnet``), which reads it where it holds a cycle.
    """
    from uavsim.data.preprocess import features

    n = len(sim["y"])
    rate, h = recipe.episodes.rate_hz, recipe.test.h
    res = {"answers": [None] * n, "why": [None] * n, "response": np.full(n, complex("nan")),
           "response_period": np.full(n, np.nan), "ms": np.full(n, np.nan), "lead": np.full(n, np.nan),
           "top": [None] * n, "act": np.full((n, bundle.n_classes), np.nan), "second": np.zeros(n, bool),
           "second_network": np.zeros(n, bool)}
    for i in range(n):
        kw = {"rate_hz": rate, "h": h, "bias": float(sim["bias"][i])}
        y, u = _run(sim, i)
        t0 = time.perf_counter()
        f2 = None
        if sim2 is not None:
            try:
                f2 = second_cycle(*_run(sim2, i), rate_hz=rate, h=h, bias=float(sim2["bias"][i]),
                                  cycles=bundle.cycles, loop=bundle.loop)
            except NoOscillation:
                f2 = None
        reading = None
        if f2 is not None and bundle2 is not None:
            reading = second_reading(bundle2, *_run(sim2, i), rate_hz=rate, h=h, bias=float(sim2["bias"][i]))
        try:
            f = extract_cycle(y, u, bundle=bundle, inputs=inputs, **kw)
            res["second"][i] = f2 is not None
            res["answers"][i] = identify_cycle(f, bundle, optimum=optimum, decision=decision, guard=guard,
                                               combine=combine, second=f2, family=family, second_network=reading)
            res["second_network"][i] = reading is not None
            res["ms"][i] = 1e3 * (time.perf_counter() - t0)
        except NoOscillation as exc:
            a2 = None if f2 is None else identify_second_point(f2, bundle, refused=str(exc), family=family)
            if a2 is not None:  # answered from the second run alone: no class, no controls of one
                res["answers"][i], res["second"][i] = a2, True
                res["ms"][i] = 1e3 * (time.perf_counter() - t0)
            else:
                res["why"][i] = str(exc)
            try:
                f = features(y, u, rate, h, kw["bias"], bundle.input_length, cycles=bundle.cycles,
                             response_cycles=response_cycles(bundle.loop))
            except NoOscillation:
                continue
        res["response"][i], res["response_period"][i] = f.response, f.response_period
        act, _ = consistent_activations(bundle, cycle_activations(bundle, f, combine=combine), f)
        res["act"][i] = act[0]
        p = decide(res["act"][i], decision="argmax", temperature=bundle.temperature).p[0]
        top = np.argsort(-p)[:TOP_RECORDED]
        res["top"][i] = [[int(c), float(p[c])] for c in top]
        res["lead"][i] = phase_lead(f.response, f.response_period, bundle.rule.beta, bundle.input_rate_hz)
    return res


def _run(sim: dict[str, Any], i: int) -> tuple[np.ndarray, np.ndarray]:
    """Episode ``i``'s relay run as a session holds it: from the start of the episode proper (the
    refinement stages before it ran at other settings: a user's earlier runs, not this one's cycles)."""
    s0 = int(sim["start"][i])
    return sim["y"][i][s0:], sim["u"][i][s0:]


def _nearest(bundle: ModelBundle, truth: dict[str, np.ndarray]) -> np.ndarray:
    fam = bundle.loop
    return nearest_centre(box_coordinates(fam, truth), box_coordinates(fam, {k: bundle.column(k) for k in BOX_KEYS[fam]}))


def _variants(bundle: ModelBundle, truth: dict[str, np.ndarray], q_opt: np.ndarray, ids: dict[str, Any],
              rule_gains: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """J per process of the answer and of every control / alternative (module docstring), (n,) each."""
    fam, rate = bundle.loop, bundle.rate_hz
    n = q_opt.size
    nan = lambda: np.full(n, np.nan)  # noqa: E731 - not computed (no cycle to measure)
    J: dict[str, np.ndarray] = {}
    ans = ids["answers"]
    ga = np.flatnonzero([a is not None for a in ans])
    # the answers with a class (not those made from a second run alone): the controls of a class decision
    gi = np.flatnonzero([a is not None and a["class"] is not None for a in ans])
    J["answer"] = np.full(n, _FAIL)
    J[f"answer_x{DETUNE:g}"] = np.full(n, _FAIL)
    J["answer_guarded"] = np.full(n, _FAIL)
    J["answer_table"] = np.full(n, _FAIL)
    if ga.size:
        kp, kd, fhz = (np.array([ans[i]["gains"][k] for i in ga], dtype=np.float64)
                       for k in ("kp", "kd", "derivative_filter_hz"))
        J["answer"][ga] = _score(fam, rate, truth, q_opt, ga, kp, kd, fhz)
        J[f"answer_x{DETUNE:g}"][ga] = _score(fam, rate, truth, q_opt, ga, DETUNE * kp, DETUNE * kd, fhz)
    col = lambda key, sub: np.array([ans[i][key][sub] for i in gi], dtype=np.float64)  # noqa: E731
    if gi.size:
        # the guard on the table's answer (the answers' own factor where identification applied it)
        tkp, tkd, tfhz = (col("gains_table", k) for k in ("kp", "kd", "derivative_filter_hz"))
        if all("guard" in ans[i] for i in gi):
            s_g = np.array([ans[i]["guard"]["scale"] for i in gi])
        else:  # the belief from the first run's activations (a second run's weighing is not kept here)
            pb = softmax(ids["act"][gi], bundle.temperature)
            s_g = np.array([answer_guard(bundle, pb[k], ans[i]["class"], ids["response"][i], ids["response_period"][i],
                                         kp=tkp[k], kd=tkd[k], derivative_filter_hz=tfhz[k])["scale"]
                            for k, i in enumerate(gi)])
        J["answer_guarded"][gi] = _score(fam, rate, truth, q_opt, gi, s_g * tkp, s_g * tkd, tfhz)
        # the table's answer (the decision's own factor on it), where a family answer replaced it
        J["answer_table"][gi] = _score(fam, rate, truth, q_opt, gi, tkp, tkd, tfhz)
    J["rule_on_truth"] = _score(fam, rate, truth, q_opt, np.arange(n), rule_gains["kp"], rule_gains["kd"],
                                rule_gains["derivative_filter_hz"])
    # controls and alternatives need a measured cycle (refused episodes included where one exists)
    meas = np.flatnonzero(np.isfinite(ids["response_period"]))
    G = process_response(ids["response"][meas], ids["response_period"][meas], rate_hz=bundle.input_rate_hz)
    nc = bundle.n_classes
    # every class for every measured episode: the oracle classifier's J-best class
    rep = np.repeat(meas, nc)
    cls = np.tile(np.arange(nc), meas.size)
    near = _nearest(bundle, truth)[meas]
    for name, K_all in (("", fitted_model(bundle, cls, np.repeat(ids["response"][meas], nc),
                                          np.repeat(ids["response_period"][meas], nc))["K"]),
                        ("_K_mrft", gain_estimate(bundle, cls, np.repeat(G, nc)))):
        g_all = table_gains(bundle, cls, K_all)
        Jall = _score(fam, rate, truth, q_opt, rep, g_all["kp"], g_all["kd"], g_all["derivative_filter_hz"])
        Jall = Jall.reshape(meas.size, nc)
        J["table_best_class" + name], J["table_nearest_class" + name] = nan(), nan()
        J["table_best_class" + name][meas] = Jall.min(axis=1)
        J["table_nearest_class" + name][meas] = Jall[np.arange(meas.size), near]
        if not name:  # the class decisions on the identified episodes, with the answer's gain estimate
            row = np.searchsorted(meas, gi)
            if gi.size and not np.array_equal(meas[np.minimum(row, meas.size - 1)], gi):
                raise RuntimeError("an identified episode without its measured cycle")
            for dec in ("bayes", "argmax") if bundle.cost is not None else ("argmax",):
                J["answer_" + dec] = np.full(n, _FAIL)
                if gi.size:
                    c_dec = decide(ids["act"][gi], bundle.cost, decision=dec, temperature=bundle.temperature).cls
                    J["answer_" + dec][gi] = Jall[row, c_dec]
            # the candidates judged on the belief's fitted models (blend: plus the grid's cost)
            for dec, fn in (("fitted", decide_fitted), ("blend", decide_blend)) if bundle.cost is not None else ():
                J["answer_" + dec] = np.full(n, _FAIL)
                if gi.size:
                    if all(ans[i]["decision"]["decision"] == dec for i in gi):
                        # the answers were decided so (--decision DEC): their classes, not a second search
                        c_fit = np.array([ans[i]["class"] for i in gi])
                    else:
                        c_fit = fn(bundle, ids["act"][gi], ids["response"][gi], ids["response_period"][gi]).cls
                    J["answer_" + dec][gi] = Jall[row, c_fit]
    # alternatives on the identified episodes: the network's class with other gain choices
    for k in ("table_K_mrft", "table_optimum", "K_true", "fitted_optimum", "optimum_when_off_grid"):
        J[k] = nan()
    if gi.size:
        c = np.array([ans[i]["class"] for i in gi])
        K_hat = col("table", "K_hat")
        K_mrft = gain_estimate(bundle, c, process_response(ids["response"][gi], ids["response_period"][gi],
                                                           rate_hz=bundle.input_rate_hz))
        for name, g in (("table_K_mrft", table_gains(bundle, c, K_mrft)),
                        ("table_optimum", table_gains(bundle, c, K_hat, robust=False)),
                        ("K_true", table_gains(bundle, c, truth["K"][gi]))):
            J[name][gi] = _score(fam, rate, truth, q_opt, gi, g["kp"], g["kd"], g["derivative_filter_hz"])
        resp = np.array([ids["response"][i] for i in gi])
        rper = np.array([ids["response_period"][i] for i in gi])
        model = fitted_model(bundle, c, resp, rper)
        with np.errstate(all="ignore"):
            opt = model_optimum(bundle, model, start=table_gains(bundle, c, K_hat))
        J["fitted_optimum"][gi] = np.where(np.isfinite(opt.ise), _score(
            fam, rate, truth, q_opt, gi, opt.kp, opt.kd, opt.derivative_filter_hz), _FAIL)
        # optimum="auto": the fitted optimum where the fitted model is off the grid, else the table
        off = np.array([bool(ans[i]["off_grid"]) for i in gi])
        tab = table_gains(bundle, c, K_hat)
        J["optimum_when_off_grid"][gi] = np.where(off, J["fitted_optimum"][gi], _score(
            fam, rate, truth, q_opt, gi, tab["kp"], tab["kd"], tab["derivative_filter_hz"]))
    # a class decision's controls have nothing to say of an answer made without a class: not computed
    no_class = np.setdiff1d(ga, gi)
    for k in J:
        if k.startswith("answer_") and k != f"answer_x{DETUNE:g}":
            J[k][no_class] = np.nan
    return J


def _failed_if_nan(j: np.ndarray) -> np.ndarray:
    """Not computed (nan) as a failure (inf); an unstable answer stays inf (``np.nan_to_num`` would make it finite)."""
    return np.where(np.isnan(j), _FAIL, j)


def _rows(J: dict[str, np.ndarray], refused: np.ndarray, level: np.ndarray, lateral: bool,
          no_class: np.ndarray | None = None) -> dict[str, Any]:
    """Summaries per noise level and over all: answer rows count refusals as failures, and the rows of a class
    decision's controls count the answers made without a class (``no_class``: from a second run alone) as
    refused by them."""
    no_class = np.zeros(refused.shape, bool) if no_class is None else no_class
    out: dict[str, Any] = {}
    groups = [("all", np.ones(level.size, bool))] + [(f"{lv:.0%}", np.isclose(level, lv)) for lv in np.unique(level)]
    for gname, sel in groups:
        rows = {}
        for name, j in J.items():
            answered_only = not name.startswith("answer")
            jj = j[sel]
            if answered_only:  # controls: over the episodes they could be computed on
                rows[name] = summarize(jj[~np.isnan(jj)])
            else:
                ref = refused | no_class if name not in ("answer", f"answer_x{DETUNE:g}") else refused
                rows[name] = summarize(_failed_if_nan(jj), ref[sel])
        out[gname] = rows
    out["goal"] = _goal_check(out["all"]["answer"], lateral)
    return out


def evaluate(spec: EvalSpec, *, models, recipe, log=None) -> dict[str, Any]:
    """Run one evaluation (module docstring); ``models``: a model root or folder, ``recipe``: path."""
    from uavsim import __version__
    from uavsim.data.recipe import load_recipe
    from uavsim.tuning.optimal import optimal_gains

    log = log or (lambda msg: print(f"evaluate: {msg}", file=sys.stderr, flush=True))
    t0 = time.perf_counter()
    rc = load_recipe(recipe)
    if spec.bias_trim is not None:
        rc = replace(rc, test=replace(rc.test, bias_trim=check_bias_trim(spec.bias_trim)))
    cycles = spec.cycles if spec.cycles is not None else RUN_CYCLES.get(spec.loop)
    if cycles is not None:
        if int(cycles) < 3:
            raise UserError(f"a relay run of {cycles} cycles: identification needs at least 3 (one transient)")
        rc = replace(rc, episodes=replace(rc.episodes, cycles=float(cycles), duration_s=None))
    if rc.test.settings != "recommended":
        raise UserError(f"{recipe}: settings = {rc.test.settings!r}; the evaluation runs the relay with a user's "
                        "settings (settings = \"recommended\"), never ones made from the true cycle")
    lateral = spec.loop == "lateral"
    beta2 = second_beta_for(spec.loop, spec.second_beta)
    default_family(spec.loop, spec.family)  # asked of an inner loop: the one-line error before any flight
    if (rc.loop == "lateral") != lateral or (not lateral and rc.loop != spec.loop):
        raise UserError(f"{recipe}: a {rc.loop} recipe, the evaluation is of {spec.loop}")
    groups = _lateral_groups(spec, models) if lateral else [(None, resolve_model_dir(spec.loop, models))]
    per: list[dict[str, Any]] = []
    for a, d in groups:
        b = load_bundle(d)
        if not b.has_table:
            b.column("table_robust_kp")  # the one-line error
        rng = np.random.default_rng([spec.seed] if a is None else [spec.seed, a])
        params = draw_processes(spec.loop, spec.n, rng, K=spec.K, attitude=b.attitude)
        kind, level = noise_plan(spec.n, rc.noise.kinds, spec.levels, rng)
        r = rc if a is None else replace(rc, att_classes=(a,))
        sim_seed = spec.seed if a is None else spec.seed * 100 + a
        sim = _simulate(params, r, sim_seed, (kind, level), spec.chunk, log)
        sim2 = None if beta2 is None else _simulate_second(params, r, sim_seed, (kind, level), beta2, spec.chunk,
                                                           log)
        # the MuJoCo vehicle flies the attitude PD at the control rate; a grid designed over it says so
        truth = _truth(params, (b.attitude or {}).get("rate_hz"))
        opt = optimal_gains(b.loop, b.rate_hz, rule=b.rule, **truth)
        rule = b.rule.gains_batch(b.loop, **truth)
        b2 = load_second_bundle(d, b, beta=beta2) if sim2 is not None and spec.second_network else None
        ids = _identify_all(b, sim, r, spec.optimum, spec.decision, spec.guard, spec.inputs, spec.combine, sim2,
                            spec.family, b2)
        refused = np.array([x is None for x in ids["answers"]])
        no_class = np.array([x is not None and x["class"] is None for x in ids["answers"]])
        J = _variants(b, truth, opt.ise, ids, rule)
        per.append({"att_class": a, "model_dir": str(d), "J": J, "refused": refused, "no_class": no_class,
                    "level": level, "kind": kind,
                    "why": ids["why"], "ms": ids["ms"], "lead": ids["lead"], "response": ids["response"],
                    "response_period": ids["response_period"], "top": ids["top"], "second": ids["second"],
                    "second_network": ids["second_network"], "second_model_dir": None if b2 is None else str(b2.dir),
                    "truth": truth, "sim": sim, "answers": ids["answers"]})
        log(f"{'attitude class ' + str(a) + ': ' if a is not None else ''}identified {int((~refused).sum())}/"
            f"{spec.n} ({time.perf_counter() - t0:.0f} s)")
    cat = lambda k: np.concatenate([p[k] for p in per])  # noqa: E731
    J = {k: np.concatenate([p["J"][k] for p in per]) for k in per[0]["J"]}
    refused, level = cat("refused"), cat("level")
    ms = cat("ms")
    out: dict[str, Any] = {
        "spec": {**asdict(spec), "K": list(spec.K), "levels": list(spec.levels), "cycles": rc.episodes.cycles,
                 "second_beta": beta2},
        "models": str(models), "recipe": str(recipe), "tool_version": __version__,
        "noise_kinds": list(rc.noise.kinds), "rate_hz": load_bundle(groups[0][1]).rate_hz,
        "rows": _rows(J, refused, level, lateral, cat("no_class")),
        "refusals": _refusal_reasons([w for p in per for w in p["why"]]),
        "identify_ms": {"median": float(np.nanmedian(ms)), "p95": float(np.nanpercentile(ms, 95))} if np.isfinite(
            ms).any() else {},
        "episodes": _episodes(per),
        **({"second_run": {"beta": beta2, "two_points": int(cat("second").sum()),
                           "answered_from_it_alone": int(cat("no_class").sum()),
                           "network": per[0]["second_model_dir"],
                           "network_read": int(cat("second_network").sum())}} if beta2 is not None else {}),
        "wall_s": time.perf_counter() - t0,
    }
    if lateral:
        out["per_attitude_class"] = {str(p["att_class"]): summarize(_failed_if_nan(p["J"]["answer"]),
                                                                   p["refused"]) for p in per}
    return out


def _lateral_groups(spec: EvalSpec, models) -> list[tuple[int, Any]]:
    from pathlib import Path

    if spec.att_classes is not None:
        return [(int(a), resolve_model_dir("lateral", models, int(a))) for a in spec.att_classes]
    root = Path(models) / "lateral"
    found = sorted(int(p.name[1:]) for p in root.glob("a[0-9][0-9]") if (p / "meta.json").is_file())
    if not found:
        raise UserError(f"no lateral networks under {root} (lateral/aNN/meta.json)")
    return [(a, root / f"a{a:02d}") for a in found]


def _refusal_reasons(why: list[str | None]) -> dict[str, int]:
    out: dict[str, int] = {}
    for w in why:
        if w:
            key = w.split(":")[0] if w.startswith(("output saturated", "no steady")) else w.split(" (")[0][:60]
            out[key] = out.get(key, 0) + 1
    return out


def _episodes(per: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One record per episode: the process, its noise, what identification answered and J (JSON)."""
    rows = []
    for p in per:
        kinds_t = p["truth"]
        for i in range(p["level"].size):
            a = p["answers"][i]
            rows.append({"att_class": p["att_class"], **{k: float(v[i]) for k, v in kinds_t.items()},
                         "noise_kind": int(p["kind"][i]), "noise_level": float(p["level"][i]),
                         "tau_obs": float(p["sim"]["tau_obs"][i]), "a_n": float(p["sim"]["a_n"][i]),
                         "bias": float(p["sim"]["bias"][i]), "phase_lead_deg": float(p["lead"][i]),
                         "response": [float(p["response"][i].real), float(p["response"][i].imag)],
                         "response_period": float(p["response_period"][i]), "network_top": p["top"][i],
                         "refused": p["why"][i], "class": None if a is None else a["class"],
                         "K_hat": None if a is None or "table" not in a else a["table"]["K_hat"],
                         "decision": None if a is None else a.get("decision"),
                         "gains_source": None if a is None else a["gains_source"],
                         "family_point": None if a is None or "family" not in a else a["family"]["point"],
                         "guard": None if a is None or "guard" not in a else
                         {k: v for k, v in a["guard"].items() if k != "latency_ms"},
                         "J": {k: None if a is None and k.startswith("answer") else _json_j(v[i])
                               for k, v in p["J"].items()}})
    return rows


def _json_j(j: float) -> float | str | None:
    """A J in JSON: the number, ``"unstable"`` (inf), or null (not computed: no cycle to measure)."""
    if np.isnan(j):
        return None
    return float(j) if np.isfinite(j) else "unstable"


def markdown(res: dict[str, Any]) -> str:
    """The result's rows as markdown: one table per noise level group, median / p95 / max, unstable, refused."""
    lines = []
    rows = res["rows"]
    names = list(rows["all"])
    groups = [g for g in rows if g not in ("goal",)]
    lines.append("| J (median / p95 / max; unstable, refused) | " + " | ".join(groups) + " |")
    lines.append("| --- |" + " --- |" * len(groups))
    for name in names:
        cells = []
        for g in groups:
            s = rows[g][name]
            if not s.get("n"):
                cells.append("-")
                continue
            f = lambda v: "inf" if not math.isfinite(v) else (">1e3" if v > 1e3 else f"{v:.3f}")  # noqa: E731
            cells.append(f"{f(s['median'])} / {f(s['p95'])} / {f(s['max'])}; {s['unstable']}, {s['refused']} "
                         f"(n {s['n']})")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    goal = rows["goal"]
    lines.append("")
    lines.append("Goals (answer, all levels): " + ", ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in goal.items()))
    return "\n".join(lines) + "\n"
