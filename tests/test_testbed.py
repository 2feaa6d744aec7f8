"""The testbed vehicle: deterministic, close to a lumped model, every hidden effect visible, sessions valid."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from uavsim.cli.main import main as cli
from uavsim.control.pd import PD
from uavsim.control.relay import MRFT, NPMRFT
from uavsim.control.runs import run_controller
from uavsim.formats.session import read_session
from uavsim.lumped import exact_limit_cycle
from uavsim.noise.analysis import rising_edges
from uavsim.testbed.equivalence import measured_cycle
from uavsim.testbed.flight import Flight
from uavsim.testbed.hidden import (
    OUTSIDE,
    VOCABULARY,
    CommandChain,
    HiddenEffect,
    Scales,
    draw_effect,
)
from uavsim.testbed.sessions import (
    RECIPE,
    STEP_DERIVATIVE,
    parse_kinds,
    parse_seeds,
    plan_session,
    read_truth,
    truth_json,
    write_testbed,
)
from uavsim.testbed.sessions import (
    testbed_session as fly_session,
)
from uavsim.testbed.vehicle import TestbedVehicle as Vehicle
from uavsim.testbed.vehicle import draw_vehicle, lumped_equivalent

RATE = 200.0


@pytest.fixture(scope="module")
def roll_plan():
    return plan_session(4, loop="roll")


def _fly(plan, effects, h_factor=1.0, seconds=4.0, seed=1):
    fl = Flight(plan.vehicle, plan.loop, effects, np.random.default_rng(seed))
    return fl.fly(MRFT(-0.73, h_factor * plan.h, RATE, 1), seconds)


def test_vehicle_is_deterministic(roll_plan):
    a = _fly(roll_plan, [], seconds=1.5, seed=3)
    b = _fly(roll_plan, [], seconds=1.5, seed=3)
    c = _fly(roll_plan, [], seconds=1.5, seed=4)
    for k in ("y", "u", "y_true", "voltage_V"):
        assert np.array_equal(getattr(a, k), getattr(b, k))
    assert not np.array_equal(a.y, c.y)  # the seed drives the sensor noise
    assert np.array_equal(a.y_true[:2], c.y_true[:2])


def test_vehicle_draws_stay_in_the_paper_box():
    for s in range(20):
        v = draw_vehicle(np.random.default_rng(s))
        for loop in ("altitude", "roll", "pitch"):
            p = lumped_equivalent(v, loop)
            assert p.in_range(), (s, loop, p)
        assert Vehicle.from_dict(v.as_dict()) == v


def test_roll_cycle_is_close_to_the_lumped_equivalent(roll_plan):
    """Small-signal behaviour near a lumped model: the sampled relay cycle near the continuous exact one.

    The 200 Hz relay alone adds about half a sample of delay, so the bounds are 5% and 10%.
    """
    rec = _fly(roll_plan, [], seconds=6.0)
    P, A, _ = measured_cycle(rec.y, rec.u)
    p = lumped_equivalent(roll_plan.vehicle, "roll")
    Pe, Ae = exact_limit_cycle(p, -0.73, roll_plan.h)
    assert abs(P / Pe - 1) < 0.05 and abs(A / Ae - 1) < 0.10, (P, Pe, A, Ae)


def test_battery_sags_and_motors_are_nonlinear(roll_plan):
    rec = _fly(roll_plan, [], h_factor=3.0, seconds=3.0)
    assert rec.voltage_V[-1] < rec.voltage_V[0]
    # the same aircraft later in a flight (lower charge) has a lower lumped gain
    v = roll_plan.vehicle
    assert lumped_equivalent(v, "roll", soc=0.3).K < lumped_equivalent(v, "roll", soc=0.9).K


def _signature(rec):
    P, A, _ = measured_cycle(rec.y, rec.u, settle=0.3)
    i0 = int(0.3 * rec.y.size)
    y, u = rec.y[i0:], rec.u[i0:]
    d = np.diff(y)
    return {"period": P, "amp": A, "mean": float(np.mean(y)), "duty": float(np.mean(u > 0)),
            "rough": float(np.std(np.diff(d))), "repeat": float(np.mean(d == 0)), "levels": np.unique(y).size}


@pytest.fixture(scope="module")
def baselines(roll_plan):
    return {f: _signature(_fly(roll_plan, [], f)) for f in (1.0, 3.0)}


# every hidden effect at a mid-range magnitude must move the relay cycle measurably
@pytest.mark.parametrize("name", VOCABULARY + OUTSIDE)
def test_each_hidden_effect_changes_the_cycle(roll_plan, baselines, name):
    s = roll_plan.scales
    scales = Scales(s.period_s, s.h, s.amp, noise_std=1e-4)
    fx = draw_effect(name, np.random.default_rng(11), scales)
    big = name in ("saturation", "asym_saturation")  # they clip only above h
    base = baselines[3.0 if big else 1.0]
    got = _signature(_fly(roll_plan, [fx], 3.0 if big else 1.0))
    change = max(abs(got["period"] / base["period"] - 1), abs(got["amp"] / base["amp"] - 1),
                 abs(got["mean"] - base["mean"]) / base["amp"], abs(got["duty"] - base["duty"]),
                 got["rough"] / base["rough"] - 1, got["repeat"] - base["repeat"])  # fmt: skip
    assert change > 0.05, (name, fx.params, base, got)


def test_command_delay_is_exact_on_a_held_command():
    fx = HiddenEffect("delay", {"delay": 0.0123})
    ch = CommandChain([fx], dt_s=0.001, rate_hz=200.0, rng=np.random.default_rng(0))
    out = []
    for k in range(20):
        ch.push(k / 200.0, 1.0 if k >= 4 else 0.0)
        for i in range(5):
            out.append(ch((k * 5 + i) / 1000.0))
    # the step at 0.020 s arrives at 0.0323 s: step 32 is 30% on, step 33 on
    assert out[31] == 0.0 and math.isclose(out[32], 0.7, abs_tol=1e-9) and out[33] == 1.0


@pytest.fixture(scope="module")
def short_session(tmp_path_factory):
    path = tmp_path_factory.mktemp("tb") / "tb_00006"
    session, truth = fly_session(6, time_scale=0.25)
    write_testbed(session, truth, path)
    return path, session, truth


def test_session_passes_check_and_has_no_model(short_session, capsys):
    path, session, truth = short_session
    assert cli(["session", "check", str(path)]) == 0
    back = read_session(path)
    assert back.model is None and back.effects == []
    assert [r.spec.file for r in back.runs] == [r["file"] for r in truth.runs]
    kinds = [r.spec.kind for r in back.runs]
    assert kinds == ["np-mrft"] * 3 + ["step"] * 2
    relay = back.runs[0]
    # the session records the controller's own view: a relay command is +-h exactly
    assert set(np.round(np.abs(relay.data.u), 12)) == {round(relay.spec.h, 12)}
    assert rising_edges(relay.data.u).size >= 3


def test_truth_file_is_complete(short_session):
    path, _, truth = short_session
    text = (path.parent / (path.name + ".truth.json")).read_text()
    d = json.loads(text)  # strict JSON
    assert d["recipe"] == RECIPE and d["seed"] == 6 and d["name"] == "tb_00006"
    for key in ("kind", "loop", "effects", "lumped", "lumped_K_by_run", "noise", "runs", "scales", "vehicle", "seeds"):
        assert key in d, key
    assert set(d["lumped"]) >= {"K", "T_prop", "T1", "tau", "noise_std"}
    for r in d["runs"]:
        assert ("oscillates" in r) != ("bounded" in r) and "crashed" in r and "saturated_share" in r
    assert truth_json(read_truth(path.parent / (path.name + ".truth.json"))) == text
    assert d["noise"]["tau_obs_b073"] > 0 and d["noise"]["a_n_b073"] >= 0


def test_same_seed_same_bytes(short_session, tmp_path):
    path, session, truth = short_session
    s2, t2 = fly_session(6, time_scale=0.25)
    write_testbed(s2, t2, tmp_path / "again")
    for f in sorted(p.name for p in path.iterdir()):
        assert (path / f).read_bytes() == (tmp_path / "again" / f).read_bytes(), f
    assert truth_json(truth) == truth_json(t2)


def test_plans_cover_every_kind_and_keep_effects_flyable():
    plans = [plan_session(s) for s in range(40)]
    assert {p.kind for p in plans} == {"single", "pair", "outside", "none"}
    for p in plans:
        assert p.kind != "pair" or len({e.name for e in p.effects}) == 2
        for e in p.effects:
            if e.name in ("delay", "lag"):
                assert next(iter(e.params.values())) < 0.15 * p.scales.period_s
    only = [plan_session(s, ("none",)) for s in range(5)]
    assert all(p.kind == "none" and p.effects == [] for p in only)


@pytest.mark.parametrize("argv, needle", [
    (["testbed", "sessions", "--seeds", "5:2", "--out", "X"], "--seeds"),
    (["testbed", "sessions", "--seeds", "a:b", "--out", "X"], "--seeds"),
    (["testbed", "sessions", "--seeds", "0:1", "--out", "X", "--kinds", "single,bogus"], "--kinds"),
    (["testbed", "sessions", "--seeds", "0:1", "--out", "X", "--jobs", "0"], "--jobs"),
    (["testbed", "equivalence", "--seeds", "0:1", "--loops", "yaw"], "--loops"),
])  # fmt: skip
def test_bad_cli_input_is_one_line_and_exit_2(argv, needle, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err and "Traceback" not in err
    assert not (tmp_path / "X").exists()


def test_out_that_is_a_file_is_refused(tmp_path, capsys):
    f = tmp_path / "afile"
    f.write_text("x")
    assert cli(["testbed", "sessions", "--seeds", "0:1", "--out", str(f)]) == 2
    assert "not a folder" in capsys.readouterr().err


def test_a_flight_that_crashes_before_its_first_run_leaves_its_seed_without_a_session(tmp_path, monkeypatch, capsys):
    from uavsim.testbed import sessions

    def crash(seed, kinds):
        raise sessions.NoSession(f"testbed seed {seed}: the flight crashed before any run")

    monkeypatch.setattr(sessions, "testbed_session", crash)
    assert cli(["testbed", "sessions", "--seeds", "3:5", "--out", str(tmp_path / "set"), "--json"]) == 0
    index = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    # the set goes on past the seed, says so and writes nothing for it: no seed is redrawn
    assert index["sessions"] == [] and sorted(index["no_session"]) == ["tb_00003", "tb_00004"]
    assert "crashed before any run" in index["no_session"]["tb_00003"]
    assert sorted(p.name for p in (tmp_path / "set").iterdir()) == ["recipe.json"]


def test_parsers():
    assert parse_seeds("3") == range(3, 4) and parse_seeds("2:5") == range(2, 5)
    assert parse_kinds("none,single,none") == ("none", "single")


@pytest.mark.slow
def test_cli_writes_a_deterministic_set(tmp_path, capsys):
    for d in ("a", "b"):
        assert cli(["testbed", "sessions", "--seeds", "0:2", "--out", str(tmp_path / d), "--json"]) == 0
    index = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert index["sessions"] == ["tb_00000", "tb_00001"]
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    # recipe.json, and per session its truth, session.toml and each run flown (a crashed run is not written)
    runs = [row["runs"] for row in index["index"]]
    assert all(1 <= r <= 5 for r in runs) and len(files) == 1 + sum(2 + r for r in runs)
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    for name in index["sessions"]:
        assert cli(["session", "check", str(tmp_path / "a" / name)]) == 0


@pytest.mark.slow
def test_equivalence_of_the_first_vehicles():
    from uavsim.testbed.equivalence import measure_equivalence

    for row in measure_equivalence(0) + measure_equivalence(1):
        # altitude NP-MRFT cycles move with the camera + KF noise's a_n (docs/results/gap-testbed.md)
        assert row["loop"] == "altitude" or abs(row["period_err"]) < 0.05, row
        assert abs(row["K_fit_err"]) < 0.10, row
        assert abs(row["gain_err_b030"]) < 0.10 and abs(row["phase_err_b030_deg"]) < 10, row


def test_npmrft_relay_on_the_testbed_is_the_sessions_controller(short_session):
    """The session's run replays exactly through uavsim.control.NPMRFT: the controller saw y, computed u."""
    _, session, _ = short_session
    run = session.runs[0]
    s = run.spec
    relay = NPMRFT(s.beta, s.h, s.tau_obs, s.a_n, RATE, 1)
    u = np.array([relay(np.array([r - y]))[0] for r, y in zip(run.data.r, run.data.y, strict=True)])
    assert np.array_equal(u, run.data.u)


