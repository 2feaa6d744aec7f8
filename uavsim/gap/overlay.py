"""Report folder of the iterated gap workflow: overlays for every run, the ranking, the residual.

``write_flow_report`` writes, next to the single search's report
(:func:`uavsim.gap.report.write_report` of the final model: ``gap.rrd``,
``gap.json``, ``model.toml``):

* ``overlay_runN_<file>.png`` per run: measured, base model (before) and final
  model (after) in time on top; below, for relay runs their mean cycles
  (phase-aligned), for steps measured minus before and minus after;
* ``ranking.png``: every search's candidates by gap, with ``none`` and the
  naming line (the gap times ``1 - NAME_SHARE``);
* ``flow.json`` (:meth:`FlowResult.to_json`) and ``flow.txt``
  (:func:`uavsim.gap.iterate.format_flow`), the residual's character included.

    flow = analyse(session, log=print)
    write_flow_report(flow, "reports/tb_00011")
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from uavsim.gap.features import run_features
from uavsim.gap.iterate import NAME_SHARE, FlowResult, format_flow
from uavsim.gap.report import write_report

__all__ = ["write_flow_report"]


def _overlays(flow: FlowResult, folder: Path, plt) -> list[Path]:
    session, final = flow.session, flow.final
    before = flow.sims_before or flow.steps[0].sims_before
    label = " + ".join(e.name for e in flow.found) or "no effect"
    out = []
    for i, run in enumerate(session.runs):
        fig, (ax, ar) = plt.subplots(2, 1, figsize=(10, 6.0), gridspec_kw={"height_ratios": [3, 2]})
        t, y = run.data.t, run.data.y
        b, a = before[i], final.sims_after[i]
        ax.plot(t, y, color="k", lw=1.0, label="measured")
        ax.plot(
            b.t, b.y, color="tab:red", lw=0.9, alpha=0.8, label=f"base model ({flow.base_source})"
        )
        if flow.found:
            ax.plot(a.t, a.y, color="tab:blue", lw=0.9, alpha=0.8, label=f"+ {label}")
        ax.set_ylabel("y")
        ax.set_title(f"run {i}: {run.spec.file} ({run.spec.kind})   answer: {flow.answer}")
        ax.legend(loc="upper right", fontsize=8)
        _lower(ar, run, b, a if flow.found else None)
        out.append(_save(fig, folder / f"overlay_run{i}_{Path(run.spec.file).stem}.png", plt))
    return out


def _lower(ar, run, b, a) -> None:
    """Relay runs: the mean cycles (phase-aligned on the relay's rising switch, so a drift of the
    cycles' timing does not swamp the shape); steps: measured minus simulated in time."""
    t, y = run.data.t, run.data.y
    fm = run_features(run.spec, t, y, run.data.u)
    sims = [
        (s, c, lab)
        for s, c, lab in ((b, "tab:red", "before"), (a, "tab:blue", "after"))
        if s is not None
    ]
    if fm is not None and "_wave" in fm:
        ph = np.arange(fm["_wave"].size) / fm["_wave"].size
        ar.plot(ph, fm["_wave"], color="k", lw=1.0, label="measured")
        for s, c, lab in sims:
            fs = None if s.diverged else run_features(run.spec, s.t, s.y, s.u)
            if fs is not None:
                ar.plot(
                    ph,
                    fs["_wave"],
                    color=c,
                    lw=0.9,
                    label=f"{lab} (amplitude x{math.exp(fs['amplitude'] - fm['amplitude']):.2f})",
                )
        ar.set_xlabel("phase of the mean cycle (0 = relay's rising switch)")
        ar.set_ylabel("y / amplitude")
    else:
        for s, c, lab in sims:
            n = min(t.size, s.y.size)
            ar.plot(t[:n], y[:n] - s.y[:n], color=c, lw=0.8, label=f"measured - {lab}")
        ar.set_xlabel("t (s)")
        ar.set_ylabel("residual")
    ar.legend(loc="upper right", fontsize=8)


def _save(fig, path: Path, plt) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _ranking(flow: FlowResult, folder: Path, plt) -> Path:
    k = len(flow.steps)
    fig, axes = plt.subplots(1, k, figsize=(5.5 * k, 3.8), squeeze=False)
    for j, (ax, s) in enumerate(zip(axes[0], flow.steps, strict=True)):
        names = [r["effect"] for r in s.ranking]
        gaps = np.array([r["gap"] for r in s.ranking], dtype=float)
        colors = [
            "tab:green" if n == s.effect and n != "none" else ("0.4" if n == "none" else "tab:gray")
            for n in names
        ]
        ax.barh(range(len(names)), np.where(np.isfinite(gaps), gaps, np.nan), color=colors)
        ax.set_yticks(range(len(names)), names, fontsize=8)
        ax.invert_yaxis()
        ax.axvline(
            (1 - NAME_SHARE) * s.gap_before, color="tab:red", ls="--", lw=0.8, label="naming line"
        )
        ax.set_xlabel("gap (RMS z)")
        ax.set_title(f"search {j + 1}: {s.effect}", fontsize=9)
        ax.legend(fontsize=7, loc="lower right")
    return _save(fig, folder / "ranking.png", plt)


def write_flow_report(flow: FlowResult, folder: str | Path) -> Path:
    """Write the report folder (created if missing) and return its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = write_report(flow.session, flow.final, folder)
    _overlays(flow, f, plt)
    _ranking(flow, f, plt)
    (f / "flow.json").write_text(json.dumps(flow.to_json(), indent=1, default=float) + "\n")
    (f / "flow.txt").write_text(format_flow(flow) + "\n")
    return f
