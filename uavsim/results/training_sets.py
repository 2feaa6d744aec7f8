"""Figures of docs/results/training-sets.md read off a training set (``uavsim-dataset/1``).

* **Refused by noise level**: the episodes of the recipe's plan (``uavsim.data.plan``,
  rebuilt from the recipe the file records; the grid must be the one the file was made
  on) that are not in the file, by noise kind and by noise level bin. They are the
  file's ``n_rejected`` and ``n_diverged`` together (which one is not recorded per
  episode; ``n_diverged`` is printed beside them).
* **The cycle's lengthening by noise kind**: median of each kept episode's period over
  its class's grid period (``classes/period``, the continuous-time relay cycle), and
  over its class's cycle at the control rate (``classes/period_sim``) where the file has it.
* **The cycle at the control rate**: each class's reference cycle (K = 1, no bias,
  no noise: ``classes/period_sim``, ``amplitude_sim``) over the grid's continuous-time
  cycle (``classes/period``, ``amplitude``): median and largest, with the class.
* **Gain recovery from one cycle**: ``K_hat = amplitude / (h amplitude_sim)`` of the
  kept episodes at zero noise and ``|bias| < 0.05 h`` against their drawn ``K``,
  ``|K_hat / K - 1|`` by the class's grid period (< 0.2 s, 0.2-0.4 s, > 0.4 s).

    python -m uavsim.results.training_sets datasets/altitude.h5
    python -m uavsim.results.training_sets datasets/small.h5 --json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from uavsim.errors import UserError

#: noise level bins (fraction of the cycle amplitude a0): upper edges
LEVEL_EDGES = (0.0, 0.05, 0.10, 0.15, 0.20)
#: grid period bins of the gain recovery, s
PERIOD_EDGES = (0.2, 0.4)


def _level_bin(level: np.ndarray) -> np.ndarray:
    """Index into ``level_labels()``: 0 for zero noise, then (0, 5%], (5, 10%], ..."""
    b = np.searchsorted(np.asarray(LEVEL_EDGES[1:]), level, side="left") + 1
    return np.where(level <= 0.0, 0, np.minimum(b, len(LEVEL_EDGES) - 1))


def level_labels() -> list[str]:
    """Names of the noise level bins, fractions of the cycle amplitude a0 as percent."""
    lab = ["0"]
    for lo, hi in zip(LEVEL_EDGES[:-1], LEVEL_EDGES[1:], strict=True):
        lab.append(f"({100 * lo:g}%, {100 * hi:g}%]")
    return lab


def _plan(ds):
    """The recipe's plan as the generator made it (UserError when the grid changed since)."""
    from uavsim.data.plan import load_family_grid, make_plan
    from uavsim.data.recipe import parse_recipe

    a = ds.attrs
    recipe = parse_recipe(a["recipe"], f"{ds.path} (recipe attribute)", ds.path.stem)
    grid = load_family_grid(recipe)
    if (grid.hash or "") != a["grid_hash"]:
        raise UserError(f"dataset {ds.path}: the {recipe.loop} grid changed since the file was made (grid hash "
                        f"{a['grid_hash'][:12]} in the file, {(grid.hash or '')[:12]} now): its plan cannot be rebuilt")
    return make_plan(recipe, grid, a.get("att_class")), recipe


def refused(ds) -> dict:
    """Plan episodes missing from the file, by noise kind and level bin (module docstring)."""
    plan, recipe = _plan(ds)
    n_train = plan.n_train or plan.n
    kept = np.zeros(plan.n, dtype=bool)
    kept[np.asarray(ds.episode, dtype=np.int64)] = True
    train = np.arange(plan.n) < n_train
    kinds = list(recipe.noise.kinds)
    lb = _level_bin(np.asarray(plan.noise_level, float))
    labels = level_labels()
    by_level = []
    for i, name in enumerate(labels):
        m = train & (lb == i)
        if m.any():
            by_level.append({"level": name, "planned": int(m.sum()), "missing": int((m & ~kept).sum()),
                             "share": float((m & ~kept).sum() / m.sum())})
    by_kind = []
    for k, name in enumerate(kinds):
        m = train & (np.asarray(plan.noise_kind) == k)
        if m.any():
            by_kind.append({"kind": name, "planned": int(m.sum()), "missing": int((m & ~kept).sum()),
                            "share": float((m & ~kept).sum() / m.sum())})
    return {"planned": int(train.sum()), "missing": int((train & ~kept).sum()),
            "n_rejected": int(ds.attrs["n_rejected"]), "n_diverged": int(ds.attrs["n_diverged"]),
            "by_level": by_level, "by_kind": by_kind}


def lengthening(ds) -> list[dict]:
    """Median period over the class's grid period (and over its control-rate cycle) by noise kind."""
    ct = ds.class_table
    lab = np.asarray(ds.labels)
    ratio = np.asarray(ds.period, float) / np.asarray(ct["period"], float)[lab]
    sim = np.asarray(ds.period, float) / np.asarray(ct["period_sim"], float)[lab] if "period_sim" in ct else None
    rows = []
    for k, name in enumerate(ds.noise_kinds):
        m = np.asarray(ds.noise_kind) == k
        if m.any():
            row = {"kind": name, "episodes": int(m.sum()), "period_over_grid_median": float(np.median(ratio[m]))}
            if sim is not None:
                row["period_over_period_sim_median"] = float(np.median(sim[m]))
            rows.append(row)
    return rows


