"""Benchmark: the gap workflow on hidden-effect sessions (``uavsim bench gap``).

Each session is drawn by :func:`uavsim.gap.hidden.hidden_session` (random
loop, random base model from the paper's box, one random effect of the
vocabulary or none, random magnitude) and flown on the MuJoCo loop; the
workflow sees the session only (the truth stays in the benchmark). Printed:
the confusion matrix (rows: truth, columns: answer), the share named
correctly, ``none`` on the sessions without an effect, parameter recovery
(share of correctly named sessions within 30% of the truth), the gap ratio
``gap_after / gap_before`` when an effect is named, and seconds per session.

    uavsim bench gap --sessions 60 --seed 0 --json > gap.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from uavsim.cli._common import eprint, print_json
from uavsim.gap.hidden import HIDDEN_EFFECTS, hidden_session
from uavsim.gap.iterate import analyse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("gap", help="gap workflow on hidden-effect sessions: confusion matrix",
                       description=__doc__.split("\n\n")[0])  # fmt: skip
    p.add_argument("--sessions", type=int, default=60, help="number of sessions (default 60)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first session (session i uses seed + i)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--log", metavar="FILE", help="append one JSON line per session to FILE")
    p.add_argument("--identified", action="store_true", help="drop each session's [model]: the workflow identifies "
                   "the base model from the relay run, as `uavsim gap` does for a user")
    p.add_argument("--models", metavar="DIR", help="networks for --identified (default: uavsim identify's)")
    p.set_defaults(func=main)


def one(seed: int, identified: bool = False, models: str | None = None) -> dict:
    """Draw, fly and analyse one hidden-effect session (``uavsim gap``'s path, one effect); return its record."""
    session, truth = hidden_session(seed)
    if identified:
        session.model = None
    t0 = time.perf_counter()
    flow = analyse(session, models=models, seed=seed, max_effects=1)
    r = flow.final
    sec = time.perf_counter() - t0
    err = None
    if r.effect == truth.effect and truth.params:
        k = next(iter(truth.params))
        err = abs(r.params[k] - truth.params[k]) / abs(truth.params[k])
    return {
        "seed": seed, "loop": truth.loop, "truth": truth.effect, "truth_params": truth.params,
        "answer": r.effect, "params": r.params, "param_rel_err": err,
        "gap_before": r.gap_before, "gap_after": r.gap_after, "seconds": sec, "kind": flow.answer,
        "base_source": flow.base_source,
    }  # fmt: skip


def summarize(records: list[dict]) -> dict:
    """Confusion matrix and the issue's figures from per-session records (e.g. a ``--log`` file's lines)."""
    names = list(HIDDEN_EFFECTS)
    M = np.zeros((len(names), len(names)), dtype=int)
    for r in records:
        M[names.index(r["truth"]), names.index(r["answer"])] += 1
    n = len(records)
    correct = sum(r["truth"] == r["answer"] for r in records)
    nones = [r for r in records if r["truth"] == "none"]
    named = [r for r in records if r["truth"] == r["answer"] and r["truth"] != "none"]
    within = [r for r in named if r["param_rel_err"] is not None and r["param_rel_err"] <= 0.30]
    answered = [r for r in records if r["answer"] != "none"]
    ratios = [r["gap_after"] / r["gap_before"] for r in answered]
    secs = [r["seconds"] for r in records]
    return {
        "sessions": n,
        "labels": names,
        "confusion": M.tolist(),
        "named_correctly": correct / n if n else float("nan"),
        "none_on_none": (sum(r["answer"] == "none" for r in nones) / len(nones)) if nones else None,
        "param_within_30pct": (len(within) / len(named)) if named else None,
        "gap_ratio_max": max(ratios) if ratios else None,
        "gap_ratio_median": float(np.median(ratios)) if ratios else None,
        "gap_ratio_le_third": (sum(x <= 1 / 3 for x in ratios) / len(ratios)) if ratios else None,
        "seconds_mean": float(np.mean(secs)) if secs else None,
        "seconds_max": float(np.max(secs)) if secs else None,
        "records": records,
    }


def format_summary(s: dict) -> str:
    names = s["labels"]
    short = [n[:6] for n in names]
    w = max(len(n) for n in names) + 1
    lines = ["truth \\ answer".ljust(w) + "".join(f"{x:>7}" for x in short)]
    for name, row in zip(names, s["confusion"], strict=True):
        lines.append(name.ljust(w) + "".join(f"{v:>7}" for v in row))
    f = lambda v: "n/a" if v is None else f"{v:.3f}"  # noqa: E731
    lines += [
        "",
        f"sessions {s['sessions']}; named correctly {f(s['named_correctly'])}; none on none {f(s['none_on_none'])}",
        f"parameters within 30% (correctly named effects) {f(s['param_within_30pct'])}",
        f"gap_after/gap_before when named: median {f(s['gap_ratio_median'])}, max {f(s['gap_ratio_max'])}, "
        f"share <= 1/3 {f(s['gap_ratio_le_third'])}",
        f"seconds per session: mean {f(s['seconds_mean'])}, max {f(s['seconds_max'])}",
    ]
    return "\n".join(lines)


def main(args: argparse.Namespace) -> int:
    records = []
    for i in range(args.sessions):
        rec = one(args.seed + i, args.identified, args.models)
        records.append(rec)
        eprint(f"[{i + 1}/{args.sessions}] seed {rec['seed']} {rec['loop']}: truth {rec['truth']} "
               f"answer {rec['answer']} gap {rec['gap_before']:.2f}->{rec['gap_after']:.2f} {rec['seconds']:.0f}s")  # fmt: skip
        if args.log:
            with open(args.log, "a") as fh:
                fh.write(json.dumps(rec) + "\n")
    s = summarize(records)
    if args.json:
        print_json(s)
    else:
        print(format_summary(s), file=sys.stdout)
    return 0
