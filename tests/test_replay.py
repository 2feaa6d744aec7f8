"""``uavsim replay``: a simulated NP-MRFT session logged to Rerun and read back.

The saved ``.rrd`` is checked with Rerun's own tooling (``rerun rrd verify``,
``rerun rrd print``): the entity paths are there, and the rows of ``y`` read
back match the CSV (count, time range, values).
"""

from __future__ import annotations

import dataclasses
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from _rerun_cli import iso_seconds, rerun

from uavsim.control.relay import NPMRFT
from uavsim.errors import UserError
from uavsim.formats.session import Run, RunData, read_session, write_session
from uavsim.lumped.params import LumpedParams
from uavsim.sim.runner import LoopBatch
from uavsim.sim.sessions import relay_session
from uavsim.viz.replay import phase_portrait, replay_session, sign_changes

RATE = 200.0
TAU_OBS = 0.02


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory) -> Path:
    """A session with the simulated relay run and a copy whose u is tampered with."""
    params = LumpedParams("altitude", K=1.0, T_prop=0.1, T1=0.8, tau=0.02)
    lb = LoopBatch([params], dt=0.001, rate_hz=RATE, y0=np.array([-1e-3]))
    res = lb.run(NPMRFT(-0.73, 1.0, TAU_OBS, 0.0, RATE, 1), 8.0)
    s = relay_session(res, 0, params, beta=-0.73, h=1.0, rate_hz=RATE, tau_obs=TAU_OBS, a_n=0.0)
    run = s.runs[0]
    u = run.data.u.copy()
    u[100:105] = -u[100:105]
    tampered = Run(
        dataclasses.replace(run.spec, file="tampered.csv"),
        RunData(run.data.t.copy(), run.data.r.copy(), run.data.y.copy(), u),
    )
    s = dataclasses.replace(s, runs=[run, tampered], path=None)
    return write_session(s, tmp_path_factory.mktemp("replay") / "sess")


@pytest.fixture(scope="module")
def replayed(session_dir: Path, tmp_path_factory) -> tuple[dict, Path]:
    rrd = tmp_path_factory.mktemp("rrd") / "out.rrd"
    return replay_session(session_dir, rrd), rrd


