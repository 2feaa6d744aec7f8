"""The paper's camera trends, checked over several seeds of the six camera scenarios.

One scenario run is one flight: its NP-MRFT sees one draw of the camera's
detection noise, and with the event and thermal cameras without the Kalman
filter (noise 7-9% of the cycle amplitude) the identified model and gains move
from seed to seed (event camera without KF: kp 0.71-1.33 over five seeds). A
trend read off one seed is then a coin toss, so this module runs each scenario
over ``n_seeds`` seeds (the scenario's own seed and the next ones), reports the
median and range of every identified quantity, and checks the paper's trends
(Table I) on the medians and per seed:

* ``delay_larger_without_kf``: per sensor, identified ``tau`` without KF >= with KF;
* ``gains_lower_without_kf``: per sensor, ``kp`` without KF < with KF;
* ``event_beats_normal_without_kf``: flown step ISE ``Q_mj`` of the event camera
  without KF < that of the normal camera without KF;
* ``similar_gains_with_kf``: with KF, max / min of the three sensors' ``kp`` <= 1.5.

    res = camera_trends(["scenarios/normal-camera-kf.toml", ...], n_seeds=5)
    res["trends"]["gains_lower_without_kf"]["median"]     # bool per sensor
"""

from __future__ import annotations

import math
import os
from dataclasses import replace
from typing import Any

import numpy as np

from uavsim.errors import UserError

__all__ = ["QUANTITIES", "SIMILAR_KP_RATIO", "run_seeds", "summarize", "check_trends", "camera_trends", "format_trends"]

#: per-run quantities of the altitude loop that are summarized
QUANTITIES = ("T_prop", "T1", "tau", "kp", "kd", "Q_sim", "Q_mj", "T0")
#: "similar gains": the largest kp over the smallest, with KF
SIMILAR_KP_RATIO = 1.5
_SENSORS = ("normal", "event", "thermal")


def _row(result: dict[str, Any]) -> dict[str, Any]:
    a = result["loops"]["altitude"]
    row = {k: a.get(k) for k in QUANTITIES if k != "T0"}
    row["T0"] = (a.get("relay") or {}).get("T0")
    row["identifier"] = a.get("identifier")
    row["retries"] = len((a.get("relay") or {}).get("retries") or [])
    return row


def run_seeds(files: list[str | os.PathLike], n_seeds: int) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """Run each scenario with seeds ``seed, seed + 1, ...``; rows keyed by ``(camera, estimator)``."""
    from uavsim.scenario.config import load_scenario
    from uavsim.scenario.flow import run_scenario

    if n_seeds < 1:
        raise UserError(f"--seeds must be >= 1, got {n_seeds}")
    out: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for f in files:
        scn = load_scenario(f)
        if "altitude" not in scn.loops or scn.test.kind != "step":
            raise UserError(f"{f}: the camera trends need an altitude step scenario")
        key = (scn.camera.name, scn.estimator)
        if key in out:
            raise UserError(f"{f}: a second scenario for {key[0]} camera, estimator {key[1]}")
        out[key] = []
        scn = replace(scn, loops=["altitude"])  # Table I's trends: the lateral loop would only cost time
        for i in range(n_seeds):
            r = run_scenario(scn, seed=scn.seed + i)
            out[key].append({"seed": scn.seed + i, **_row(r)})
    return out


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Median, min and max of each quantity over the rows that have it; identifiers used."""
    s: dict[str, Any] = {}
    for k in QUANTITIES:
        v = np.array([r[k] for r in rows if r.get(k) is not None and math.isfinite(r[k])], dtype=float)
        s[k] = ({"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max()), "n": int(v.size)}
                if v.size else None)
    s["identifiers"] = sorted({str(r["identifier"]) for r in rows})
    s["retried"] = int(sum(r["retries"] > 0 for r in rows))
    return s


def _med(summary: dict[str, Any], key: tuple[str, str], q: str) -> float:
    v = summary.get(key, {}).get(q)
    return v["median"] if v else math.nan


def check_trends(runs: dict[tuple[str, str], list[dict[str, Any]]]) -> dict[str, Any]:
    """The paper's trends on the medians and the fraction of seeds where each holds (see module doc)."""
    summ = {k: summarize(v) for k, v in runs.items()}
    sensors = [s for s in _SENSORS if (s, "kf") in runs and (s, "camera") in runs]

    def per_seed(fn) -> float | None:
        n = min((len(v) for v in runs.values()), default=0)
        hits = [fn(i) for i in range(n)]
        hits = [h for h in hits if h is not None]
        return float(np.mean(hits)) if hits else None

    def val(key, i, q):
        v = runs[key][i].get(q)
        return None if v is None or not math.isfinite(v) else float(v)

    def cmp(a, b, op):
        return None if a is None or b is None else bool(op(a, b))

    t: dict[str, Any] = {}
    t["delay_larger_without_kf"] = {
        s: {"median": bool(_med(summ, (s, "camera"), "tau") >= _med(summ, (s, "kf"), "tau")),
            "seeds": per_seed(lambda i, s=s: cmp(val((s, "camera"), i, "tau"), val((s, "kf"), i, "tau"),
                                                 lambda a, b: a >= b))}
        for s in sensors}
    t["gains_lower_without_kf"] = {
        s: {"median": bool(_med(summ, (s, "camera"), "kp") < _med(summ, (s, "kf"), "kp")),
            "seeds": per_seed(lambda i, s=s: cmp(val((s, "camera"), i, "kp"), val((s, "kf"), i, "kp"),
                                                 lambda a, b: a < b))}
        for s in sensors}
    if ("event", "camera") in runs and ("normal", "camera") in runs:
        t["event_beats_normal_without_kf"] = {
            "median": bool(_med(summ, ("event", "camera"), "Q_mj") < _med(summ, ("normal", "camera"), "Q_mj")),
            "seeds": per_seed(lambda i: cmp(val(("event", "camera"), i, "Q_mj"), val(("normal", "camera"), i, "Q_mj"),
                                            lambda a, b: a < b))}
    kf = [(s, "kf") for s in _SENSORS if (s, "kf") in runs]
    if len(kf) >= 2:
        meds = [_med(summ, k, "kp") for k in kf]

        def ratio_ok(i):
            v = [val(k, i, "kp") for k in kf]
            return None if any(x is None for x in v) else bool(max(v) / min(v) <= SIMILAR_KP_RATIO)

        t["similar_gains_with_kf"] = {"median": bool(max(meds) / min(meds) <= SIMILAR_KP_RATIO),
                                      "kp_ratio": max(meds) / min(meds), "seeds": per_seed(ratio_ok)}
    return {"summary": {f"{c}/{e}": v for (c, e), v in summ.items()}, "trends": t}


