"""Replay a flight session in Rerun, with the relay's decisions recomputed.

A relay test is easiest to debug by looking at it: the reference and the
measurement, the command, the error with the switching instants, the extrema
the NP-MRFT accepted and the ``tau_obs`` windows during which it would not
switch, and the phase portrait ``(e, de/dt)`` whose limit cycle should close.
This module reads a session (format ``uavsim-session/1``), replays every relay
run through the project's own :class:`uavsim.control.relay.NPMRFT` (or
:class:`~uavsim.control.relay.MRFT`) fed with the logged error sample by
sample, counts the samples where the recomputed command differs from the
logged ``u`` (a mismatch means the flight code and the simulator disagree on
the controller semantics), and writes everything to a Rerun recording with a
blueprint that lays it out.

Entity layout, per run ``runs/<file stem>/``: ``r``, ``y``, ``e``, ``u``
(scalars on the ``time`` timeline, seconds), ``switches`` (e at the samples
where ``u`` changes sign), ``extrema`` (accepted extrema, relay runs),
``inhibition`` (1 inside a ``tau_obs`` window after an extremum, else 0; relay
runs), ``phase`` (static 2D line strip ``(e, de/dt)``) and ``log`` (text).

    from uavsim.viz.replay import replay_session
    summary = replay_session("flights/2024-05-01", "flights/2024-05-01/replay.rrd")
    print(summary["runs"][0]["u_mismatch"])

From the command line: ``uavsim replay flights/2024-05-01 --save replay.rrd``.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.control.relay import MRFT, NPMRFT
from uavsim.errors import UserError
from uavsim.formats.session import Run, Session, read_session

#: Rerun application id of replay recordings.
APP_ID = "uavsim_replay"
#: Name of the timeline (seconds).
TIMELINE = "time"
#: File written in the session folder when neither a file nor a viewer is asked for.
DEFAULT_RRD = "replay.rrd"

_RELAY_KINDS = ("np-mrft", "mrft")


@dataclass
class RelayReplay:
    """What the recomputed relay did on a logged error sequence.

    Parameters
    ----------
    u : numpy.ndarray
        Recomputed command, one per sample.
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


def entity_stem(file: str) -> str:
    """Entity-path-safe stem of a run file (``"a/mrft b.csv"`` -> ``"mrft_b"``)."""
    stem = Path(file).stem or "run"
    return re.sub(r"[^A-Za-z0-9_\-]", "_", stem)


def make_relay(run: Run, rate_hz: float) -> NPMRFT:
    """Build the relay (n=1) that the session says produced ``run``.

    Parameters
    ----------
    run : Run
        A run of kind ``np-mrft`` or ``mrft``.
    rate_hz : float
        Controller rate of the session, Hz.
    """
    s = run.spec
    if s.kind == "mrft":
        return MRFT(s.beta, s.h, rate_hz, 1, bias=s.bias)
    if s.kind == "np-mrft":
        return NPMRFT(s.beta, s.h, s.tau_obs, s.a_n, rate_hz, 1, bias=s.bias)
    raise UserError(f"{run.spec.file}: run kind {s.kind!r} is not a relay run")


def recompute_relay(run: Run, rate_hz: float) -> RelayReplay:
    """Feed the logged error of a relay run to a fresh relay, sample by sample.

    Parameters
    ----------
    run : Run
        A run of kind ``np-mrft`` or ``mrft``.
    rate_hz : float
        Controller rate, Hz.

    Returns
    -------
    RelayReplay
    """
    relay = make_relay(run, rate_hz)
    e = run.data.r - run.data.y
    n = e.size
    u = np.empty(n)
    switches: list[int] = []
    ext_idx: list[int] = []
    ext_e: list[float] = []
    for k in range(n):
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


def sign_changes(u: np.ndarray, offset: float = 0.0) -> np.ndarray:
    """Sample indices ``k >= 1`` where ``u - offset`` changes sign from sample ``k-1``."""
    s = np.sign(np.asarray(u, dtype=np.float64) - offset)
    return np.flatnonzero(s[1:] * s[:-1] < 0) + 1


