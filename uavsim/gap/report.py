"""Report folder of the gap workflow: before/after overlays (PNG), a Rerun recording, the answer.

For every run, one PNG overlays the measured output with the session model's
simulation (before) and with the fitted model (after); the window where they
disagree most is shaded. The same series go into ``gap.rrd`` (open with
``rerun gap.rrd``), with the table as a text document. ``gap.json`` holds the
answer and ``model.toml`` the updated model (``[model]`` plus ``[[effects]]``).

    write_report(session, result, "reports/thermal_kf")
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from uavsim.errors import UserError
from uavsim.formats.session import ModelSpec, Session
from uavsim.gap.workflow import GapResult, format_table

__all__ = ["write_report", "model_toml"]

TIMELINE = "time"


def model_toml(result: GapResult) -> str:
    """The updated model as TOML: the ``[model]`` table and one ``[[effects]]`` table per effect."""
    m = result.model
    lines = ["[model]"]
    for k in (f.name for f in dataclasses.fields(ModelSpec)):
        v = getattr(m, k)
        if v is not None:
            lines.append(f"{k} = {float(v)!r}")
    for e in result.effects:
        lines += ["", "[[effects]]", f'name = "{e.name}"']
        lines += [f"{k} = {float(v)!r}" for k, v in e.params.items()]
    return "\n".join(lines) + "\n"


def _plots(session: Session, result: GapResult, folder: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    worst = {}
    for d in result.disagreements:
        worst.setdefault(int(d.run.split(":")[0]), d)
    out = []
    for i, run in enumerate(session.runs):
        fig, ax = plt.subplots(figsize=(10, 3.6))
        t = run.data.t
        ax.plot(t, run.data.y, color="k", lw=1.0, label="measured")
        b, a = result.sims_before[i], result.sims_after[i]
        ax.plot(b.t, b.y, color="tab:red", lw=0.9, alpha=0.8, label="model (before)")
        if result.effect != "none":
            ax.plot(a.t, a.y, color="tab:blue", lw=0.9, alpha=0.8, label=f"model + {result.effect} (after)")
        if i in worst:
            w = worst[i].window_s
            ax.axvspan(w[0], w[1], color="orange", alpha=0.2, label=f"worst: {worst[i].feature} z={worst[i].z:.1f}")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("y")
        ax.set_title(f"run {i}: {run.spec.file} ({run.spec.kind})")
        ax.legend(loc="upper right", fontsize=8)
        fig.tight_layout()
        p = folder / f"run{i}_{Path(run.spec.file).stem}.png"
        fig.savefig(p, dpi=90)
        plt.close(fig)
        out.append(p)
    return out


def _recording(session: Session, result: GapResult, path: Path) -> None:
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    import rerun as rr

    rec = rr.RecordingStream("uavsim_gap", send_properties=False)
    rec.set_sinks(rr.FileSink(str(path)))

    def series(name: str, t: np.ndarray, v: np.ndarray) -> None:
        ok = np.isfinite(v)
        if ok.any():
            rec.send_columns(name, indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(t, float)[ok])],
                             columns=rr.Scalars.columns(scalars=np.asarray(v, float)[ok]))  # fmt: skip

    for i, run in enumerate(session.runs):
        stem = f"run{i}_{Path(run.spec.file).stem}"
        series(f"{stem}/measured", run.data.t, run.data.y)
        series(f"{stem}/before", result.sims_before[i].t, result.sims_before[i].y)
        series(f"{stem}/after", result.sims_after[i].t, result.sims_after[i].y)
        series(f"{stem}/u_measured", run.data.t, run.data.u)
    rec.log("summary", rr.TextDocument("```\n" + format_table(result) + "\n```", media_type=rr.MediaType.MARKDOWN),
            static=True)  # fmt: skip
    rec.flush()
    rec.disconnect()


def write_report(session: Session, result: GapResult, folder: str | Path) -> Path:
    """Write the report folder (created if missing) and return its path."""
    f = Path(folder)
    if f.exists() and not f.is_dir():
        raise UserError(f"{f}: exists and is not a folder")
    f.mkdir(parents=True, exist_ok=True)
    _plots(session, result, f)
    _recording(session, result, f / "gap.rrd")
    (f / "gap.json").write_text(json.dumps(result.to_json(), indent=1) + "\n")
    (f / "model.toml").write_text(model_toml(result))
    (f / "table.txt").write_text(format_table(result) + "\n")
    return f
