"""Evaluation of a trained network: held-out sets, off-grid processes, closed-loop criterion.

Three views, from the cheapest to the one that matters:

* **held-out set** (a dataset generated with other seeds): top-1 accuracy and
  mean / p95 of ``J[predicted, true]`` (``class_metrics``);
* **off-grid processes**: random processes drawn log-uniformly in the paper's
  box (not grid points), simulated in MuJoCo through the dataset path
  (``uavsim.data.generate.simulate_features``: same relay, noise, preprocessing);
* **closed-loop criterion**: the gains identification answers
  (``decide_gains``: the rule on one of the best-fitting models, the one whose
  gains cost least over all of them) against the tuning rule applied to the *true*
  process: ISE deterioration ``Q(picked, G) / Q(rule(G), G) - 1`` of a unit step
  (``uavsim.lumped.ise.step_ise_batch``, exact delays); an unstable loop is
  ``inf`` and counted. This includes the gain-recovery error, which the
  normalized J does not see; the normalized J of the predicted class against
  the true process (``uavsim.tuning.jmatrix.deterioration``) is reported too.

    python -m uavsim.learning.evaluate training/runs/altitude --recipe datasets/altitude.toml --n 300 --json
    from uavsim.learning.evaluate import evaluate_offgrid
    res = evaluate_offgrid("training/runs/small", "datasets/small.toml", n=50, seed=11)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.learning.export import Predictor
from uavsim.learning.identify import (
    decide_gains,
    fit_response,
    measured_point_gains,
    model_gains,
    period_in_grid,
    phase_refusal,
    rank_candidates,
)
from uavsim.learning.train import class_metrics, load_training_data
from uavsim.lumped.params import RANGES, LumpedParams

__all__ = ["OffGridSpec", "evaluate_heldout", "random_processes", "pipeline_gains", "class_gains", "amplitude_gain",
           "RuleReference", "closed_loop_deterioration", "evaluate_offgrid", "evaluate_offgrid_lateral", "summarize_deterioration"]


@dataclass
class OffGridSpec:
    """How off-grid processes are drawn.

    Attributes
    ----------
    n : int
        Processes.
    seed : int
        Seed of the draw and of the simulation (recorded in the result).
    K : tuple of float
        Gain range, log-uniform.
    chunk : int
        Episodes per MuJoCo batch.
    """

    n: int = 300
    seed: int = 11
    K: tuple[float, float] = (0.5, 2.0)
    chunk: int = 100


def evaluate_heldout(model_dir: str | os.PathLike, dataset: str | os.PathLike) -> dict[str, Any]:
    """Top-1 and J metrics of an exported model on a dataset of the same classes."""
    pred = Predictor(model_dir)
    data = load_training_data(dataset)
    if data.attrs.get("grid_hash") != pred.meta.get("grid_hash"):
        raise UserError(f"{dataset}: grid differs from the model's")
    gi_m = pred.meta["classes"].get("grid_index")
    gi_d = data.classes.get("grid_index")
    if gi_m is not None and gi_d is not None and not np.array_equal(np.asarray(gi_m), np.asarray(gi_d)):
        raise UserError(f"{dataset}: class subset differs from the model's")
    cls, _ = pred.predict(data.X)
    return class_metrics(cls, data.labels, data.J)


def random_processes(loop: str, n: int, seed: int, K: tuple[float, float] = (0.5, 2.0)) -> list[LumpedParams]:
    """``n`` processes log-uniform in the paper's box of ``loop`` (altitude / roll), K log-uniform."""
    fam = "altitude" if loop == "altitude" else "attitude"
    rng = np.random.default_rng(seed)
    box = RANGES[fam]
    draw = {k: np.exp(rng.uniform(math.log(lo), math.log(hi), n)) for k, (lo, hi) in box.items()}
    Ks = np.exp(rng.uniform(math.log(K[0]), math.log(K[1]), n))
    name = "altitude" if fam == "altitude" else "roll"
    return [LumpedParams(name, float(Ks[i]), float(draw["T_prop"][i]), float(draw["T1"][i]), float(draw["tau"][i]))
            for i in range(n)]