def phase_portrait(t: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Points ``(e, de/dt)``, shape (n, 2); ``de/dt`` by central differences (one-sided at the ends)."""
    if e.size < 2:
        return np.zeros((e.size, 2))
    return np.column_stack([e, np.gradient(e, t)])


def _blueprint(stems: list[str]) -> Any:
    import rerun.blueprint as rrb

    def run_layout(stem: str) -> Any:
        base = f"/runs/{stem}"
        series = rrb.Vertical(
            rrb.TimeSeriesView(
                name=f"{stem}: y, r", origin=base, contents=[f"{base}/y", f"{base}/r"]
            ),
            rrb.TimeSeriesView(name=f"{stem}: u", origin=base, contents=[f"{base}/u"]),
            rrb.TimeSeriesView(
                name=f"{stem}: e",
                origin=base,
                contents=[f"{base}/e", f"{base}/switches", f"{base}/extrema"],
            ),
            rrb.TimeSeriesView(
                name=f"{stem}: tau_obs inhibition", origin=base, contents=[f"{base}/inhibition"]
            ),
            row_shares=[3, 2, 3, 1],
        )
        side = rrb.Vertical(
            rrb.Spatial2DView(name=f"{stem}: phase (e, de/dt)", origin=f"{base}/phase"),
            rrb.TextLogView(name=f"{stem}: log", origin=base, contents=[f"{base}/log"]),
            row_shares=[3, 1],
        )
        return rrb.Horizontal(series, side, column_shares=[3, 2], name=stem)

    layouts = [run_layout(s) for s in stems]
    root = layouts[0] if len(layouts) == 1 else rrb.Tabs(*layouts)
    return rrb.Blueprint(root, collapse_panels=False)


def _send_series(rec: Any, path: str, t: np.ndarray, values: np.ndarray) -> None:
    import rerun as rr

    rec.send_columns(
        path,
        indexes=[rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=np.float64))],
        columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)),
    )


def _log_run(rec: Any, run: Run, stem: str, rate_hz: float) -> dict[str, Any]:
    import rerun as rr

    d = run.data
    s = run.spec
    base = f"runs/{stem}"
    e = d.r - d.y
    rows: dict[str, int] = {}

    styles = {
        "r": rr.SeriesLines(names="r", colors=[150, 150, 150]),
        "y": rr.SeriesLines(names="y", colors=[31, 119, 180]),
        "e": rr.SeriesLines(names="e = r - y", colors=[44, 160, 44]),
        "u": rr.SeriesLines(names="u", colors=[214, 39, 40], interpolation_mode="StepAfter"),
    }
    for name, values in (("r", d.r), ("y", d.y), ("e", e), ("u", d.u)):
        rec.log(f"{base}/{name}", styles[name], static=True)
        _send_series(rec, f"{base}/{name}", d.t, values)
        rows[f"{base}/{name}"] = int(values.size)

    relay = s.kind in _RELAY_KINDS
    sw = sign_changes(d.u, s.bias if relay else 0.0)
    rec.log(
        f"{base}/switches",
        rr.SeriesPoints(
            names="switches (u changes sign)", colors=[0, 0, 0], markers="Cross", marker_sizes=4.0
        ),
        static=True,
    )
    if sw.size:
        _send_series(rec, f"{base}/switches", d.t[sw], e[sw])
    rows[f"{base}/switches"] = int(sw.size)

    info: dict[str, Any] = {
        "file": s.file,
        "stem": stem,
        "kind": s.kind,
        "rows": int(d.t.size),
        "t0": float(d.t[0]),
        "t1": float(d.t[-1]),
        "switches": int(sw.size),
    }

    messages: list[tuple[str, str]] = [
        ("INFO", f"{s.file}: {s.kind} run, {d.t.size} samples, t = {d.t[0]:.6g} .. {d.t[-1]:.6g} s, "
                 f"{sw.size} sign changes of u"),
    ]  # fmt: skip
    if relay:
        rep = recompute_relay(run, rate_hz)
        tol = 1e-9 * max(1.0, abs(s.h) + abs(s.bias))
        bad = np.flatnonzero(np.abs(rep.u - d.u) > tol)
        info.update(
            extrema=int(rep.ext_idx.size),
            windows=[[float(d.t[a]), float(d.t[b])] for a, b in rep.windows],
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
        if rep.ext_idx.size:
            _send_series(rec, f"{base}/extrema", d.t[rep.ext_idx], rep.ext_e)
        rows[f"{base}/extrema"] = int(rep.ext_idx.size)

        inhibit = np.zeros(d.t.size)
        for a, b in rep.windows:
            inhibit[a : b + 1] = 1.0
        rec.log(
            f"{base}/inhibition",
            rr.SeriesLines(names=f"tau_obs window ({rep.n_obs} samples)", colors=[148, 103, 189],
                           interpolation_mode="StepAfter"),
            static=True,
        )  # fmt: skip
        _send_series(rec, f"{base}/inhibition", d.t, inhibit)
        rows[f"{base}/inhibition"] = int(d.t.size)

        if bad.size:
            messages.append(
                ("WARN", f"{s.file}: recomputed {s.kind} output differs from logged u at {bad.size} of "
                         f"{d.t.size} samples (first at t = {d.t[bad[0]]:.6g} s)")
            )  # fmt: skip
        else:
            messages.append(
                ("INFO", f"{s.file}: recomputed {s.kind} output matches logged u at all {d.t.size} samples "
                         f"({rep.switch_idx.size} switches, {rep.ext_idx.size} accepted extrema)")
            )  # fmt: skip
    else:
        messages.append(("INFO", f"{s.file}: step run, no relay to recompute"))

    pts = phase_portrait(d.t, e)
    rec.log(f"{base}/phase", rr.LineStrips2D([pts], colors=[44, 160, 44], radii=-1.0), static=True)
    rows[f"{base}/phase"] = 1
    info["phase_points"] = int(pts.shape[0])

    rec.send_columns(
        f"{base}/log",
        indexes=[rr.TimeColumn(TIMELINE, duration=np.full(len(messages), float(d.t[0])))],
        columns=rr.TextLog.columns(text=[m for _, m in messages], level=[lv for lv, _ in messages]),
    )
    rows[f"{base}/log"] = len(messages)
    info["messages"] = [m for _, m in messages]
    info["entities"] = rows
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


def replay_session(
    path: str | os.PathLike,
    rrd_path: str | os.PathLike | None = None,
    *,
    run: str | None = None,
    spawn: bool = False,
) -> dict[str, Any]:
    """Log a session to Rerun: save it to ``rrd_path`` and/or spawn a viewer.

    Parameters
    ----------
    path : path-like
        Session folder or its ``session.toml``.
    rrd_path : path-like, optional
        File to write. When None and ``spawn`` is False (or no viewer can be
        spawned), ``<session>/replay.rrd`` is written.
    run : str, optional
        Replay only this run (its file name or stem).
    spawn : bool
        Open the Rerun viewer (if it can be started).

    Returns
    -------
    dict
        ``session``, ``rrd`` (path written or None), ``spawned``, ``timeline``
        and ``runs``: per run its file, entity stem, kind, rows, time range,
        switch count, row count per entity path and, for relay runs, the
        accepted extrema, inhibition windows (s) and ``u_mismatch`` (samples
        where the recomputed relay output differs from the logged ``u``).

    Raises
    ------
    UserError
        Malformed session, unknown run, or an unwritable output file.
    """
    import rerun as rr

    session = read_session(path)
    runs = select_runs(session, run)
    stems: list[str] = []
    for r in runs:
        stem = entity_stem(r.spec.file)
        while stem in stems:
            stem += "_"
        stems.append(stem)
    blueprint = _blueprint(stems)

    rec = rr.RecordingStream(APP_ID, send_properties=False)
    sinks: list[Any] = []
    spawned = False
    if spawn and viewer_available():
        try:
            rec.spawn(default_blueprint=blueprint)
            spawned = True
        except Exception:  # no viewer available: fall back to a file
            spawned = False
    if rrd_path is None and not spawned:
        rrd_path = Path(session.path) / DEFAULT_RRD
    if rrd_path is not None:
        rrd_path = Path(rrd_path)
        if rrd_path.is_dir():
            raise UserError(f"{rrd_path}: is a folder, expected an .rrd file path")
        if not rrd_path.parent.is_dir():
            raise UserError(f"{rrd_path}: folder {rrd_path.parent} does not exist")
        sinks.append(rr.FileSink(str(rrd_path)))
        if spawned:
            sinks.append(rr.GrpcSink())
        rec.set_sinks(*sinks, default_blueprint=blueprint)

    infos = [
        _log_run(rec, r, stem, session.control_rate_hz) for r, stem in zip(runs, stems, strict=True)
    ]
    rec.flush()
    rec.disconnect()
    if rrd_path is not None:
        if not rrd_path.is_file():
            raise UserError(f"{rrd_path}: recording was not written")
    return {
        "session": str(session.path),
        "loop": session.loop,
        "control_rate_hz": session.control_rate_hz,
        "rrd": str(rrd_path) if rrd_path is not None else None,
        "spawned": spawned,
        "timeline": TIMELINE,
        "runs": infos,
    }
