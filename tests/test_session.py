"""Tests of the flight-session format (``uavsim-session/2``; version 1 is read too).

Three groups: the exact round trip (``read_session(write_session(s))`` gives
the same bits), one test per malformed case of the spec (each must be a
``SessionError`` naming the file and the problem, also through the CLI), and
property-based corruption of valid sessions, which must only ever produce
``SessionError``.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
import re
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import uavsim.cli.main as cli_main
from uavsim.errors import UserError
from uavsim.formats import (
    EFFECT_PARAMS,
    FORMAT,
    FORMATS,
    LOOPS,
    ActuatorSpec,
    EffectSpec,
    ModelSpec,
    Run,
    RunData,
    RunSpec,
    Session,
    SessionError,
    read_session,
    validate_run_params,
    write_session,
)
from uavsim.formats import session as session_mod

RATE = 100.0  # Hz; Ts = 10 ms
HYPO = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# ---------------------------------------------------------------------------
# Helpers: a valid session written by hand (independent of the writer)


def base_doc() -> dict:
    """A valid session.toml as a dict: model, one effect, all three run kinds."""
    return {
        "format": FORMAT,
        "loop": "altitude",
        "control_rate_hz": RATE,
        "model": {"K": 20.0, "T_prop": 0.1, "T1": 0.8, "tau": 0.02, "noise_std": 0.0014},
        "runs": [
            {"file": "np.csv", "kind": "np-mrft", "beta": -0.73, "h": 0.2,
             "tau_obs": 0.0325, "a_n": 0.0028},
            {"file": "mrft.csv", "kind": "mrft", "beta": -0.5, "h": 1, "bias": 0.05},
            {"file": "runs/step.csv", "kind": "step", "kp": 2.31, "kd": 0.85,
             "derivative_filter_hz": 7.9577, "step": 1.0, "step_time": 1.0},
        ],
        "effects": [{"name": "delay", "delay": 0.021}],
    }  # fmt: skip


def _toml_key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, dt.date | dt.time):
        return v.isoformat()
    raise TypeError(type(v))


def to_toml(doc: dict) -> str:
    """Generic TOML for test documents: top-level dicts become [tables],
    non-empty lists of dicts become [[arrays of tables]], the rest is inline."""
    head, tail = [], []
    for k, v in doc.items():
        if isinstance(v, dict):
            tail += ["", f"[{_toml_key(k)}]"] + [
                f"{_toml_key(a)} = {_toml_value(b)}" for a, b in v.items()
            ]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                tail += ["", f"[[{_toml_key(k)}]]"]
                tail += [f"{_toml_key(a)} = {_toml_value(b)}" for a, b in item.items()]
        else:
            head.append(f"{_toml_key(k)} = {_toml_value(v)}")
    return "\n".join(head + tail) + "\n"


def csv_text(n: int = 12, rate: float = RATE) -> str:
    t = (np.arange(n) / rate).tolist()
    rows = [f"{ti!r},{0.5 if ti >= 0.05 else 0.0!r},{math.sin(ti)!r},{math.cos(ti)!r}" for ti in t]
    return "t,r,y,u\n" + "\n".join(rows) + "\n"


def make_session(folder: Path, doc: dict | None = None, n: int = 12) -> Path:
    doc = base_doc() if doc is None else doc
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "session.toml").write_text(to_toml(doc), encoding="utf-8")
    for run in doc["runs"]:
        path = folder / run["file"]
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(csv_text(n), encoding="utf-8")
    return folder


def awkward_session(loop: str = "lateral_x", n: int = 257, seed: int = 0) -> Session:
    """A session with floats that a naive writer would not round-trip."""
    rng = np.random.default_rng(seed)
    ts = 1.0 / 200.0
    t = (0.1 + 0.2) + np.arange(n) * ts
    special = np.array([0.1 + 0.2, 1e-300, -0.0, 5e-324, 1.7976931348623157e308,
                        -2.2250738585072014e-308, 1 / 3, math.pi, 0.0, -1e16])  # fmt: skip

    def col() -> np.ndarray:
        x = rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n)
        k = min(n, special.size)
        x[:k] = rng.permutation(special)[:k]
        return x

    model = ModelSpec(K=0.1 + 0.2, T_prop=1e-300, T1=0.8, tau=-0.0, noise_std=5e-324,
                      T2=1.5 if loop in ("lateral_x", "lateral_y") else None)  # fmt: skip
    runs = [
        Run(RunSpec("np.csv", "np-mrft", beta=-0.73, h=0.1 + 0.2, tau_obs=0.0325,
                    a_n=1e-300, bias=-0.0), RunData(t.copy(), col(), col(), col())),
        Run(RunSpec("sub dir/mrft, b=0.5.csv", "mrft", beta=0.5, h=2.0, bias=0.125),
            RunData(t.copy(), col(), col(), col())),
        Run(RunSpec("step.csv", "step", kp=-0.0, kd=1e-300, derivative_filter_hz=7.9577,
                    step=-(0.1 + 0.2), step_time=0.0), RunData(t.copy(), col(), col(), col())),
    ]  # fmt: skip
    effects = [EffectSpec(name, {p: 0.1 + 0.2 for p in params})
               for name, params in EFFECT_PARAMS.items()]  # fmt: skip
    return Session(loop=loop, control_rate_hz=200.0, runs=runs, model=model, effects=effects,
                   actuator=ActuatorSpec(command_min=-(0.1 + 0.2), command_max=1e-300))


def bits(a: np.ndarray) -> bytes:
    a = np.asarray(a)
    assert a.dtype == np.float64 and a.ndim == 1
    return a.tobytes()


def assert_same_session(a: Session, b: Session) -> None:
    # repr of dataclasses shows -0.0 and every float digit, so equal reprs
    # mean equal values bit for bit (== would confuse 0.0 and -0.0).
    assert repr(a.model) == repr(b.model)
    assert repr(a.actuator) == repr(b.actuator)
    assert repr(a.effects) == repr(b.effects)
    assert a.loop == b.loop
    assert repr(a.control_rate_hz) == repr(b.control_rate_hz)
    assert len(a.runs) == len(b.runs)
    for ra, rb in zip(a.runs, b.runs, strict=True):
        assert repr(ra.spec) == repr(rb.spec)
        for c in "tryu":
            assert bits(getattr(ra.data, c)) == bits(getattr(rb.data, c)), c


def run_cli(argv: list[str], monkeypatch, capsys) -> tuple[int, str, str]:
    monkeypatch.setattr(cli_main, "_COMMAND_MODULES", ["uavsim.cli.session_cmd"])
    rc = cli_main.main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def assert_one_line_error(exc: SessionError, folder: Path, fragment: str, word: str) -> None:
    msg = str(exc)
    assert "\n" not in msg
    assert msg.startswith(str(folder)), msg  # the offending path comes first
    assert fragment in msg, msg
    assert word.lower() in msg.lower(), msg


# ---------------------------------------------------------------------------
# Round trip


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    s = awkward_session()
    folder = write_session(s, tmp_path / "out")
    assert folder == tmp_path / "out"
    back = read_session(folder)
    assert back.path == folder
    assert_same_session(s, back)
    # Writing what was read gives the same bytes: nothing drifts on re-save.
    again = write_session(back, tmp_path / "again")
    for name in ["session.toml", "np.csv", "sub dir/mrft, b=0.5.csv", "step.csv"]:
        assert (folder / name).read_bytes() == (again / name).read_bytes(), name


@pytest.mark.parametrize("loop", LOOPS)
def test_round_trip_every_loop(tmp_path: Path, loop: str) -> None:
    s = awkward_session(loop=loop, n=20, seed=1)
    assert_same_session(s, read_session(write_session(s, tmp_path)))


def test_round_trip_without_model_or_effects(tmp_path: Path) -> None:
    s = awkward_session(n=5)
    s.model, s.effects, s.actuator = None, [], None
    folder = write_session(s, tmp_path / "s")
    assert "[actuator]" not in (folder / "session.toml").read_text()
    back = read_session(folder)
    assert back.model is None and back.effects == [] and back.actuator is None
    assert_same_session(s, back)


def test_actuator_range_is_written_and_summarized(tmp_path: Path) -> None:
    s = awkward_session(n=5)
    s.actuator = ActuatorSpec(command_min=-44.5, command_max=56.25)
    folder = write_session(s, tmp_path / "a")
    doc = tomllib.loads((folder / "session.toml").read_text())
    assert doc["actuator"] == {"command_min": -44.5, "command_max": 56.25}
    back = read_session(folder)
    assert session_mod.session_summary(back)["actuator"] == {"command_min": -44.5, "command_max": 56.25}


@pytest.mark.parametrize(("run", "other", "key", "word", "default"),
                         [(2, 0, "derivative", "measurement", "error"), (0, 1, "bias_trim", "duty", "off")])
def test_optional_word_key_round_trip(tmp_path: Path, run: int, other: int, key: str, word: str,
                                      default: str) -> None:
    # a step run's derivative, a relay run's bias_trim: the word is written and read back; the default
    # (what an absent key reads as) is not written
    s = awkward_session(n=10)
    setattr(s.runs[run].spec, key, word)
    folder = write_session(s, tmp_path / "w")
    assert f'{key} = "{word}"' in (folder / "session.toml").read_text()
    back = read_session(folder)
    assert getattr(back.runs[run].spec, key) == word and getattr(back.runs[other].spec, key) == default
    assert_same_session(s, back)
    setattr(s.runs[run].spec, key, default)
    assert f"{key} =" not in (write_session(s, tmp_path / "d") / "session.toml").read_text()


def test_round_trip_large_arrays(tmp_path: Path) -> None:
    s = awkward_session(n=100_000, seed=2)
    assert_same_session(s, read_session(write_session(s, tmp_path)))


def test_written_toml_values_equal_the_original(tmp_path: Path) -> None:
    # A hand-written file (comments, ints where floats are meant) read and
    # written again carries the same TOML values.
    src = make_session(tmp_path / "src")
    original = tomllib.loads((src / "session.toml").read_text())
    out = write_session(read_session(src), tmp_path / "out")
    written = tomllib.loads((out / "session.toml").read_text())
    assert written == original  # 1 == 1.0 in Python, so ints compare fine
    assert isinstance(written["runs"][1]["h"], float)
    for run in original["runs"]:
        assert (src / run["file"]).read_text() == (out / run["file"]).read_text()


def test_spec_example_with_comments_reads(tmp_path: Path) -> None:
    (tmp_path / "session.toml").write_text(
        'format = "uavsim-session/1"\n'
        'loop = "altitude"          # altitude | roll | pitch | lateral_x | lateral_y\n'
        "control_rate_hz = 200.0\n\n"
        "[model]                    # optional\n"
        "K = 20.0\nT_prop = 0.10\nT1 = 0.80\n# T2 = 1.5\ntau = 0.020\nnoise_std = 0.0014\n\n"
        '[[runs]]\nfile = "mrft_b073_h1.csv"\nkind = "np-mrft"\nbeta = -0.73\nh = 0.2\n'
        "tau_obs = 0.0325\na_n = 0.0028\n# bias = 0.0\n"
    )
    (tmp_path / "mrft_b073_h1.csv").write_text(csv_text(5, 200.0))
    s = read_session(tmp_path / "session.toml")
    assert s.path == tmp_path
    assert s.model == ModelSpec(K=20.0, T_prop=0.1, T1=0.8, tau=0.02, noise_std=0.0014)
    assert s.runs[0].spec == RunSpec("mrft_b073_h1.csv", "np-mrft", beta=-0.73, h=0.2,
                                     tau_obs=0.0325, a_n=0.0028)  # fmt: skip
    assert s.runs[0].data.t.dtype == np.float64 and s.runs[0].data.t.size == 5


def test_csv_with_bom_crlf_and_trailing_blank_lines_reads(tmp_path: Path) -> None:
    folder = make_session(tmp_path)
    text = csv_text(6).replace("\n", "\r\n")
    (folder / "np.csv").write_bytes(b"\xef\xbb\xbf" + text.encode() + b"\r\n\n")
    assert read_session(folder).runs[0].data.t.size == 6


def test_write_to_session_toml_path_and_overwrite(tmp_path: Path) -> None:
    s = awkward_session(n=10)
    folder = write_session(s, tmp_path / "x" / "session.toml")
    assert folder == tmp_path / "x"
    s.runs[0].data.y[3] = 42.0
    write_session(s, folder)  # overwriting an existing session is fine
    assert read_session(folder).runs[0].data.y[3] == 42.0
    assert not list(folder.rglob("*.tmp"))


@given(
    rate=st.floats(1.0, 1e4),
    t0=st.floats(-1e3, 1e3),
    cols=st.integers(2, 30).flatmap(
        lambda n: st.lists(
            st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=n, max_size=n),
            min_size=3,
            max_size=3,
        )
    ),
)
@HYPO
def test_round_trip_property(rate: float, t0: float, cols: list[list[float]]) -> None:
    n = len(cols[0])
    t = t0 + np.arange(n) / rate
    s = Session("roll", rate, [Run(RunSpec("a.csv", "mrft", beta=-0.2, h=0.5),
                                   RunData(t, *(np.array(c) for c in cols)))])  # fmt: skip
    with tempfile.TemporaryDirectory() as d:
        assert_same_session(s, read_session(write_session(s, d)))


# ---------------------------------------------------------------------------
# Writer behaviour


def test_write_rejects_invalid_session_and_writes_nothing(tmp_path: Path) -> None:
    s = awkward_session(n=10)
    s.runs[1].data.y[4] = math.nan
    with pytest.raises(SessionError) as info:
        write_session(s, tmp_path / "s")
    assert_one_line_error(info.value, tmp_path, "mrft, b=0.5.csv:6:", "finite")
    assert not (tmp_path / "s" / "session.toml").exists()


@pytest.mark.parametrize(
    ("mutate", "word"),
    [
        (lambda s: setattr(s.runs[0].spec, "file", "../evil.csv"), "inside"),
        (lambda s: setattr(s.runs[0].spec, "file", "/abs.csv"), "relative"),
        (lambda s: setattr(s.runs[1].spec, "file", "np.csv"), "already used"),
        (lambda s: setattr(s.runs[0].spec, "file", "session.toml"), "cannot be"),
        (lambda s: setattr(s.runs[2].spec, "bias", 0.5), "not a key of a step run"),
        (lambda s: setattr(s.runs[1].spec, "tau_obs", 0.1), "not a key of a mrft run"),
        (lambda s: setattr(s.runs[1].spec, "derivative", "measurement"), "not a key of a mrft run"),
        (lambda s: setattr(s.runs[2].spec, "derivative", "setpoint"), "unknown derivative of a step run 'setpoint'"),
        (lambda s: setattr(s.runs[2].spec, "bias_trim", "duty"), "not a key of a step run"),
        (lambda s: setattr(s.runs[1].spec, "bias_trim", "integral"), "unknown bias_trim of a mrft run 'integral'"),
        (lambda s: setattr(s, "runs", []), "no runs"),
        (
            lambda s: setattr(s.runs[0], "data", RunData(*(np.zeros(3),) * 3, np.zeros(4))),
            "lengths",
        ),
        (lambda s: setattr(s.effects[0], "params", {"delay": 0.1, "T": 1.0}), "not a parameter"),
        (lambda s: setattr(s, "loop", "yaw"), "unknown loop"),
    ],
)
def test_write_rejects(tmp_path: Path, mutate: Callable[[Session], None], word: str) -> None:
    s = awkward_session(n=10)
    mutate(s)
    with pytest.raises(SessionError, match=re.escape(word)):
        write_session(s, tmp_path)
    assert not (tmp_path / "session.toml").exists()


def test_interrupted_write_leaves_no_partial_files(tmp_path: Path, monkeypatch) -> None:
    old = awkward_session(n=10, seed=3)
    folder = write_session(old, tmp_path / "s")
    new = awkward_session(n=10, seed=4)
    real_replace = os.replace
    calls = []

    def flaky_replace(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise KeyboardInterrupt  # the user hits ^C mid-write
        real_replace(src, dst)

    monkeypatch.setattr(session_mod.os, "replace", flaky_replace)
    with pytest.raises(KeyboardInterrupt):
        write_session(new, folder)
    monkeypatch.undo()
    assert not list(folder.rglob("*.tmp"))
    # session.toml goes last, so the old one is still there and every file it
    # points at is complete (the first CSV was replaced whole).
    back = read_session(folder)
    assert repr(back.model) == repr(old.model)
    assert bits(back.runs[0].data.y) == bits(new.runs[0].data.y)
    assert bits(back.runs[1].data.y) == bits(old.runs[1].data.y)


def test_unwritable_target_is_session_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(SessionError, match="cannot write"):
        write_session(awkward_session(n=4), tmp_path / "file")


# ---------------------------------------------------------------------------
# validate_run_params, shared with the controllers


def test_validate_run_params_accepts_valid_specs() -> None:
    validate_run_params(RunSpec("", "np-mrft", beta=-0.73, h=0.2, tau_obs=0.0, a_n=0.0), "x")
    validate_run_params(RunSpec("", "mrft", beta=0.0, h=1, bias=-2.0), "x")
    validate_run_params(RunSpec("", "step", kp=1.0, kd=0.0, derivative_filter_hz=10.0,
                                step=-1.0, step_time=0.0), "x")  # fmt: skip


@pytest.mark.parametrize(
    ("spec", "word"),
    [
        (RunSpec("", "np-mrft", beta=1.0, h=0.2, tau_obs=0.0, a_n=0.0), "beta must be in (-1, 1)"),
        (RunSpec("", "np-mrft", beta=-1.0, h=0.2, tau_obs=0.0, a_n=0.0), "beta"),
        (RunSpec("", "np-mrft", beta=0.1, h=0.0, tau_obs=0.0, a_n=0.0), "h must be > 0"),
        (RunSpec("", "np-mrft", beta=0.1, h=0.2, tau_obs=-1e-9, a_n=0.0), "tau_obs must be >= 0"),
        (RunSpec("", "np-mrft", beta=0.1, h=0.2, tau_obs=0.0, a_n=-1.0), "a_n must be >= 0"),
        (RunSpec("", "np-mrft", beta=0.1, h=0.2, tau_obs=0.0), "missing key 'a_n'"),
        (RunSpec("", "mrft", beta=0.1, h=math.inf), "finite"),
        (RunSpec("", "mrft", beta=0.1, h=0.2, bias=math.nan), "finite"),
        (RunSpec("", "mrft", beta=0.1, h=0.2, a_n=0.0), "not a key of a mrft run"),
        (RunSpec("", "step", kp=math.nan, kd=0.0, derivative_filter_hz=1.0, step=1.0,
                 step_time=0.0), "finite"),
        (RunSpec("", "step", kp=1.0, kd=0.0, derivative_filter_hz=0.0, step=1.0,
                 step_time=0.0), "derivative_filter_hz must be > 0"),
        (RunSpec("", "step", kp=1.0, kd=0.0, derivative_filter_hz=1.0, step=1.0,
                 step_time=-1.0), "step_time must be >= 0"),
        (RunSpec("", "step", kp=True, kd=0.0, derivative_filter_hz=1.0, step=1.0,
                 step_time=0.0), "must be a number"),
        (RunSpec("", "relay", beta=0.1, h=0.2), "unknown run kind"),
        (RunSpec("", "mrft", beta=0.1, h=0.2, bias=None), "bias must be a number"),
    ],
)  # fmt: skip
def test_validate_run_params_rejects(spec: RunSpec, word: str) -> None:
    with pytest.raises(SessionError) as info:
        validate_run_params(spec, "ctl")
    assert str(info.value).startswith("ctl: ")
    assert word in str(info.value)


def test_public_constants() -> None:
    assert FORMAT == "uavsim-session/2"
    assert FORMATS == {"uavsim-session/1": 1, "uavsim-session/2": 2}
    assert LOOPS == ("altitude", "roll", "pitch", "lateral_x", "lateral_y")
    assert EFFECT_PARAMS["delay"] == ("delay",) and EFFECT_PARAMS["none"] == ()
    assert set(EFFECT_PARAMS) == {"none", "delay", "lag", "gain", "saturation", "dead_zone",
                                  "rate_limit", "bias", "quantization", "sample_hold",
                                  "lowpass", "noise"}  # fmt: skip
    assert issubclass(SessionError, UserError)


# ---------------------------------------------------------------------------
# Malformed sessions: one case per problem of the spec


def doc_case(mutate: Callable[[dict], object]) -> Callable[[Path], None]:
    def apply(folder: Path) -> None:
        doc = base_doc()
        mutate(doc)
        (folder / "session.toml").write_text(to_toml(doc))
        for run in doc["runs"] if isinstance(doc.get("runs"), list) else []:
            if isinstance(run, dict) and isinstance(run.get("file"), str):
                path = folder / run["file"]
                if not path.exists() and ".." not in run["file"] and not os.path.isabs(run["file"]):
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.write_text(csv_text())

    return apply


def csv_case(text: str | bytes, file: str = "np.csv") -> Callable[[Path], None]:
    def apply(folder: Path) -> None:
        data = text.encode() if isinstance(text, str) else text
        (folder / file).write_bytes(data)

    return apply


def csv_edit(edit: Callable[[list[str]], None]) -> Callable[[Path], None]:
    def apply(folder: Path) -> None:
        lines = csv_text().splitlines()
        edit(lines)
        (folder / "np.csv").write_text("\n".join(lines) + "\n")

    return apply


def set_cell(row_line: int, col: int, value: str) -> Callable[[list[str]], None]:
    def edit(lines: list[str]) -> None:
        cells = lines[row_line - 1].split(",")
        cells[col] = value
        lines[row_line - 1] = ",".join(cells)

    return edit


def _set(path: tuple, value) -> Callable[[dict], None]:
    def mutate(doc: dict) -> None:
        node = doc
        for p in path[:-1]:
            node = node[p]
        node[path[-1]] = value

    return mutate


def _del(path: tuple) -> Callable[[dict], None]:
    def mutate(doc: dict) -> None:
        node = doc
        for p in path[:-1]:
            node = node[p]
        del node[path[-1]]

    return mutate


def _both(*fs: Callable[[dict], None]) -> Callable[[dict], None]:
    def mutate(doc: dict) -> None:
        for f in fs:
            f(doc)

    return mutate


def _swap_rows(lines: list[str]) -> None:
    lines[4], lines[5] = lines[5], lines[4]


def _rm(name: str) -> Callable[[Path], None]:
    return lambda folder: (folder / name).unlink()


TOML, NP = "session.toml", "np.csv"
MALFORMED = {
    # files
    "missing_toml": (_rm("session.toml"), TOML, "missing"),
    "missing_run_file": (_rm("np.csv"), NP, "not found"),
    "toml_syntax": (csv_case('format = "uavsim-session/1"\nloop = \n', TOML), TOML, "TOML syntax"),
    "toml_not_utf8": (csv_case(b'format = "\xff"\n', TOML), TOML, "UTF-8"),
    # format
    "format_wrong": (doc_case(_set(("format",), "uavsim-session/3")), TOML, "unsupported format"),
    "format_missing": (doc_case(_del(("format",))), TOML, "missing key 'format'"),
    "format_not_string": (doc_case(_set(("format",), 1)), TOML, "must be a string"),
    # unknown keys, with the closest valid one
    "unknown_top_key": (doc_case(_set(("lop",), "x")), TOML, "unknown key 'lop' (did you mean 'loop'?)"),
    "unknown_model_key": (doc_case(_set(("model", "Tprop"), 0.1)), TOML, "did you mean 'T_prop'"),
    "unknown_run_key": (doc_case(_set(("runs", 0, "bta"), 0.1)), TOML, "did you mean 'beta'"),
    "unknown_effect_key": (doc_case(_set(("effects", 0, "dealy"), 0.1)), TOML, "did you mean 'delay'"),
    "unknown_far_key": (doc_case(_set(("runs", 2, "zzz"), 0.1)), TOML, "valid keys"),
    "other_kind_key": (doc_case(_set(("runs", 1, "tau_obs"), 0.1)), TOML, "not a key of a mrft run"),
    "step_with_bias": (doc_case(_set(("runs", 2, "bias"), 0.1)), TOML, "not a key of a step run"),
    "relay_with_derivative": (doc_case(_set(("runs", 0, "derivative"), "measurement")), TOML,
                              "not a key of a np-mrft run"),
    "other_effect_param": (doc_case(_set(("effects", 0, "T"), 0.1)), TOML, "not a parameter of a delay effect"),
    # missing keys
    "missing_loop": (doc_case(_del(("loop",))), TOML, "missing key 'loop'"),
    "missing_rate": (doc_case(_del(("control_rate_hz",))), TOML, "missing key 'control_rate_hz'"),
    "missing_runs": (doc_case(_del(("runs",))), TOML, "missing key 'runs'"),
    "empty_runs": (doc_case(_set(("runs",), [])), TOML, "no runs"),
    "missing_run_file_key": (doc_case(_del(("runs", 0, "file"))), TOML, "missing key 'file'"),
    "missing_run_kind": (doc_case(_del(("runs", 0, "kind"))), TOML, "missing key 'kind'"),
    "missing_h": (doc_case(_del(("runs", 0, "h"))), TOML, "missing key 'h'"),
    "missing_a_n": (doc_case(_del(("runs", 0, "a_n"))), TOML, "missing key 'a_n'"),
    "missing_step_time": (doc_case(_del(("runs", 2, "step_time"))), TOML, "missing key 'step_time'"),
    "missing_model_tau": (doc_case(_del(("model", "tau"))), TOML, "missing key 'tau'"),
    "missing_effect_name": (doc_case(_del(("effects", 0, "name"))), TOML, "missing key 'name'"),
    "missing_effect_param": (doc_case(_del(("effects", 0, "delay"))), TOML, "missing key 'delay'"),
    # wrong types
    "rate_string": (doc_case(_set(("control_rate_hz",), "200")), TOML, "must be a number, got string"),
    "K_bool": (doc_case(_set(("model", "K"), True)), TOML, "must be a number, got boolean"),
    "beta_string": (doc_case(_set(("runs", 0, "beta"), "-0.7")), TOML, "beta must be a number"),
    "kp_array": (doc_case(_set(("runs", 2, "kp"), [1, 2])), TOML, "kp must be a number, got array"),
    "h_date": (doc_case(_set(("runs", 1, "h"), dt.date(2024, 5, 1))), TOML, "date/time"),
    "effect_param_string": (doc_case(_set(("effects", 0, "delay"), "0.1")), TOML, "must be a number"),
    "loop_number": (doc_case(_set(("loop",), 3)), TOML, "loop must be a string"),
    "kind_number": (doc_case(_set(("runs", 0, "kind"), 1)), TOML, "kind must be a string"),
    "file_number": (doc_case(_set(("runs", 0, "file"), 1)), TOML, "file must be a string"),
    "runs_string": (doc_case(_set(("runs",), "np.csv")), TOML, "array of tables"),
    "model_number": (doc_case(_set(("model",), 1.0)), TOML, "must be a table"),
    "actuator_number": (doc_case(_set(("actuator",), 3.0)), TOML, "actuator must be a table"),
    "actuator_missing_max": (doc_case(_set(("actuator",), {"command_min": -3.0})), TOML, "missing key 'command_max'"),
    "actuator_unknown_key": (doc_case(_set(("actuator",), {"command_min": -3.0, "command_max": 4.0, "max": 1.0})),
                             TOML, "unknown key"),
    "actuator_min_positive": (doc_case(_set(("actuator",), {"command_min": 1.0, "command_max": 4.0})), TOML,
                              "command_min must be < 0"),
    "actuator_max_zero": (doc_case(_set(("actuator",), {"command_min": -1.0, "command_max": 0})), TOML,
                          "command_max must be > 0"),
    "actuator_string": (doc_case(_set(("actuator",), {"command_min": "-1", "command_max": 2.0})), TOML,
                        "command_min must be a number"),
    "effects_table": (doc_case(_set(("effects",), {"name": "delay"})), TOML, "array of tables"),
    "huge_int": (doc_case(_set(("model", "K"), 10**400)), TOML, "out of range"),
    # bad names
    "bad_loop": (doc_case(_set(("loop",), "altitdue")), TOML, "unknown loop 'altitdue' (did you mean 'altitude'?"),
    "bad_kind": (doc_case(_set(("runs", 0, "kind"), "np_mrft")), TOML, "unknown run kind"),
    "bad_effect": (doc_case(_set(("effects", 0, "name"), "dealy")), TOML, "unknown effect name"),
    "bad_derivative": (doc_case(_set(("runs", 2, "derivative"), "measurment")), TOML,
                       "unknown derivative of a step run 'measurment' (did you mean 'measurement'?"),
    "derivative_number": (doc_case(_set(("runs", 2, "derivative"), 1)), TOML, "derivative must be a string"),
    "bad_bias_trim": (doc_case(_set(("runs", 0, "bias_trim"), "dutty")), TOML,
                      "unknown bias_trim of a np-mrft run 'dutty' (did you mean 'duty'?"),
    "step_with_bias_trim": (doc_case(_set(("runs", 2, "bias_trim"), "duty")), TOML, "not a key of a step run"),
    # invalid values
    "beta_out_of_range": (doc_case(_set(("runs", 0, "beta"), 1.2)), TOML, "beta must be in (-1, 1)"),
    "h_negative": (doc_case(_set(("runs", 1, "h"), -1)), TOML, "h must be > 0"),
    "tau_obs_negative": (doc_case(_set(("runs", 0, "tau_obs"), -0.01)), TOML, "tau_obs must be >= 0"),
    "filter_zero": (doc_case(_set(("runs", 2, "derivative_filter_hz"), 0)), TOML, "derivative_filter_hz must be > 0"),
    "rate_zero": (doc_case(_set(("control_rate_hz",), 0)), TOML, "control_rate_hz must be > 0"),
    "rate_inf": (doc_case(_set(("control_rate_hz",), math.inf)), TOML, "finite"),
    "K_zero": (doc_case(_set(("model", "K"), 0.0)), TOML, "K must be non-zero"),
    "T1_negative": (doc_case(_set(("model", "T1"), -0.8)), TOML, "T1 must be > 0"),
    "tau_negative": (doc_case(_set(("model", "tau"), -0.01)), TOML, "tau must be >= 0"),
    "noise_negative": (doc_case(_set(("model", "noise_std"), -1)), TOML, "noise_std must be >= 0"),
    "T2_not_lateral": (doc_case(_set(("model", "T2"), 1.5)), TOML, "'T2' is not a key"),
    "T2_missing_lateral": (doc_case(_set(("loop",), "lateral_y")), TOML, "missing key 'T2'"),
    "effect_negative_delay": (doc_case(_set(("effects", 0, "delay"), -0.1)), TOML, "delay must be >= 0"),
    "effect_lag_zero": (doc_case(_set(("effects", 0), {"name": "lag", "T": 0})), TOML, "T must be > 0"),
    "effect_none_param": (doc_case(_set(("effects", 0), {"name": "none", "std": 1.0})), TOML, "not a parameter of a none effect"),
    "file_escapes": (doc_case(_set(("runs", 0, "file"), "../np.csv")), TOML, "inside the session folder"),
    "file_absolute": (doc_case(_set(("runs", 0, "file"), "/tmp/np.csv")), TOML, "relative"),
    "file_duplicate": (doc_case(_set(("runs", 1, "file"), "./np.csv")), TOML, "already used"),
    "file_control_char": (doc_case(_set(("runs", 0, "file"), "a\nb.csv")), TOML, "control characters"),
    "key_with_newline": (doc_case(_set(("a\nb",), 1)), TOML, "unknown key"),
    # CSV
    "header_missing_column": (csv_edit(lambda ls: ls.__setitem__(0, "t,r,y,x")), "np.csv:1:", "missing column 'u'"),
    "header_short": (csv_edit(lambda ls: ls.__setitem__(0, "t,r,y")), "np.csv:1:", "missing column 'u'"),
    "header_extra": (csv_edit(lambda ls: ls.__setitem__(0, "t,r,y,u,v")), "np.csv:1:", "extra column 'v'"),
    "header_reordered": (csv_edit(lambda ls: ls.__setitem__(0, "t,y,r,u")), "np.csv:1:", "out of order"),
    "header_spaces": (csv_edit(lambda ls: ls.__setitem__(0, "t, r, y, u")), "np.csv:1:", "header"),
    "cell_text": (csv_edit(set_cell(5, 2, "abc")), "np.csv:5:", "y cell 'abc' is not a number"),
    "cell_empty": (csv_edit(set_cell(3, 0, "")), "np.csv:3:", "not a number"),
    "cell_nan": (csv_edit(set_cell(7, 1, "nan")), "np.csv:7:", "r is nan"),
    "cell_inf": (csv_edit(set_cell(8, 3, "-inf")), "np.csv:8:", "finite"),
    "too_few_cells": (csv_edit(lambda ls: ls.__setitem__(4, "0.03,0,1")), "np.csv:5:", "3 cells, expected 4"),
    "too_many_cells": (csv_edit(lambda ls: ls.__setitem__(4, ls[4] + ",1")), "np.csv:5:", "5 cells"),
    "blank_line": (csv_edit(lambda ls: ls.insert(3, "")), "np.csv:4:", "empty line"),
    "no_rows": (csv_case("t,r,y,u\n"), NP, "no data rows"),
    "empty_file": (csv_case(""), NP, "empty file"),
    "one_row": (csv_case("t,r,y,u\n0.0,0,0,0\n"), NP, "at least 2"),
    "t_swapped": (csv_edit(_swap_rows), "np.csv:6:", "t is not increasing (0.03 after 0.04)"),
    "t_repeated": (csv_edit(lambda ls: ls.insert(4, ls[4])), "np.csv:6:", "not increasing"),
    "t_gap": (csv_edit(lambda ls: ls.pop(4)), "np.csv:5:", "t spacing"),
    "t_rate_mismatch": (csv_case(csv_text(12, rate=50.0)), "np.csv:3:", "expected 1/control_rate_hz"),
    "csv_not_utf8": (csv_case(b"t,r,y,u\n\xff\n"), NP, "UTF-8"),
    "csv_is_folder": (lambda f: ((f / NP).unlink(), (f / NP).mkdir()), NP, "not a regular file"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_session(tmp_path: Path, case: str) -> None:
    apply, fragment, word = MALFORMED[case]
    folder = make_session(tmp_path / "sess")
    apply(folder)
    with pytest.raises(SessionError) as info:
        read_session(folder)
    assert_one_line_error(info.value, folder, fragment, word)


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_session_cli(tmp_path: Path, case: str, monkeypatch, capsys) -> None:
    apply, fragment, word = MALFORMED[case]
    folder = make_session(tmp_path / "sess")
    apply(folder)
    rc, out, err = run_cli(["session", "check", str(folder), "--json"], monkeypatch, capsys)
    assert rc == 2
    assert out == ""
    assert err.count("\n") == 1 and err.endswith("\n")
    assert "Traceback" not in err
    assert fragment in err and word.lower() in err.lower()


def test_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="no such session"):
        read_session(tmp_path / "nope")


def test_toml_error_names_the_line(tmp_path: Path) -> None:
    folder = make_session(tmp_path)
    (folder / "session.toml").write_text('format = "uavsim-session/1"\nloop = "roll"\nx = = 1\n')
    with pytest.raises(SessionError, match=r"session\.toml: TOML syntax error: .*line 3"):
        read_session(folder)


# ---------------------------------------------------------------------------
# CLI on a valid session


def test_cli_check_text(tmp_path: Path, monkeypatch, capsys) -> None:
    folder = make_session(tmp_path / "sess")
    rc, out, err = run_cli(["session", "check", str(folder)], monkeypatch, capsys)
    assert rc == 0, err
    assert "altitude" in out and "np-mrft" in out and "runs/step.csv" in out
    assert "delay" in out


def test_cli_check_json(tmp_path: Path, monkeypatch, capsys) -> None:
    folder = make_session(tmp_path / "sess", n=11)
    rc, out, err = run_cli(
        ["session", "check", str(folder / "session.toml"), "--json"], monkeypatch, capsys
    )
    assert rc == 0, err
    assert out.count("\n") == 1
    obj = json.loads(out)
    assert set(obj) == {"path", "format", "loop", "control_rate_hz", "model", "actuator", "runs", "effects"}
    assert obj["format"] == FORMAT
    assert obj["path"] == str(folder)
    assert obj["loop"] == "altitude" and obj["control_rate_hz"] == RATE
    assert obj["model"]["K"] == 20.0 and obj["model"]["T2"] is None
    assert obj["effects"] == [{"name": "delay", "params": {"delay": 0.021}}]
    np_run, mrft_run, step_run = obj["runs"]
    assert np_run == {"file": "np.csv", "kind": "np-mrft", "samples": 11, "duration_s": 0.1,
                      "beta": -0.73, "h": 0.2, "tau_obs": 0.0325, "a_n": 0.0028, "bias": 0.0,
                      "bias_trim": "off"}  # fmt: skip
    assert mrft_run["bias"] == 0.05 and "tau_obs" not in mrft_run
    assert step_run["kind"] == "step" and step_run["step_time"] == 1.0 and "bias" not in step_run
    assert "bias_trim" not in step_run


def test_cli_check_no_model(tmp_path: Path, monkeypatch, capsys) -> None:
    doc = base_doc()
    del doc["model"], doc["effects"]
    folder = make_session(tmp_path / "sess", doc)
    rc, out, _ = run_cli(["session", "check", str(folder), "--json"], monkeypatch, capsys)
    assert rc == 0 and json.loads(out)["model"] is None and json.loads(out)["effects"] == []
    rc, out, _ = run_cli(["session", "check", str(folder)], monkeypatch, capsys)
    assert rc == 0 and "none" in out


# ---------------------------------------------------------------------------
# Property-based: corruption only ever gives SessionError

TOKENS = ["nan", "NaN", "-nan", "inf", "-inf", "Infinity", "abc", "", " ", "1.0.0", "0x10",
          "--1", "1e", "1,5", "\"1\"", "true"]  # fmt: skip
ALNUM = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_"


def _expect_session_error(folder: Path) -> SessionError:
    try:
        read_session(folder)
    except SessionError as exc:
        msg = str(exc)
        assert "\n" not in msg and msg.startswith(str(folder)), msg
        return exc
    raise AssertionError("corrupted session was accepted")


@given(data=st.data())
@HYPO
def test_corrupted_csv_is_session_error(data: st.DataObject) -> None:
    file = data.draw(st.sampled_from(["np.csv", "mrft.csv", "runs/step.csv"]), label="file")
    lines = csv_text(12).splitlines()
    n = len(lines)  # header + 12 rows
    how = data.draw(st.sampled_from(["inject", "drop", "extra", "swap", "dup", "delete", "shift"]))
    row = data.draw(st.integers(1, n - 1), label="row")
    if how == "inject":
        col = data.draw(st.integers(0, 3), label="col")
        token = data.draw(st.sampled_from(TOKENS) | st.text("abcdefinty", min_size=1, max_size=8))
        cells = lines[row].split(",")
        cells[col] = token
        lines[row] = ",".join(cells)
    elif how == "drop":
        cells = lines[row].split(",")
        del cells[data.draw(st.integers(0, 3), label="col")]
        lines[row] = ",".join(cells)
    elif how == "extra":
        lines[row] += "," + data.draw(st.sampled_from(["0", "1.5", ""]))
    elif how == "swap":
        other = data.draw(st.integers(1, n - 1).filter(lambda j: j != row), label="other")
        lines[row], lines[other] = lines[other], lines[row]
    elif how == "dup":
        lines.insert(row, lines[row])
    elif how == "delete":
        del lines[data.draw(st.integers(2, n - 2), label="inner row")]
    else:  # shift one t by a visible fraction of Ts
        frac = data.draw(st.sampled_from([-0.6, -0.2, 0.01, 0.3, 2.0]))
        cells = lines[row].split(",")
        cells[0] = repr(float(cells[0]) + frac / RATE)
        lines[row] = ",".join(cells)
    with tempfile.TemporaryDirectory() as d:
        folder = make_session(Path(d))
        (folder / file).write_text("\n".join(lines) + "\n")
        exc = _expect_session_error(folder)
        assert file in str(exc)


def _allowed_keys(table: str) -> set[str]:
    if table == "top":
        return set(session_mod._TOP_KEYS)
    if table == "model":
        return {"K", "T_prop", "T1", "tau", "noise_std"}  # altitude: no T2
    if table == "effect":
        return {"name", "delay"}
    kind = base_doc()["runs"][int(table[-1])]["kind"]
    required, optional = session_mod.RUN_KEYS[kind]
    return {"file", "kind", *required, *optional}


def _table(doc: dict, table: str) -> dict:
    if table == "top":
        return doc
    if table == "model":
        return doc["model"]
    if table == "effect":
        return doc["effects"][0]
    return doc["runs"][int(table[-1])]


TABLES = ["top", "model", "run0", "run1", "run2", "effect"]


@given(
    table=st.sampled_from(TABLES),
    key=st.text(ALNUM, min_size=1, max_size=12),
    value=st.sampled_from([1.0, 0, "x", True]),
)
@HYPO
def test_unknown_key_is_session_error(table: str, key: str, value) -> None:
    if key in _allowed_keys(table):
        return  # not unknown: nothing to test
    doc = base_doc()
    _table(doc, table)[key] = value
    with tempfile.TemporaryDirectory() as d:
        folder = make_session(Path(d), doc)
        exc = _expect_session_error(folder)
        assert "session.toml" in str(exc) and repr(key) in str(exc)


STRING_KEYS = {"format", "loop", "kind", "file", "name"}
SAFE_TEXT = st.text(ALNUM + " .-", max_size=8)
NOT_A_NUMBER = st.one_of(
    SAFE_TEXT,
    st.booleans(),
    st.lists(st.integers(-5, 5), max_size=3),
    st.dictionaries(st.text("abc", min_size=1, max_size=3), st.integers(0, 3), max_size=2),
    st.dates(min_value=dt.date(1000, 1, 1)),
    st.datetimes(min_value=dt.datetime(1000, 1, 1)),
)
NOT_A_STRING = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.floats(),
    st.booleans(),
    st.lists(SAFE_TEXT, max_size=2),
    st.dates(min_value=dt.date(1000, 1, 1)),
)


@given(data=st.data())
@HYPO
def test_wrong_type_is_session_error(data: st.DataObject) -> None:
    doc = base_doc()
    table = data.draw(st.sampled_from(TABLES), label="table")
    target = _table(doc, table)
    key = data.draw(st.sampled_from(sorted(target)), label="key")
    if key in ("model", "runs", "effects"):
        value = data.draw(st.one_of(SAFE_TEXT, st.integers(), st.booleans()), label="value")
    elif key in STRING_KEYS:
        value = data.draw(NOT_A_STRING, label="value")
    else:
        value = data.draw(NOT_A_NUMBER, label="value")
    target[key] = value
    with tempfile.TemporaryDirectory() as d:
        folder = make_session(Path(d), base_doc())  # CSVs for the original file names
        (folder / "session.toml").write_text(to_toml(doc))
        exc = _expect_session_error(folder)
        assert "session.toml" in str(exc)


@given(raw=st.binary(max_size=200), where=st.sampled_from(["session.toml", "np.csv"]))
@HYPO
def test_random_bytes_are_session_error(raw: bytes, where: str) -> None:
    with tempfile.TemporaryDirectory() as d:
        folder = make_session(Path(d))
        (folder / where).write_bytes(raw)
        exc = _expect_session_error(folder)
        assert where in str(exc)


def test_version_1_is_read_with_its_reading_and_written_back_as_version_1(tmp_path: Path) -> None:
    (tmp_path / "session.toml").write_text(
        'format = "uavsim-session/1"\nloop = "altitude"\ncontrol_rate_hz = 200.0\n\n'
        '[[runs]]\nfile = "np.csv"\nkind = "np-mrft"\nbeta = -0.73\nh = 0.2\ntau_obs = 0.0325\na_n = 0.0028\n'
    )
    (tmp_path / "np.csv").write_text(csv_text(5, 200.0))
    s = read_session(tmp_path)
    assert s.format == "uavsim-session/1" and s.reading == 1
    out = write_session(s, tmp_path / "copy")
    assert 'format = "uavsim-session/1"' in (out / "session.toml").read_text()
    # a new session is version 2, with the half-wave reading
    s.format = FORMAT
    assert s.reading == 2
    assert 'format = "uavsim-session/2"' in (write_session(s, tmp_path / "v2") / "session.toml").read_text()
    s.format = "uavsim-session/9"
    with pytest.raises(SessionError, match="format"):
        write_session(s, tmp_path / "bad")
