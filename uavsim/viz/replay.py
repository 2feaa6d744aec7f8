"""Replay a session, a dataset episode or a scenario run in Rerun, relay decisions recomputed.

A relay test is easiest to debug by looking at it: the reference and the
measurement, the command, the error with the switching instants, the extrema
the NP-MRFT accepted and the ``tau_obs`` windows during which it would not
switch, and the phase portrait ``(e, de/dt)`` whose limit cycle should close;
for a simulation also the noise-free output beside the noisy one and the
vehicle itself, its pose and rotor thrusts. This module reads one of three
sources into :class:`uavsim.viz.sources.ReplayRun` (a session folder; a
dataset file, one class and episode, simulated again exactly; a scenario run),
replays every relay run through the project's own
:class:`uavsim.control.relay.NPMRFT` (or :class:`~uavsim.control.relay.MRFT`)
fed with the logged error sample by sample, counts the samples where the
recomputed command differs from the logged ``u`` (a mismatch means the flight
code and the simulator disagree on the controller semantics), and writes
everything to a Rerun recording with a blueprint that lays it out.

Entity layout, per run ``runs/<stem>/``: ``r``, ``y`` (as the controller saw
it), ``y_true`` (noise-free, simulations), ``e``, ``u`` (scalars on the
``time`` timeline, seconds), ``switches`` (e at the samples where ``u``
changes sign), ``extrema`` (accepted extrema, relay runs), ``inhibition`` (1
inside a ``tau_obs`` window after an extremum, else 0; relay runs), ``phase``
(static 2D line strip ``(e, de/dt)``; ``phase/noise_free`` the same of
``r - y_true``), ``signals/<name>`` (other signals:
camera, Kalman filter, target, the file's raw trace), ``world/vehicle`` (the
vehicle's ``Transform3D``, its geometry and ``thrust`` arrows; simulations,
:mod:`uavsim.viz.vehicle3d`), ``world/path`` and ``log`` (text).

    from uavsim.viz.replay import replay
    summary = replay("flights/2024-05-01", "replay.rrd")                 # a session
    summary = replay("datasets/small.h5", "ep.rrd", cls=2, episode=0)    # a dataset episode
    summary = replay("normal-camera-kf.rrd", "run-replay.rrd")           # a scenario run
    summary["runs"][0]["u_mismatch"], summary["runs"][0]["entities"]

From the command line: ``uavsim replay PATH [--class C --episode E] --save replay.rrd``.
"""

from __future__ import annotations

import os
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.control.relay import NPMRFT, READING
from uavsim.control.runs import run_controller
from uavsim.errors import UserError
from uavsim.formats.session import RELAY_KINDS, Run, RunSpec, Session
from uavsim.viz.sources import (
    ReplayRun,
    dataset_runs,
    detect_source,
    entity_stem,
    scenario_runs,
    session_runs,
)

__all__ = ["replay", "replay_session", "recompute_relay", "recompute_relay_e", "phase_portrait", "sign_changes",
           "entity_stem", "APP_ID", "TIMELINE"]

#: Rerun application id of replay recordings.
APP_ID = "uavsim_replay"
#: Name of the timeline (seconds).
TIMELINE = "time"
#: File written in the session folder when neither a file nor a viewer is asked for.
DEFAULT_RRD = "replay.rrd"

@dataclass
class RelayReplay:
    """What the recomputed relay did on a logged error sequence.

    Parameters
    ----------
    u : numpy.ndarray
        Recomputed command, one per sample, (T,).
    switch_idx : numpy.ndarray
        Sample indices where the recomputed relay switched.
    ext_idx, ext_e : numpy.ndarray
        Sample indices and error values of the accepted extrema (the extremum
        in force when the relay switched).
    windows : list of (int, int)
        Inhibition windows ``[k_ext, k_ext + ceil(tau_obs * rate)]`` (sample
        indices, inclusive, clipped to the run) of the accepted extrema.
    n_obs : int
        Observation time in samples, ``ceil(tau_obs * rate)``.
    """

    u: np.ndarray
    switch_idx: np.ndarray
    ext_idx: np.ndarray
    ext_e: np.ndarray
    windows: list[tuple[int, int]] = field(default_factory=list)
    n_obs: int = 0


