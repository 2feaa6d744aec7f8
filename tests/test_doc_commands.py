"""Code that lived beside the docs, now in the package: it runs, and refuses bad input with one line, exit 2.

``uavsim.sim.example_session`` writes the committed example session byte for byte; the two pictures
of ``uavsim.viz`` (``replay_png``, ``viewer_png``); ``uavsim testbed score``; ``uavsim.results.lateral_grid``.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SESSIONS = ROOT / "scenarios" / "sessions"


def _one_line_error(capsys, needle: str) -> None:
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1 and "Traceback" not in err, err


# --- uavsim.sim.example_session -------------------------------------------------------------

def test_example_session_is_the_committed_one(tmp_path):
    from _platform import platform_differs

    from uavsim.sim.example_session import NAME, main

    why = platform_differs()
    if why:
        pytest.skip(why)

    assert main(["--out", str(tmp_path)]) == 0
    for f in sorted((SESSIONS / NAME).iterdir()):
        assert (tmp_path / NAME / f.name).read_bytes() == f.read_bytes(), f.name
    assert (tmp_path / f"{NAME}.truth.json").read_bytes() == (SESSIONS / f"{NAME}.truth.json").read_bytes()


def test_example_session_refuses_a_file_as_folder(tmp_path, capsys):
    from uavsim.sim.example_session import main

    f = tmp_path / "file"
    f.write_text("x")
    assert main(["--out", str(f)]) == 2
    _one_line_error(capsys, "not a folder")


# --- uavsim.viz.replay_png / viewer_png -----------------------------------------------------

def test_replay_png_draws_a_session(tmp_path):
    from uavsim.viz.replay_png import main

    out = tmp_path / "r.png"
    assert main([str(SESSIONS / "altitude-npmrft"), str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 10_000


@pytest.mark.parametrize("argv", [["/no/such/source", "x.png"], ["--rrd", "/no/such.rrd", "x.png"]])
def test_replay_png_missing_input(argv, capsys):
    from uavsim.viz.replay_png import main

    assert main(argv) == 2
    _one_line_error(capsys, "not found")


def test_viewer_png_names_what_is_missing(tmp_path, capsys, monkeypatch):
    from uavsim.viz import viewer_png

    monkeypatch.setattr(viewer_png.shutil, "which", lambda tool: None)
    assert viewer_png.main(["--out", str(tmp_path / "v.png")]) == 2
    _one_line_error(capsys, "Xvfb not found; apt-get install")
    assert not (tmp_path / "v.png").exists()


# --- uavsim testbed score -------------------------------------------------------------------

def _record(name: str, kind: str, answer: str, gap_before: float) -> dict:
    return {"name": name, "condition": "identified", "kind": kind, "loop": "altitude", "truth": "none",
            "truth_params": [], "answer": answer, "found": [], "gap_before": gap_before, "gap_after": gap_before,
            "absorbed": None, "seconds": 1.0, "ok": False}


def test_testbed_score_summarize_redecides_a_log(tmp_path, capsys):
    from uavsim.cli.main import main as cli

    log = tmp_path / "log.jsonl"
    # logged as wrong answers; today's thresholds decide them again from their gaps
    log.write_text(json.dumps(_record("tb_00000", "none", "unexplained", 0.0)) + "\n"
                   + json.dumps(_record("tb_00001", "none", "none", 1e6)) + "\n")
    assert cli(["testbed", "score", str(log), "--summarize"]) == 0
    out = capsys.readouterr().out
    assert "| tb_00000 | none | altitude | none | none |" in out
    assert "| tb_00001 | none | altitude | none | unexplained |" in out
    assert "answered right: 1/2" in out


@pytest.mark.parametrize("argv_tail, needle", [
    (["{tmp}/none"], "not a folder"),
    (["{tmp}"], "no session folders"),
    (["{tmp}", "--conditions", "oracle"], "--conditions"),
    (["{tmp}/none.jsonl", "--summarize"], "not a file"),
    (["{tmp}/bad.jsonl", "--summarize"], "not a --log file"),
])
def test_testbed_score_user_errors(tmp_path, capsys, argv_tail, needle):
    from uavsim.cli.main import main as cli

    (tmp_path / "bad.jsonl").write_text("{not json\n")
    assert cli(["testbed", "score", *[a.format(tmp=tmp_path) for a in argv_tail]]) == 2
    _one_line_error(capsys, needle)


def test_testbed_score_needs_truth_files(tmp_path, capsys):
    from uavsim.cli.main import main as cli

    (tmp_path / "tb_00000").mkdir()
    (tmp_path / "tb_00000" / "session.toml").write_text("")
    assert cli(["testbed", "score", str(tmp_path)]) == 2
    _one_line_error(capsys, "no truth file beside tb_00000")


def test_lateral_grid_render_of_its_own_json(tmp_path, capsys):
    from uavsim.results.lateral_grid import main

    st = {"median": 1.01, "p95": 1.05, "max": 1e3, "unstable": 1, "n": 10}
    row = {"att_class": 0, "beta": -0.73, "T0_min_s": 1.0, "n_classes": 6, "pm_deg": 20, "gain_scale": 0.7,
           "neighbour_J_robust": st, "neighbour_J_optimum": st, "robust_own_J": st, "coverage_robust_best": st,
           "coverage_best": st}
    doc = {"pooled": {k: st for k in ("best", "robust_best", "nearest", "robust_nearest", "rule")},
           "fast_corner": {k: st for k in ("best", "robust_best")}, "per_class_figures": [row]}
    p = tmp_path / "f.json"
    p.write_text(json.dumps(doc))
    assert main(["--render", str(p), str(p)]) == 0
    out = capsys.readouterr().out
    assert "| best class, optimum | 1.010 / 1.050 / -, 1 | 1.010 / 1.050 / -, 1 |" in out
    (tmp_path / "g.json").write_text("{}")
    assert main(["--render", str(tmp_path / "g.json"), str(p)]) == 2
    _one_line_error(capsys, "not this module's JSON")
