"""Flight sessions: reader, writer and checks for the ``uavsim-session/2`` format.

A *session* is one folder: a ``session.toml`` that says which loop was flown,
at which controller rate, with which experiments ("runs") and optionally the
current model of the loop and the effects the gap workflow found, plus one CSV
file ``t,r,y,u`` per run. The normative description is
``docs/formats/session.md``; this module is its one implementation, used both
for measured data (read) and for simulated data (written), so that both go
through the same checks. Version-1 sessions are read too; ``Session.reading``
says which NP-MRFT reading their relay runs were written with (pass it to
``uavsim.control.relay.NPMRFT``).

Two rules drive the design:

* **Strict reading.** A typo must not pass silently: unknown keys, wrong types,
  impossible parameter values and malformed CSV rows all raise
  :class:`SessionError`, a :class:`~uavsim.errors.UserError` whose one-line
  message starts with the offending path (``file`` or ``file:line``) and says
  what is wrong, so the CLI can print it and exit 2.
* **Exact round trip.** Floats are written with ``repr(float(x))`` (the
  shortest string that reads back to the same double), so
  ``read_session(write_session(s, d))`` reproduces every array bit for bit and
  every TOML value exactly. Files are written to temporary names and renamed
  into place, ``session.toml`` last, so an interrupted write never leaves a
  half file that looks complete.

Usage::

    from uavsim.formats import read_session, write_session

    session = read_session("flights/2024-05-01")   # the folder or its session.toml
    for run in session.runs:
        print(run.spec.kind, run.data.t.size, "samples")
    write_session(session, "flights/copy")          # identical on re-reading
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re
import tempfile
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path, PureWindowsPath
from typing import Any

import numpy as np

from uavsim.errors import UserError
from uavsim.errors import short_repr as _short
from uavsim.errors import type_name as _type_name
from uavsim.model.effects.vocabulary import EFFECT_PARAMS, PARAM_RANGES

__all__ = [
    "CSV_HEADER",
    "EFFECT_PARAMS",
    "FORMAT",
    "FORMATS",
    "LATERAL_LOOPS",
    "LOOPS",
    "RUN_KINDS",
    "RELAY_KINDS",
    "NP_MRFT_RUN",
    "MRFT_RUN",
    "STEP_RUN",
    "STEP_DERIVATIVES",
    "RUN_KEYS",
    "SESSION_FILE",
    "ActuatorSpec",
    "EffectSpec",
    "ModelSpec",
    "Run",
    "RunData",
    "RunSpec",
    "Session",
    "SessionError",
    "read_run_csv",
    "read_session",
    "session_summary",
    "validate_actuator",
    "validate_effect",
    "validate_model",
    "validate_run_data",
    "validate_run_params",
    "validate_session",
    "write_session",
]

FORMAT = "uavsim-session/2"
# Every version a reader accepts -> the NP-MRFT/MRFT reading its runs were written
# with (uavsim.control.relay READINGS; docs/formats/session.md, "Versions").
FORMATS: dict[str, int] = {"uavsim-session/1": 1, "uavsim-session/2": 2}
SESSION_FILE = "session.toml"
LOOPS = ("altitude", "roll", "pitch", "lateral_x", "lateral_y")
# Lateral loops have the extra body time constant T2 (position is two
# integrations behind attitude); the others must not have it.
LATERAL_LOOPS = ("lateral_x", "lateral_y")
# The run kinds: an NP-MRFT or MRFT relay run, a PD step response.
NP_MRFT_RUN, MRFT_RUN, STEP_RUN = "np-mrft", "mrft", "step"
RUN_KINDS = (NP_MRFT_RUN, MRFT_RUN, STEP_RUN)
RELAY_KINDS = (NP_MRFT_RUN, MRFT_RUN)
# What a step run's PD differentiates (docs/formats/session.md, "step"): the error
# (the default, the meaning of every session written before the key existed) or the
# measurement (no derivative kick when the reference steps).
STEP_DERIVATIVES = ("error", "measurement")
# How a relay run's bias moves (docs/formats/session.md, "np-mrft"): it stays (the default,
# the meaning of every session written before the key existed) or the relay trims it from
# each cycle's duty.
RELAY_BIAS_TRIMS = ("off", "duty")
CSV_HEADER = ("t", "r", "y", "u")

# The effect vocabulary of the spec, in its table order: name -> parameter names, and
# each parameter's allowed range (PARAM_RANGES: ">0", ">=0", "any"; the names are unique
# across effects). Both are live views of the effects' own session terms
# (uavsim.model.effects.vocabulary), so a new vocabulary effect is one new effect file.

# Per run kind: (required parameter keys, optional parameter keys).
RUN_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    NP_MRFT_RUN: (("beta", "h", "tau_obs", "a_n"), ("bias", "bias_trim")),
    MRFT_RUN: (("beta", "h"), ("bias", "bias_trim")),
    STEP_RUN: (("kp", "kd", "derivative_filter_hz", "step", "step_time"), ("derivative",)),
}
# Parameters whose value is a word, each with its words; the first is what an absent key reads as.
_RUN_WORDS: dict[str, tuple[str, ...]] = {"derivative": STEP_DERIVATIVES, "bias_trim": RELAY_BIAS_TRIMS}
# Every parameter field of RunSpec, in the order they are written.
_RUN_PARAMS = (
    "beta", "h", "tau_obs", "a_n", "bias", "bias_trim",
    "kp", "kd", "derivative_filter_hz", "step", "step_time", "derivative",
)  # fmt: skip
_RUN_ALL_KEYS = ("file", "kind", *_RUN_PARAMS)
_TOP_KEYS = ("format", "loop", "control_rate_hz", "model", "actuator", "runs", "effects")
_ACTUATOR_KEYS = ("command_min", "command_max")
_MODEL_KEYS = ("K", "T_prop", "T1", "T2", "tau", "noise_std", "noise_corner_hz")
_MODEL_REQUIRED = ("K", "T_prop", "T1", "tau")

# Tolerance on the CSV time step: clocks on flight computers jitter a little
# and t may have been printed with few digits, but a dropped or doubled sample
# (dt off by a whole Ts) must be caught.
_DT_ABS_TOL = 1e-6
_DT_REL_TOL = 1e-3


class SessionError(UserError):
    """A malformed or invalid session.

    The message always starts with the offending path (``file`` or
    ``file:line`` for CSV rows) and fits on one line.
    """

    def __init__(self, message: str) -> None:
        # One line is part of the CLI contract; user-supplied text (keys, file
        # names) could smuggle in line breaks.
        super().__init__(message.replace("\r", "\\r").replace("\n", "\\n"))


@dataclass
class ModelSpec:
    """Lumped model of one loop (the ``[model]`` table).

    Parameters
    ----------
    K : float
        Loop gain, output units per command unit (per second for type-1 loops).
    T_prop : float
        Propulsion time constant, s.
    T1 : float
        Body time constant, s.
    tau : float
        Total loop delay, s.
    T2 : float or None
        Second body time constant, s; lateral loops only (None otherwise).
    noise_std : float
        Measurement noise standard deviation the model assumes, output units.
    noise_corner_hz : float or None
        Corner of the 2nd-order Butterworth low-pass that colours that noise, Hz; None: white.
    """

    K: float
    T_prop: float
    T1: float
    tau: float
    T2: float | None = None
    noise_std: float = 0.0
    noise_corner_hz: float | None = None


@dataclass
class ActuatorSpec:
    """The actuators' command range (the ``[actuator]`` table): what the vehicle can deliver.

    Parameters
    ----------
    command_min, command_max : float
        The loop's command (command units, as the runs' ``u``) at which the mixer first drives a
        motor to its ESC's lowest (highest) output from the hover trim; ``command_min < 0 < command_max``.
    """

    command_min: float
    command_max: float


@dataclass
class EffectSpec:
    """One ``[[effects]]`` entry: a vocabulary name and its parameters.

    Parameters
    ----------
    name : str
        A key of :data:`EFFECT_PARAMS`.
    params : dict of str to float
        Exactly that effect's parameters, in the units of the spec's table.
    """

    name: str
    params: dict[str, float]


@dataclass
class RunSpec:
    """One ``[[runs]]`` entry: the CSV file and the controller that produced it.

    Only the fields of ``kind`` are set; the others stay None (``bias`` stays
    0.0 for step runs).

    Parameters
    ----------
    file : str
        CSV path relative to the session folder.
    kind : str
        ``"np-mrft"``, ``"mrft"`` or ``"step"``.
    beta : float, optional
        Relay phase parameter, in (-1, 1) (np-mrft, mrft).
    h : float, optional
        Relay amplitude, command units, > 0 (np-mrft, mrft).
    tau_obs : float, optional
        NP-MRFT observation time, s, >= 0 (np-mrft).
    a_n : float, optional
        Noise amplitude of the switching correction, output units, >= 0 (np-mrft).
    bias : float
        Constant added to the relay output, command units (np-mrft, mrft); with
        ``bias_trim = "duty"`` the bias the run starts with.
    bias_trim : str
        How the relay's bias moves, one of :data:`RELAY_BIAS_TRIMS`: ``"off"`` (the
        default; also what step runs keep) or ``"duty"``, trimmed from each cycle's duty
        (np-mrft, mrft).
    kp, kd : float, optional
        PD gains, command per output unit and command*s per output unit (step).
    derivative_filter_hz : float, optional
        Cut-off of the first-order derivative filter, Hz, > 0 (step).
    step : float, optional
        Reference step size, output units (step).
    step_time : float, optional
        Time of the reference step, s, >= 0 (step).
    derivative : str
        What the step's PD differentiates, one of :data:`STEP_DERIVATIVES`:
        ``"error"`` (the default; also what relay runs keep) or ``"measurement"`` (step).
    """

    file: str
    kind: str
    beta: float | None = None
    h: float | None = None
    tau_obs: float | None = None
    a_n: float | None = None
    bias: float = 0.0
    bias_trim: str = RELAY_BIAS_TRIMS[0]
    kp: float | None = None
    kd: float | None = None
    derivative_filter_hz: float | None = None
    step: float | None = None
    step_time: float | None = None
    derivative: str = STEP_DERIVATIVES[0]


@dataclass
class RunData:
    """The samples of one run, one entry per controller sample.

    Parameters
    ----------
    t : numpy.ndarray
        Time, s, strictly increasing with step 1/control_rate_hz.
    r : numpy.ndarray
        Reference, output units (m or rad).
    y : numpy.ndarray
        Measurement exactly as the controller saw it, output units.
    u : numpy.ndarray
        Command exactly as the controller computed it, command units.
    """

    t: np.ndarray
    r: np.ndarray
    y: np.ndarray
    u: np.ndarray


@dataclass
class Run:
    """A run: its ``[[runs]]`` entry and its samples."""

    spec: RunSpec
    data: RunData


@dataclass
class Session:
    """A whole session folder in memory.

    Parameters
    ----------
    loop : str
        One of :data:`LOOPS`.
    control_rate_hz : float
        Rate at which the controller sampled y and updated u, Hz.
    runs : list of Run
        The experiments, at least one.
    model : ModelSpec or None
        Current model of the loop; None means "no model yet".
    actuator : ActuatorSpec or None
        The actuators' command range; None: not known (simulations do not clip the command).
    effects : list of EffectSpec
        Effects added on top of the model (written by the gap workflow).
    path : Path or None
        Folder the session was read from (None when built in memory).
    format : str
        Format version, a key of :data:`FORMATS`: what was read, and what is
        written (new sessions: :data:`FORMAT`).
    """

    loop: str
    control_rate_hz: float
    runs: list[Run]
    model: ModelSpec | None = None
    effects: list[EffectSpec] = field(default_factory=list)
    path: Path | None = None
    actuator: ActuatorSpec | None = None
    format: str = FORMAT

    @property
    def reading(self) -> int:
        """The relay reading of this session's np-mrft and mrft runs (1 or 2)."""
        if self.format not in FORMATS:
            raise SessionError(f"unsupported format {_short(self.format)} (known: {', '.join(FORMATS)})")
        return FORMATS[self.format]


