"""Scenario flow: DF identification, the identification call, a short end-to-end run, the CLI."""

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams
from uavsim.lumped.simulate import simulate_relay_batch
from uavsim.scenario.config import load_scenario
from uavsim.scenario.flow import identify, identify_mrft_df, run_scenario
from uavsim.scenario.table import format_table, table_rows
from uavsim.tuning.rule import TuningRule

SCEN = Path(__file__).resolve().parents[1] / "scenarios"


def test_mrft_df_gains_close_to_rule_on_true_model():
    p = LumpedParams("altitude", K=2.0, T_prop=0.1, T1=0.8, tau=0.02)
    dt, beta, h = 0.001, -0.73, 0.5
    out = simulate_relay_batch("altitude", beta, h, dt, 20000, K=2.0, T_prop=0.1, T1=0.8, tau=0.02)
    t = out["t"]
    ident = identify_mrft_df(t, out["e"][0], out["u"][0], beta, h, 20.0, settle_s=5.0)
    g = TuningRule(beta=beta).gains(p)
    # the describing function is approximate (exact cycles differ by 4-18%)
    assert ident["gains"]["kp"] == pytest.approx(g.kp, rel=0.25)
    assert ident["gains"]["kd"] == pytest.approx(g.kd, rel=0.25)
    assert ident["params"] is None and ident["identifier"] == "mrft-df"


def test_mrft_df_needs_a_cycle():
    t = np.arange(1000) * 0.005
    with pytest.raises(UserError, match="no steady cycle"):
        identify_mrft_df(t, np.zeros_like(t), np.ones_like(t), -0.73, 1.0, 20.0, 1.0)


def test_identify_calls_identify_session(monkeypatch, tmp_path):
    """The DNN path is one call to uavsim.ident.session.identify_session."""
    import uavsim.ident.session as li

    seen = {}

    def fake_identify_session(path, models=None):  # TEST double, tests only
        seen["path"], seen["model_dir"] = path, models
        return {"loop": "altitude", "class": 3, "params": {"K": 1.0, "T_prop": 0.1, "T1": 0.5, "tau": 0.02},
                "gains": {"kp": 1.0, "kd": 0.3}}

    monkeypatch.setattr(li, "identify_session", fake_identify_session)
    df = {"identifier": "mrft-df", "gains": {"kp": 9.0, "kd": 9.0}}
    out = identify(tmp_path, "dnn", "", df)
    assert out["class"] == 3 and out["identifier"] == "dnn"
    assert seen == {"path": tmp_path, "model_dir": None}


def test_identify_auto_falls_back_and_says_why(monkeypatch, tmp_path):
    import uavsim.ident.session as li

    def failing(path, models=None):  # TEST double, tests only
        raise UserError("no trained altitude network")

    monkeypatch.setattr(li, "identify_session", failing)
    df = {"identifier": "mrft-df", "gains": {"kp": 9.0, "kd": 9.0}}
    out = identify(tmp_path, "auto", "", df)
    assert out["identifier"] == "mrft-df" and "no trained" in out["note"]
    with pytest.raises(UserError):
        identify(tmp_path, "dnn", "", df)


def _short(name, **test):
    scn = load_scenario(SCEN / f"{name}.toml")
    scn.identification = replace(scn.identification, hover_s=2.0, duration_s=8.0, method="mrft-df")
    if test:
        scn.test = replace(scn.test, **test)
    return scn


def test_short_flow_and_recording(tmp_path):
    scn = _short("normal-camera-kf", duration_s=3.0)
    res = run_scenario(scn, seed=3, workdir=tmp_path)
    alt = res["loops"]["altitude"]
    assert set(("T_prop", "T1", "tau", "kp", "kd", "Q_sim")) <= set(alt)
    assert alt["kp"] > 0 and alt["kd"] > 0 and math.isfinite(alt["Q_mj"])
    assert Path(alt["session"]).is_dir()
    assert res["test"]["kind"] == "step"
    from uavsim.scenario.record import write_recording

    rrd = write_recording(res, tmp_path / "run.rrd", format_table(table_rows([res])))
    assert rrd.stat().st_size > 1000
    json.dumps({k: v for k, v in res.items() if not k.startswith("_")})


