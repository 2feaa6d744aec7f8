"""Scenario tables beside the paper's Tables I (altitude) and II (lateral).

    rows = table_rows([result_a, result_b])    # results of ``run_scenario``
    print(format_table(rows))                  # markdown, sim beside paper
"""

from __future__ import annotations

from typing import Any

__all__ = ["PAPER_ALTITUDE", "PAPER_LATERAL", "table_rows", "format_table"]

#: paper Table I: (camera, estimator) -> T_prop, T1, tau_in, Kp, Kd, Q_exp, Q_sim
PAPER_ALTITUDE: dict[tuple[str, str], dict[str, float | None]] = {
    ("normal", "kf"): {"T_prop": 0.30, "T1": 0.20, "tau": 0.0128, "kp": 1.1766, "kd": 0.3143, "Q_exp": 0.0874, "Q_sim": 0.080},
    ("event", "kf"): {"T_prop": 0.30, "T1": 0.20, "tau": 0.0128, "kp": 1.2993, "kd": 0.3471, "Q_exp": 0.0771, "Q_sim": 0.0698},
    ("thermal", "kf"): {"T_prop": 0.1675, "T1": 0.6523, "tau": 0.0048, "kp": 1.7766, "kd": 0.5352, "Q_exp": 0.0933, "Q_sim": 0.0684},
    ("normal", "camera"): {"T_prop": 0.1355, "T1": 1.6825, "tau": 0.06, "kp": 0.3739, "kd": 0.1705, "Q_exp": 0.2174, "Q_sim": 0.1629},
    ("event", "camera"): {"T_prop": 0.0135, "T1": 1.6834, "tau": 0.0237, "kp": 0.888, "kd": 0.3258, "Q_exp": 0.1293, "Q_sim": 0.1068},
    ("thermal", "camera"): {"T_prop": 0.2766, "T1": 2.0059, "tau": 0.0022, "kp": 0.257, "kd": 0.1435, "Q_exp": None, "Q_sim": None},
}
#: paper Table II: (camera, estimator) -> T2, tau_out, Kp, Kd, Q_exp, Q_sim
PAPER_LATERAL: dict[tuple[str, str], dict[str, float | None]] = {
    ("normal", "kf"): {"T2": 0.40, "tau": 0.0825, "kp": 1.4343, "kd": 0.5662, "Q_exp": 0.2608, "Q_sim": 0.2574},
    ("event", "kf"): {"T2": 3.6789, "tau": 0.01, "kp": 1.0155, "kd": 0.5270, "Q_exp": 0.3332, "Q_sim": 0.2556},
    ("thermal", "kf"): {"T2": 0.40, "tau": 0.30, "kp": 0.9089, "kd": 0.4962, "Q_exp": 0.2523, "Q_sim": 0.3580},
    ("normal", "camera"): {"T2": 3.6789, "tau": 0.01, "kp": 0.9403, "kd": 0.488, "Q_exp": 0.3855, "Q_sim": 0.3449},
    ("event", "camera"): {"T2": 3.6789, "tau": 0.01, "kp": 0.8154, "kd": 0.4231, "Q_exp": 0.2479, "Q_sim": 0.1927},
    ("thermal", "camera"): {"T2": 0.40, "tau": 0.30, "kp": 0.3585, "kd": 0.1957, "Q_exp": None, "Q_sim": None},
}


def table_rows(results: list[dict[str, Any]], loop: str = "altitude") -> list[dict[str, Any]]:
    """One row per scenario result that has ``loop``: simulation values and the paper's."""
    paper = PAPER_ALTITUDE if loop == "altitude" else PAPER_LATERAL
    rows = []
    for r in results:
        li = r.get("loops", {}).get(loop)
        if li is None:
            continue
        pp = paper.get((r["camera"], r["estimator"]), {})
        rows.append({
            "sensor": r["camera"], "KF": "with" if r["estimator"] == "kf" else "without",
            "identifier": li.get("identifier"),
            "T_prop": li.get("T_prop"), "T1": li.get("T1"), "T2": li.get("T2"), "tau": li.get("tau"),
            "T0": (li.get("relay") or {}).get("T0"),
            "kp": li["kp"], "kd": li["kd"], "Q_sim": li.get("Q_sim"), "Q_mj": li.get("Q_mj"),
            "paper": pp,
        })
    return rows


def _f(v: Any, nd: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{nd}g}"
    return str(v)


def format_table(rows: list[dict[str, Any]], loop: str = "altitude") -> str:
    """Markdown table: each simulated value with the paper's beside it as ``sim (paper)``."""
    keys = ["T_prop", "T1", "tau"] if loop == "altitude" else ["T2", "tau"]
    keys += ["kp", "kd", "Q_sim"]
    head = ["sensor", "KF", "identifier", "T0 s"] + [k for k in keys] + ["Q_mj (paper Q_exp)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        p = r["paper"]
        cells = [r["sensor"], r["KF"], _f(r["identifier"]), _f(r["T0"], 3)]
        cells += [f"{_f(r[k])} ({_f(p.get(k))})" for k in keys]
        cells.append(f"{_f(r['Q_mj'])} ({_f(p.get('Q_exp'))})")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
