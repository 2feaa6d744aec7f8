"""The gap workflow on testbed sessions, scored against their truth files.

For each session folder of a set written by ``uavsim testbed sessions``:

- ``true``: ``uavsim gap SESSION --model M.toml`` with ``M`` the truth's
  lumped equivalent (K, T_prop, T1, tau at the flight's start) and the hover's
  noise std: the oracle base model, which a user does not have;
- ``identified``: ``uavsim gap SESSION --models MODELS`` on the session as
  flown (no ``[model]``): the workflow identifies the base model from the relay
  run itself, the user's case.

Both call what ``uavsim gap`` calls (``uavsim.gap.iterate.analyse``: base
model, dead runs dropped, effects added one by one, ``named`` / ``none`` /
``absorbed`` / ``unexplained``). One JSON line per session and condition goes to
``--log``; the summary tables (markdown) go to stdout, progress to stderr.
``--summarize LOG`` prints the tables of a logged run with its answers decided
again by today's thresholds (``redecide``).

    uavsim testbed score out/testbed-dev --models training/runs --log out/baseline.jsonl
    uavsim testbed score out/baseline.jsonl --summarize
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from uavsim.errors import UserError
from uavsim.formats.session import ModelSpec, read_session
from uavsim.gap.iterate import (
    BEYOND,
    IDENTIFIED_SEARCHES,
    READ_FROM,
    TAKEN_IN,
    absorbed_by,
    analyse,
    decide,
)

CONDITIONS = ("true", "identified")

#: linear effects an identified linear model can take in (answer ``absorbed`` or ``none`` counts for them)
ABSORBABLE = TAKEN_IN


def truth_label(t: dict) -> str:
    return "+".join(e["name"] for e in t["effects"]) or "none"


def score(t: dict, answer: str, found: list[dict], gb: float, ga: float) -> dict:
    """Right or wrong against the truth file, per kind (the issue's 'done when')."""
    names = [e["name"] for e in t["effects"]]
    got = [f["name"] for f in found]
    kind = t["kind"]
    ratio = ga / gb if gb > 0 else float("nan")
    one_of_two = None
    if kind == "none":
        ok = answer == "none"
    elif kind == "single":
        # the effect and nothing else: a second name beside it is a false one
        ok = got == names or (answer in ("absorbed", "none") and names[0] in ABSORBABLE)
    elif kind == "pair":
        # as for singles: a member a linear identified model takes in may go unnamed (nothing else beside them)
        both = sorted(got) == sorted(names)
        must = {n for n in names if n not in ABSORBABLE}
        ok = must <= set(got) <= set(names) and (bool(got) or answer in ("absorbed", "none"))
        one_of_two = bool(set(got) & set(names))
    else:  # outside: `unexplained`, or the nearest vocabulary effect when it shrinks the gap 3x
        ok = answer == "unexplained" or (answer == "named" and ratio <= 1 / 3)
    err = None
    if kind == "single" and got[:1] == names:
        k = next(iter(t["effects"][0]["params"]))
        if k in found[0]:
            err = abs(found[0][k] - t["effects"][0]["params"][k]) / abs(t["effects"][0]["params"][k])
    return {"ok": bool(ok), "one_of_two": one_of_two, "both_named": both if kind == "pair" else None,
            "param_rel_err": err, "gap_ratio": ratio}


def one(folder: Path, models: str | None, condition: str, seed: int, nthread: int = 0, screen: bool = False) -> dict:
    t = json.loads(Path(str(folder) + ".truth.json").read_text())
    rec = {"name": t["name"], "condition": condition, "kind": t["kind"], "loop": t["loop"], "truth": truth_label(t),
           "truth_params": [e["params"] for e in t["effects"]]}  # fmt: skip
    t0 = time.perf_counter()
    try:
        session = read_session(folder)
        model = None
        if condition == "true":
            lm = t["lumped"]
            model = ModelSpec(K=lm["K"], T_prop=lm["T_prop"], T1=lm["T1"], tau=lm["tau"], noise_std=lm["noise_std"])
        flow = analyse(session, model, models=models, seed=seed, nthread=nthread, screen=screen)
    except UserError as exc:
        rec.update({"answer": "error", "error": str(exc), "ok": False, "seconds": time.perf_counter() - t0})
        return rec
    j = flow.to_json()
    rec.update({"answer": flow.answer, "found": j["found"], "by_level": j["by_level"],
                "from_samples": [d["name"] for d in j["from_samples"]],
                "read_from": {d["name"]: d["evidence"] for d in j["from_samples"]},
                "gap_before": flow.gap_before, "gap_after": flow.gap_after,
                "actuator": session.actuator is not None, "absorbed": flow.absorbed, "moved": flow.moved,
                "dropped": flow.dropped,
                "residual": flow.residual["summary"],
                **{k: flow.residual.get(k) for k in BEYOND}, "third_rise": flow.residual.get("third_rise"),
                "steps": [(s["effect"], round(s["gap_before"], 3), round(s["gap_after"], 3)) for s in j["steps"]],
                "ranking": [(r["effect"], round(r["gap"], 3)) for r in flow.steps[0].ranking[:4]],
                "rankings": [[(r["effect"], r["params"], round(r["gap"], 3)) for r in s.ranking] for s in flow.steps],
                "identified": {k: j["base_model"][k] for k in ("K", "T_prop", "T1", "tau", "noise_std")},
                "identification": ({k: flow.identification.get(k) for k in ("run", "refused_runs", "duty_check", "class",
                                                                   "class_params", "params", "oscillation", "refit",
                                                                   "noise_colour")}
                                   if flow.identification else None),
                "seconds": time.perf_counter() - t0})  # fmt: skip
    rec.update(score(t, flow.answer, j["found"], flow.gap_before, flow.gap_after))
    return rec


def redecide(r: dict) -> dict:
    """A logged record with its answer decided again by ``uavsim.gap.iterate.decide`` (thresholds of today).

    An identified record keeps the effects of its first :data:`uavsim.gap.iterate.IDENTIFIED_SEARCHES`
    searches (and those read off the runs or named from the level), its gap after theirs.
    """
    if r["answer"] == "error":
        return r
    ident = r.get("identification")
    found, gap_after = list(r["found"]), r["gap_after"]
    searched = [s for s in r.get("steps") or [] if s[0] != "none"]
    if ident and len(searched) > IDENTIFIED_SEARCHES:
        later = {s[0] for s in searched[IDENTIFIED_SEARCHES:]}
        found = [f for f in found if f["name"] not in later]
        gap_after = searched[IDENTIFIED_SEARCHES - 1][2]
    # the first search's best candidate, as logged (an identified base model's only)
    best = next((e for e, _ in r.get("ranking") or [] if e != "none"), None) if ident else None
    answer = decide(bool(found), r["gap_before"], r["loop"], beyond=any(bool(r.get(k)) for k in BEYOND),
                    actuator=bool(r.get("actuator")), best=best)
    moved = absorbed_by(ident) if ident else None
    absorbed = r.get("absorbed") if answer == "absorbed" else None
    if answer == "absorbed" and not (absorbed and "best" in absorbed):
        absorbed = {**(absorbed_by(ident, any_move=True) or {"parameter": "tau", "moved_s": 0.0}), "effects": [best]}
    t = truth_of(r)
    return {**r, "answer": answer, "found": found, "gap_after": gap_after, "absorbed": absorbed,
            "moved": moved if answer == "none" else None, **score(t, answer, found, r["gap_before"], gap_after)}


def truth_of(r: dict) -> dict:
    """The truth file's ``kind`` and ``effects`` rebuilt from a logged record (parameters empty where not logged)."""
    if r["kind"] == "none":
        return {"kind": "none", "effects": []}
    names = r["truth"].split("+")
    params = r.get("truth_params") or [{}] * len(names)
    return {"kind": r["kind"], "effects": [{"name": n, "params": p} for n, p in zip(names, params, strict=False)]}


def controls(records: list[dict]) -> dict[str, int]:
    """How many of ``records`` a constant answer gets right: ``{"none": n, "unexplained": n}`` (the same scoring)."""
    return {a: sum(score(truth_of(r), a, [], 1.0, 1.0)["ok"] for r in records) for a in ("none", "unexplained")}


KINDS = ("none", "single", "pair", "outside")
ANSWERS = ("named", "absorbed", "none", "unexplained", "error")


def summary(records: list[dict]) -> str:
    out = []
    for cond in ("true", "identified"):
        rs = [r for r in records if r["condition"] == cond]
        if not rs:
            continue
        out.append(f"\n### base model: {cond}\n")
        out.append("| session | kind | loop | truth | answer | found | gap before -> after | right | s |")
        out.append("|---|---|---|---|---|---|---|---|---|")
        for r in rs:
            found = "; ".join(f["name"] + " " + ", ".join(f"{k} {v:.4g}" for k, v in f.items() if k != "name")
                              + (" (from its level)" if f["name"] in (r.get("by_level") or ()) else "")
                              # logs written before relay reads held staircases only
                              + (f" (off {READ_FROM[(r.get('read_from') or {}).get(f['name'], 'staircase')]})"
                                 if f["name"] in (r.get("from_samples") or ()) else "")
                              for f in r.get("found") or [])  # fmt: skip
            if r["answer"] == "absorbed":
                a = r["absorbed"] or {}
                found = (f"best {a['best']['effect']}, " if "best" in a else "") + f"tau +{a.get('moved_s', 0.0) * 1e3:.1f} ms"
            gap = f"{r['gap_before']:.2f} -> {r['gap_after']:.2f}" if "gap_before" in r else r.get("error", "")
            right = "yes" if r["ok"] else ("one of two" if r.get("one_of_two") else "no")
            out.append(f"| {r['name']} | {r['kind']} | {r['loop']} | {r['truth']} | {r['answer']} | {found} | {gap} | "
                       f"{right} | {r['seconds']:.0f} |")
        out += ["", "| truth \\ answer | " + " | ".join(ANSWERS) + " |", "|---" * (len(ANSWERS) + 1) + "|"]
        for k in KINDS:
            row = [sum(r["kind"] == k and r["answer"] == a for r in rs) for a in ANSWERS]
            if sum(row):
                out.append(f"| {k} ({sum(row)}) | " + " | ".join(str(v) for v in row) + " |")
        by = {}
        for r in rs:
            by.setdefault(r["kind"], []).append(r["ok"])
        errs = [r["param_rel_err"] for r in rs if r.get("param_rel_err") is not None]
        named = [r for r in rs if r["kind"] == "single" and r["ok"] and r["answer"] == "named"]
        # noise named from its level: the model carries the measured noise, so there is no gap to shrink
        by_level = [r for r in named if r.get("by_level")]
        ratios = [r["gap_ratio"] for r in named if not r.get("by_level")]
        shown = [", ".join(f"{x:.2f}" for x in ratios)] if ratios else []
        shown += [f"{len(by_level)} more named from their level, no gap to shrink"] if by_level else []
        secs = [r["seconds"] for r in rs]
        pairs = [r for r in rs if r["kind"] == "pair"]
        out.append("")
        out.append(f"answered right: {sum(r['ok'] for r in rs)}/{len(rs)} ("
                   + ", ".join(f"{k} {sum(v)}/{len(v)}" for k, v in sorted(by.items())) + "); "
                   f"pairs with both named: {sum(bool(r.get('both_named')) for r in pairs)}/{len(pairs)}; "
                   f"singles named with parameter within 30%: {sum(e <= 0.3 for e in errs)}/{len(errs)}; "
                   f"gap after/before <= 1/3 when a single is named: {sum(x <= 1 / 3 for x in ratios)}/{len(ratios)} "
                   f"({'; '.join(shown)}); "
                   f"seconds per session: mean {np.mean(secs):.0f}, max {np.max(secs):.0f}")
        c = controls(rs)
        out.append(f"controls on the same truths: always none {c['none']}/{len(rs)}, "
                   f"always unexplained {c['unexplained']}/{len(rs)}")
    return "\n".join(out)


def parse_conditions(text: str) -> tuple[str, ...]:
    """``"true,identified"`` -> the conditions in order; ``UserError`` on an unknown one."""
    conds = tuple(c.strip() for c in text.split(",") if c.strip())
    bad = [c for c in conds if c not in CONDITIONS]
    if not conds or bad:
        raise UserError(f"--conditions: expected a subset of {','.join(CONDITIONS)}, got {text!r}")
    return conds


def _read_log(path: Path) -> list[dict]:
    """The records of a ``--log`` file; a clear error when it is not one."""
    try:
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a --log file of JSON lines ({exc})") from None


def summarize_log(path: str | Path) -> str:
    """The tables of a ``--log`` file, its answers re-decided with today's thresholds (they are set on these logs)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: not a file (--summarize reads a --log file)")
    return summary([redecide(r) for r in _read_log(path)])


def score_set(folder: str | Path, *, models: str | None = None, conditions: tuple[str, ...] = CONDITIONS,
              log: str | Path | None = None, seed: int = 0, nthread: int = 0, screen: bool = False) -> list[dict]:
    """Run and score every session of a ``uavsim testbed sessions`` folder under each condition.

    One record per session and condition (appended to ``log`` as a JSON line as soon as it is done).
    An interrupted run resumes: sessions and conditions already in ``log`` are read back, not run again.
    ``screen``: identified base models refitted from the best-flying class (``analyse``'s ``screen``).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: not a folder (a set written by `uavsim testbed sessions`)")
    folders = sorted(p for p in folder.iterdir() if p.is_dir() and (p / "session.toml").exists())
    if not folders:
        raise UserError(f"{folder}: no session folders (a set written by `uavsim testbed sessions`)")
    missing = [f.name for f in folders if not Path(str(f) + ".truth.json").is_file()]
    if missing:
        raise UserError(f"{folder}: no truth file beside {missing[0]} ({missing[0]}.truth.json; {len(missing)} missing)")
    done = {(r.get("name"), r.get("condition")): r for r in _read_log(Path(log))} if log and Path(log).exists() else {}
    again = sum((f.name, c) in done for f in folders for c in conditions)
    if again:
        print(f"{log}: {again} sessions and conditions already scored, not run again", file=sys.stderr, flush=True)
    records = []
    for cond in conditions:
        for f in folders:
            if (f.name, cond) in done:
                records.append(done[(f.name, cond)])
                continue
            r = one(f, models, cond, seed, nthread, screen)
            records.append(r)
            print(f"{cond} {r['name']} {r['truth']} -> {r['answer']} {[x['name'] for x in r.get('found') or []]} "
                  f"({r['seconds']:.0f} s)", file=sys.stderr, flush=True)  # fmt: skip
            if log:
                with open(log, "a") as fh:
                    fh.write(json.dumps(r, default=float) + "\n")
    return records