def camera_trends(files: list[str | os.PathLike], n_seeds: int = 5) -> dict[str, Any]:
    """``run_seeds`` then ``check_trends``; also the per-seed rows (``runs``)."""
    runs = run_seeds(files, n_seeds)
    out = check_trends(runs)
    out["runs"] = {f"{c}/{e}": v for (c, e), v in runs.items()}
    out["n_seeds"] = n_seeds
    return out


def format_trends(res: dict[str, Any]) -> str:
    """Markdown: medians [min-max] per scenario with the paper's values, then the trends."""
    from uavsim.scenario.table import PAPER_ALTITUDE

    def cell(s, q):
        v = s.get(q)
        return "-" if not v else f"{v['median']:.4g} [{v['min']:.3g}-{v['max']:.3g}]"

    head = ["sensor", "KF", "identifier", "T0 s", "T_prop", "T1", "tau", "kp", "kd", "Q_sim", "Q_mj",
            "paper T_prop / T1 / tau", "paper kp / kd", "paper Q_exp"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, s in res["summary"].items():
        cam, est = name.split("/")
        p = PAPER_ALTITUDE.get((cam, est), {})
        idents = ", ".join(s["identifiers"]) + (f" ({s['retried']} relay re-runs)" if s["retried"] else "")
        lines.append("| " + " | ".join([cam, "with" if est == "kf" else "without", idents]
                                       + [cell(s, q) for q in ("T0", "T_prop", "T1", "tau", "kp", "kd", "Q_sim", "Q_mj")]
                                       + [f"{p.get('T_prop')} / {p.get('T1')} / {p.get('tau')}",
                                          f"{p.get('kp')} / {p.get('kd')}", str(p.get("Q_exp"))]) + " |")
    lines.append("")
    lines.append(f"trend (median over {res['n_seeds']} seeds; fraction of seeds where it holds):")
    for name, t in res["trends"].items():
        if "median" in t:
            extra = f", kp max/min {t['kp_ratio']:.2f}" if "kp_ratio" in t else ""
            lines.append(f"- {name}: {t['median']} ({_frac(t['seeds'])}{extra})")
        else:
            lines.append(f"- {name}: " + "; ".join(f"{s} {v['median']} ({_frac(v['seeds'])})" for s, v in t.items()))
    return "\n".join(lines)


def _frac(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f}% of seeds"