# ---------------------------------------------------------------------------
# Small checking helpers


def _fmt(x: float) -> str:
    # repr of a plain float: shortest round-trip text, never "np.float64(...)".
    return repr(float(x))


def _hint(key: str, valid: Sequence[str]) -> str:
    close = difflib.get_close_matches(key, list(valid), n=1, cutoff=0.6)
    if close:
        return f"did you mean {close[0]!r}?"
    return "valid keys: " + ", ".join(valid) if valid else "no keys allowed"


def _unknown_key(where: str, key: str, valid: Sequence[str]) -> SessionError:
    return SessionError(f"{where}: unknown key {_short(key)} ({_hint(key, valid)})")


def _number(value: Any, name: str, where: str) -> float:
    """Return ``value`` as a finite float or raise; TOML ints count, bools do not."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise SessionError(
            f"{where}: {name} must be a number, got {_type_name(value)} {_short(value)}"
        )
    try:
        x = float(value)
    except OverflowError:
        raise SessionError(f"{where}: {name} = {_short(value)} is out of range") from None
    if not math.isfinite(x):
        raise SessionError(f"{where}: {name} must be finite, got {_fmt(x)}")
    return x


def _string(value: Any, name: str, where: str) -> str:
    if not isinstance(value, str):
        raise SessionError(
            f"{where}: {name} must be a string, got {_type_name(value)} {_short(value)}"
        )
    return value


def _check_range(x: float, name: str, where: str, rule: str) -> None:
    if rule == ">0" and not x > 0:
        raise SessionError(f"{where}: {name} must be > 0, got {_fmt(x)}")
    if rule == ">=0" and not x >= 0:
        raise SessionError(f"{where}: {name} must be >= 0, got {_fmt(x)}")


def _choice(value: str, name: str, where: str, valid: Sequence[str], what: str) -> str:
    if value not in valid:
        close = difflib.get_close_matches(value, list(valid), n=1, cutoff=0.6)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise SessionError(
            f"{where}: unknown {what} {_short(value)} ({hint}expected one of {', '.join(valid)})"
        )
    return value


def _is_plus_zero(x: float) -> bool:
    return x == 0 and math.copysign(1.0, x) > 0


def _is_unset(name: str, value: Any) -> bool:
    """Whether an optional run key holds the value its absence reads as."""
    if name in _RUN_WORDS:
        return value == _RUN_WORDS[name][0]
    return _is_plus_zero(value)


# ---------------------------------------------------------------------------
# Validation shared by the reader, the writer and the controllers


def validate_run_params(spec: RunSpec, where: str) -> None:
    """Check the controller parameters of a run.

    Shared with the controllers, so that a parameter the simulator refuses is
    also refused in a session file, and the other way round.

    Parameters
    ----------
    spec : RunSpec
        The run; only ``kind`` and the parameter fields are checked (not ``file``).
    where : str
        Prefix of the error message, normally the offending path.

    Raises
    ------
    SessionError
        Unknown kind, a required parameter missing, a parameter of another kind
        set, a non-number, or a value out of range: beta in (-1, 1), h > 0,
        tau_obs >= 0 s, a_n >= 0, bias/kp/kd/step finite,
        derivative_filter_hz > 0 Hz, step_time >= 0 s, derivative one of
        :data:`STEP_DERIVATIVES`.
    """
    kind = _choice(_string(spec.kind, "kind", where), "kind", where, RUN_KINDS, "run kind")
    required, optional = RUN_KEYS[kind]
    values: dict[str, float] = {}
    for name in _RUN_PARAMS:
        value = getattr(spec, name)
        if name in _RUN_WORDS:
            words = _RUN_WORDS[name]
            if name in optional:
                _choice(_string(value, name, where), name, where, words, f"{name} of a {kind} run")
            elif value != words[0]:
                # the default word means "not set", as +0.0 does for bias
                raise SessionError(f"{where}: {name!r} is not a key of a {kind} run")
            continue
        if name in required:
            if value is None:
                raise SessionError(f"{where}: missing key {name!r} (required for a {kind} run)")
        elif name not in optional:
            # bias defaults to 0.0 rather than None, so +0.0 means "not set";
            # anything else would be silently lost when the run is written.
            unset = value is None or (
                name == "bias"
                and isinstance(value, float | int)
                and not isinstance(value, bool)
                and _is_plus_zero(value)
            )
            if not unset:
                raise SessionError(f"{where}: {name!r} is not a key of a {kind} run")
            continue
        if value is None and name in optional:
            raise SessionError(f"{where}: {name} must be a number (0.0 when unused), got None")
        values[name] = _number(value, name, where)
    if "beta" in values and not -1.0 < values["beta"] < 1.0:
        raise SessionError(f"{where}: beta must be in (-1, 1), got {_fmt(values['beta'])}")
    for name, rule in (
        ("h", ">0"),
        ("tau_obs", ">=0"),
        ("a_n", ">=0"),
        ("derivative_filter_hz", ">0"),
        ("step_time", ">=0"),
    ):
        if name in values:
            _check_range(values[name], name, where, rule)


def validate_model(model: ModelSpec, loop: str, where: str) -> None:
    """Check a loop model.

    Parameters
    ----------
    model : ModelSpec
        The model.
    loop : str
        The session's loop; decides whether ``T2`` is required (lateral) or
        forbidden (others).
    where : str
        Prefix of the error message.

    Raises
    ------
    SessionError
        Non-finite or non-number values, K == 0, a time constant <= 0 s,
        tau < 0 s, noise_std < 0, or T2 present/missing against the loop.
    """
    values = {}
    for name in _MODEL_KEYS:
        value = getattr(model, name)
        if name == "T2":
            if loop in LATERAL_LOOPS and value is None:
                raise SessionError(f"{where}: missing key 'T2' (required for the {loop} loop)")
            if loop not in LATERAL_LOOPS and value is not None:
                raise SessionError(
                    f"{where}: 'T2' is not a key of the {loop} loop model (lateral loops only)"
                )
            if value is None:
                continue
        if name == "noise_corner_hz" and value is None:
            continue
        if value is None and name in _MODEL_REQUIRED:
            raise SessionError(f"{where}: missing key {name!r}")
        values[name] = _number(value, name, where)
    if values["K"] == 0:
        raise SessionError(f"{where}: K must be non-zero")
    for name in ("T_prop", "T1", "T2"):
        if name in values:
            _check_range(values[name], name, where, ">0")
    _check_range(values["tau"], "tau", where, ">=0")
    _check_range(values["noise_std"], "noise_std", where, ">=0")
    if "noise_corner_hz" in values:
        _check_range(values["noise_corner_hz"], "noise_corner_hz", where, ">0")


def validate_effect(effect: EffectSpec, where: str) -> None:
    """Check an effect against the vocabulary.

    Parameters
    ----------
    effect : EffectSpec
        The effect.
    where : str
        Prefix of the error message.

    Raises
    ------
    SessionError
        Unknown name, missing or extra parameters, non-numbers, or values out
        of range (delay >= 0 s, T > 0 s, factor > 0, limit > 0, width >= 0,
        rate > 0 per s, offset finite, step > 0, rate_hz > 0, cutoff_hz > 0,
        std >= 0).
    """
    name = _choice(_string(effect.name, "name", where), "name", where,
                   tuple(EFFECT_PARAMS), "effect name")  # fmt: skip
    expected = EFFECT_PARAMS[name]
    if not isinstance(effect.params, Mapping):
        raise SessionError(f"{where}: params must be a mapping, got {_type_name(effect.params)}")
    for key in effect.params:
        if key not in expected:
            raise _effect_key_error(where, str(key), name)
    for key in expected:
        if key not in effect.params:
            raise SessionError(f"{where}: missing key {key!r} (parameter of a {name} effect)")
        x = _number(effect.params[key], key, where)
        _check_range(x, key, where, PARAM_RANGES[key])


def _effect_key_error(where: str, key: str, name: str) -> SessionError:
    expected = EFFECT_PARAMS[name]
    if any(key in params for params in EFFECT_PARAMS.values()):
        allowed = ", ".join(repr(p) for p in expected) if expected else "none"
        return SessionError(
            f"{where}: {key!r} is not a parameter of a {name} effect (its parameters: {allowed})"
        )
    return _unknown_key(where, key, ("name", *expected))


def validate_run_data(data: RunData, control_rate_hz: float, where: str) -> None:
    """Check the samples of a run.

    Parameters
    ----------
    data : RunData
        The arrays.
    control_rate_hz : float
        Controller rate, Hz; t must advance by 1/control_rate_hz s per row,
        within ``1e-6 + 1e-3 / control_rate_hz`` s.
    where : str
        The CSV path; row problems are reported as ``where:line`` with the
        line the row has (or would have) in the file, the header being line 1.

    Raises
    ------
    SessionError
        Arrays not 1-D or of different lengths, fewer than 2 samples,
        non-finite values, t not strictly increasing or badly spaced.
    """
    arrays = []
    for name in CSV_HEADER:
        try:
            a = np.asarray(getattr(data, name), dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise SessionError(f"{where}: column {name} is not numeric ({exc})") from None
        if a.ndim != 1:
            raise SessionError(f"{where}: column {name} must be 1-D, got shape {a.shape}")
        arrays.append(a)
    lengths = {a.size for a in arrays}
    if len(lengths) != 1:
        sizes = ", ".join(f"{n}={a.size}" for n, a in zip(CSV_HEADER, arrays, strict=True))
        raise SessionError(f"{where}: columns have different lengths ({sizes})")
    _check_columns(arrays, control_rate_hz, where)


def _check_columns(arrays: list[np.ndarray], control_rate_hz: float, where: str) -> None:
    n = arrays[0].size
    if n == 0:
        raise SessionError(f"{where}: no data rows (the run is empty)")
    if n < 2:
        raise SessionError(f"{where}: only 1 data row; a run needs at least 2")
    table = np.stack(arrays, axis=1)
    bad = ~np.isfinite(table)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise SessionError(
            f"{where}:{row + 2}: {CSV_HEADER[col]} is {_fmt(table[row, col])} "
            "(values must be finite: no NaN or inf)"
        )
    t = arrays[0]
    ts = 1.0 / control_rate_hz
    with np.errstate(over="ignore", invalid="ignore"):
        dt = np.diff(t)
        off = np.abs(dt - ts) > _DT_ABS_TOL + _DT_REL_TOL * ts
    # Rows out of order are reported before spacing: a swapped pair of rows
    # also shows as a gap one row earlier, but the disorder is the real fault.
    back = np.flatnonzero(dt <= 0)
    if back.size:
        i = int(back[0])
        raise SessionError(
            f"{where}:{i + 3}: t is not increasing ({_fmt(t[i + 1])} after {_fmt(t[i])})"
        )
    problems = np.flatnonzero(off)
    if problems.size:
        i = int(problems[0])
        line = i + 3  # row i+1 of the data, after the header line
        raise SessionError(
            f"{where}:{line}: t spacing is {_fmt(dt[i])} s after t = {_fmt(t[i])}, expected "
            f"1/control_rate_hz = {_fmt(ts)} s (a dropped or repeated sample?)"
        )


def _check_run_file(file: Any, where: str) -> str:
    file = _string(file, "file", where)
    parts = re.split(r"[\\/]", file)
    if any(ord(ch) < 0x20 or ord(ch) == 0x7F for ch in file):
        raise SessionError(f"{where}: file name {file!r} contains control characters")
    if not file or file.endswith(("/", "\\")):
        raise SessionError(f"{where}: file must name a CSV file, got {file!r}")
    if os.path.isabs(file) or PureWindowsPath(file).is_absolute() or PureWindowsPath(file).drive:
        raise SessionError(f"{where}: file must be relative to the session folder, got {file!r}")
    if ".." in parts:
        raise SessionError(f"{where}: file must stay inside the session folder, got {file!r}")
    if [p for p in parts if p not in ("", ".")] == [SESSION_FILE]:
        raise SessionError(f"{where}: file cannot be {SESSION_FILE!r}")
    return file


def _norm_file(file: str) -> str:
    return "/".join(p for p in re.split(r"[\\/]", file) if p not in ("", "."))


def validate_session(session: Session, folder: str | os.PathLike | None = None) -> None:
    """Check a whole in-memory session (what :func:`write_session` checks first).

    Parameters
    ----------
    session : Session
        The session.
    folder : path-like, optional
        Folder used in error messages (defaults to ``session.path`` or ".").

    Raises
    ------
    SessionError
        Any problem the reader would report for the written files.
    """
    base = Path(folder) if folder is not None else (session.path or Path("."))
    toml = str(base / SESSION_FILE)
    _choice(_string(session.format, "format", toml), "format", toml, tuple(FORMATS), "format")
    loop = _choice(_string(session.loop, "loop", toml), "loop", toml, LOOPS, "loop")
    rate = _number(session.control_rate_hz, "control_rate_hz", toml)
    _check_range(rate, "control_rate_hz", toml, ">0")
    if session.model is not None:
        validate_model(session.model, loop, f"{toml}: [model]")
    if session.actuator is not None:
        validate_actuator(session.actuator, f"{toml}: [actuator]")
    for i, effect in enumerate(session.effects):
        validate_effect(effect, f"{toml}: [[effects]] #{i + 1}")
    if not session.runs:
        raise SessionError(f"{toml}: no runs (a session needs at least one [[runs]] table)")
    seen: dict[str, int] = {}
    for i, run in enumerate(session.runs):
        where = f"{toml}: [[runs]] #{i + 1}"
        file = _check_run_file(run.spec.file, where)
        _check_duplicate(seen, file, i, where)
        validate_run_params(run.spec, f"{where} ({file})")
        validate_run_data(run.data, rate, str(base / file))


def _check_duplicate(seen: dict[str, int], file: str, i: int, where: str) -> None:
    key = _norm_file(file)
    if key in seen:
        raise SessionError(f"{where}: file {file!r} is already used by [[runs]] #{seen[key] + 1}")
    seen[key] = i


# ---------------------------------------------------------------------------
# Reading


def read_session(path: str | os.PathLike) -> Session:
    """Read and check a session.

    Parameters
    ----------
    path : path-like
        The session folder, or its ``session.toml``.

    Returns
    -------
    Session
        With ``path`` set to the folder; arrays are float64.

    Raises
    ------
    SessionError
        Anything malformed, with the offending path first in the message.
    """
    path = Path(path)
    try:
        if path.is_dir():
            folder, toml_path = path, path / SESSION_FILE
        elif path.exists():
            folder, toml_path = path.parent, path
        else:
            raise SessionError(f"{path}: no such session folder or file")
        toml_is_file = toml_path.is_file()
    except (OSError, ValueError) as exc:
        raise SessionError(f"{path}: cannot access ({exc})") from None
    where = str(toml_path)
    if not toml_is_file:
        raise SessionError(f"{where}: missing {SESSION_FILE} (not a session folder?)")
    text = _read_text(toml_path, where)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SessionError(f"{where}: TOML syntax error: {exc}") from None

    fmt, loop, rate, model_table, run_tables, effect_tables = _parse_top(doc, where)
    model = _parse_model(model_table, loop, where) if model_table is not None else None
    actuator = _parse_actuator(doc["actuator"], where) if "actuator" in doc else None
    effects = [_parse_effect(t, i, where) for i, t in enumerate(effect_tables)]
    specs = [_parse_run(t, i, where) for i, t in enumerate(run_tables)]
    if not specs:
        raise SessionError(f"{where}: no runs (a session needs at least one [[runs]] table)")
    seen: dict[str, int] = {}
    for i, spec in enumerate(specs):
        _check_duplicate(seen, spec.file, i, f"{where}: [[runs]] #{i + 1}")
    from uavsim.schema import validate

    # the checks above give the hints; the schema (uavsim.schema.session) is what the file must be
    validate("session", doc, where)
    runs = [Run(spec, read_run_csv(folder / spec.file, rate)) for spec in specs]
    return Session(loop=loop, control_rate_hz=rate, runs=runs, model=model,
                   effects=effects, path=folder, format=fmt, actuator=actuator)  # fmt: skip


def _read_text(path: Path, where: str) -> str:
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise SessionError(f"{where}: file not found") from None
    except OSError as exc:
        raise SessionError(f"{where}: cannot read ({exc.strerror or exc})") from None
    try:
        # utf-8-sig: spreadsheet programs like to prepend a byte-order mark.
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise SessionError(f"{where}: not UTF-8 text (bad byte at offset {exc.start})") from None


def _array_of_tables(value: Any, name: str, where: str) -> list[dict]:
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise SessionError(
            f"{where}: {name} must be an array of tables ([[{name}]]), "
            f"got {_type_name(value)} {_short(value)}"
        )
    return value


def _parse_top(doc: dict, where: str) -> tuple[str, str, float, dict | None, list, list]:
    # A wrong format is checked before anything else: a file of another version
    # or tool has other keys, and "unsupported format" is the useful message.
    if "format" in doc:
        fmt = _string(doc["format"], "format", where)
        if fmt not in FORMATS:
            known = " or ".join(repr(f) for f in reversed(FORMATS))
            raise SessionError(f"{where}: unsupported format {_short(fmt)}, expected {known}")
    for key in doc:
        if key not in _TOP_KEYS:
            raise _unknown_key(where, key, _TOP_KEYS)
    for key in ("format", "loop", "control_rate_hz", "runs"):
        if key not in doc:
            extra = f" (expected format = {FORMAT!r})" if key == "format" else ""
            raise SessionError(f"{where}: missing key {key!r}{extra}")
    loop = _choice(_string(doc["loop"], "loop", where), "loop", where, LOOPS, "loop")
    rate = _number(doc["control_rate_hz"], "control_rate_hz", where)
    _check_range(rate, "control_rate_hz", where, ">0")
    model = doc.get("model")
    if model is not None and not isinstance(model, dict):
        raise SessionError(
            f"{where}: model must be a table ([model]), got {_type_name(model)} {_short(model)}"
        )
    runs = _array_of_tables(doc["runs"], "runs", where)
    effects = _array_of_tables(doc.get("effects", []), "effects", where)
    return doc["format"], loop, rate, model, runs, effects


def _check_keys(table: dict, where: str, known: tuple[str, ...], required: tuple[str, ...]) -> None:
    for key in table:
        if key not in known:
            raise _unknown_key(where, key, known)
    for key in required:
        if key not in table:
            raise SessionError(f"{where}: missing key {key!r}")


def _parse_model(table: dict, loop: str, toml: str) -> ModelSpec:
    where = f"{toml}: [model]"
    _check_keys(table, where, _MODEL_KEYS, _MODEL_REQUIRED)
    values = {k: _number(v, k, where) for k, v in table.items()}
    model = ModelSpec(**values)
    validate_model(model, loop, where)
    return model


def _parse_actuator(table: Any, toml: str) -> ActuatorSpec:
    where = f"{toml}: [actuator]"
    if not isinstance(table, dict):
        raise SessionError(f"{toml}: actuator must be a table ([actuator]), got {_type_name(table)} {_short(table)}")
    _check_keys(table, where, _ACTUATOR_KEYS, _ACTUATOR_KEYS)
    actuator = ActuatorSpec(**{k: _number(table[k], k, where) for k in _ACTUATOR_KEYS})
    validate_actuator(actuator, where)
    return actuator


def validate_actuator(actuator: ActuatorSpec, where: str) -> None:
    """Check an actuator range: finite, ``command_min < 0 < command_max`` (``SessionError`` naming ``where``)."""
    lo = _number(actuator.command_min, "command_min", where)
    hi = _number(actuator.command_max, "command_max", where)
    if not lo < 0:
        raise SessionError(f"{where}: command_min must be < 0 (the command is about the hover trim), got {_short(lo)}")
    if not hi > 0:
        raise SessionError(f"{where}: command_max must be > 0 (the command is about the hover trim), got {_short(hi)}")


def _parse_effect(table: dict, i: int, toml: str) -> EffectSpec:
    where = f"{toml}: [[effects]] #{i + 1}"
    if "name" not in table:
        for key in table:
            if key not in PARAM_RANGES:
                raise _unknown_key(where, key, ("name",))
        raise SessionError(f"{where}: missing key 'name'")
    name = _string(table["name"], "name", where)
    _choice(name, "name", where, tuple(EFFECT_PARAMS), "effect name")
    where = f"{where} ({name})"
    for key in table:
        if key != "name" and key not in EFFECT_PARAMS[name]:
            raise _effect_key_error(where, key, name)
    params = {}
    for key in EFFECT_PARAMS[name]:
        if key not in table:
            raise SessionError(f"{where}: missing key {key!r} (parameter of a {name} effect)")
        params[key] = _number(table[key], key, where)
    effect = EffectSpec(name=name, params=params)
    validate_effect(effect, where)
    return effect


def _parse_run(table: dict, i: int, toml: str) -> RunSpec:
    where = f"{toml}: [[runs]] #{i + 1}"
    kind = table.get("kind")
    known_kind = isinstance(kind, str) and kind in RUN_KINDS
    if known_kind:
        required, optional = RUN_KEYS[kind]
        allowed: tuple[str, ...] = ("file", "kind", *required, *optional)
    else:
        allowed = _RUN_ALL_KEYS
    # Unknown keys first: a typo such as "fille" is better reported as such
    # than as the "missing key 'file'" it causes.
    for key in table:
        if key not in _RUN_ALL_KEYS:
            raise _unknown_key(where, key, allowed)
    if "file" not in table:
        raise SessionError(f"{where}: missing key 'file'")
    file = _check_run_file(table["file"], where)
    where = f"{where} ({file})"
    if "kind" not in table:
        raise SessionError(f"{where}: missing key 'kind' (one of {', '.join(RUN_KINDS)})")
    kind = _choice(_string(kind, "kind", where), "kind", where, RUN_KINDS, "run kind")
    required, optional = RUN_KEYS[kind]
    for key in table:
        if key not in ("file", "kind", *required, *optional):
            raise SessionError(f"{where}: {key!r} is not a key of a {kind} run")
    for key in required:
        if key not in table:
            raise SessionError(f"{where}: missing key {key!r} (required for a {kind} run)")
    values: dict[str, Any] = {}
    for k, v in table.items():
        if k in _RUN_WORDS:
            values[k] = _choice(_string(v, k, where), k, where, _RUN_WORDS[k], f"{k} of a {kind} run")
        elif k not in ("file", "kind"):
            values[k] = _number(v, k, where)
    spec = RunSpec(file=file, kind=kind, **values)
    validate_run_params(spec, where)
    return spec


def read_run_csv(path: str | os.PathLike, control_rate_hz: float) -> RunData:
    """Read and check one run CSV (header ``t,r,y,u``, one row per sample).

    Parameters
    ----------
    path : path-like
        The CSV file; it is named first in every error message.
    control_rate_hz : float
        Controller rate, Hz, for the t spacing check.

    Returns
    -------
    RunData
        float64 arrays, exactly the values written in the file.

    Raises
    ------
    SessionError
        Missing file, bad header, wrong cell count, non-numeric or non-finite
        cells, no or a single data row, t not increasing or badly spaced.
    """
    where = str(path)
    p = Path(path)
    try:
        exists, is_file = p.exists(), p.is_file()
    except (OSError, ValueError) as exc:
        raise SessionError(f"{where}: cannot access run file ({exc})") from None
    if not exists:
        raise SessionError(f"{where}: run file not found")
    if not is_file:
        raise SessionError(f"{where}: run file is not a regular file")
    text = _read_text(p, where)
    lines = text.split("\n")
    # Tolerate trailing blank lines (editors add them); nothing else is blank.
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise SessionError(f"{where}: empty file (expected the header 't,r,y,u' and data rows)")
    _check_header(lines[0].rstrip("\r"), where)
    body = lines[1:]
    flat: list[str] = []
    for i, line in enumerate(body):
        cells = line.rstrip("\r").split(",")
        if len(cells) != len(CSV_HEADER):
            if not line.strip():
                raise SessionError(f"{where}:{i + 2}: empty line")
            raise SessionError(
                f"{where}:{i + 2}: {len(cells)} cells, expected {len(CSV_HEADER)} (t,r,y,u)"
            )
        flat.extend(cells)
    try:
        values = [float(c) for c in flat]
    except ValueError:
        # Slow path only to say where: find the first bad cell.
        for k, cell in enumerate(flat):
            try:
                float(cell)
            except ValueError:
                row, col = divmod(k, len(CSV_HEADER))
                raise SessionError(
                    f"{where}:{row + 2}: {CSV_HEADER[col]} cell {_short(cell)} is not a number"
                ) from None
        raise  # unreachable: some cell failed above
    table = np.array(values, dtype=np.float64).reshape(-1, len(CSV_HEADER))
    arrays = [np.ascontiguousarray(table[:, j]) for j in range(len(CSV_HEADER))]
    _check_columns(arrays, control_rate_hz, where)
    return RunData(*arrays)


def _check_header(header: str, where: str) -> None:
    names = header.split(",")
    if tuple(names) == CSV_HEADER:
        return
    missing = [c for c in CSV_HEADER if c not in names]
    extra = [c for c in names if c not in CSV_HEADER]
    if missing:
        detail = "missing column " + ", ".join(repr(c) for c in missing)
    elif extra:
        detail = "extra column " + ", ".join(_short(c) for c in extra)
    elif len(names) != len(set(names)):
        detail = "repeated column"
    else:
        detail = "columns out of order"
    raise SessionError(f"{where}:1: bad header {_short(header, 60)}, expected 't,r,y,u' ({detail})")


# ---------------------------------------------------------------------------
# Writing


def _toml_string(s: str) -> str:
    out = ['"']
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _toml_lines(pairs: Iterable[tuple[str, Any]]) -> list[str]:
    # Only the shapes of a session: bare keys with string or float values.
    lines = []
    for key, value in pairs:
        text = _toml_string(value) if isinstance(value, str) else _fmt(value)
        lines.append(f"{key} = {text}")
    return lines


def _session_toml(session: Session) -> str:
    lines = _toml_lines(
        [("format", session.format), ("loop", session.loop),
         ("control_rate_hz", session.control_rate_hz)]
    )  # fmt: skip
    m = session.model
    if m is not None:
        pairs = [("K", m.K), ("T_prop", m.T_prop), ("T1", m.T1)]
        if m.T2 is not None:
            pairs.append(("T2", m.T2))
        pairs += [("tau", m.tau), ("noise_std", m.noise_std)]
        if m.noise_corner_hz is not None:
            pairs.append(("noise_corner_hz", m.noise_corner_hz))
        lines += ["", "[model]", *_toml_lines(pairs)]
    a = session.actuator
    if a is not None:
        lines += ["", "[actuator]", *_toml_lines([("command_min", a.command_min), ("command_max", a.command_max)])]
    for run in session.runs:
        spec = run.spec
        required, optional = RUN_KEYS[spec.kind]
        pairs = [("file", spec.file), ("kind", spec.kind)]
        pairs += [(k, getattr(spec, k)) for k in required]
        # Optional keys: written unless they hold what an absent key reads back as
        # (bias exactly +0.0, so -0.0 survives the round trip too; derivative "error",
        # bias_trim "off").
        pairs += [(k, getattr(spec, k)) for k in optional if not _is_unset(k, getattr(spec, k))]
        lines += ["", "[[runs]]", *_toml_lines(pairs)]
    for effect in session.effects:
        pairs = [("name", effect.name)]
        pairs += [(k, effect.params[k]) for k in EFFECT_PARAMS[effect.name]]
        lines += ["", "[[effects]]", *_toml_lines(pairs)]
    return "\n".join(lines) + "\n"


def _csv_text(data: RunData) -> str:
    cols = [np.asarray(getattr(data, c), dtype=np.float64).tolist() for c in CSV_HEADER]
    rows = [",".join(CSV_HEADER)]
    rows += [f"{t!r},{r!r},{y!r},{u!r}" for t, r, y, u in zip(*cols, strict=True)]
    return "\n".join(rows) + "\n"


def write_session(session: Session, path: str | os.PathLike) -> Path:
    """Write a session folder: every run CSV, then ``session.toml``.

    The session is checked first (same rules as reading), so what is written
    can always be read back, exactly. Each file is written to a temporary name
    in its folder and renamed into place, ``session.toml`` last: an interrupted
    write leaves either the old file or the complete new one, and never a
    ``session.toml`` that points at missing or partial runs.

    Parameters
    ----------
    session : Session
        The session; ``session.path`` is ignored.
    path : path-like
        Target folder (created if needed), or a ``session.toml`` path in it.

    Returns
    -------
    Path
        The session folder.

    Raises
    ------
    SessionError
        An invalid session, or the files cannot be written.
    """
    folder = Path(path)
    if folder.name == SESSION_FILE and not folder.is_dir():
        folder = folder.parent
    validate_session(session, folder)
    files = [(folder / run.spec.file, _csv_text(run.data)) for run in session.runs]
    files.append((folder / SESSION_FILE, _session_toml(session)))
    _write_atomically(files)
    return folder


def _write_atomically(files: list[tuple[Path, str]]) -> None:
    temps: list[tuple[str, Path]] = []
    target = files[0][0]
    try:
        for target, text in files:
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
            temps.append((tmp, target))
            with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            # mkstemp makes 0600 files; a session is data meant to be shared.
            os.chmod(tmp, 0o644)
        for tmp, target in temps:
            os.replace(tmp, target)
    except BaseException as exc:
        for tmp, _ in temps:
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
        if isinstance(exc, OSError):
            # Name the file the user asked for, not our temporary one.
            reason = exc.strerror or exc.__class__.__name__
            raise SessionError(f"{target}: cannot write session file ({reason})") from None
        raise


# ---------------------------------------------------------------------------
# Summary


def session_summary(session: Session) -> dict[str, Any]:
    """A JSON-ready summary of a session (what ``uavsim session check --json`` prints).

    Returns
    -------
    dict
        ``{"path", "format", "loop", "control_rate_hz", "model", "actuator", "runs", "effects"}``;
        ``model`` is a dict of the lumped parameters or None, ``actuator`` of the command range or None; each run has
        ``file``, ``kind``, ``samples``, ``duration_s`` (t[-1] - t[0], s) and
        the parameters of its kind; each effect is ``{"name", "params"}``.
    """
    runs = []
    for run in session.runs:
        spec = run.spec
        required, optional = RUN_KEYS[spec.kind]
        t = np.asarray(run.data.t, dtype=np.float64)
        entry: dict[str, Any] = {
            "file": spec.file,
            "kind": spec.kind,
            "samples": int(t.size),
            "duration_s": float(t[-1] - t[0]) if t.size else 0.0,
        }
        for key in (*required, *optional):
            entry[key] = getattr(spec, key) if key in _RUN_WORDS else float(getattr(spec, key))
        runs.append(entry)
    return {
        "path": str(session.path) if session.path is not None else None,
        "format": session.format,
        "loop": session.loop,
        "control_rate_hz": float(session.control_rate_hz),
        "model": dataclasses.asdict(session.model) if session.model is not None else None,
        "actuator": dataclasses.asdict(session.actuator) if session.actuator is not None else None,
        "runs": runs,
        "effects": [{"name": e.name, "params": dict(e.params)} for e in session.effects],
    }
