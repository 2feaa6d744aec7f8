"""Rerun recording of a scenario run.

Entities, per episode ``<loop>/<phase>`` (``altitude/relay``,
``altitude/step``, ``test/target-step``, ...): ``r``, ``y`` (as the
controller saw it), ``y_true`` (true position relative to the target),
``y_cam``, ``y_kf``, ``u``, ``target``, ``innovation`` and, in scheduled
episodes, ``schedule`` (1 PBVS, 2 IBVS: the switch is a step in this line) and
``switch`` (text events). Scalars on the ``time`` timeline (s). The result
table is logged as a static text document ``summary``.

Beside the recording, ``write_recording`` also writes the run file
``<name>.run.npz`` (format ``uavsim-scenario-run/1``, :func:`write_run`): the
episodes' arrays at full precision (``t``, ``r``, ``y``, ``y_true``, ``u``,
the vision signals, the vehicle's ``qpos`` and ``rotor_force`` (T, 6)) and a
JSON ``meta`` with the result and each episode's controller (relay ``beta, h,
tau_obs, a_n``; PD gains). ``uavsim replay <name>.rrd`` (or the ``.run.npz``)
replays it (``uavsim.viz.sources``).

    write_recording(result, "run.rrd")          # run.rrd and run.run.npz
    run = read_run("run.run.npz")
    run["episodes"]["altitude/relay"]["y_true"].shape   # (T,)
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.control.relay import READING
from uavsim.errors import UserError
from uavsim.formats.session import MRFT_RUN, NP_MRFT_RUN

__all__ = ["write_recording", "write_run", "read_run", "run_path", "APP_ID", "TIMELINE", "RUN_FORMAT"]

APP_ID = "uavsim_scenario"
TIMELINE = "time"
RUN_FORMAT = "uavsim-scenario-run/1"
#: per-episode arrays of a run file: (T,) signals, then (T, 6) state
RUN_SIGNALS = ("r", "y", "y_true", "u", "y_cam", "y_kf", "target", "innovation", "force", "schedule")
RUN_STATE = ("qpos", "rotor_force")


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
    if result.get("_episodes"):
        write_run(result, run_path(p))
    return p


def run_path(rrd: str | Path) -> Path:
    """The run file written beside a scenario recording: ``x.rrd`` -> ``x.run.npz``."""
    p = Path(rrd)
    return p.with_name(p.stem + ".run.npz")


def _controller(result: dict[str, Any], name: str) -> dict[str, Any]:
    """What closed the loop in episode ``name`` (``<loop>/relay``, ``<loop>/step``, ``test/<kind>``)."""
    head, _, phase = name.partition("/")
    if phase in ("relay", "ibvs_relay"):
        src = (result.get("ibvs") or {}).get(head) if phase == "ibvs_relay" else result["loops"].get(head)
        relay = (src or {}).get("relay") or {}
        np_mrft = (relay.get("tau_obs") or 0) > 0 or (relay.get("a_n") or 0) > 0
        # reading: the relay reading it ran with (uavsim.control.relay; absent in older runs: 1)
        return {"kind": NP_MRFT_RUN if np_mrft else MRFT_RUN, "beta": relay.get("beta"), "h": relay.get("h"),
                "tau_obs": relay.get("tau_obs"), "a_n": relay.get("a_n"), "bias": 0.0, "reading": READING}
    loop = head if head != "test" else (result.get("test") or {}).get("loop")
    gains = result["loops"].get(loop) or {}
    kind = "scheduled-pd" if phase == "target-step" else "pd"
    return {"kind": kind, "kp": gains.get("kp"), "kd": gains.get("kd")}


def write_run(result: dict[str, Any], path: str | Path) -> Path:
    """Write the episodes of ``result`` (from ``run_scenario``) as a run file (``.run.npz``).

    Parameters
    ----------
    result : dict
        ``run_scenario``'s result (its ``_episodes``: ``VisionResult`` with one episode each).
    path : path-like
        The file; written through ``path.partial`` and renamed, so a file at ``path`` is whole.

    Returns
    -------
    Path
        ``path``. Arrays: ``e<i>_<key>``, episode ``i`` of ``meta["episodes"]``:
        ``t`` (T,) s, ``RUN_SIGNALS`` (T,) (output units, command units, N),
        ``RUN_STATE`` (T, 6) (m and rad; N), absent when the episode has none.
    """
    p = Path(path)
    arrays: dict[str, np.ndarray] = {}
    episodes = []
    for i, (name, res) in enumerate(result.get("_episodes", {}).items()):
        arrays[f"e{i}_t"] = np.asarray(res.t, dtype=np.float64)
        keys = []
        for key in (*RUN_SIGNALS, *RUN_STATE):
            arr = getattr(res, key, None)
            if arr is not None:
                arrays[f"e{i}_{key}"] = np.asarray(arr[0], dtype=np.float64)
                keys.append(key)
        loop = name.split("/")[0] if not name.startswith("test/") else (result.get("test") or {}).get("loop")
        episodes.append({"name": name, "loop": loop, "arrays": keys, "controller": _controller(result, name),
                         "diverged": bool(res.diverged[0]), "seed": int(res.seed)})
    public = {k: v for k, v in result.items() if not k.startswith("_")}
    meta = {"format": RUN_FORMAT, "scenario": result.get("scenario"), "episodes": episodes, "result": public}
    arrays["meta"] = np.array(json.dumps(meta, default=str))
    tmp = p.with_name(p.name + ".partial")
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
    tmp.replace(p)
    return p


def read_run(path: str | Path) -> dict[str, Any]:
    """Read a scenario run file: ``{"meta": dict, "episodes": {name: {key: array}}}``.

    Raises
    ------
    UserError
        Not a readable run file (wrong format, missing or inconsistent arrays), naming the file.
    """
    p = Path(path)
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        meta = json.loads(str(data["meta"]))
    except FileNotFoundError:
        raise UserError(f"scenario run {p}: no such file") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise UserError(f"scenario run {p}: not a readable run file ({type(exc).__name__}: {exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != RUN_FORMAT:
        fmt = meta.get("format") if isinstance(meta, dict) else None
        raise UserError(f"scenario run {p}: format is {fmt!r}, expected {RUN_FORMAT!r}")
    episodes: dict[str, dict[str, np.ndarray]] = {}
    for i, ep in enumerate(meta.get("episodes", [])):
        t = data.get(f"e{i}_t")
        if t is None or t.ndim != 1:
            raise UserError(f"scenario run {p}: episode {ep.get('name')!r} has no time column")
        arrs = {"t": t}
        for key in ep.get("arrays", []):
            a = data.get(f"e{i}_{key}")
            want = (t.size, 6) if key in RUN_STATE else (t.size,)
            if a is None or a.shape[0] != t.size or a.ndim != len(want):
                raise UserError(f"scenario run {p}: episode {ep.get('name')!r} array {key} is missing or not "
                                f"{want}")
            arrs[key] = a
        episodes[ep["name"]] = arrs
    return {"meta": meta, "episodes": episodes}