def test_step_runs_replay_through_their_pd(short_session):
    """The step runs carry the testbed's derivative choice and replay exactly through that PD."""
    path, _, _ = short_session
    for run in read_session(path).runs[3:]:
        s, d = run.spec, run.data
        assert s.kind == "step" and s.derivative == STEP_DERIVATIVE
        pd = run_controller(s, RATE)
        u = np.array([(pd(np.array([r - y]), np.array([r])) if pd.reads_reference else pd(np.array([r - y])))[0]
                      for r, y in zip(d.r, d.y, strict=True)])
        np.testing.assert_allclose(u, d.u, rtol=0, atol=1e-9 * np.abs(d.u).max())


@pytest.mark.parametrize("loop", ["altitude", "roll", "pitch"])
def test_command_range_is_where_the_mixer_reaches_an_esc_limit(loop):
    # the session's [actuator]: at command_max (command_min) one rotor's PWM is at its upper or lower
    # limit and none beyond; 1 % further, one is beyond
    plan = plan_session(5, loop=loop)
    fl = Flight(plan.vehicle, loop, [], np.random.default_rng(0))
    low, high = fl.command_range()
    assert low < 0 < high
    pr, ap = plan.vehicle.propulsion, plan.vehicle.autopilot
    unit = ap.force_unit_N if loop == "altitude" else ap.moment_unit_Nm
    axis = {"altitude": 0, "roll": 1, "pitch": 2}[loop]

    def pwm(command):
        wr = np.zeros(4)
        wr[axis] = unit * command
        return fl._pwm(wr)

    def beyond(p):
        return max(p.max() - pr.pwm_max_us, pr.pwm_min_us - p.min())

    for c in (low, high):
        assert beyond(pwm(c)) == pytest.approx(0.0, abs=1e-6)
        assert beyond(pwm(1.01 * c)) > 0.1