def _read_scalars(rrd: Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    """(time s, value) rows of a scalar entity, as printed by ``rerun rrd print -vvv``."""
    out = rerun("rrd", "print", "-vvv", "--entity", entity, str(rrd))
    assert out.returncode == 0, out.stderr
    t, v = [], []
    for line in out.stdout.splitlines():
        cells = [c.strip(" │") for c in line.split("┆")]
        if len(cells) == 3 and cells[0].startswith("row_") and cells[1].startswith("P"):
            t.append(iso_seconds(cells[1]))
            v.append(float(cells[2].strip("[]")))
    return np.array(t), np.array(v)


def test_summary_recomputes_relay(replayed) -> None:
    summary, rrd = replayed
    assert summary["rrd"] == str(rrd) and rrd.is_file()
    good, bad = summary["runs"]
    assert good["stem"] == "relay" and good["kind"] == "np-mrft"
    assert good["rows"] == 1600 and good["t0"] == 0.0 and good["t1"] == pytest.approx(7.995)
    # the simulator and the recomputed relay agree exactly
    assert good["u_mismatch"] == 0
    assert good["recomputed_switches"] == good["switches"] > 10
    assert good["extrema"] == len(good["windows"]) == good["switches"]
    n_obs = int(np.ceil(TAU_OBS * RATE - 1e-9))
    assert good["n_obs"] == n_obs
    for a, b in good["windows"]:
        assert b - a == pytest.approx(n_obs / RATE)
    assert "matches" in good["messages"][-1]
    # a noise-free simulated session is simulated again from its [model]: pose and thrusts
    assert good["vehicle"] and good["resimulated"]["dt"] == 0.001
    assert good["entities"]["runs/relay/world/vehicle"] == good["entities"]["runs/relay/y_true"] == 1600
    assert good["entities"]["runs/relay/world/vehicle/thrust"] == 1600
    # the tampered copy: 5 flipped samples, 2 sign changes more
    assert bad["u_mismatch"] == 5
    assert "differs" in bad["messages"][-1]
    for stem in ("relay", "tampered"):
        info = summary["runs"][0 if stem == "relay" else 1]
        assert info["entities"][f"runs/{stem}/y"] == 1600
        assert set(info["entities"]) >= {
            f"runs/{stem}/{n}"
            for n in ("r", "y", "e", "u", "switches", "extrema", "inhibition", "phase", "log")
        }


def test_rrd_verify_and_entities(replayed) -> None:
    summary, rrd = replayed
    verify = rerun("rrd", "verify", str(rrd))
    assert verify.returncode == 0, verify.stderr
    printed = rerun("rrd", "print", str(rrd))
    assert printed.returncode == 0, printed.stderr
    for info in summary["runs"]:
        for path, rows in info["entities"].items():
            if path.endswith("/phase"):
                assert f"/{path} " in printed.stdout
                continue
            assert re.search(rf"with {rows} rows .* - /{re.escape(path)} - ", printed.stdout), path


def test_rrd_rows_match_csv(replayed, session_dir: Path) -> None:
    _, rrd = replayed
    data = read_session(session_dir).runs[0].data
    t, y = _read_scalars(rrd, "/runs/relay/y")
    assert t.size == data.t.size
    assert t[0] == pytest.approx(data.t[0]) and t[-1] == pytest.approx(data.t[-1])
    np.testing.assert_allclose(t, data.t, atol=1e-9)
    np.testing.assert_allclose(y, data.y, rtol=1e-6, atol=1e-12)
    ts, es = _read_scalars(rrd, "/runs/relay/switches")
    k = sign_changes(data.u)
    np.testing.assert_allclose(ts, data.t[k], atol=1e-9)
    np.testing.assert_allclose(es, (data.r - data.y)[k], rtol=1e-6, atol=1e-12)


def test_run_selection_and_default_path(session_dir: Path) -> None:
    summary = replay_session(session_dir, run="tampered")
    assert [r["stem"] for r in summary["runs"]] == ["tampered"]
    assert Path(summary["rrd"]) == session_dir / "replay.rrd"
    assert (session_dir / "replay.rrd").is_file()
    with pytest.raises(UserError, match="no run 'nope'"):
        replay_session(session_dir, run="nope")


def test_helpers() -> None:
    u = np.array([1.0, 1.0, -1.0, -1.0, 1.0])
    np.testing.assert_array_equal(sign_changes(u), [2, 4])
    np.testing.assert_array_equal(sign_changes(u + 0.5, 0.5), [2, 4])
    t = np.arange(5) * 0.1
    pts = phase_portrait(t, 2.0 * t)
    np.testing.assert_allclose(pts[:, 1], 2.0)


@pytest.fixture
def cli(monkeypatch):
    import uavsim.cli.main as cli_main

    monkeypatch.setattr(cli_main, "_COMMAND_MODULES", ["uavsim.cli.replay_cmd"])
    return cli_main.main


def test_cli_json(cli, session_dir: Path, tmp_path: Path, capsys) -> None:
    rrd = tmp_path / "cli.rrd"
    assert (
        cli(["replay", str(session_dir), "--save", str(rrd), "--run", "relay.csv", "--json"]) == 0
    )
    summary = json.loads(capsys.readouterr().out)
    assert summary["rrd"] == str(rrd) and rrd.is_file()
    assert summary["runs"][0]["u_mismatch"] == 0


def test_cli_text(cli, session_dir: Path, tmp_path: Path, capsys) -> None:
    assert cli(["replay", str(session_dir), "--save", str(tmp_path / "x.rrd")]) == 0
    out = capsys.readouterr().out
    assert "runs/relay" in out and "u mismatch 5" in out


@pytest.mark.parametrize(
    "argv_tail",
    [[], ["--run", "nope"]],
    ids=["missing-path", "unknown-run"],
)
def test_cli_user_errors(cli, session_dir: Path, tmp_path: Path, capsys, argv_tail) -> None:
    path = tmp_path / "missing" if not argv_tail else session_dir
    assert cli(["replay", str(path), *argv_tail]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("uavsim replay: error:")


def test_cli_bad_save_folder(cli, session_dir: Path, tmp_path: Path, capsys) -> None:
    assert cli(["replay", str(session_dir), "--save", str(tmp_path / "no" / "x.rrd")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_spawn_without_display_falls_back_to_file(session_dir: Path, monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    summary = replay_session(session_dir, spawn=True, run="relay")
    assert summary["spawned"] is False
    assert Path(summary["rrd"]) == session_dir / "replay.rrd"


def test_step_run_has_no_relay_entities(session_dir: Path, tmp_path: Path) -> None:
    s = read_session(session_dir)
    run = s.runs[0]
    spec = dataclasses.replace(
        run.spec, file="step.csv", kind="step", beta=None, h=None, tau_obs=None, a_n=None,
        kp=1.0, kd=0.1, derivative_filter_hz=8.0, step=1.0, step_time=1.0,
    )  # fmt: skip
    folder = write_session(
        dataclasses.replace(s, runs=[Run(spec, run.data)], path=None), tmp_path / "s"
    )
    summary = replay_session(folder, tmp_path / "step.rrd")
    info = summary["runs"][0]
    assert info["kind"] == "step" and "u_mismatch" not in info
    assert "runs/step/extrema" not in info["entities"] and info["entities"]["runs/step/y"] == 1600
    assert rerun("rrd", "verify", str(tmp_path / "step.rrd")).returncode == 0
