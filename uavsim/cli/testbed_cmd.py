"""``uavsim testbed``: "measured" sessions from a richer vehicle the workflow does not simulate.

``sessions`` flies the testbed vehicle (``uavsim.testbed``) for each seed and
writes ``DIR/tb_NNNNN/`` (a session without ``[model]``) and
``DIR/tb_NNNNN.truth.json`` beside it, plus ``DIR/recipe.json`` (recipe,
seeds, kinds). Same seed and kinds, same bytes. Development seeds 0-999;
held-out seeds 10000-10099 are to be run once. ``equivalence`` measures the
vehicles' relay cycles against their nearest lumped models. ``plan`` prints
what a seed draws, without flying. ``score`` runs the gap workflow on a set
(with the oracle base model, ``true``, and with an identified one,
``identified``) and scores its answers against the truth files.

    uavsim testbed sessions --seeds 0:12 --out out/testbed
    uavsim testbed sessions --seeds 0:40 --out out/tb --kinds single,none --jobs 2
    uavsim testbed equivalence --seeds 0:4 --json
    uavsim testbed score out/testbed --models training/runs --conditions identified --log out/score.jsonl
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from uavsim.cli._common import eprint, print_json, print_table
from uavsim.errors import UserError


def register(subparsers) -> None:
    p = subparsers.add_parser("testbed", help="measured sessions from a richer vehicle (hidden effects, truth files)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="testbed_command", metavar="ACTION")
    sub.required = True
    s = sub.add_parser("sessions", help="fly and write sessions + truth files for a seed range")
    s.add_argument("--seeds", required=True, metavar="A:B", help="seeds A (included) to B (excluded), or one seed N")
    s.add_argument("--out", required=True, metavar="DIR", help="folder for the sessions and truth files")
    s.add_argument("--kinds", default="single,pair,outside,none", metavar="K,K",
                   help="kinds to draw from: single, pair, outside, none (default: all)")
    s.add_argument("--jobs", type=int, default=1, help="sessions flown at once (processes; default 1)")
    s.add_argument("--json", action="store_true", help="print one JSON object (the set's index) on stdout")
    s.set_defaults(func=sessions)
    e = sub.add_parser("equivalence", help="relay cycles of the vehicles against their nearest lumped models")
    e.add_argument("--seeds", default="0:3", metavar="A:B", help="vehicles of these seeds (default 0:3)")
    e.add_argument("--loops", default="altitude,roll,pitch", help="loops to measure (default all three)")
    e.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    e.set_defaults(func=equivalence)
    q = sub.add_parser("plan", help="what a seed draws (kind, loop, effects, lumped equivalent), without flying")
    q.add_argument("--seeds", required=True, metavar="A:B")
    q.add_argument("--kinds", default="single,pair,outside,none", metavar="K,K")
    q.add_argument("--json", action="store_true")
    q.set_defaults(func=plan)
    c = sub.add_parser("score", help="the gap workflow on a set of sessions, scored against the truth files")
    c.add_argument("set", help="folder written by `uavsim testbed sessions` (with --summarize: a --log file)")
    c.add_argument("--models", help="network root for identification (default: uavsim's default)")
    c.add_argument("--conditions", default="true,identified",
                   help="base model: true (the truth's lumped equivalent), identified (default: both)")
    c.add_argument("--log", metavar="FILE", help="append one JSON line per session and condition")
    c.add_argument("--seed", type=int, default=0, help="seed of the workflow's simulated noise (default 0)")
    c.add_argument("--threads", type=int, default=0, help="MuJoCo threads (default: all CPUs the process may use)")
    c.add_argument("--summarize", action="store_true", help="print the tables of a --log file given as SET")
    c.add_argument("--screen-classes", action="store_true",
                   help="identified base models: refit from the best-flying class (`uavsim gap --screen-classes`)")
    c.set_defaults(func=score)


def _one(args: tuple[int, str, tuple[str, ...]]) -> dict:
    from uavsim.testbed.sessions import (
        NoSession,
        plan_session,
        session_name,
        testbed_session,
        write_testbed,
    )

    seed, out, kinds = args
    t0 = time.perf_counter()
    try:
        session, truth = testbed_session(seed, kinds)
    except NoSession as exc:
        # no log to analyse: said and left out of the set, not redrawn (the seed keeps its place)
        p = plan_session(seed, kinds)
        return {"name": session_name(seed), "seed": seed, "kind": p.kind, "loop": p.loop,
                "effects": "+".join(e.name for e in p.effects) or "none", "runs": 0, "not_oscillating": 0, "crashed": True,
                "seconds": round(time.perf_counter() - t0, 1), "no_session": str(exc)}  # fmt: skip
    write_testbed(session, truth, Path(out) / session_name(seed))
    return {"name": truth.name, "seed": seed, "kind": truth.kind, "loop": truth.loop,
            "effects": "+".join(truth.effect_names), "runs": len(session.runs),
            "not_oscillating": sum(1 for r in truth.runs if r.get("oscillates") is False),
            "crashed": any(r["crashed"] for r in truth.runs), "seconds": round(time.perf_counter() - t0, 1)}


def _progress(i: int, n: int, r: dict) -> str:
    what = f"no session: {r['no_session']}" if r.get("no_session") else f"{r['kind']} {r['loop']}: {r['effects']}"
    return f"[{i + 1}/{n}] {r['name']} {what} ({r['seconds']} s)"


def sessions(args: argparse.Namespace) -> int:
    from uavsim.testbed.sessions import DEV_SEEDS, HELDOUT_SEEDS, RECIPE, parse_kinds, parse_seeds

    seeds = parse_seeds(args.seeds)
    kinds = parse_kinds(args.kinds)
    if args.jobs < 1:
        raise UserError(f"--jobs must be >= 1, got {args.jobs}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    work = [(s, str(out), kinds) for s in seeds]
    rows = []
    if args.jobs == 1:
        for i, w in enumerate(work):
            rows.append(_one(w))
            eprint(_progress(i, len(work), rows[-1]))
    else:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.jobs) as ex:
            for i, r in enumerate(ex.map(_one, work)):
                rows.append(r)
                eprint(_progress(i, len(work), r))
    recipe = {"recipe": RECIPE, "seeds": [seeds.start, seeds.stop], "kinds": list(kinds),
              "dev_seeds": [DEV_SEEDS.start, DEV_SEEDS.stop], "heldout_seeds": [HELDOUT_SEEDS.start, HELDOUT_SEEDS.stop],
              "sessions": [r["name"] for r in rows if not r.get("no_session")],
              "no_session": {r["name"]: r["no_session"] for r in rows if r.get("no_session")}}  # fmt: skip
    (out / "recipe.json").write_text(json.dumps(recipe, indent=1) + "\n")
    if args.json:
        print_json({**recipe, "index": rows})
    else:
        print_table(rows)
    return 0


def equivalence(args: argparse.Namespace) -> int:
    from uavsim.testbed.equivalence import measure_equivalence
    from uavsim.testbed.sessions import parse_seeds
    from uavsim.testbed.vehicle import TESTBED_LOOPS

    seeds = parse_seeds(args.seeds)
    loops = tuple(x.strip() for x in args.loops.split(",") if x.strip())
    bad = [x for x in loops if x not in TESTBED_LOOPS]
    if not loops or bad:
        raise UserError(f"--loops: expected a subset of {','.join(TESTBED_LOOPS)}, got {args.loops!r}")
    rows = []
    for s in seeds:
        rows += measure_equivalence(s, loops)
        eprint(f"vehicle of seed {s} measured")
    if args.json:
        print_json({"rows": rows})
    else:
        cols = ["seed", "loop", "K", "T_prop", "T1", "tau", "period_err", "amp_err", "amp_true_err", "K_fit_err",
                "tau_fit", "tau_fit_true_output", "gain_err_b030", "phase_err_b030_deg"]
        print_table(rows, cols)
    return 0


def plan(args: argparse.Namespace) -> int:
    from uavsim.testbed.sessions import parse_kinds, parse_seeds, plan_session

    kinds = parse_kinds(args.kinds)
    rows = []
    for s in parse_seeds(args.seeds):
        p = plan_session(s, kinds)
        rows.append({"seed": s, "kind": p.kind, "loop": p.loop,
                     "effects": "; ".join(f"{e.name} {e.params}" for e in p.effects) or "none",
                     **{k: round(v, 4) for k, v in p.nominal.items()}, "period_s": round(p.scales.period_s, 3),
                     "h": round(p.h, 4)})  # fmt: skip
    if args.json:
        print_json({"plans": rows})
    else:
        print_table(rows)
    return 0


def score(args: argparse.Namespace) -> int:
    from uavsim.testbed.score import parse_conditions, score_set, summarize_log, summary

    if args.summarize:
        print(summarize_log(args.set))
        return 0
    conditions = parse_conditions(args.conditions)
    records = score_set(args.set, models=args.models, conditions=conditions, log=args.log, seed=args.seed,
                        nthread=args.threads, screen=args.screen_classes)
    print(summary(records))
    return 0
