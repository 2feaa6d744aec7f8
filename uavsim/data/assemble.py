"""A dataset file from a plan's chunk results: inputs, labels, draws, class table, metadata.

The chunks' results are put in plan order, the training episodes whose
preprocessing succeeded are kept, the class table (grid parameters, the
reference episodes' cycle, the table's PD gains and J) and the attributes
(recipe, seeds, versions, commit) are written by :func:`uavsim.data.h5.write_dataset`.

    summary = assemble(plan, {i: run_chunk(plan, i) for i in range(len(plan.chunks))}, Path("out.h5"))
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.control.relay import READING, TRIM_RULE
from uavsim.data import preprocess
from uavsim.data.backends import git_commit, versions
from uavsim.data.h5 import CLASS_FIELDS, CLASS_PARAMS, write_dataset
from uavsim.data.plan import Plan, att_classes_of
from uavsim.data.recipe import Recipe
from uavsim.errors import UserError
from uavsim.noise.estimate import SETTINGS_RULE


def class_table_gains(family: str, rate_hz: float, att_class: int | None) -> dict[str, np.ndarray]:
    """The grid's table of ISE-optimal PDs at the data's control rate, as class-table columns.

    ``table_kp``, ``table_kd`` (the class's own optimum), ``table_robust_kp``, ``table_robust_kd`` (the
    answer identification gives), ``table_filter_hz``, ``table_omega`` and ``table_gain_at_omega`` (the
    gain estimate's reference), each (n,) for K = 1, and ``J``: the table's robust answers' relative
    sensitivity (n, n), which the network's loss weighs (``uavsim.tuning.table``).
    """
    from uavsim.tuning.table import load_table

    t = load_table(family, rate_hz)
    if att_class is not None:
        t = t.lateral(att_class)
    return {"table_kp": t.kp, "table_kd": t.kd, "table_robust_kp": t.robust_kp, "table_robust_kd": t.robust_kd,
            "table_filter_hz": t.derivative_filter_hz, "table_omega": t.omega,
            "table_gain_at_omega": t.gain_at_omega, "J": np.asarray(t.J_robust, dtype=np.float64)}


def assemble(plan: Plan, results: dict[int, dict], out: Path, run_versions: dict[str, str] | None = None
              ) -> dict[str, Any]:
    n = plan.n
    r = plan.recipe
    C, L = len(preprocess.CHANNELS), plan.L
    X = np.zeros((n, C, L), dtype=np.float32)
    period, amp = np.full(n, np.nan), np.full(n, np.nan)
    resp, resp_period = np.full(n, complex("nan")), np.full(n, np.nan)
    ok, div = np.zeros(n, bool), np.zeros(n, bool)
    tau_obs, a_n = plan.tau_obs.copy(), plan.a_n.copy()
    seed_of = np.zeros(n, dtype=np.uint32)
    keep_raw = r.preprocess.keep_raw
    Tmax = int(round(plan.durations.max() * r.episodes.rate_hz)) if keep_raw else 0
    raw_y = np.full((n, Tmax), np.nan, np.float32) if keep_raw else None
    raw_u = np.full((n, Tmax), np.nan, np.float32) if keep_raw else None
    length = np.zeros(n, np.int64)
    for i, res in results.items():
        ids = res["ids"]
        X[ids], period[ids], amp[ids], ok[ids], div[ids] = res["X"], res["period"], res["amplitude"], res["ok"], \
            res["diverged"]
        if "response" in res:  # chunks saved by an older version for resume lack it
            resp[ids], resp_period[ids] = res["response"], res["response_period"]
        if "tau_obs" in res:
            tau_obs[ids], a_n[ids] = res["tau_obs"], res["a_n"]
        seed_of[ids] = plan.sim_seeds[i]
        if keep_raw:
            T = res["y"].shape[1]
            raw_y[ids, :T], raw_u[ids, :T], length[ids] = res["y"], res["u"], T
    nt = plan.n_train
    keep = np.flatnonzero(ok[:nt] & np.isfinite(X[:nt]).all(axis=(1, 2)))
    g = plan.grid
    ci = plan.class_index
    fam = r.loop
    classes = {k: np.asarray(g.params[k], float)[ci] for k in CLASS_PARAMS[fam]}
    classes.update({k: np.asarray(getattr(g, k), float)[ci] for k in CLASS_FIELDS})
    classes["grid_index"] = ci.astype(np.float64)
    # the reference episodes' cycle (K = 1, h = 1 scale): NaN where it failed
    classes["period_sim"] = period[nt:].copy()
    classes["amplitude_sim"] = amp[nt:] / r.test.h
    tab = class_table_gains(fam, r.episodes.rate_hz, plan.att_class)
    classes.update({k: v[ci] for k, v in tab.items() if k != "J"})
    J = tab["J"][np.ix_(ci, ci)]
    fixed = r.test.settings == "fixed"
    episodes = {"inputs": X[keep], "labels": plan.labels[keep], "K": plan.K[keep], "bias": plan.bias[keep],
                "noise_kind": plan.noise_kind[keep], "noise_level": plan.noise_level[keep], "period": period[keep],
                "amplitude": amp[keep], "y0": plan.y0[keep], "tau_obs": tau_obs[keep], "a_n": a_n[keep],
                "episode": keep, "sim_seed": seed_of[keep], "response_re": resp[keep].real,
                "response_im": resp[keep].imag, "response_period": resp_period[keep]}
    cost = None
    if plan.process is not None:
        from uavsim.data.costs import COST_SOURCE, sample_costs

        proc = {k: v[keep] for k, v in plan.process.items()}
        episodes.update({f"process_{k}": v for k, v in proc.items()})
        episodes["offgrid"] = plan.offgrid[keep]
        cost = sample_costs(fam, r.episodes.rate_hz, proc, plan.K[keep], resp[keep], resp_period[keep], classes)
    n_div = int(div[:nt].sum())
    attrs = {"loop": fam, "grid_hash": g.hash or "", "grid_version": int(g.version), "beta": plan.beta,
             "h": r.test.h, "relay_reading": READING, "relay_settings": r.test.settings,
             "settings_rule": SETTINGS_RULE, "trim_rule": TRIM_RULE,
             "tau_obs": r.test.tau_obs if fixed else float("nan"), "a_n": r.test.a_n if fixed else float("nan"),
             "refinements": 0 if fixed else r.test.refinements, "rate_hz": r.episodes.rate_hz,
             "dt": r.episodes.dt, "input_length": L, "input_rate_hz": preprocess.INPUT_RATE_HZ,
             "channels": list(preprocess.CHANNELS), "cycles_per_input": r.preprocess.cycles,
             "noise_kinds": list(r.noise.kinds), "recipe": r.text, "seed": r.seed,
             "versions": json.dumps(run_versions or versions(), sort_keys=True), "git_commit": git_commit(), "n_episodes": nt,
             "n_diverged": n_div, "n_rejected": int(nt - n_div - len(keep)),
             "J_source": f"table robust answers at {r.episodes.rate_hz:g} Hz (J of table_robust_kp/kd)",
             "simulated_s": float(sum(len(c) * d for c, d in zip(plan.chunks, plan.durations, strict=True)))}
    if plan.att_class is not None:
        attrs["att_class"] = int(plan.att_class)
    if cost is not None:
        attrs["offgrid"] = float(r.randomize.offgrid)
        attrs["cost_source"] = COST_SOURCE
    effects = {k: v[keep] for k, v in plan.effect_params.items()}
    raw = {"y": raw_y[keep], "u": raw_u[keep], "length": length[keep]} if keep_raw else None
    write_dataset(out, episodes, classes, J, attrs, effects=effects, raw=raw, cost=cost)
    return {"file": str(out), "n_episodes": nt, "n_kept": int(len(keep)), "n_diverged": n_div,
            "n_rejected": attrs["n_rejected"], "simulated_s": attrs["simulated_s"]}


def output_paths(recipe: Recipe, out: str | Path | None, grid) -> list[tuple[int | None, Path]]:
    """(attitude class, file) of each file a recipe makes: ``OUT`` or ``OUT_aNN.h5`` for lateral."""
    base = Path(out) if out is not None else Path(recipe.source).with_suffix(".h5")
    if base.suffix != ".h5":
        raise UserError(f"output {base} must end in .h5")
    atts = att_classes_of(recipe, grid)
    if atts == [None]:
        return [(None, base)]
    return [(a, base.with_name(f"{base.stem}_a{a:02d}.h5")) for a in atts]
