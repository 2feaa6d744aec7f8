"""Gains out: the parameter files carry the documented names, units and values, and refuse what
they cannot map."""

from __future__ import annotations

import json
import math

import pytest

import uavsim.cli.main as cli_main
from uavsim.autopilot import MAPPING, export_gains, read_params, write_params
from uavsim.autopilot.params import G
from uavsim.errors import UserError

ANS = {"loop": "roll", "class": 17, "params": {"K": 40.0, "T_prop": 0.05, "T1": 0.4, "tau": 0.01},
       "gains": {"kp": 0.12, "kd": 0.018, "derivative_filter_hz": 25.0},
       "gains_table": {"kp": 0.1, "kd": 0.02, "derivative_filter_hz": 20.0}}

# the documented mapping, written out independently of MAPPING: outer P, rate P, the rest fixed
EXPECTED = {
    ("roll", "px4"): {"MC_ROLL_P": "kp/kd", "MC_ROLLRATE_P": "kd*S", "MC_ROLLRATE_D": 0.0, "MC_ROLLRATE_K": 1.0},
    ("pitch", "px4"): {"MC_PITCH_P": "kp/kd", "MC_PITCHRATE_P": "kd*S", "MC_PITCHRATE_D": 0.0,
                       "MC_PITCHRATE_K": 1.0},
    ("roll", "ardupilot"): {"ATC_ANG_RLL_P": "kp/kd", "ATC_RAT_RLL_P": "kd*S", "ATC_RAT_RLL_D": 0.0,
                            "ATC_RAT_RLL_FLTE": "filter"},
    ("pitch", "ardupilot"): {"ATC_ANG_PIT_P": "kp/kd", "ATC_RAT_PIT_P": "kd*S", "ATC_RAT_PIT_D": 0.0,
                             "ATC_RAT_PIT_FLTE": "filter"},
    ("altitude", "px4"): {"MPC_Z_P": "kp/kd", "MPC_Z_VEL_P_ACC": "kd*S", "MPC_Z_VEL_D_ACC": 0.0},
    ("altitude", "ardupilot"): {"PSC_POSZ_P": "kp/kd", "PSC_VELZ_P": "kd*S"},
    ("lateral_y", "px4"): {"MPC_XY_P": "kp/kd", "MPC_XY_VEL_P_ACC": "kd*S", "MPC_XY_VEL_D_ACC": 0.0},
    ("lateral_x", "ardupilot"): {"PSC_POSXY_P": "kp/kd", "PSC_VELXY_P": "kd*S"},
}
UNITS = {"roll": ("1/s", "norm. torque/(rad/s)"), "pitch": ("1/s", "norm. torque/(rad/s)"),
         "altitude": ("1/s", "(m/s^2)/(m/s)"), "lateral_y": ("1/s", "(m/s^2)/(m/s)"),
         "lateral_x": ("1/s", "(m/s^2)/(m/s)")}


@pytest.mark.parametrize("loop, autopilot", list(EXPECTED))
def test_names_units_and_values_round_trip(loop, autopilot, tmp_path):
    ans = dict(ANS, loop=loop)
    S = 2.5
    exp = export_gains(ans, autopilot, cmd_scale=S)
    ext = ".params" if autopilot == "px4" else ".parm"
    path = write_params(exp, tmp_path / f"g{ext}")
    got = read_params(path)
    kp, kd, f = (ANS["gains"][k] for k in ("kp", "kd", "derivative_filter_hz"))
    want = {"kp/kd": kp / kd, "kd*S": kd * S, "filter": f}
    assert set(got) == set(EXPECTED[loop, autopilot])
    for name, rule in EXPECTED[loop, autopilot].items():
        assert got[name] == pytest.approx(want.get(rule, rule), rel=1e-8), name
    text = path.read_text()
    outer, rate = list(EXPECTED[loop, autopilot])[:2]
    # each value's unit and formula are in the comment above it; the header states S and its unit
    lines = text.splitlines()
    for name, unit in ((outer, UNITS[loop][0]), (rate, UNITS[loop][1])):
        i = next(i for i, ln in enumerate(lines) if not ln.startswith("#") and name in ln)
        assert lines[i - 1].startswith(f"# {name}: ") and unit in lines[i - 1], lines[i - 1]
    assert f"S = {S:g}" in text and "outer P = kp / kd, rate P = kd * S" in text
    if autopilot == "px4":  # QGroundControl's format: vehicle, component, name, value, type 9 (float)
        assert all(ln.split("\t")[4] == "9" for ln in lines if not ln.startswith("#"))
    # the cascade is the PD: rate P * (outer P e - y') = kp e - kd S y'
    assert got[rate] * got[outer] == pytest.approx(kp * S) and got[rate] == pytest.approx(kd * S)


def test_hover_thrust_sets_the_altitude_scale(tmp_path):
    exp = export_gains(dict(ANS, loop="altitude"), "px4", hover_thrust=0.4)
    assert exp.as_dict()["MPC_Z_VEL_P_ACC"] == pytest.approx(ANS["gains"]["kd"] * G / 0.4)
    assert "g / hover thrust" in exp.cmd_scale_source


@pytest.mark.parametrize("change, kw, words", [
    ({}, {}, "need the vehicle's scale"),
    ({"loop": "altitude"}, {}, "--hover-thrust H (u normalized thrust) or --cmd-scale S"),
    ({"loop": "yaw"}, {"cmd_scale": 1.0}, "cannot map the 'yaw' loop"),
    ({"gains": {"kp": 0.1, "kd": 0.0}}, {"cmd_scale": 1.0}, "cannot map kp = 0.1, kd = 0"),
    ({"gains": {"kp": -0.1, "kd": 0.01}}, {"cmd_scale": 1.0}, "both must be > 0"),
    ({}, {"cmd_scale": -1.0}, "--cmd-scale must be > 0"),
    ({}, {"cmd_scale": math.nan}, "--cmd-scale must be > 0"),
    ({}, {"hover_thrust": 0.4}, "--hover-thrust is for the altitude loop"),
    ({"loop": "altitude"}, {"hover_thrust": 1.5}, "in (0, 1)"),
    ({"gains": None}, {"cmd_scale": 1.0}, "no gains"),
])
def test_refusals_are_one_line(change, kw, words):
    with pytest.raises(UserError) as info:
        export_gains({**ANS, **change}, "px4", **kw)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_every_session_loop_is_mapped():
    from uavsim.formats.session import LOOPS

    assert set(MAPPING) == set(LOOPS)


def test_cli_from_identify_json(tmp_path, capsys):
    src = tmp_path / "id.json"
    src.write_text(json.dumps(ANS))
    out = tmp_path / "roll.parm"
    assert cli_main.main(["export-gains", str(src), "--autopilot", "ardupilot", "--cmd-scale", "1",
                          "--gains", "gains_table", "--out", str(out), "--json"]) == 0
    ans = json.loads(capsys.readouterr().out)
    assert ans["params"] == read_params(out)
    assert ans["params"]["ATC_ANG_RLL_P"] == pytest.approx(0.1 / 0.02)
    rc = cli_main.main(["export-gains", str(src), "--autopilot", "px4", "--out", str(tmp_path / "x.params")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "--cmd-scale" in err and not (tmp_path / "x.params").exists()