def make_relay(run: Run, rate_hz: float, reading: int = READING) -> NPMRFT:
    """Build the relay (n=1) that the session says produced ``run``.

    Parameters
    ----------
    run : Run
        A run of kind ``np-mrft`` or ``mrft``.
    rate_hz : float
        Controller rate of the session, Hz.
    reading : int
        The relay reading of the session's format version (``Session.reading``).
    """
    s = run.spec
    if s.kind not in RELAY_KINDS:
        raise UserError(f"{run.spec.file}: run kind {s.kind!r} is not a relay run")
    return run_controller(s, rate_hz, reading=reading)


def _params(run: Run, reading: int) -> dict[str, Any]:
    s = run.spec
    return {"beta": s.beta, "h": s.h, "tau_obs": s.tau_obs, "a_n": s.a_n, "bias": s.bias, "reading": reading}


def _relay(kind: str, p: dict[str, Any], rate_hz: float) -> NPMRFT:
    spec = RunSpec(file="(replay)", kind=kind, beta=p["beta"], h=p["h"], tau_obs=p.get("tau_obs"), a_n=p.get("a_n"),
                   bias=p.get("bias") or 0.0)
    return run_controller(spec, rate_hz, reading=int(p.get("reading", READING)))


def recompute_relay_e(e: np.ndarray, kind: str, params: dict[str, Any], rate_hz: float) -> RelayReplay:
    """Feed an error sequence to a fresh relay, sample by sample.

    Parameters
    ----------
    e : (T,) output units
        The error ``r - y`` the relay saw.
    kind : str
        ``np-mrft`` or ``mrft``.
    params : dict
        ``beta``, ``h`` (command units), ``tau_obs`` (s), ``a_n`` (output units), ``bias`` (command units),
        optionally ``reading`` (the relay reading, default the current one) and ``retunes``, a list of
        ``(sample, tau_obs, a_n)`` settings changes (a dataset episode's refined runs).
    rate_hz : float
        Controller rate, Hz.

    Returns
    -------
    RelayReplay
    """
    relay = _relay(kind, params, rate_hz)
    retunes = {int(k): (tau, a_n) for k, tau, a_n in params.get("retunes") or ()}
    e = np.asarray(e, dtype=np.float64)
    n = e.size
    u = np.empty(n)
    switches: list[int] = []
    ext_idx: list[int] = []
    ext_e: list[float] = []
    for k in range(n):
        if k in retunes:
            relay.retune(tau_obs=retunes[k][0], a_n=retunes[k][1])
        prev_e, prev_k = float(relay.e_ext[0]), int(relay.k_ext[0])
        u[k] = relay(e[k : k + 1])[0]
        if relay.switched[0]:
            switches.append(k)
            ext_idx.append(prev_k)
            ext_e.append(prev_e)
    n_obs = int(relay.n_obs[0])
    windows = [(k, min(k + n_obs, n - 1)) for k in ext_idx]
    return RelayReplay(
        u=u,
        switch_idx=np.asarray(switches, dtype=np.int64),
        ext_idx=np.asarray(ext_idx, dtype=np.int64),
        ext_e=np.asarray(ext_e, dtype=np.float64),
        windows=windows,
        n_obs=n_obs,
    )


def recompute_relay(run: Run, rate_hz: float, reading: int = READING) -> RelayReplay:
    """:func:`recompute_relay_e` on a session relay run (its logged ``r - y``), in the session's ``reading``."""
    make_relay(run, rate_hz, reading)  # refuses non-relay runs
    return recompute_relay_e(run.data.r - run.data.y, run.spec.kind, _params(run, reading), rate_hz)


def sign_changes(u: np.ndarray, offset: float = 0.0) -> np.ndarray:
    """Sample indices ``k >= 1`` where ``u - offset`` changes sign from sample ``k-1``."""
    s = np.sign(np.asarray(u, dtype=np.float64) - offset)
    return np.flatnonzero(s[1:] * s[:-1] < 0) + 1


