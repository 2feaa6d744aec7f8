"""The importer behind ``uavsim session import`` (see ``uavsim.logs``)."""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from uavsim.formats.session import MRFT_RUN, NP_MRFT_RUN, RELAY_BIAS_TRIMS, RELAY_KINDS
from uavsim.logs.errors import LogError, hint

__all__ = ["FORMATS", "PRESETS", "LogError", "hint", "Preset", "FieldSpec", "detect_format", "parse_field", "read_series",
           "sample_on_grid", "detect_relay", "import_log"]

FORMATS = ("ulog", "dataflash", "rosbag")


@dataclass(frozen=True)
class Preset:
    """Where one loop's r, y and u are in one autopilot's log."""

    format: str
    loop: str
    r: str
    y: str
    u: str
    note: str = ""


PRESETS: dict[str, Preset] = {
    "px4-altitude": Preset("ulog", "altitude", "-trajectory_setpoint.position[2]", "-vehicle_local_position.z",
                           "-vehicle_thrust_setpoint.xyz[2]", "NED z negated: up; u = collective thrust, normalized"),
    "px4-roll": Preset("ulog", "roll", "roll(vehicle_attitude_setpoint.q_d)", "roll(vehicle_attitude.q)",
                       "vehicle_torque_setpoint.xyz[0]", "u = roll torque setpoint, normalized"),
    "px4-pitch": Preset("ulog", "pitch", "pitch(vehicle_attitude_setpoint.q_d)", "pitch(vehicle_attitude.q)",
                        "vehicle_torque_setpoint.xyz[1]", "u = pitch torque setpoint, normalized"),
    "ardupilot-altitude": Preset("dataflash", "altitude", "CTUN.DAlt", "CTUN.Alt", "CTUN.ThO",
                                 "u = throttle output 0..1"),
    "ardupilot-roll": Preset("dataflash", "roll", "rad(ATT.DesRoll)", "rad(ATT.Roll)", "RATE.ROut",
                             "ATT in degrees (converted to rad); u = roll rate controller output, normalized"),
    "ardupilot-pitch": Preset("dataflash", "pitch", "rad(ATT.DesPitch)", "rad(ATT.Pitch)", "RATE.POut",
                              "ATT in degrees (converted to rad); u = pitch rate controller output, normalized"),
}


@dataclass(frozen=True)
class FieldSpec:
    """One signal: ``topic``/``field`` in the log and the transform applied (or a constant)."""

    text: str
    topic: str = ""
    field: str = ""
    transform: str = "id"  # id | neg | rad | roll | pitch | const
    constant: float = 0.0

    @property
    def fields(self) -> list[str]:
        """The log fields it needs (a quaternion needs its four)."""
        if self.transform == "const":
            return []
        if self.transform in ("roll", "pitch"):
            return [f"{self.field}[{i}]" for i in range(4)]
        return [self.field]


_WRAP = re.compile(r"^(rad|roll|pitch)\((.+)\)$")


def parse_field(text: str, what: str) -> FieldSpec:
    """Parse a field spec (see ``uavsim.logs``); ``what`` (r, y or u) names it in errors."""
    s = text.strip()
    try:
        return FieldSpec(text, transform="const", constant=float(s))
    except ValueError:
        pass
    transform = "id"
    if s.startswith("-"):
        transform, s = "neg", s[1:].strip()
    m = _WRAP.match(s)
    if m:
        if transform == "neg":
            raise LogError(f"--{what} {text!r}: negate inside the function, e.g. rad(-X) is not supported; use -X or "
                           "rad(X)")
        transform, s = m.group(1), m.group(2).strip()
    if "." not in s.lstrip("/"):
        raise LogError(f"--{what} {text!r}: name a field as TOPIC.FIELD (e.g. vehicle_local_position.z, CTUN.Alt)")
    # ROS topics have slashes and dots may appear in field paths: the topic ends at the first dot after
    # the last slash
    head = s.rfind("/")
    dot = s.index(".", head + 1)
    topic, field = s[:dot], s[dot + 1:]
    if not topic or not field:
        raise LogError(f"--{what} {text!r}: name a field as TOPIC.FIELD")
    return FieldSpec(text, topic, field, transform)