def test_session_states_the_actuator_range_of_its_flight(short_session):
    path, _, truth = short_session
    plan = plan_session(6)
    low, high = Flight(plan.vehicle, plan.loop, plan.effects, np.random.default_rng(0)).command_range()
    a = read_session(path).actuator
    assert (a.command_min, a.command_max) == (low, high)


def test_flight_hands_the_reference_to_a_measurement_pd(roll_plan):
    """A PD on the measurement flown on the vehicle: its record replays exactly, and the step sends no kick."""
    g = roll_plan.step_gains
    make = lambda: PD(g["kp"], g["kd"], g["derivative_filter_hz"], RATE, 1, derivative="measurement")  # noqa: E731
    step = 2 * roll_plan.scales.amp
    rec = Flight(roll_plan.vehicle, "roll", [], np.random.default_rng(2)).fly(
        make(), 0.5, lambda t: step if t >= 0.1 else 0.0)
    pd = make()
    u = np.array([pd(np.array([r - y]), np.array([r]))[0] for r, y in zip(rec.r, rec.y, strict=True)])
    np.testing.assert_allclose(u, rec.u, rtol=0, atol=1e-9 * np.abs(rec.u).max())
    k = int(round(0.1 * RATE))
    assert abs(rec.u[k] - rec.u[k - 1]) < 1.5 * g["kp"] * step  # the error form would add kd a step / Ts
    assert g["kd"] * pd.a[0] * step / pd.Ts > 5 * g["kp"] * step