def class_gains(cls: np.ndarray, K_hat: np.ndarray, table: dict[str, Any]) -> dict[str, np.ndarray]:
    """The class's rule gains (K = 1) over ``K_hat`` (the authors' tuning lookup).

    Returns ``K_hat``, ``kp``, ``kd``, ``N`` (rad/s), each (m,).
    """
    cls = np.asarray(cls, dtype=np.int64)
    K_hat = np.asarray(K_hat, dtype=np.float64)
    return {"K_hat": K_hat, "kp": np.asarray(table["kp"], float)[cls] / K_hat,
            "kd": np.asarray(table["kd"], float)[cls] / K_hat,
            "N": 2 * np.pi * np.asarray(table["derivative_filter_hz"], float)[cls]}


def pipeline_gains(cls: np.ndarray, response: np.ndarray, response_period: np.ndarray, table: dict[str, Any],
                   family: str, beta: float, pm_deg: float) -> dict[str, np.ndarray]:
    """What identification picks (``uavsim.learning.identify``): the rule on the class's model fitted
    to the measured response. Returns ``K_hat``, ``tau_hat``, ``kp``, ``kd``, ``N`` (rad/s), each (m,)."""
    model = fit_response(response, response_period, cls, table, family)
    g = model_gains(model, family, beta, pm_deg)
    return {"K_hat": model["K"], "tau_hat": model["tau"], "kp": g["kp"], "kd": g["kd"], "N": g["N"]}


def amplitude_gain(cls: np.ndarray, amplitude: np.ndarray, h: float | np.ndarray, table: dict[str, Any]) -> np.ndarray:
    """The authors' gain recovery, ``K_hat = (a / h) / a_class`` (continuous plain-MRFT class amplitude), (m,)."""
    a_cls = np.asarray(table["amplitude"], float)[np.asarray(cls, dtype=np.int64)]
    return (np.asarray(amplitude, float) / np.asarray(h, float)) / a_cls


class RuleReference:
    """The tuning rule applied to the true processes: the reference every picked PD is scored against.

    The rule's gains and their step ISE are computed once; ``deterioration`` then scores any
    number of picked gains on the same processes (one ISE evaluation each).

    Parameters
    ----------
    family : str
    rule : TuningRule (with its ``gain_scale`` for lateral sub-grids)
    params : dict of (m,) arrays, the true processes as ``freq_response_batch`` takes them
    """

    def __init__(self, family: str, rule, params: dict[str, np.ndarray]):
        from uavsim.lumped.ise import step_ise_batch

        self.family, self.params = family, params
        g = rule.gains_batch(family, **params)
        self.kp, self.kd, self.omega = g["kp"], g["kd"], g["omega"]
        self.q, self.stable = step_ise_batch(family, g["kp"], g["kd"], g["N"], g["omega"], return_stable=True,
                                             **params)

    def deterioration(self, kp: np.ndarray, kd: np.ndarray, N: np.ndarray) -> dict[str, np.ndarray]:
        """``Q_picked``, ``Q_rule`` (output^2 s), ``deterioration`` (Q_picked / Q_rule - 1; inf if unstable),
        ``stable`` (m,) bool and the rule's own ``kp_rule``, ``kd_rule`` (m,)."""
        from uavsim.lumped.ise import step_ise_batch

        q_pick, stable = step_ise_batch(self.family, kp, kd, N, self.omega, return_stable=True, **self.params)
        with np.errstate(invalid="ignore", divide="ignore"):
            det = np.where(stable, q_pick / self.q - 1.0, np.inf)
        return {"Q_picked": q_pick, "Q_rule": self.q, "deterioration": det, "stable": stable, "kp_rule": self.kp,
                "kd_rule": self.kd}


