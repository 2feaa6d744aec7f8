"""Scenario files: every shipped file loads; strict reading rejects typos and impossible values."""

import tomllib
from pathlib import Path

import pytest

from uavsim.errors import UserError
from uavsim.scenario.config import load_scenario, parse_scenario

SCEN = Path(__file__).resolve().parents[1] / "scenarios"
NAMES = [f"{c}-camera-{k}" for c in ("normal", "event", "thermal") for k in ("kf", "no-kf")] + [
    "wind-5ms", "pull-release-10n", "target-step"]


@pytest.mark.parametrize("name", NAMES)
def test_shipped_scenarios_load(name):
    scn = load_scenario(SCEN / f"{name}.toml")
    assert scn.name == name
    if "camera" in name:
        assert scn.camera.name == name.split("-")[0]
        assert scn.estimator == ("camera" if name.endswith("no-kf") else "kf")


def _doc(**changes):
    doc = tomllib.loads((SCEN / "normal-camera-kf.toml").read_text())
    for path, v in changes.items():
        d = doc
        keys = path.split(".")
        for k in keys[:-1]:
            d = d.setdefault(k, {})
        d[keys[-1]] = v
    return doc


@pytest.mark.parametrize("change, match", [
    ({"speed": 3}, "unknown key"),
    ({"camera.focal": 500.0}, "camera.focal: unknown key"),
    ({"camera.preset": "ir"}, "camera.preset: unknown value 'ir'"),
    ({"identification.bta": -0.7}, "unknown key"),
    ({"identification.beta": -1.2}, "beta"),
    ({"identification.method": "magic"}, "method"),
    ({"test.kind": "earthquake"}, "test.kind"),
    ({"test.kind": "wind"}, "lateral_y"),
    ({"estimator": "ekf"}, "estimator"),
    ({"loops": ["yaw"]}, "loops"),
    ({"format": "uavsim-scenario/2"}, "format"),
    ({"truth.altitude.T_prop": -0.1}, "truth.altitude.T_prop: must be > 0"),
    ({"truth.altitude.Tprop": 0.1}, "unknown key"),
    ({"seed": -3}, "seed"),
    ({"imu.noise_std_mps2": "high"}, "imu.noise_std_mps2: must be a number, got string 'high'"),
])
def test_strict_errors(change, match):
    with pytest.raises(UserError, match=match):
        parse_scenario(_doc(**change))


def test_missing_and_bad_files(tmp_path):
    with pytest.raises(UserError, match="no such"):
        load_scenario(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("format = \n")
    with pytest.raises(UserError, match="not valid TOML"):
        load_scenario(bad)
