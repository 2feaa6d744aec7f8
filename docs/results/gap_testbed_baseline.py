"""Today's gap workflow on testbed sessions: with the vehicle's lumped equivalent, and with an identified model.

For each session folder of a set written by ``uavsim testbed sessions``:

- ``true``: ``uavsim gap SESSION --model M.toml`` with ``M`` the truth's
  lumped equivalent (K, T_prop, T1, tau at the flight's start) and the hover's
  noise std: the oracle base model, which a user does not have;
- ``identified``: a copy of the session, ``uavsim identify COPY --write-model
  --models MODELS`` (the user's case), then ``uavsim gap COPY``.

Both call the same functions as those commands (``uavsim.gap.workflow.run_gap``,
``uavsim.ident.session``). One JSON line per session and condition goes to
``--log``; the summary tables (markdown) go to stdout.

    python docs/results/gap_testbed_baseline.py out/testbed-dev --models training/runs --log out/baseline.jsonl
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from uavsim.errors import UserError
from uavsim.formats.session import ModelSpec, read_session
from uavsim.gap.workflow import run_gap
from uavsim.ident.session import identify_session, write_model


def truth_label(t: dict) -> str:
    return "+".join(e["name"] for e in t["effects"]) or "none"


def score(t: dict, answer: str, params: dict, gb: float, ga: float) -> dict:
    names = [e["name"] for e in t["effects"]]
    kind = t["kind"]
    ratio = ga / gb if gb > 0 else float("nan")
    if kind == "none":
        ok = answer == "none"
    elif kind == "single":
        ok = answer == names[0]
    elif kind == "pair":
        ok = answer in names  # today's workflow names one effect at most
    else:  # outside: the issue accepts the nearest vocabulary effect when it shrinks the gap 3x
        ok = answer != "none" and ratio <= 1 / 3
    err = None
    if kind == "single" and answer == names[0]:
        k = next(iter(t["effects"][0]["params"]))
        if k in params:
            err = abs(params[k] - t["effects"][0]["params"][k]) / abs(t["effects"][0]["params"][k])
    return {"ok": bool(ok), "param_rel_err": err, "gap_ratio": ratio}


def one(folder: Path, models: str | None, condition: str, seed: int) -> dict:
    t = json.loads(Path(str(folder) + ".truth.json").read_text())
    rec = {"name": t["name"], "condition": condition, "kind": t["kind"], "loop": t["loop"], "truth": truth_label(t),
           "truth_params": [e["params"] for e in t["effects"]]}  # fmt: skip
    t0 = time.perf_counter()
    try:
        if condition == "true":
            lm = t["lumped"]
            model = ModelSpec(K=lm["K"], T_prop=lm["T_prop"], T1=lm["T1"], tau=lm["tau"], noise_std=lm["noise_std"])
            res = run_gap(read_session(folder), model=model, seed=seed)
        else:
            with tempfile.TemporaryDirectory() as tmp:
                copy = Path(tmp) / folder.name
                shutil.copytree(folder, copy)
                ans = identify_session(copy, models=models)
                write_model(copy, ans)
                rec["identified"] = {**ans["params"], "noise_std": ans["noise_std"], "class": ans["class"]}
                res = run_gap(read_session(copy), seed=seed)
    except UserError as exc:
        rec.update({"answer": "error", "error": str(exc), "ok": False, "seconds": time.perf_counter() - t0})
        return rec
    rec.update({"answer": res.effect, "params": res.params, "gap_before": res.gap_before, "gap_after": res.gap_after,
                "ranking": [(r["effect"], round(r["score"], 3)) for r in res.ranking[:4]],
                "seconds": time.perf_counter() - t0})  # fmt: skip
    rec.update(score(t, res.effect, res.params, res.gap_before, res.gap_after))
    return rec


def summary(records: list[dict]) -> str:
    out = []
    for cond in ("true", "identified"):
        rs = [r for r in records if r["condition"] == cond]
        if not rs:
            continue
        out.append(f"\n### base model: {cond}\n")
        out.append("| session | kind | loop | truth | answer | params | gap before -> after | ok | s |")
        out.append("|---|---|---|---|---|---|---|---|---|")
        for r in rs:
            par = ", ".join(f"{k} {v:.4g}" for k, v in (r.get("params") or {}).items())
            gap = f"{r['gap_before']:.2f} -> {r['gap_after']:.2f}" if "gap_before" in r else r.get("error", "")
            out.append(f"| {r['name']} | {r['kind']} | {r['loop']} | {r['truth']} | {r['answer']} | {par} | {gap} | "
                       f"{'yes' if r['ok'] else 'no'} | {r['seconds']:.0f} |")
        by = {}
        for r in rs:
            by.setdefault(r["kind"], []).append(r["ok"])
        errs = [r["param_rel_err"] for r in rs if r.get("param_rel_err") is not None]
        named = [r for r in rs if r["kind"] == "single" and r["ok"]]
        ratios = [r["gap_ratio"] for r in named]
        out.append("")
        out.append(f"answered right: {sum(r['ok'] for r in rs)}/{len(rs)} ("
                   + ", ".join(f"{k} {sum(v)}/{len(v)}" for k, v in sorted(by.items())) + "); "
                   f"singles named with parameter within 30%: {sum(e <= 0.3 for e in errs)}/{len(errs)}; "
                   f"gap after/before <= 1/3 when a single is named: {sum(x <= 1 / 3 for x in ratios)}/{len(ratios)}; "
                   f"seconds per session: mean {np.mean([r['seconds'] for r in rs]):.0f}, "
                   f"max {np.max([r['seconds'] for r in rs]):.0f}")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("set", help="folder written by uavsim testbed sessions")
    ap.add_argument("--models", help="network root for identification (default: uavsim's default)")
    ap.add_argument("--conditions", default="true,identified")
    ap.add_argument("--log", help="append one JSON line per session and condition")
    ap.add_argument("--seed", type=int, default=0, help="seed of the workflow's simulated noise")
    args = ap.parse_args()
    folders = sorted(p for p in Path(args.set).iterdir() if p.is_dir() and (p / "session.toml").exists())
    records = []
    for cond in args.conditions.split(","):
        for f in folders:
            r = one(f, args.models, cond, args.seed)
            records.append(r)
            print(f"{cond} {r['name']} {r['truth']} -> {r['answer']} ({r['seconds']:.0f} s)", file=sys.stderr, flush=True)
            if args.log:
                with open(args.log, "a") as fh:
                    fh.write(json.dumps(r, default=float) + "\n")
    print(summary(records))
    return 0


if __name__ == "__main__":
    sys.exit(main())