def test_cli_json(tmp_path, capsys, monkeypatch):
    import argparse

    from uavsim.cli import scenario_cmd

    text = (SCEN / "normal-camera-no-kf.toml").read_text()
    text = text.replace("duration_s = 8.0\n", "duration_s = 3.0\n")  # the step test
    text = text.replace("hover_s = 5.0", "hover_s = 2.0").replace("duration_s = 20.0", "duration_s = 8.0")
    text = text.replace('method = "auto"', 'method = "mrft-df"')
    f = tmp_path / "quick.toml"
    f.write_text(text)
    p = argparse.ArgumentParser()
    scenario_cmd.register(p.add_subparsers())
    args = p.parse_args(["scenario", "run", str(f), "--json", "--save", str(tmp_path / "q.rrd")])
    assert args.func(args) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    d = json.loads(out[0])
    assert d["loops"]["altitude"]["identifier"] == "mrft-df"
    assert (tmp_path / "q.rrd").is_file()
    bad = p.parse_args(["scenario", "run", str(f), "--save", str(tmp_path / "q.txt")])
    with pytest.raises(UserError):
        bad.func(bad)


@pytest.mark.slow
def test_camera_trends():
    """The paper's four Table I trends on the medians of 5 seeds per scenario: without KF more delay
    and lower gains (each sensor), the event camera's step ISE below the normal camera's, with KF
    similar gains."""
    from uavsim.scenario.trends import camera_trends

    files = sorted(SCEN.glob("*-camera-*.toml"))
    assert len(files) == 6
    t = camera_trends(files, n_seeds=5)["trends"]
    for cam in ("normal", "event", "thermal"):
        assert t["delay_larger_without_kf"][cam]["median"], cam
        assert t["gains_lower_without_kf"][cam]["median"], cam
    assert t["similar_gains_with_kf"]["median"]
    assert t["event_beats_normal_without_kf"]["median"]


@pytest.mark.slow
def test_disturbance_scenarios():
    pull = run_scenario(load_scenario(SCEN / "pull-release-10n.toml"))["test"]
    assert pull["stable"] and pull["recovery_s"] is not None
    ts = run_scenario(load_scenario(SCEN / "target-step.toml"))["test"]
    assert [s["to"] for s in ts["switches"]][:1] == ["IBVS"]
    assert ts["final_error_m"] < 0.05