def _inner_reference(params: list[LumpedParams], beta: float, pm_deg: float) -> RuleReference:
    from uavsim.tuning.rule import TuningRule

    pa = {k: np.array([getattr(p, k) for p in params], float) for k in ("K", "T_prop", "T1", "tau")}
    return RuleReference(params[0].family, TuningRule(beta, pm_deg), pa)


def closed_loop_deterioration(params: list[LumpedParams], kp: np.ndarray, kd: np.ndarray, N: np.ndarray,
                              beta: float, pm_deg: float) -> dict[str, np.ndarray]:
    """Step-ISE deterioration of given PD gains against the rule's gains for each true process.

    Returns ``RuleReference.deterioration``'s dict. To score several gain sets on the same
    processes, build one ``RuleReference`` instead (the rule's ISE is computed once).
    """
    return _inner_reference(params, beta, pm_deg).deterioration(kp, kd, N)


def summarize_deterioration(det: np.ndarray) -> dict[str, float]:
    """Median, p95 and max ISE deterioration (fractions), and the unstable count."""
    det = np.asarray(det, float)
    if det.size == 0:
        return {"n": 0, "median": float("nan"), "p95": float("nan"), "max": float("nan"), "unstable": 0}
    # unstable loops are inf: rank them above everything without interpolating inf - inf
    finite = np.where(np.isfinite(det), det, 1e300)
    p95 = float(np.percentile(finite, 95))
    return {"n": int(det.size), "median": float(np.median(det)), "p95": p95 if p95 < 1e300 else float("inf"),
            "max": float(np.max(det)), "unstable": int(np.sum(~np.isfinite(det)))}


def nearest_class(params: list[LumpedParams], table: dict[str, Any]) -> np.ndarray:
    """Per process, the class nearest to it in the log parameter box (each axis scaled to [0, 1]), (m,)."""
    keys = ("T_prop", "T1", "tau")
    return _nearest_in_box(params[0].family, keys, np.array([[getattr(p, k) for k in keys] for p in params]), table)


def _nearest_in_box(fam: str, keys: tuple[str, ...], P: np.ndarray, table: dict[str, Any]) -> np.ndarray:
    """Row of ``table`` nearest to each row of ``P`` (m, len(keys)) in the family's log box, each axis on [0, 1]."""
    lo = np.log([RANGES[fam][k][0] for k in keys])
    hi = np.log([RANGES[fam][k][1] for k in keys])
    Pn = (np.log(P) - lo) / (hi - lo)
    C = (np.log(np.column_stack([np.asarray(table[k], dtype=np.float64) for k in keys])) - lo) / (hi - lo)
    return np.argmin(((Pn[:, None, :] - C[None, :, :]) ** 2).sum(axis=-1), axis=1)


def _phase_ok(resp: np.ndarray, rper: np.ndarray, ok: np.ndarray, beta: float) -> np.ndarray:
    """(m,) bool: the cycles identification does not refuse as switched by noise (``phase_refusal``)."""
    return np.array([not k or phase_refusal(r, q, beta) is None for r, q, k in zip(resp, rper, ok, strict=True)])


def _pct(x: np.ndarray) -> list[float]:
    """5th, 50th and 95th percentiles (empty without data)."""
    return [float(v) for v in np.percentile(x, [5, 50, 95])] if len(x) else []


def _rel_err(K_hat: np.ndarray, K: np.ndarray) -> dict[str, float]:
    """Median and p95 of ``|K_hat / K - 1|`` (empty without data)."""
    if not len(K):
        return {}
    e = np.abs(np.asarray(K_hat) / np.asarray(K) - 1.0)
    return {"median": float(np.median(e)), "p95": float(np.percentile(e, 95))}