def detect_format(path: str | os.PathLike) -> str:
    """``ulog`` (.ulg), ``dataflash`` (.bin), or ``rosbag`` (a bag folder or .db3/.mcap)."""
    p = Path(path)
    if p.is_dir() or p.suffix in (".db3", ".mcap"):
        return "rosbag"
    if p.suffix.lower() == ".ulg":
        return "ulog"
    if p.suffix.lower() in (".bin", ".log"):
        return "dataflash"
    try:
        head = p.read_bytes()[:8]
    except OSError as exc:
        raise LogError(f"{p}: cannot read ({exc.strerror or exc})") from None
    if head.startswith(b"ULog"):
        return "ulog"
    if head[:2] == b"\xa3\x95":
        return "dataflash"
    raise LogError(f"{p}: unknown log format (expected a .ulg, a DataFlash .bin or a ROS 2 bag; pass --format)")


def _reader(fmt: str):
    from uavsim.logs import dataflash, rosbag, ulog

    return {"ulog": ulog.read, "dataflash": dataflash.read, "rosbag": rosbag.read}[fmt]


def read_series(path: str | os.PathLike, specs: dict[str, FieldSpec], fmt: str | None = None
                ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Read each spec's signal: name -> (t s, values), checked (time strictly increasing, values finite).

    Constants come back as ``(empty, [value])``.
    """
    p = Path(path)
    if not p.exists():
        raise LogError(f"{p}: no such log")
    fmt = fmt or detect_format(p)
    if fmt not in FORMATS:
        raise LogError(f"{p}: unknown format {fmt!r} (known: {', '.join(FORMATS)})")
    wanted: dict[str, set[str]] = {}
    for s in specs.values():
        for f in s.fields:
            wanted.setdefault(s.topic, set()).add(f)
    raw = _reader(fmt)(p, {k: sorted(v) for k, v in wanted.items()}) if wanted else {}
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, s in specs.items():
        if s.transform == "const":
            out[name] = (np.zeros(0), np.array([s.constant]))
            continue
        t, cols = raw[s.topic]
        values = _apply(s, cols)
        where = f"{p}: {name} ({s.text})"
        _check_time(t, where)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise LogError(f"{where}: value {values[bad[0]]!r} at t = {t[bad[0]]:.6g} s (values must be finite; "
                           "cut the window with --start/--stop or use another field)")
        out[name] = (t, values)
    return out


def _apply(s: FieldSpec, cols: dict[str, np.ndarray]) -> np.ndarray:
    if s.transform in ("roll", "pitch"):
        w, x, y, z = (np.asarray(cols[f"{s.field}[{i}]"], np.float64) for i in range(4))
        if s.transform == "roll":
            return np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        return np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    v = np.asarray(cols[s.field], np.float64)
    return {"id": v, "neg": -v, "rad": np.radians(v)}[s.transform]


def _check_time(t: np.ndarray, where: str) -> None:
    if t.size < 2:
        raise LogError(f"{where}: {t.size} sample(s); a run needs many")
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        i = int(back[0])
        raise LogError(f"{where}: time is not increasing ({t[i + 1]:.6f} s after {t[i]:.6f} s)")


def sample_on_grid(series: dict[str, tuple[np.ndarray, np.ndarray]], rate_hz: float, start: float, stop: float,
                   where: str, max_gap_periods: float = 3.0) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Each series' value at every tick ``start + k / rate_hz < stop``: the last sample logged before half a
    control period after the tick (the controller's view; logging jitter below half a period is absorbed).

    Refuses a series logged slower than the control rate (median step above 1.1 control periods) and
    a gap inside the window longer than ``max_gap_periods`` control periods (or 3 of the series' own steps).
    """
    ts = 1.0 / rate_hz
    n = int(math.floor((stop - start) * rate_hz + 1e-9))
    if n < 2:
        raise LogError(f"{where}: the window [{start:.6g}, {stop:.6g}] s holds no control period")
    grid = start + np.arange(n) * ts
    out: dict[str, np.ndarray] = {}
    for name, (t, v) in series.items():
        if t.size == 0:  # a constant
            out[name] = np.full(n, v[0])
            continue
        inside = (t >= start - 1e-9) & (t < stop)
        step = float(np.median(np.diff(t)))
        if step > 1.1 * ts:
            raise LogError(f"{where}: {name} is logged at {1 / step:.4g} Hz, below the control rate {rate_hz:g} Hz "
                           f"(log it at the control rate, or import with --rate {1 / step:.4g})")
        k = np.flatnonzero(inside)
        if k.size == 0 or t[0] > start + 0.5 * ts:
            raise LogError(f"{where}: {name} has no sample at the window's start t = {start:.6g} s")
        lo, hi = max(k[0] - 1, 0), k[-1]
        gaps = np.diff(t[lo : hi + 1])
        limit = max(max_gap_periods * ts, 3.0 * step)
        big = np.flatnonzero(gaps > limit)
        if big.size:
            i = lo + int(big[0])
            raise LogError(f"{where}: {name} has a gap of {gaps[big[0]]:.4g} s after t = {t[i]:.6g} s (more than "
                           f"{limit:.3g} s: lost log data; cut the window with --start/--stop)")
        if stop - t[hi] > limit:
            raise LogError(f"{where}: {name} ends at t = {t[hi]:.6g} s, before the window's end {stop:.6g} s")
        # each tick takes the last sample logged before half a period after it: topics logged a little
        # before or after the controller's tick (and clock jitter below half a period) land on that tick
        idx = np.searchsorted(t, grid + 0.5 * ts, side="right") - 1
        out[name] = v[idx]
    return grid, out


def detect_relay(t: np.ndarray, u: np.ndarray, min_switches: int = 6) -> dict[str, float] | None:
    """The relay segment of a command trace: the longest stretch where u takes only two values.

    Returns ``h``, ``bias`` (command units), ``start``, ``stop`` (s) and ``switches``, or None when no
    stretch with ``min_switches`` switches exists. A relay's output repeats its two levels exactly,
    which nothing else in a log does for long.
    """
    vals, counts = np.unique(u, return_counts=True)
    if vals.size < 2:
        return None
    top = vals[np.argsort(-counts)[:2]]
    lo, hi = float(min(top)), float(max(top))
    if hi <= lo:
        return None
    on = np.isin(u, (lo, hi))
    # runs of samples on a relay level
    edges = np.flatnonzero(np.diff(np.r_[0, on.astype(np.int8), 0]))
    best = None
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        seg = u[a:b]
        switches = int(np.sum(seg[1:] != seg[:-1]))
        if switches >= min_switches and (best is None or b - a > best[1] - best[0]):
            best = (a, b, switches)
    if best is None:
        return None
    a, b, sw = best
    return {"h": (hi - lo) / 2.0, "bias": (hi + lo) / 2.0, "start": float(t[a]), "stop": float(t[b - 1]),
            "switches": sw}


def import_log(log: str | os.PathLike, out: str | os.PathLike, *, preset: str | None = None,
               r: str | None = None, y: str | None = None, u: str | None = None, loop: str | None = None,
               fmt: str | None = None, kind: str = NP_MRFT_RUN, beta: float | None = None, h: float | None = None,
               bias: float | None = None, tau_obs: float | None = None, a_n: float | None = None,
               rate_hz: float | None = None, start: float | None = None, stop: float | None = None,
               run_file: str | None = None, bias_trim: str = "off", log_fn=None) -> dict[str, Any]:
    """Turn a flight log into a session folder ``out`` with one relay run (see ``uavsim.logs``).

    Parameters
    ----------
    log : path of the log (.ulg, DataFlash .bin, ROS 2 bag folder)
    out : session folder to write (created; an existing session.toml is replaced)
    preset : name in ``PRESETS`` (its r, y, u, loop and format), or None
    r, y, u : field specs; each overrides the preset's
    loop : session loop (``altitude``, ``roll``, ``pitch``, ``lateral_x``, ``lateral_y``); default the preset's
    fmt : ``ulog``, ``dataflash`` or ``rosbag`` (default: from the file)
    kind : ``np-mrft`` or ``mrft``
    beta : the relay's beta (required); h, bias : its amplitude and bias (default: detected from u)
    tau_obs, a_n : NP-MRFT parameters (required for np-mrft)
    rate_hz : control rate (default: from u's median logging step)
    start, stop : window in the log's time, s (default: the detected relay segment)
    run_file : CSV name (default ``relay.csv``)
    bias_trim : ``"duty"`` where the flight's relay trimmed its bias (docs/formats/session.md); its ``u`` then
        holds more than two levels, so ``h``, ``bias`` (the bias it started at), ``start`` and ``stop`` are given
    log_fn : called with one line per finding (detected levels, window)

    Returns
    -------
    dict: ``session`` (folder), ``loop``, ``rate_hz``, ``samples``, ``start``, ``stop``, the run's parameters and
    ``detected`` (what came from the data rather than the arguments).
    """
    from uavsim.formats.session import LOOPS, Run, RunData, RunSpec, Session, write_session

    say = log_fn or (lambda s: None)
    path = Path(log)
    pre = None
    if preset is not None:
        if preset not in PRESETS:
            raise LogError(f"unknown preset {preset!r} (known: {', '.join(PRESETS)})")
        pre = PRESETS[preset]
    loop = loop or (pre.loop if pre else None)
    if loop is None:
        raise LogError("name the loop (--loop) or a preset (--preset)")
    if loop not in LOOPS:
        raise LogError(f"unknown loop {loop!r} (known: {', '.join(LOOPS)})")
    names = {"r": r or (pre.r if pre else None), "y": y or (pre.y if pre else None), "u": u or (pre.u if pre else None)}
    missing = [k for k, v in names.items() if v is None]
    if missing:
        raise LogError(f"name the log fields of {', '.join(missing)} (--{missing[0]} TOPIC.FIELD) or a preset")
    if kind not in RELAY_KINDS:
        raise LogError(f"--kind must be np-mrft or mrft (a relay run), got {kind!r}")
    if beta is None:
        raise LogError("--beta is required: the relay's beta cannot be read off the log")
    if bias_trim not in RELAY_BIAS_TRIMS:
        raise LogError(f"--bias-trim must be one of {', '.join(RELAY_BIAS_TRIMS)}, got {bias_trim!r}")
    if bias_trim != "off" and any(v is None for v in (h, bias, start, stop)):
        raise LogError("a trimmed relay's u moves between more than two levels: pass --h, --bias (the bias it "
                       "started at), --start and --stop")
    if kind == NP_MRFT_RUN and (tau_obs is None or a_n is None):
        raise LogError("an np-mrft run needs --tau-obs and --a-n (the relay's settings in flight)")
    if not path.exists():
        raise LogError(f"{path}: no such log")
    fmt = fmt or detect_format(path)
    if pre is not None and pre.format != fmt:
        raise LogError(f"{path}: a {fmt} log, but the preset {preset} is for {pre.format} logs")
    specs = {k: parse_field(v, k) for k, v in names.items()}
    series = read_series(path, specs, fmt)
    t_u, u_raw = series["u"]
    if t_u.size == 0:
        raise LogError(f"{path}: u must be a log field (the relay's command), not a constant")
    detected: dict[str, Any] = {}
    relay = detect_relay(t_u, u_raw)
    if rate_hz is None:
        rate_hz = float(round(1.0 / float(np.median(np.diff(t_u))), 3))
        detected["rate_hz"] = rate_hz
        say(f"control rate {rate_hz:g} Hz (u's median logging step; pass --rate to set it)")
    given = {"h": h, "bias": bias, "start": start, "stop": stop}
    for keys, why in ((("h", "bias"), f"no relay in u ({names['u']}): it never holds two levels for 6 switches; "
                                      "pass --h and --bias (and --start/--stop)"),
                      (("start", "stop"), "no relay segment found in u; pass --start and --stop (s, log time)")):
        if all(given[k] is not None for k in keys):
            continue
        if relay is None:
            raise LogError(f"{path}: {why}")
        for k in keys:
            if given[k] is None:
                given[k] = detected[k] = relay[k]
        say(f"relay levels detected in u: h = {given['h']:.6g}, bias = {given['bias']:.6g} "
            f"({relay['switches']} switches)" if keys[0] == "h" else
            f"relay segment t = {given['start']:.6g} .. {given['stop']:.6g} s")
    h, bias, start, stop = (given[k] for k in ("h", "bias", "start", "stop"))
    if not stop > start:
        raise LogError(f"--start {start} must be before --stop {stop}")
    grid, cols = sample_on_grid(series, rate_hz, start, stop, str(path))
    spec = RunSpec(file=run_file or "relay.csv", kind=kind, beta=float(beta), h=float(h), bias=float(bias),
                   tau_obs=None if kind == MRFT_RUN else float(tau_obs), a_n=None if kind == MRFT_RUN else float(a_n),
                   bias_trim=bias_trim)
    # session time starts at 0; the log time of the first sample is in the answer
    data = RunData(t=np.arange(grid.size) / rate_hz, r=cols["r"], y=cols["y"], u=cols["u"])
    folder = write_session(Session(loop=loop, control_rate_hz=float(rate_hz), runs=[Run(spec, data)]), out)
    return {"session": str(folder), "log": str(path), "format": fmt, "loop": loop, "rate_hz": float(rate_hz),
            "samples": int(grid.size), "start": float(start), "stop": float(stop), "fields": names,
            "run": {"file": spec.file, "kind": kind, "beta": spec.beta, "h": spec.h, "bias": spec.bias,
                    "tau_obs": spec.tau_obs, "a_n": spec.a_n, "bias_trim": spec.bias_trim}, "detected": detected}
