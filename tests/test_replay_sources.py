"""``uavsim replay`` of a dataset episode and of a scenario run, read back with Rerun's own tooling.

A tiny dataset (2 classes x 2 episodes, raw traces kept) and a short scenario
run are made here; their replays are checked with ``rerun rrd verify`` and
``rerun rrd print``: entity paths, row counts, time ranges and values against
the source data (the dataset's raw traces, the scenario's run file), and the
vehicle's pose rows. Also the pieces: ``LoopBatch(record_state=True)`` changes
nothing else, the body quaternion is MuJoCo's, user errors are one line.
"""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from _rerun_cli import iso_seconds, rerun

from uavsim.data.generate import generate
from uavsim.data.h5 import open_dataset
from uavsim.data.recipe import parse_recipe
from uavsim.errors import UserError
from uavsim.viz.replay import replay

ROOT = Path(__file__).resolve().parents[1]


def _read_rows(rrd: Path, entity: str) -> tuple[np.ndarray, list[list[str]]]:
    """(time s, the other cells) of the temporal rows of ``entity``, from ``rerun rrd print -vvv``."""
    out = rerun("rrd", "print", "-vvv", "--entity", entity, str(rrd))
    assert out.returncode == 0, out.stderr
    t, cells = [], []
    for line in out.stdout.splitlines():
        c = [x.strip(" │") for x in line.split("┆")]
        if len(c) >= 3 and c[0].startswith("row_") and c[1].startswith("P"):
            t.append(iso_seconds(c[1]))
            cells.append(c[2:])
    return np.array(t), cells