def evaluate_offgrid(model_dir: str | os.PathLike, recipe_path: str | os.PathLike, n: int = 300, seed: int = 11,
                     K: tuple[float, float] = (0.5, 2.0), chunk: int = 100, progress: bool = False) -> dict[str, Any]:
    """Off-grid random processes through MuJoCo and the whole identification pipeline.

    Parameters
    ----------
    model_dir : exported model folder
    recipe_path : dataset recipe whose test, noise and preprocessing settings the episodes use
    n, seed, K, chunk : see ``OffGridSpec``

    Returns
    -------
    dict: ``n``, ``n_rejected`` (no usable oscillation: not identified), ``seed``,
    ``deterioration`` (``summarize_deterioration`` of the gains identification answers,
    ``decide_gains``), ``decision`` (how often it leaves the best fit; its gains over the best fit's
    and over the rule's on the true process: 5/50/95th percentiles), ``best_fit`` (the rule on the
    best harmonic fit, ``select_class``), ``best_fit_scaled`` (those gains times the decision's
    median ratio: a plain detuning, the control), ``network_first_choice`` (the rule on the network's
    argmax class),
    ``selection_changed`` (fraction where they differ), ``J`` (normalized J of the predicted class:
    mean, p95), ``K_rel_err`` (median, p95 of |K_hat / K - 1|; not a measure of the gains by
    itself: classes of one Omega level differ in gain normalization), ``kp_rel_err``,
    ``kd_rel_err`` (against the rule's gains for the true process), ``by_noise`` (median
    deterioration per noise level band), ``baseline_nearest_period`` (deterioration when the
    class is the one of nearest exact period), ``class_table_gains`` (deterioration and
    errors of the class's tabulated gains over ``K_hat`` from the amplitude, ``amplitude_K``, or
    from the response, ``response_K``, with the network's classes), ``measured_point_rule``
    (deterioration of ``measured_point_gains``: no network, no model), ``oracle_class``
    (the pipeline with the grid class nearest to the truth: what a perfect classifier gives), ``wall_s``.
    """
    from uavsim.data.generate import simulate_features
    from uavsim.data.recipe import load_recipe
    from uavsim.tuning.grid import load_grid
    from uavsim.tuning.jmatrix import deterioration

    t0 = time.perf_counter()
    pred = Predictor(model_dir)
    recipe = load_recipe(recipe_path)
    meta = pred.meta
    grid = load_grid(meta["loop"])
    if meta.get("grid_hash") and grid.hash and meta["grid_hash"] != grid.hash:
        raise UserError(f"{model_dir}: trained on another {meta['loop']} grid than the current one")
    table = meta["classes"]
    params = random_processes(meta["loop"], n, seed, K)
    parts = []
    for i in range(0, n, chunk):
        X, per, amp, ok, m = simulate_features(params[i : i + chunk], recipe, seed + 1 + i // chunk)
        parts.append((X, per, amp, ok, m["noise_level"], m["response"], m["response_period"], m["harmonics_y"],
                      m["harmonics_u"]))
        if progress:
            print(f"off-grid: simulated {min(i + chunk, n)}/{n} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    X, period, amp, ok, level, resp, rper, hy, hu = (np.concatenate(v) for v in zip(*parts, strict=True))
    ok &= period_in_grid(np.nan_to_num(period), table)  # identification refuses the others
    ok &= _phase_ok(resp, rper, ok, grid.beta)
    idx = np.flatnonzero(ok)
    h = recipe.test.h
    fam = meta["loop"]
    net_cls, act = pred.predict(X[idx])
    cand, ws = rank_candidates(act, resp[idx], rper[idx], hy[idx], hu[idx], table, fam)
    cls = cand[:, 0]
    gd = decide_gains(cand, ws, hy[idx], resp[idx], rper[idx], table, fam, grid.beta, grid.pm_deg)
    g = pipeline_gains(cls, resp[idx], rper[idx], table, fam, grid.beta, grid.pm_deg)
    used = [params[i] for i in idx]
    ref = _inner_reference(used, grid.beta, grid.pm_deg)
    cl = ref.deterioration(g["kp"], g["kd"], g["N"])
    # identification's answer: the gains of least expected deterioration over the best fits
    cd = ref.deterioration(gd["kp"], gd["kd"], gd["N"])
    # control: the best fit's gains scaled by the decision's median gain ratio (a plain detuning)
    scale = float(np.median(gd["kp"] / g["kp"])) if idx.size else 1.0
    det_scaled = ref.deterioration(scale * g["kp"], scale * g["kd"], g["N"])["deterioration"]
    K_true = np.array([p.K for p in used])
    # same run, the class-table lookup (the authors' tuning): the class's gains over K_hat from the
    # amplitude (their recovery) or from the response at the measured frequency
    lookups = {}
    for name, K_hat in (("amplitude_K", amplitude_gain(cls, amp[idx], h, table)),
                        ("response_K", fit_response(resp[idx], rper[idx], cls, table, fam)["K"])):
        gl = class_gains(cls, K_hat, table)
        lookups[name] = {
            "deterioration": summarize_deterioration(
                ref.deterioration(gl["kp"], gl["kd"], gl["N"])["deterioration"]),
            "K_rel_err": _rel_err(K_hat, K_true), "kp_rel_err": _rel_err(gl["kp"], cl["kp_rule"])}
    # normalized J of the predicted class's controller on the true process (no gain error)
    gi = np.asarray(table.get("grid_index", np.arange(len(table["kp"]))), dtype=np.int64)
    pa = {k: np.array([getattr(p, k) for p in used]) for k in ("T_prop", "T1", "tau")}
    from uavsim.lumped.frequency import mrft_prediction_batch

    w_pt, _ = mrft_prediction_batch(grid.loop, grid.beta, 1.0, K=1.0, **pa)
    Jpc = deterioration(grid.loop, w_pt, grid.omega_df[gi], grid.c1, grid.c3, **pa)  # (n_classes, m)
    jsel = Jpc[cls, np.arange(len(idx))]
    det = cl["deterioration"]
    # same run, the network's first choice with no harmonic selection
    gn = pipeline_gains(net_cls, resp[idx], rper[idx], table, fam, grid.beta, grid.pm_deg)
    det_net = ref.deterioration(gn["kp"], gn["kd"], gn["N"])["deterioration"]
    # same-run baseline: the class of nearest exact period, fitted the same way (what a network must beat)
    near = np.argmin(np.abs(np.log(period[idx])[:, None] - np.log(np.asarray(table["period"], float))[None, :]), axis=1)
    gb = pipeline_gains(near, resp[idx], rper[idx], table, fam, grid.beta, grid.pm_deg)
    det_base = ref.deterioration(gb["kp"], gb["kd"], gb["N"])["deterioration"]
    # same run, an oracle classifier: the class nearest to the true process in the log box
    go = pipeline_gains(nearest_class(used, table), resp[idx], rper[idx], table, fam, grid.beta, grid.pm_deg)
    det_or = ref.deterioration(go["kp"], go["kd"], go["N"])["deterioration"]
    # same run, no network and no model: the rule's constants at the measured point
    gm = measured_point_gains(resp[idx], rper[idx], grid.beta, grid.pm_deg)
    det_mp = ref.deterioration(gm["kp"], gm["kd"], gm["N"])["deterioration"]
    bands = [(0.0, 0.05), (0.05, 0.1), (0.1, 0.15), (0.15, 0.2001)]
    by_noise = {}
    for lo, hi in bands:
        sel = (level[idx] >= lo) & (level[idx] < hi)
        by_noise[f"{lo:.2f}-{min(hi, 0.2):.2f}"] = summarize_deterioration(cd["deterioration"][sel])
    return {
        "model": str(model_dir), "recipe": str(recipe_path), "n": n, "n_identified": int(idx.size),
        "n_rejected": int(n - idx.size), "seed": seed, "K_range": list(K),
        "noise_level_max": float(np.max(level)) if level.size else 0.0,
        "deterioration": summarize_deterioration(cd["deterioration"]),
        "decision": {"changed": float(np.mean(gd["pick"] != cls)) if idx.size else 0.0,
                     "kp_over_best_fit": _pct(gd["kp"] / g["kp"]), "kp_over_rule": _pct(gd["kp"] / cl["kp_rule"]),
                     "kd_over_rule": _pct(gd["kd"] / cl["kd_rule"])},
        "best_fit": summarize_deterioration(det),
        "best_fit_scaled": {"scale": scale, **summarize_deterioration(det_scaled)},
        "network_first_choice": summarize_deterioration(det_net),
        "selection_changed": float(np.mean(cls != net_cls)) if idx.size else 0.0,
        "baseline_nearest_period": summarize_deterioration(det_base),
        "class_table_gains": lookups,
        "measured_point_rule": summarize_deterioration(det_mp),
        "oracle_class": summarize_deterioration(det_or),
        "J": {"mean": float(np.mean(jsel)), "p95": float(np.percentile(jsel, 95))} if jsel.size else {},
        "K_rel_err": _rel_err(g["K_hat"], K_true),
        "kp_rel_err": _rel_err(g["kp"], cl["kp_rule"]),
        "kd_rel_err": _rel_err(g["kd"], cl["kd_rule"]),
        "by_noise": by_noise,
        "wall_s": time.perf_counter() - t0,
    }


def evaluate_offgrid_lateral(model_root: str | os.PathLike, recipe_path: str | os.PathLike, att_classes: list[int],
                             n_per: int = 40, seed: int = 11, K: tuple[float, float] = (0.5, 2.0)) -> dict[str, Any]:
    """Off-grid lateral processes over given attitude classes, through MuJoCo and identification.

    For each attitude class ``a``: ``n_per`` processes with ``T2``, the outer delay and ``K``
    log-uniform in the lateral box, over the class's own closed attitude loop (its rule PD), simulated
    with the lateral recipe's episode, noise and preprocessing; identified with the network
    ``lateral/aNN`` (``fit_response_lateral``, the sub-grid's rule). Deterioration is against the
    sub-grid's rule on the true process; processes where that rule itself is unstable are counted
    (``rule_unstable``) and left out.

    Returns
    -------
    dict: ``per_class`` (att class -> n, n_identified, deterioration), ``deterioration`` (all),
    ``measured_point_rule``, ``oracle_class`` (nearest sub-grid class in the log box), ``rule_unstable``,
    ``wall_s``.
    """
    from dataclasses import replace as _replace

    from uavsim.data.generate import simulate_features
    from uavsim.data.recipe import load_recipe
    from uavsim.learning.identify import (
        fit_response_lateral,
        lateral_context,
        lateral_gains,
        resolve_model_dir,
    )

    t0 = time.perf_counter()
    recipe = load_recipe(recipe_path)
    if recipe.loop != "lateral":
        raise UserError(f"{recipe_path}: not a lateral recipe")
    box = RANGES["lateral"]
    det_all, det_mp, det_or, per_class, rule_unstable = [], [], [], {}, 0
    for a in att_classes:
        sub, att = lateral_context(a)
        pred = Predictor(resolve_model_dir("lateral", model_root, a))
        table = pred.meta["classes"]
        rng = np.random.default_rng([seed, a])
        T2, tau = (np.exp(rng.uniform(math.log(box[k][0]), math.log(box[k][1]), n_per)) for k in ("T2", "tau"))
        Ks = np.exp(rng.uniform(math.log(K[0]), math.log(K[1]), n_per))
        params = [LumpedParams("lateral_x", float(Ks[i]), att["T_prop"], att["T1"], float(tau[i]), T2=float(T2[i]),
                               tau_in=att["tau_in"], att_kp=att["att_kp"], att_kd=att["att_kd"],
                               att_filter_hz=att["att_filter_hz"]) for i in range(n_per)]
        X, period, _, ok, m = simulate_features(params, _replace(recipe, att_classes=(a,)), seed + 1000 * a)
        ok = ok & period_in_grid(np.nan_to_num(period), table)
        idx = np.flatnonzero(ok & _phase_ok(m["response"], m["response_period"], ok, sub.beta))
        if idx.size == 0:
            per_class[a] = {"n": n_per, "n_identified": 0}
            continue
        cls, _ = pred.predict(X[idx])
        resp, rper = m["response"][idx], m["response_period"][idx]
        truth = {"K": Ks[idx], "T2": T2[idx], "tau": tau[idx], **{k: np.full(idx.size, v) for k, v in (
            ("T_prop", att["T_prop"]), ("T1", att["T1"]), ("tau_in", att["tau_in"]), ("att_kp", att["att_kp"]),
            ("att_kd", att["att_kd"]), ("att_N", 2 * np.pi * att["att_filter_hz"]))}}
        ref = RuleReference("lateral", sub.rule, truth)
        rule_unstable += int(np.sum(~ref.stable))

        def det_of(kp, kd, N, ref=ref):
            return ref.deterioration(kp, kd, N)["deterioration"][ref.stable]

        g = lateral_gains(fit_response_lateral(resp, rper, cls, table, att), sub.rule)
        d = det_of(g["kp"], g["kd"], g["N"])
        det_all.append(d)
        gm = measured_point_gains(resp, rper, sub.beta, sub.pm_deg, gain_scale=sub.gain_scale)
        det_mp.append(det_of(gm["kp"], gm["kd"], gm["N"]))
        near = _nearest_in_box("lateral", ("T2", "tau"), np.column_stack([T2[idx], tau[idx]]), table)
        go = lateral_gains(fit_response_lateral(resp, rper, near, table, att), sub.rule)
        det_or.append(det_of(go["kp"], go["kd"], go["N"]))
        per_class[a] = {"n": n_per, "n_identified": int(idx.size), "deterioration": summarize_deterioration(d)}
    cat = lambda v: np.concatenate(v) if v else np.zeros(0)  # noqa: E731
    return {"model_root": str(model_root), "att_classes": list(att_classes), "n_per": n_per, "seed": seed,
            "deterioration": summarize_deterioration(cat(det_all)),
            "measured_point_rule": summarize_deterioration(cat(det_mp)),
            "oracle_class": summarize_deterioration(cat(det_or)), "rule_unstable": rule_unstable,
            "per_class": per_class, "wall_s": time.perf_counter() - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uavsim.learning.evaluate", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model_dir")
    ap.add_argument("--recipe", required=True, help="dataset recipe for the off-grid episodes")
    ap.add_argument("--heldout", help="held-out dataset (.h5) for top-1 / J metrics")
    ap.add_argument("--n", type=int, default=300)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--lateral-classes", help="lateral: comma-separated attitude classes (MODEL_DIR is the "
                                              "root holding lateral/aNN; --n processes per class)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    try:
        out: dict[str, Any] = {}
        if args.lateral_classes:
            classes = [int(c) for c in args.lateral_classes.split(",") if c.strip()]
            out["offgrid_lateral"] = evaluate_offgrid_lateral(args.model_dir, args.recipe, classes, n_per=args.n,
                                                              seed=args.seed)
            print(json.dumps(out, indent=None if args.json else 1))
            return 0
        if args.heldout:
            out["heldout"] = evaluate_heldout(args.model_dir, args.heldout)
        out["offgrid"] = evaluate_offgrid(args.model_dir, args.recipe, n=args.n, seed=args.seed, progress=True)
    except UserError as exc:
        print(f"evaluate: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(out, indent=None if args.json else 1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