def test_unsteady_relay_cycles_are_named():
    """The flow re-runs the NP-MRFT with a larger a_n when the last cycles are not steady."""
    from types import SimpleNamespace

    from uavsim.scenario.flow import _unsteady

    def run(lengths):
        u = np.concatenate([np.r_[np.ones(n // 2), -np.ones(n - n // 2)] for n in lengths]) * 0.1
        y = np.cumsum(u)  # an integrator's triangle wave
        return SimpleNamespace(y=y[None], u=u[None])

    assert _unsteady(run([100] * 6), 0.1) is None
    why = _unsteady(run([100] * 4 + [87, 154, 100]), 0.1)
    assert why is not None and "no steady state" in why


def test_lateral_uses_the_roll_class_network_or_says_why(tmp_path):
    """With a roll class whose lateral network exists the lateral relay runs at that sub-grid's beta
    and identification gets the identified roll loop (its PD for the unit-gain process); without
    one, or with mrft-df, the scenario's beta_lateral and no context."""
    from uavsim.scenario.flow import _lateral_networks
    from uavsim.tuning.grid import load_grid

    scn = load_scenario(SCEN / "wind-5ms.toml")
    roll = {"class": 4, "params": {"K": 20.0, "T_prop": 0.05, "T1": 0.4, "tau": 0.01},
            "gains": {"kp": 0.9, "kd": 0.1, "derivative_filter_hz": 12.0}}
    from _learning_fixtures import trained_like_net

    from uavsim.learning.bundle import bundle_section
    from uavsim.learning.export import export_model

    g = load_grid("lateral")
    sub = g.lateral(4)
    ident = bundle_section(loop="lateral", grid_hash=g.hash, rate_hz=200.0, beta=None, input_length=40, cycles=1,
                           att_class=4)
    classes = {k: np.asarray(sub.params[k])[:5].tolist() for k in ("T2", "tau")}
    export_model(trained_like_net(), {"channels": 2, "input_length": 40, "n_classes": 5, "loop": "lateral",
                                      "att_class": 4, "classes": classes, "identification": ident},
                 tmp_path / "lateral" / "a04")
    scn.identification = replace(scn.identification, method="auto", model_dir=str(tmp_path))
    beta, ctx = _lateral_networks(scn, roll)
    assert beta == load_grid("lateral").lateral(4).beta
    assert ctx["attitude_class"] == 4
    assert ctx["attitude"]["att_kp"] == pytest.approx(0.9 * 20.0) and ctx["attitude"]["tau_in"] == 0.01
    assert _lateral_networks(replace(scn, identification=replace(scn.identification, method="mrft-df")),
                             roll) == (None, None)
    assert _lateral_networks(scn, {**roll, "class": 5}) == (None, None)  # no lateral/a05


def test_relay_faster_than_every_class_is_noise_switched():
    """A cycle faster than 0.75 x the grid's fastest class is named (and re-run by the flow); slower is
    not; a lateral loop without its attitude class's sub-grid is not judged."""
    from uavsim.scenario.flow import _faster_than_grid
    from uavsim.tuning.grid import load_grid

    P = load_grid("altitude").period
    assert "faster than any class" in _faster_than_grid(0.5 * P.min(), "altitude", None)
    assert _faster_than_grid(0.8 * P.min(), "altitude", None) is None
    sub = load_grid("lateral").lateral(4).period
    assert _faster_than_grid(0.5 * sub.min(), "lateral_y", {"attitude_class": 4}) is not None
    assert _faster_than_grid(0.5 * sub.min(), "lateral_y", None) is None
    assert _faster_than_grid(float("nan"), "altitude", None) is None


def test_target_step_switch_is_in_the_recording(tmp_path):
    """A target step under the PBVS/IBVS schedules switches to IBVS; the recording carries the
    ``schedule`` line stepping from 1 to 2 at that time and a ``switch`` text event, read back
    with Rerun's own ``rrd print``."""
    import re

    from _rerun_cli import iso_seconds, rerun

    from uavsim.scenario.flow import _episode
    from uavsim.scenario.record import write_recording
    from uavsim.vision.schedules import Schedule, ScheduledPD

    scn = load_scenario(SCEN / "target-step.toml")
    truth = scn.truth["altitude"]
    ctrl = ScheduledPD(Schedule(1.1, 0.23, 10.0), Schedule(0.42, 0.13, 10.0), 200.0, 1)
    res = _episode(truth, scn, "scheduled", 5).run(ctrl, 4.0, target=lambda t: 0.5 if t >= 1.0 else 0.0)
    sched = res.schedule[0]
    k = int(np.flatnonzero(np.diff(sched) != 0)[0] + 1)
    assert sched[k - 1] == 1 and sched[k] == 2 and res.t[k] >= 1.0
    result = {"_episodes": {"test/target-step": res}, "loops": {"altitude": {"kp": 1.1, "kd": 0.23}},
              "test": {"kind": "target-step", "loop": "altitude"}}
    rrd = write_recording(result, tmp_path / "t.rrd")
    out = rerun("rrd", "print", "-vvv", "--entity", "/test/target-step/schedule", str(rrd))
    assert out.returncode == 0, out.stderr
    rows = []
    for line in out.stdout.splitlines():
        cells = [c.strip(" │") for c in line.split("┆")]
        if len(cells) == 3 and cells[0].startswith("row_") and cells[1].startswith("P"):
            rows.append((iso_seconds(cells[1]), float(cells[2].strip("[]"))))
    rows = np.array(rows)
    assert len(rows) == len(res.t)
    step = rows[np.argmax(rows[:, 1] == 2.0), 0]
    assert step == pytest.approx(res.t[k], abs=1e-6)
    text = rerun("rrd", "print", "-vvv", "--entity", "/test/target-step/switch", str(rrd))
    assert text.returncode == 0 and re.search(r"switch to IBVS", text.stdout), text.stdout[-2000:]