def phase_portrait(t: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Points ``(e, de/dt)``, shape (n, 2); ``de/dt`` by central differences (one-sided at the ends)."""
    if e.size < 2:
        return np.zeros((e.size, 2))
    return np.column_stack([e, np.gradient(e, t)])


def replay_blueprint(runs: list[ReplayRun]) -> Any:
    """The viewer layout ``replay`` logs for ``runs`` (a ``rerun.blueprint.Blueprint``)."""
    import rerun.blueprint as rrb

    def run_layout(run: ReplayRun) -> Any:
        stem = run.stem
        base = f"/runs/{stem}"
        ys = [f"{base}/y", f"{base}/r"] + ([f"{base}/y_true"] if run.y_true is not None else [])
        ys += [f"{base}/signals/raw_y"] if "raw_y" in run.signals else []
        title = f"{stem}: y (as the controller saw it), y_true (noise-free), r" if run.y_true is not None else \
            f"{stem}: y, r"
        views = [
            rrb.TimeSeriesView(name=title, origin=base, contents=ys),
            rrb.TimeSeriesView(name=f"{stem}: u", origin=base, contents=[f"{base}/u"]),
            rrb.TimeSeriesView(name=f"{stem}: e", origin=base,
                               contents=[f"{base}/e", f"{base}/switches", f"{base}/extrema"]),
        ]
        shares = [3, 2, 3]
        if run.relay is not None:
            views.append(rrb.TimeSeriesView(name=f"{stem}: tau_obs inhibition", origin=base,
                                            contents=[f"{base}/inhibition"]))
            shares.append(1)
        others = [k for k in run.signals if k != "raw_y"]
        if others:
            views.append(rrb.TimeSeriesView(name=f"{stem}: {', '.join(others)}", origin=f"{base}/signals",
                                            contents=[f"{base}/signals/{k}" for k in others]))
            shares.append(2)
        series = rrb.Vertical(*views, row_shares=shares)
        side_views = [rrb.Spatial2DView(name=f"{stem}: phase (e, de/dt)", origin=f"{base}/phase")]
        side_shares = [3]
        if run.qpos is not None:
            side_views.append(rrb.Spatial3DView(name=f"{stem}: vehicle (thrust arrows)", origin=f"{base}/world"))
            side_shares.append(3)
        side_views.append(rrb.TextLogView(name=f"{stem}: log", origin=base, contents=[f"{base}/log"]))
        side_shares.append(1)
        side = rrb.Vertical(*side_views, row_shares=side_shares)
        return rrb.Horizontal(series, side, column_shares=[3, 2], name=stem)

    layouts = [run_layout(r) for r in runs]
    root = layouts[0] if len(layouts) == 1 else rrb.Tabs(*layouts)
    return rrb.Blueprint(root, collapse_panels=False)


def _send_series(rec: Any, path: str, t: np.ndarray, values: np.ndarray) -> int:
    """Scalars on the timeline; non-finite samples are skipped. Returns the rows sent."""
    import rerun as rr

    v = np.asarray(values, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    ok = np.isfinite(v) & np.isfinite(t)
    if not ok.any():
        return 0
    rec.send_columns(
        path,
        indexes=[rr.TimeColumn(TIMELINE, duration=t[ok])],
        columns=rr.Scalars.columns(scalars=v[ok]),
    )
    return int(ok.sum())


_STYLE = {
    "r": ("r", [150, 150, 150], None),
    "y": ("y (as the controller saw it)", [31, 119, 180], None),
    "y_true": ("y_true (noise-free)", [23, 190, 207], None),
    "e": ("e = r - y", [44, 160, 44], None),
    "u": ("u", [214, 39, 40], "StepAfter"),
}


def _log_run(rec: Any, run: ReplayRun) -> dict[str, Any]:
    import rerun as rr

    base = f"runs/{run.stem}"
    t = np.asarray(run.t, dtype=np.float64)
    e = run.r - run.y
    rows: dict[str, int] = {}

    series = [("r", run.r), ("y", run.y), ("e", e), ("u", run.u)]
    if run.y_true is not None and np.shape(run.y_true) == t.shape:
        series.insert(2, ("y_true", run.y_true))
    for name, values in series:
        label, color, interp = _STYLE[name]
        style = rr.SeriesLines(names=label, colors=[color], **({"interpolation_mode": interp} if interp else {}))
        rec.log(f"{base}/{name}", style, static=True)
        rows[f"{base}/{name}"] = _send_series(rec, f"{base}/{name}", t, values)
    for name, values in run.signals.items():
        v = np.asarray(values, dtype=np.float64)
        m = min(v.size, t.size)
        rec.log(f"{base}/signals/{name}", rr.SeriesLines(names=name), static=True)
        rows[f"{base}/signals/{name}"] = _send_series(rec, f"{base}/signals/{name}", t[:m], v[:m])

    relay = run.relay is not None and run.kind in RELAY_KINDS
    bias = float(run.relay.get("bias") or 0.0) if relay else 0.0
    fin = np.isfinite(run.u) & np.isfinite(e)
    sw = sign_changes(np.where(fin, run.u, bias), bias)
    rec.log(
        f"{base}/switches",
        rr.SeriesPoints(
            names="switches (u changes sign)", colors=[230, 230, 230], markers="Cross", marker_sizes=4.0
        ),
        static=True,
    )
    rows[f"{base}/switches"] = _send_series(rec, f"{base}/switches", t[sw], e[sw]) if sw.size else 0

    info: dict[str, Any] = {
        "file": run.info.get("file", run.label),
        "label": run.label,
        "stem": run.stem,
        "kind": run.kind,
        "rows": int(t.size),
        "t0": float(t[0]),
        "t1": float(t[-1]),
        "switches": int(sw.size),
    }
    info.update({k: v for k, v in run.info.items() if k != "file"})

    messages: list[tuple[str, str]] = [
        ("INFO", f"{run.label}: {run.kind} run, {t.size} samples, t = {t[0]:.6g} .. {t[-1]:.6g} s, "
                 f"{sw.size} sign changes of u"),
        *run.notes,
    ]  # fmt: skip
    if relay:
        rep = recompute_relay_e(np.where(fin, e, 0.0), run.kind, run.relay, run.rate_hz)
        p = run.relay
        tol = 1e-9 * max(1.0, abs(p["h"]) + abs(bias))
        bad = np.flatnonzero(fin & (np.abs(rep.u - run.u) > tol))
        info.update(
            extrema=int(rep.ext_idx.size),
            windows=[[float(t[a]), float(t[b])] for a, b in rep.windows],
            n_obs=rep.n_obs,
            u_mismatch=int(bad.size),
            recomputed_switches=int(rep.switch_idx.size),
        )
        rec.log(
            f"{base}/extrema",
            rr.SeriesPoints(
                names="accepted extrema", colors=[255, 127, 14], markers="Circle", marker_sizes=4.0
            ),
            static=True,
        )
        rows[f"{base}/extrema"] = (_send_series(rec, f"{base}/extrema", t[rep.ext_idx], rep.ext_e)
                                   if rep.ext_idx.size else 0)

        inhibit = np.zeros(t.size)
        for a, b in rep.windows:
            inhibit[a : b + 1] = 1.0
        rec.log(
            f"{base}/inhibition",
            rr.SeriesLines(names=f"tau_obs window ({rep.n_obs} samples)", colors=[148, 103, 189],
                           interpolation_mode="StepAfter"),
            static=True,
        )  # fmt: skip
        rows[f"{base}/inhibition"] = _send_series(rec, f"{base}/inhibition", t, inhibit)

        if bad.size:
            messages.append(
                ("WARN", f"{run.label}: recomputed {run.kind} output differs from logged u at {bad.size} of "
                         f"{t.size} samples (first at t = {t[bad[0]]:.6g} s)")
            )  # fmt: skip
        else:
            messages.append(
                ("INFO", f"{run.label}: recomputed {run.kind} output matches logged u at all {int(fin.sum())} "
                         f"samples ({rep.switch_idx.size} switches, {rep.ext_idx.size} accepted extrema)")
            )  # fmt: skip
    else:
        messages.append(("INFO", f"{run.label}: {run.kind} run, no relay to recompute"))

    ok = np.isfinite(e)
    pts = phase_portrait(t[ok], e[ok])
    rec.log(f"{base}/phase", rr.LineStrips2D([pts], colors=[44, 160, 44], radii=-1.0), static=True)
    rows[f"{base}/phase"] = 1  # one static row
    info["phase_points"] = int(pts.shape[0])
    static = [f"{base}/phase"]
    if run.y_true is not None and np.shape(run.y_true) == t.shape:
        # the noise-free cycle: with sensor noise de/dt of the measured e is mostly noise
        e_true = run.r - run.y_true
        okt = np.isfinite(e_true)
        rec.log(f"{base}/phase/noise_free", rr.LineStrips2D([phase_portrait(t[okt], e_true[okt])],
                                                            colors=[23, 190, 207], radii=-1.0), static=True)
        static.append(f"{base}/phase/noise_free")

    if run.qpos is not None and np.shape(run.qpos) == (t.size, 6):
        from uavsim.viz.vehicle3d import log_vehicle

        rf = run.rotor_force if run.rotor_force is not None and np.shape(run.rotor_force) == (t.size, 6) else None
        rows.update(log_vehicle(rec, base, t, run.qpos, rf, timeline=TIMELINE))
        static += [f"{base}/world/vehicle/body", f"{base}/world/vehicle/arms", f"{base}/world/vehicle/rotors",
                   f"{base}/world/path"]
        info["vehicle"] = True
    else:
        info["vehicle"] = False

    rec.send_columns(
        f"{base}/log",
        indexes=[rr.TimeColumn(TIMELINE, duration=np.full(len(messages), float(t[0])))],
        columns=rr.TextLog.columns(text=[m for _, m in messages], level=[lv for lv, _ in messages]),
    )
    rows[f"{base}/log"] = len(messages)
    info["messages"] = [m for _, m in messages]
    info["entities"] = rows
    info["static_entities"] = static
    return info


def viewer_available() -> bool:
    """True when a Rerun viewer executable exists and a display can show it."""
    exe = Path(sys.executable).with_name("rerun")
    if not (exe.is_file() or shutil.which("rerun")):
        return False
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def select_runs(session: Session, run: str | None) -> list[Run]:
    """The runs to replay: all, or the one whose file (or stem) is ``run``.

    Raises
    ------
    UserError
        When ``run`` names no run of the session.
    """
    if run is None:
        return list(session.runs)
    chosen = [
        r
        for r in session.runs
        if run in (r.spec.file, Path(r.spec.file).name, Path(r.spec.file).stem)
    ]
    if not chosen:
        names = ", ".join(r.spec.file for r in session.runs)
        raise UserError(f"no run {run!r} in session {session.path} (runs: {names})")
    return chosen[:1]


def _default_rrd(source: str, path: Path, info: dict[str, Any]) -> Path:
    if source == "session":
        return Path(info["session"]) / DEFAULT_RRD
    if source == "dataset":
        return path.with_name(f"{path.stem}-class{info['class']}-episode{info['episode']}.replay.rrd")
    run_file = Path(info["run_file"])
    return run_file.with_name(run_file.name.removesuffix(".run.npz") + ".replay.rrd")


def replay(
    path: str | os.PathLike,
    rrd_path: str | os.PathLike | None = None,
    *,
    run: str | None = None,
    cls: int | None = None,
    episode: int | None = None,
    spawn: bool = False,
    resimulate: bool = True,
) -> dict[str, Any]:
    """Log a session, a dataset episode or a scenario run to Rerun: save it and/or spawn a viewer.

    Parameters
    ----------
    path : path-like
        A session folder (or its ``session.toml``), a dataset file (``.h5``),
        or a scenario run (its ``.rrd`` with the ``.run.npz`` beside it, or the
        ``.run.npz``); see :func:`uavsim.viz.sources.detect_source`.
    rrd_path : path-like, optional
        File to write. When None and ``spawn`` is False (or no viewer can be
        spawned): ``<session>/replay.rrd``, ``<dataset>-class<C>-episode<E>.replay.rrd``
        or ``<run>.replay.rrd`` beside the source.
    run : str, optional
        Sessions: only this run (file name or stem); scenario runs: only this
        episode (``altitude/relay`` or ``altitude_relay``).
    cls, episode : int, optional
        Datasets only: the label (0..n_classes-1) and the index among its kept
        episodes (default 0 and 0).
    spawn : bool
        Open the Rerun viewer (if it can be started).
    resimulate : bool
        Simulate again where the source allows it (datasets, noise-free
        simulated sessions) for the noise-free output and the vehicle pose.

    Returns
    -------
    dict
        ``source`` (``session``/``dataset``/``scenario``), the source's fields
        (sessions: ``session``, ``loop``, ``control_rate_hz``; datasets:
        ``dataset``, ``class``, ``episode``, ``row``, ``resimulated``, ...;
        scenario runs: ``scenario``, ``run_file``), ``rrd`` (path written or
        None), ``spawned``, ``timeline`` and ``runs``: per run its file or
        label, entity stem, kind, rows, time range (s), switch count, rows per
        temporal entity path (``entities``), its ``static_entities``,
        ``vehicle`` (pose logged) and, for relay runs, the accepted extrema,
        inhibition windows (s) and ``u_mismatch`` (samples where the
        recomputed relay output differs from the logged ``u``).

    Raises
    ------
    UserError
        Unreadable or malformed source, unknown run, class or episode out of
        range, options that do not fit the source, or an unwritable output file.
    """
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    import rerun as rr

    src = Path(path)
    source = detect_source(src)
    if source != "dataset" and (cls is not None or episode is not None):
        raise UserError(f"{src}: --class and --episode choose a dataset episode; this is a {source}")
    if source == "session":
        runs, info = session_runs(src, run, resimulate=resimulate)
    elif source == "dataset":
        if run is not None:
            raise UserError(f"{src}: --run picks a session run or scenario episode; use --class and --episode")
        runs, info = dataset_runs(src, cls or 0, episode or 0, resimulate=resimulate)
    else:
        runs, info = scenario_runs(src, run)
    blueprint = replay_blueprint(runs)

    rec = rr.RecordingStream(APP_ID, send_properties=False)
    sinks: list[Any] = []
    spawned = False
    if spawn and viewer_available():
        try:
            rec.spawn(default_blueprint=blueprint)
            spawned = True
        except Exception:  # no viewer available: fall back to a file
            spawned = False
    out: Path | None = None
    if rrd_path is None and not spawned:
        out = _default_rrd(source, src, info)
    elif rrd_path is not None:
        out = Path(rrd_path)
    if out is not None:
        if out.is_dir():
            raise UserError(f"{out}: is a folder, expected an .rrd file path")
        if not out.parent.is_dir():
            raise UserError(f"{out}: folder {out.parent} does not exist")
        sinks.append(rr.FileSink(str(out)))
        if spawned:
            sinks.append(rr.GrpcSink())
        rec.set_sinks(*sinks, default_blueprint=blueprint)

    infos = [_log_run(rec, r) for r in runs]
    rec.flush()
    rec.disconnect()
    if out is not None and not out.is_file():
        raise UserError(f"{out}: recording was not written")
    return {
        "source": source,
        **{k: v for k, v in info.items() if k != "result"},
        "rrd": str(out) if out is not None else None,
        "spawned": spawned,
        "timeline": TIMELINE,
        "runs": infos,
    }


def replay_session(
    path: str | os.PathLike,
    rrd_path: str | os.PathLike | None = None,
    *,
    run: str | None = None,
    spawn: bool = False,
) -> dict[str, Any]:
    """:func:`replay` of a session folder (refuses other sources).

    Parameters
    ----------
    path : path-like
        Session folder or its ``session.toml``.
    rrd_path : path-like, optional
        File to write (default without a viewer: ``<session>/replay.rrd``).
    run : str, optional
        Replay only this run (its file name or stem).
    spawn : bool
        Open the Rerun viewer (if it can be started).
    """
    if detect_source(path) != "session":
        raise UserError(f"{path}: not a session folder (use uavsim.viz.replay.replay for datasets and scenario runs)")
    return replay(path, rrd_path, run=run, spawn=spawn)
