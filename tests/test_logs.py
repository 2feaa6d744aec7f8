"""Flight logs in: ULog and DataFlash logs written in their formats become sessions that identify as
the flight they came from; bad logs are one-line errors and write nothing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _learning_fixtures import CLASSES, three_model  # noqa: F401 (fixture)
from _log_writers import write_dataflash, write_ulog

import uavsim.cli.main as cli_main
from uavsim.errors import UserError
from uavsim.formats.session import read_session, write_session
from uavsim.ident.session import identify_session
from uavsim.logs import detect_relay, import_log

HOVER = 0.45  # the thrust the relay is added to (normalized)
T0_US = 12_000_000  # log time of the relay's first tick
PRE_S = 2.0  # hover before the relay test


@pytest.fixture(scope="module")
def flight(three_model, tmp_path_factory):  # noqa: F811
    """A relay run of a known altitude class (MuJoCo) and its identification: what the logs must give back."""
    from test_identify import _mujoco_session

    tmp, model, grid = three_model
    folder = tmp_path_factory.mktemp("flight")
    s = _mujoco_session(grid, CLASSES[1])
    src = write_session(s, folder / "source")
    return {"session": read_session(src), "path": src, "model": model,
            "answer": identify_session(src, models=model)}


def _ticks(run, rate):
    n_pre = int(PRE_S * rate)
    n = n_pre + run.data.t.size
    tick_us = T0_US - n_pre * int(1e6 / rate) + np.arange(n) * int(1e6 / rate)
    u = np.r_[np.full(n_pre, 0.0), run.data.u]  # relay command; 0 before the test (plain hover)
    y = np.r_[np.full(n_pre, run.data.y[0]), run.data.y]
    r = np.r_[np.full(n_pre, run.data.r[0]), run.data.r]
    return n_pre, tick_us, r, y, u


def px4_log(path: Path, flight, *, y_offset_us: int = -100, u_offset_us: int = 300, edit=None) -> Path:
    """The flight as PX4 logs it: NED z (down), thrust setpoint z (down, hover added), own timestamps."""
    s = flight["session"]
    n_pre, tick, r, y, u = _ticks(s.runs[0], s.control_rate_hz)
    thrust = np.c_[np.zeros_like(u), np.zeros_like(u), -(HOVER + u)]
    topics = {
        "vehicle_local_position": ([("float", "x"), ("float", "z")], tick + y_offset_us, np.c_[0 * y, -y]),
        "trajectory_setpoint": ([("float", f"position[{i}]") for i in range(3)], tick + y_offset_us,
                                np.c_[0 * r, 0 * r, -r]),
        "vehicle_thrust_setpoint": ([("float", f"xyz[{i}]") for i in range(3)], tick + u_offset_us, thrust),
    }
    if edit:
        edit(topics)
    return write_ulog(path, topics)


def ardupilot_log(path: Path, flight, edit=None) -> Path:
    s = flight["session"]
    _, tick, r, y, u = _ticks(s.runs[0], s.control_rate_hz)
    rows = np.c_[tick, r, y, HOVER + u]
    msgs = {"CTUN": (["TimeUS", "DAlt", "Alt", "ThO"], "Qfff", rows),
            "ATT": (["TimeUS", "Roll"], "Qf", np.c_[tick[::4], 0 * tick[::4]])}
    if edit:
        edit(msgs)
    return write_dataflash(path, msgs)


def _spec(flight) -> dict:
    sp = flight["session"].runs[0].spec
    return {"kind": sp.kind, "beta": sp.beta, "tau_obs": sp.tau_obs, "a_n": sp.a_n}


def _same_identification(ans, want):
    assert ans["class"] == want["class"]
    for k in ("K", "tau", "T_prop", "T1"):
        assert ans["params"][k] == pytest.approx(want["params"][k], rel=1e-3, abs=1e-5), k
    for k in ("kp", "kd"):
        assert ans["gains"][k] == pytest.approx(want["gains"][k], rel=1e-3), k
    assert ans["oscillation"]["period"] == pytest.approx(want["oscillation"]["period"], rel=1e-3)


def test_ulog_round_trip_identifies_as_the_flight(flight, tmp_path):
    log = px4_log(tmp_path / "flight.ulg", flight)
    found = []
    ans = import_log(log, tmp_path / "s", preset="px4-altitude", log_fn=found.append, **_spec(flight))
    src = flight["session"].runs[0]
    assert ans["rate_hz"] == flight["session"].control_rate_hz and ans["detected"]["rate_hz"] == ans["rate_hz"]
    assert ans["start"] == pytest.approx(T0_US * 1e-6 + 300e-6)  # the relay segment, found in u
    assert ans["run"]["h"] == pytest.approx(src.spec.h, rel=1e-6)
    assert ans["run"]["bias"] == pytest.approx(HOVER + src.spec.bias, rel=1e-6)
    assert any("relay levels detected" in f for f in found) and any("relay segment" in f for f in found)
    s = read_session(tmp_path / "s")
    run = s.runs[0]
    n = run.data.t.size
    assert src.data.t.size - 2 <= n <= src.data.t.size
    # the controller's samples come back exactly (as float32, the log's type), on the controller's ticks
    np.testing.assert_array_equal(run.data.y, src.data.y[:n].astype(np.float32).astype(np.float64))
    np.testing.assert_allclose(run.data.u - ans["run"]["bias"], src.data.u[:n] - src.spec.bias, atol=1e-6)
    _same_identification(identify_session(tmp_path / "s", models=flight["model"]), flight["answer"])


def test_trimmed_relay_log_needs_its_levels_and_is_written_trimmed(flight, tmp_path):
    """A flight whose relay trimmed its bias: its levels are not detected (u has more than two), so the import
    asks for them in one line; given, the run is written with ``bias_trim = "duty"`` and read by its states."""
    log = px4_log(tmp_path / "flight.ulg", flight)
    with pytest.raises(UserError, match="pass --h, --bias"):
        import_log(log, tmp_path / "none", preset="px4-altitude", bias_trim="duty", **_spec(flight))
    assert not (tmp_path / "none").exists()
    src = flight["session"].runs[0]
    t0 = T0_US * 1e-6 + 300e-6
    ans = import_log(log, tmp_path / "s", preset="px4-altitude", bias_trim="duty", h=src.spec.h,
                     bias=HOVER + src.spec.bias, start=t0, stop=t0 + src.data.t[-1], **_spec(flight))
    assert ans["run"]["bias_trim"] == "duty" and read_session(tmp_path / "s").runs[0].spec.bias_trim == "duty"
    _same_identification(identify_session(tmp_path / "s", models=flight["model"]), flight["answer"])


def test_dataflash_round_trip_identifies_as_the_flight(flight, tmp_path, capsys):
    log = ardupilot_log(tmp_path / "00000001.BIN", flight)
    sp = _spec(flight)
    argv = ["session", "import", str(log), "--preset", "ardupilot-altitude", "--out", str(tmp_path / "s"),
            "--beta", str(sp["beta"]), "--tau-obs", str(sp["tau_obs"]), "--a-n", str(sp["a_n"]), "--json"]
    assert cli_main.main(argv) == 0
    ans = json.loads(capsys.readouterr().out)
    assert ans["format"] == "dataflash" and ans["loop"] == "altitude"
    src = flight["session"].runs[0]
    run = read_session(tmp_path / "s").runs[0]
    np.testing.assert_array_equal(run.data.r, src.data.r[: run.data.t.size].astype(np.float32))
    assert cli_main.main(["identify", str(tmp_path / "s"), "--models", str(flight["model"]), "--json"]) == 0
    _same_identification(json.loads(capsys.readouterr().out), flight["answer"])


def _drop(topic, a, b):
    def edit(topics):
        fields, t, v = topics[topic][:3] if len(topics[topic]) == 3 else topics[topic]
        keep = np.r_[np.arange(a), np.arange(b, len(t))]
        topics[topic] = (fields, t[keep], v[keep])
    return edit


def _swap(topic, i):
    def edit(topics):
        fields, t, v = topics[topic]
        t = t.copy()
        t[i], t[i + 1] = t[i + 1], t[i]
        topics[topic] = (fields, t, v)
    return edit


def _nan(topic, i):
    def edit(topics):
        fields, t, v = topics[topic]
        v = v.astype(np.float64).copy()
        v[i, -1] = np.nan
        topics[topic] = (fields, t, v)
    return edit


N_PRE = 400  # PRE_S at 200 Hz
BAD_ULOGS = {
    "gap": (_drop("vehicle_local_position", N_PRE + 300, N_PRE + 330), {}, "has a gap of 0.155 s"),
    "time_back": (_swap("vehicle_thrust_setpoint", N_PRE + 500), {}, "time is not increasing"),
    "nan": (_nan("vehicle_local_position", N_PRE + 50), {}, "must be finite"),
    "missing_field": (None, {"y": "vehicle_local_position.zz"}, "has no field 'zz' (did you mean 'z'?"),
    "missing_topic": (None, {"r": "-trajectory_setpont.position[2]"}, "no topic 'trajectory_setpont'"),
    "slow_log": (None, {"rate_hz": 400.0}, "below the control rate 400 Hz"),
    "no_beta": (None, {"beta": None}, "--beta is required"),
    "bad_spec": (None, {"u": "thrust"}, "TOPIC.FIELD"),
}


@pytest.mark.parametrize("case", list(BAD_ULOGS))
def test_bad_ulog_is_one_line_error_and_writes_nothing(flight, tmp_path, case):
    edit, kw, words = BAD_ULOGS[case]
    log = px4_log(tmp_path / "bad.ulg", flight, edit=edit)
    args = {"preset": "px4-altitude", **_spec(flight), **kw}
    with pytest.raises(UserError) as info:
        import_log(log, tmp_path / "s", **args)
    msg = str(info.value)
    assert "\n" not in msg and words in msg, msg
    if case not in ("no_beta", "bad_spec"):
        assert msg.startswith(str(log)), msg
    assert not (tmp_path / "s").exists()


def test_damaged_logs_and_cli_exit_2(flight, tmp_path, capsys):
    good = ardupilot_log(tmp_path / "a.bin", flight)
    (tmp_path / "cut.bin").write_bytes(good.read_bytes()[:2000] + b"\xa3\x95\xff garbage")
    (tmp_path / "junk.ulg").write_bytes(b"ULog\x01\x12\x35\x01" + bytes(3))
    (tmp_path / "what.dat").write_bytes(b"hello")
    sp = _spec(flight)
    # a cut DataFlash log reads up to the cut: too short for a relay
    for name, preset, words in (("cut.bin", "ardupilot-altitude", "no relay in u"),
                                ("junk.ulg", "px4-altitude", "not a readable ULog"),
                                ("junk.ulg", "ardupilot-altitude", "a ulog log, but the preset ardupilot-altitude"),
                                ("what.dat", "px4-altitude", "unknown log format"),
                                ("none.ulg", "px4-altitude", "no such log")):
        rc = cli_main.main(["session", "import", str(tmp_path / name), "--preset", preset,
                            "--out", str(tmp_path / "s"), "--beta", str(sp["beta"]), "--tau-obs", "0.01",
                            "--a-n", "0.0"])
        err = capsys.readouterr().err
        errors = [ln for ln in err.splitlines() if "error:" in ln]  # findings ("control rate ...") may precede
        assert rc == 2 and len(errors) == 1 and words in errors[0] and "Traceback" not in err, (name, err)
        assert not (tmp_path / "s").exists()


def test_detect_relay_finds_the_longest_two_level_stretch():
    t = np.arange(1000) / 100.0
    u = np.r_[np.linspace(0, 1, 200), np.where(np.arange(600) // 25 % 2, 0.7, 0.3), np.full(200, 0.5)]
    d = detect_relay(t, u)
    assert d["h"] == pytest.approx(0.2) and d["bias"] == pytest.approx(0.5)
    assert d["start"] == pytest.approx(2.0) and d["stop"] == pytest.approx(7.99) and d["switches"] == 23
    assert detect_relay(t, np.sin(t)) is None


def test_ros2_bag_round_trip(flight, tmp_path):
    """A ROS 2 bag (rosbags' writer): y from a PoseStamped (header stamp), r and u from Float64 topics."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    f64, pose_t = store.types["std_msgs/msg/Float64"], store.types["geometry_msgs/msg/PoseStamped"]
    hdr, stamp_t = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    point, quat = store.types["geometry_msgs/msg/Point"], store.types["geometry_msgs/msg/Quaternion"]
    pose = store.types["geometry_msgs/msg/Pose"]
    s = flight["session"]
    _, tick, r, y, u = _ticks(s.runs[0], s.control_rate_hz)
    bag = tmp_path / "bag"
    with Writer(bag, version=8) as w:
        cy = w.add_connection("/mavros/local_position/pose", pose_t.__msgtype__, typestore=store)
        cr = w.add_connection("/relay/r", f64.__msgtype__, typestore=store)
        cu = w.add_connection("/relay/u", f64.__msgtype__, typestore=store)
        for k in range(tick.size):
            ns = int(tick[k]) * 1000
            msg = pose_t(header=hdr(stamp=stamp_t(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="map"),
                         pose=pose(position=point(x=0.0, y=0.0, z=float(y[k])), orientation=quat(x=0.0, y=0.0, z=0.0,
                                                                                                  w=1.0)))
            w.write(cy, ns, store.serialize_cdr(msg, pose_t.__msgtype__))
            w.write(cr, ns, store.serialize_cdr(f64(data=float(r[k])), f64.__msgtype__))
            w.write(cu, ns + 300_000, store.serialize_cdr(f64(data=float(HOVER + u[k])), f64.__msgtype__))
    ans = import_log(bag, tmp_path / "s", loop="altitude", r="/relay/r.data",
                     y="/mavros/local_position/pose.pose.position.z", u="/relay/u.data", **_spec(flight))
    assert ans["format"] == "rosbag"
    run = read_session(tmp_path / "s").runs[0]
    np.testing.assert_array_equal(run.data.y, s.runs[0].data.y[: run.data.t.size])  # float64 all the way
    _same_identification(identify_session(tmp_path / "s", models=flight["model"]), flight["answer"])
    with pytest.raises(UserError, match="no number at 'pose.position.w'"):
        import_log(bag, tmp_path / "s2", loop="altitude", r="/relay/r.data", y="/mavros/local_position/pose.pose"
                   ".position.w", u="/relay/u.data", **_spec(flight))
