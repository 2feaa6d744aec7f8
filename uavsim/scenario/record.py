"""Rerun recording of a scenario run.

Entities, per episode ``<loop>/<phase>`` (``altitude/relay``,
``altitude/step``, ``test/target-step``, ...): ``r``, ``y`` (as the
controller saw it), ``y_true`` (true position relative to the target),
``y_cam``, ``y_kf``, ``u``, ``target``, ``innovation`` and, in scheduled
episodes, ``schedule`` (1 PBVS, 2 IBVS: the switch is a step in this line) and
``switch`` (text events). Scalars on the ``time`` timeline (s). The result
table is logged as a static text document ``summary``.

    write_recording(result, "run.rrd")
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.errors import UserError

__all__ = ["write_recording", "APP_ID", "TIMELINE"]

APP_ID = "uavsim_scenario"
TIMELINE = "time"


def _series(rec: Any, path: str, t: np.ndarray, v: np.ndarray) -> None:
    import rerun as rr

    v = np.asarray(v, dtype=np.float64)
    ok = np.isfinite(v)
    if not ok.any():
        return
    rec.send_columns(path, indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=np.float64)[ok])],
                     columns=rr.Scalars.columns(scalars=v[ok]))


def write_recording(result: dict[str, Any], path: str | Path, summary_md: str = "") -> Path:
    """Write the episodes of ``result`` (from ``run_scenario``) to an ``.rrd`` file at ``path``."""
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    import rerun as rr

    p = Path(path)
    if p.is_dir():
        raise UserError(f"{p}: is a folder, expected an .rrd file path")
    if not p.parent.is_dir():
        raise UserError(f"{p}: folder {p.parent} does not exist")
    rec = rr.RecordingStream(APP_ID, send_properties=False)
    rec.set_sinks(rr.FileSink(str(p)))
    for name, res in result.get("_episodes", {}).items():
        t = res.t
        for key, arr in (("r", res.r), ("y", res.y), ("y_true", res.y_true), ("u", res.u),
                         ("y_cam", res.y_cam), ("y_kf", res.y_kf), ("target", res.target),
                         ("innovation", res.innovation), ("force", res.force), ("schedule", res.schedule)):
            if arr is not None:
                _series(rec, f"{name}/{key}", t, arr[0])
        if res.schedule is not None:
            sched = res.schedule[0]
            idx = np.flatnonzero(np.diff(sched) != 0) + 1
            for i in idx:
                rec.set_time(TIMELINE, duration=float(t[i]))
                to = "IBVS (schedule 2, camera only)" if sched[i] == 2 else "PBVS (schedule 1, KF)"
                rec.log(f"{name}/switch", rr.TextLog(f"switch to {to}", level="INFO"))
    public = {k: v for k, v in result.items() if not k.startswith("_")}
    text = (summary_md + "\n\n" if summary_md else "") + "```json\n" + json.dumps(public, indent=1, default=str) + "\n```"
    rec.log("summary", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
    rec.flush()
    rec.disconnect()
    if not p.is_file():
        raise UserError(f"{p}: recording was not written")
    return p