def _scalars(rrd: Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    t, cells = _read_rows(rrd, entity)
    return t, np.array([float(c[0].strip("[]")) for c in cells])


def _chunk_rows(printed: str, entity: str) -> int:
    """Rows of the temporal chunks of ``entity`` in ``rerun rrd print`` output (static chunks have 1 row)."""
    rows = [int(n) for n in re.findall(rf"with (\d+) rows .* - {re.escape(entity)} - ", printed)]
    return sum(n for n in rows if n > 1) or max(rows, default=0)


# -- dataset ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny_h5(tmp_path_factory) -> Path:
    """2 classes x 2 episodes of the small recipe, raw traces kept."""
    text = (ROOT / "datasets" / "small.toml").read_text()
    text = text.replace("per_class = 8", "per_class = 2").replace(
        "classes = [30, 60, 90, 120, 160, 207]", "classes = [90, 120]")
    text += "\n[preprocess]\nkeep_raw = true\n"
    tmp = tmp_path_factory.mktemp("tiny")
    out = tmp / "tiny.h5"
    generate(parse_recipe(text, str(tmp / "tiny.toml"), "tiny"), out, progress=False)
    return out


@pytest.fixture(scope="module")
def ds_replayed(tiny_h5: Path, tmp_path_factory) -> tuple[dict, Path]:
    rrd = tmp_path_factory.mktemp("rrd") / "ds.rrd"
    ds = open_dataset(tiny_h5)
    cls = int(ds.labels[-1])
    ep = int(np.count_nonzero(ds.labels == cls)) - 1  # the last kept episode of the last label
    return replay(tiny_h5, rrd, cls=cls, episode=ep), rrd


def test_dataset_summary_and_exact_resimulation(ds_replayed, tiny_h5: Path) -> None:
    s, rrd = ds_replayed
    ds = open_dataset(tiny_h5)
    assert s["source"] == "dataset" and s["rrd"] == str(rrd) and rrd.is_file()
    row = s["row"]
    assert ds.labels[row] == s["class"] and s["raw"] and s["resimulated"] and s["exact"]
    (info,) = s["runs"]
    stem = f"class{s['class']}_episode{s['episode']}"
    assert info["stem"] == stem and info["kind"] == "np-mrft" and info["vehicle"]
    n = int(ds.raw["length"][row])
    assert info["rows"] == n == s["raw_length"]
    assert info["t0"] == 0.0 and info["t1"] == pytest.approx((n - 1) / ds.attrs["rate_hz"])
    assert info["u_mismatch"] == 0 and info["extrema"] == info["switches"] > 3
    assert any("reproduces the file exactly" in m for m in info["messages"])
    base = f"runs/{stem}"
    for name in ("r", "y", "y_true", "e", "u", "inhibition", "world/vehicle", "world/vehicle/thrust",
                 "signals/raw_y"):
        assert info["entities"][f"{base}/{name}"] == n, name


def test_dataset_rrd_against_the_file(ds_replayed, tiny_h5: Path) -> None:
    s, rrd = ds_replayed
    assert rerun("rrd", "verify", str(rrd)).returncode == 0
    printed = rerun("rrd", "print", str(rrd))
    assert printed.returncode == 0, printed.stderr
    ds = open_dataset(tiny_h5)
    row = s["row"]
    n = int(ds.raw["length"][row])
    rate = ds.attrs["rate_hz"]
    base = f"/runs/{s['runs'][0]['stem']}"
    for name in ("y", "y_true", "u", "e", "world/vehicle", "world/vehicle/thrust"):
        assert _chunk_rows(printed.stdout, f"{base}/{name}") == n, name
    for name in ("phase", "world/vehicle/body", "world/vehicle/rotors", "world/vehicle/arms", "world/path"):
        assert f"- {base}/{name} - " in printed.stdout, name
    # y as the relay saw it = the file's raw trace (float32), on the control-rate clock
    t, y = _scalars(rrd, f"{base}/y")
    assert t.size == n and t[0] == 0.0 and t[-1] == pytest.approx((n - 1) / rate)
    np.testing.assert_allclose(t, np.arange(n) / rate, atol=1e-9)
    np.testing.assert_allclose(y, ds.raw["y"][row, :n], rtol=1e-6, atol=1e-9)
    _, u = _scalars(rrd, f"{base}/u")
    np.testing.assert_allclose(u, ds.raw["u"][row, :n], rtol=1e-6, atol=1e-9)
    # the noise-free output and the noisy one differ by the episode's noise only
    _, yt = _scalars(rrd, f"{base}/y_true")
    assert np.all(np.abs(yt - y) <= 0.5 * ds.amplitude[row])
    # the vehicle moves along z with y_true (altitude loop)
    tv, cells = _read_rows(rrd, f"{base}/world/vehicle")
    z = np.array([json.loads(c[-1])[0][2] for c in cells])
    np.testing.assert_allclose(tv, t, atol=1e-9)
    np.testing.assert_allclose(z, yt, rtol=1e-5, atol=1e-7)


def test_dataset_without_resimulation_replays_the_raw_traces(tiny_h5: Path, tmp_path: Path) -> None:
    s = replay(tiny_h5, tmp_path / "raw.rrd", cls=0, episode=0, resimulate=False)
    (info,) = s["runs"]
    assert not s["resimulated"] and not info["vehicle"] and f"runs/{info['stem']}/y_true" not in info["entities"]
    assert any("no exact re-simulation" in m for m in info["messages"])
    assert info["rows"] == int(open_dataset(tiny_h5).raw["length"][s["row"]])
    assert rerun("rrd", "verify", str(tmp_path / "raw.rrd")).returncode == 0


@pytest.fixture
def cli(monkeypatch):
    import uavsim.cli.main as cli_main

    monkeypatch.setattr(cli_main, "_COMMAND_MODULES", ["uavsim.cli.replay_cmd"])
    return cli_main.main


def _one_line_error(cli, argv: list[str], capsys) -> str:
    assert cli(["replay", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("uavsim replay: error:"), err
    return err


def test_dataset_user_errors(cli, tiny_h5: Path, tmp_path: Path, capsys) -> None:
    err = _one_line_error(cli, [str(tiny_h5), "--class", "2"], capsys)
    assert str(tiny_h5) in err and "class 2 out of range 0..1" in err
    err = _one_line_error(cli, [str(tiny_h5), "--class", "0", "--episode", "9"], capsys)
    assert "episode 9 out of range" in err
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.arange(3)
    assert "format is None" in _one_line_error(cli, [str(other)], capsys)
    bad = tmp_path / "corrupt.h5"
    bad.write_bytes(tiny_h5.read_bytes()[:4000])
    assert "corrupt.h5" in _one_line_error(cli, [str(bad)], capsys)
    half = tmp_path / "half.h5"
    shutil.copy(tiny_h5, half)
    with h5py.File(half, "r+") as f:
        f.attrs["complete"] = False
    assert "incomplete" in _one_line_error(cli, [str(half)], capsys)
    assert "--run" in _one_line_error(cli, [str(tiny_h5), "--run", "x"], capsys)


def test_dataset_cli_json(cli, tiny_h5: Path, tmp_path: Path, capsys) -> None:
    rrd = tmp_path / "c.rrd"
    assert cli(["replay", str(tiny_h5), "--class", "1", "--episode", "0", "--save", str(rrd), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["source"] == "dataset" and s["class"] == 1 and s["runs"][0]["u_mismatch"] == 0 and rrd.is_file()


# -- scenario run ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def scenario_run(tmp_path_factory) -> tuple[dict, Path]:
    from uavsim.scenario.config import load_scenario
    from uavsim.scenario.flow import run_scenario
    from uavsim.scenario.record import write_recording

    scn = load_scenario(ROOT / "scenarios" / "normal-camera-kf.toml")
    scn.identification = replace(scn.identification, hover_s=2.0, duration_s=8.0, method="mrft-df")
    scn.test = replace(scn.test, duration_s=3.0)
    tmp = tmp_path_factory.mktemp("scn")
    res = run_scenario(scn, seed=3, workdir=tmp / "sessions")
    return res, write_recording(res, tmp / "run.rrd")


def test_scenario_run_file_round_trip(scenario_run) -> None:
    from uavsim.scenario.record import read_run, run_path

    res, rrd = scenario_run
    run = read_run(run_path(rrd))
    assert run_path(rrd).name == "run.run.npz"
    assert list(run["episodes"]) == list(res["_episodes"])
    for name, ep in res["_episodes"].items():
        got = run["episodes"][name]
        for key in ("t", "r", "y", "y_true", "u", "y_kf", "y_cam"):
            np.testing.assert_array_equal(got[key], ep.t if key == "t" else getattr(ep, key)[0])
        assert got["qpos"].shape == got["rotor_force"].shape == (ep.t.size, 6)
        if name.startswith("lateral"):
            # the lateral loop's true output carries the process's outer delay: y follows it
            assert np.corrcoef(got["qpos"][:, 1], ep.pos[0])[0, 1] > 0.99
        else:
            np.testing.assert_array_equal(got["qpos"][:, 2], ep.pos[0])  # altitude: z is the true position
    relay = next(e for e in run["meta"]["episodes"] if e["name"] == "altitude/relay")["controller"]
    assert relay["kind"] == "np-mrft" and relay["tau_obs"] == res["loops"]["altitude"]["relay"]["tau_obs"]


def test_scenario_replay_against_the_run(scenario_run, tmp_path: Path) -> None:
    from uavsim.scenario.record import read_run, run_path

    res, rrd = scenario_run
    out = tmp_path / "scn-replay.rrd"
    s = replay(rrd, out)
    assert s["source"] == "scenario" and s["run_file"] == str(run_path(rrd))
    assert [r["label"] for r in s["runs"]] == list(res["_episodes"])
    assert rerun("rrd", "verify", str(out)).returncode == 0
    printed = rerun("rrd", "print", str(out)).stdout
    run = read_run(run_path(rrd))
    for info in s["runs"]:
        ep = run["episodes"][info["label"]]
        T = ep["t"].size
        base = f"/runs/{info['stem']}"
        assert info["vehicle"] and info["rows"] == T
        for name in ("r", "y", "y_true", "u", "world/vehicle", "world/vehicle/thrust", "signals/y_kf"):
            assert _chunk_rows(printed, f"{base}/{name}") == T, (info["stem"], name)
        t, y = _scalars(out, f"{base}/y")
        assert t[0] == pytest.approx(ep["t"][0]) and t[-1] == pytest.approx(ep["t"][-1])
        np.testing.assert_allclose(y, ep["y"], rtol=1e-9, atol=1e-12)
        _, yt = _scalars(out, f"{base}/y_true")
        np.testing.assert_allclose(yt, ep["y_true"], rtol=1e-9, atol=1e-12)
    relay = next(r for r in s["runs"] if r["label"] == "altitude/relay")
    assert relay["kind"] == "np-mrft" and relay["u_mismatch"] == 0 and relay["extrema"] > 3
    assert _chunk_rows(printed, "/runs/altitude_relay/extrema") == relay["extrema"]


def test_scenario_episode_selection_and_errors(scenario_run, tmp_path: Path) -> None:
    from uavsim.scenario.record import run_path

    _, rrd = scenario_run
    s = replay(run_path(rrd), tmp_path / "one.rrd", run="altitude/relay")
    assert [r["stem"] for r in s["runs"]] == ["altitude_relay"]
    with pytest.raises(UserError, match="no episode 'nope'"):
        replay(rrd, tmp_path / "x.rrd", run="nope")
    with pytest.raises(UserError, match="--class and --episode"):
        replay(rrd, tmp_path / "x.rrd", cls=1)
    lone = tmp_path / "lone.rrd"
    shutil.copy(rrd, lone)
    with pytest.raises(UserError, match="no scenario run file lone.run.npz"):
        replay(lone)
    junk = tmp_path / "junk.run.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(UserError, match="junk.run.npz"):
        replay(junk)


# -- pieces ----------------------------------------------------------------------------------------

def test_record_state_changes_nothing_else() -> None:
    from uavsim.control.relay import NPMRFT
    from uavsim.lumped.params import LumpedParams
    from uavsim.model.vehicle import Vehicle
    from uavsim.sim.runner import LoopBatch

    p = LumpedParams("altitude", K=1.0, T_prop=0.1, T1=0.8, tau=0.02)
    out = []
    for rec in (False, True):
        lb = LoopBatch([p, p], dt=0.001, rate_hz=200.0, y0=np.array([-1e-3, 2e-3]), record_state=rec)
        out.append(lb.run(NPMRFT(-0.73, 1.0, 0.02, 0.0, 200.0, 2), 2.0))
    plain, rec = out
    assert plain.qpos is None and plain.rotor_force is None
    np.testing.assert_array_equal(plain.y, rec.y)
    np.testing.assert_array_equal(plain.u, rec.u)
    assert rec.qpos.shape == rec.rotor_force.shape == (2, 400, 6)
    np.testing.assert_array_equal(rec.qpos[:, :, 2], rec.y_true)
    hover = Vehicle().hover_thrust_per_rotor_N
    assert np.all(np.abs(rec.rotor_force - hover) < 0.5 * hover)


def test_body_quaternion_is_mujocos() -> None:
    import mujoco

    from uavsim.model.vehicle import hexarotor_mjcf
    from uavsim.viz.vehicle3d import body_quaternion, geometry

    m = mujoco.MjModel.from_xml_string(hexarotor_mjcf())
    d = mujoco.MjData(m)
    q = np.random.default_rng(0).uniform(-1.0, 1.0, (5, 6))
    ours = body_quaternion(q)
    for qi, xyzw in zip(q, ours, strict=True):
        d.qpos[:] = qi
        mujoco.mj_kinematics(m, d)
        wxyz = d.xquat[m.body("hexarotor").id]
        assert min(np.abs(wxyz - xyzw[[3, 0, 1, 2]]).max(), np.abs(wxyz + xyzw[[3, 0, 1, 2]]).max()) < 1e-12
    g = geometry()
    assert g.rotor_pos.shape == (6, 3) and g.prop_radius == pytest.approx(0.19)