def reference_cycle(ds) -> dict:
    """The classes' cycle at the control rate over the grid's (module docstring); {} without it."""
    ct = ds.class_table
    if "period_sim" not in ct or "amplitude_sim" not in ct:
        return {}
    out = {}
    for name, sim, grid in (("period", "period_sim", "period"), ("amplitude", "amplitude_sim", "amplitude")):
        r = np.asarray(ct[sim], float) / np.asarray(ct[grid], float) - 1.0
        k = int(np.nanargmax(r))
        out[name] = {"median": float(np.nanmedian(r)), "max": float(r[k]), "label_of_max": k,
                     "grid_class_of_max": int(ct["grid_index"][k]) if "grid_index" in ct else None,
                     f"{sim}_of_max": float(ct[sim][k]), f"{grid}_of_max": float(ct[grid][k])}
    return out


def gain_recovery(ds) -> list[dict]:
    """``|K_hat / K - 1|`` at zero noise and small bias, by the class's grid period (module docstring)."""
    ct = ds.class_table
    if "amplitude_sim" not in ct:
        raise UserError(f"dataset {ds.path}: no classes/amplitude_sim (made before the class cycle at the control rate)")
    h = float(ds.attrs["h"])
    lab = np.asarray(ds.labels)
    m = (np.asarray(ds.noise_level) == 0) & (np.abs(np.asarray(ds.bias)) < 0.05 * h)
    err = np.abs(np.asarray(ds.amplitude, float) / h / np.asarray(ct["amplitude_sim"], float)[lab]
                 / np.asarray(ds.K, float) - 1.0)
    P = np.asarray(ct["period"], float)[lab]
    rows = []
    edges = (0.0, *PERIOD_EDGES, np.inf)
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        s = m & (P >= lo) & (P < hi)
        name = f"< {hi:g} s" if lo == 0 else (f"> {lo:g} s" if not np.isfinite(hi) else f"{lo:g}-{hi:g} s")
        row = {"grid_period": name, "episodes": int(s.sum())}
        if s.any():
            row.update(median=float(np.median(err[s])), p95=float(np.percentile(err[s], 95)))
        rows.append(row)
    return rows


def figures(path: str | Path) -> dict:
    """All three figures of one file."""
    from uavsim.data.h5 import open_dataset

    ds = open_dataset(path)
    return {"file": str(path), "loop": ds.attrs["loop"], "episodes": ds.n, "refused": refused(ds),
            "lengthening": lengthening(ds), "reference_cycle": reference_cycle(ds), "gain_recovery": gain_recovery(ds)}


def _markdown(f: dict) -> str:
    r = f["refused"]
    out = [f"{f['file']} ({f['loop']}): {f['episodes']} episodes kept of {r['planned']} planned; "
           f"missing {r['missing']} (file: {r['n_rejected']} rejected, {r['n_diverged']} diverged)", "",
           "| noise level | planned | missing | share |", "| --- | --- | --- | --- |"]
    out += [f"| {x['level']} | {x['planned']} | {x['missing']} | {x['share']:.1%} |" for x in r["by_level"]]
    out += ["", "| noise kind | planned | missing | kept | period / grid period (median) | period / period_sim (median) |",
            "| --- | --- | --- | --- | --- | --- |"]
    le = {x["kind"]: x for x in f["lengthening"]}
    for x in r["by_kind"]:
        y = le.get(x["kind"], {})
        g = y.get("period_over_grid_median")
        s = y.get("period_over_period_sim_median")
        out.append(f"| {x['kind']} | {x['planned']} | {x['missing']} | {y.get('episodes', 0)} | "
                   f"{'-' if g is None else f'{g:.3f}'} | {'-' if s is None else f'{s:.3f}'} |")
    rc = f.get("reference_cycle") or {}
    if rc:
        out += ["", "| class cycle at the control rate over the grid's | median | largest (label, grid class) |",
                "| --- | --- | --- |"]
        for name in ("period", "amplitude"):
            x = rc[name]
            out.append(f"| {name} | {x['median']:+.1%} | {x['max']:+.1%} ({x['label_of_max']}, "
                       f"{x['grid_class_of_max']}) |")
    out += ["", "| grid period | episodes (zero noise, abs(bias) < 0.05 h) | median abs(K_hat/K - 1) | p95 |",
            "| --- | --- | --- | --- |"]
    for x in f["gain_recovery"]:
        med = f"{x['median']:.1%}" if "median" in x else "-"
        p95 = f"{x['p95']:.1%}" if "p95" in x else "-"
        out.append(f"| {x['grid_period']} | {x['episodes']} | {med} | {p95} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m uavsim.results.training_sets", description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+", metavar="DATASET.h5", help="training sets written by `uavsim generate`")
    ap.add_argument("--json", action="store_true", help="one JSON object per file (a list) instead of tables")
    args = ap.parse_args(argv)
    try:
        res = [figures(p) for p in args.files]
    except UserError as exc:
        print(f"python -m uavsim.results.training_sets: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(res, indent=1))
    else:
        print("\n\n".join(_markdown(f) for f in res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
