"""Class grids: artefacts, counts, J, round trip and the ``uavsim grid`` command."""

import json

import numpy as np
import pytest

import uavsim.cli.main as cli_main
from uavsim.errors import UserError
from uavsim.lumped import RANGES, LumpedParams
from uavsim.tuning.grid import TARGETS, grid_report, load_grid, save_grid
from uavsim.tuning.rule import TuningRule


@pytest.mark.parametrize("loop", ["attitude", "altitude"])
def test_inner_grid_artefact(loop):
    g = load_grid(loop)
    assert abs(g.n / TARGETS[loop] - 1) <= 0.15
    assert g.J.shape == (g.n, g.n)
    np.testing.assert_array_equal(np.diag(g.J), 1.0)
    assert np.all(g.J >= 1.0)
    for k, (lo, hi) in RANGES[loop].items():
        assert np.all((g.params[k] >= lo) & (g.params[k] <= hi))
    np.testing.assert_allclose(g.period, 2 * np.pi / g.omega)
    # stored gains are the rule's unit-gain gains of each class
    i = g.n // 2
    p = g.params_of(i)
    assert isinstance(p, LumpedParams) and p.K == 1.0
    ref = TuningRule(g.beta, g.pm_deg).gains(p)
    assert g.kp[i] == pytest.approx(ref.kp, rel=1e-6) and g.kd[i] == pytest.approx(ref.kd, rel=1e-6)
    assert len(g.hash) == 64


def test_loop_aliases():
    assert load_grid("roll").loop == "attitude" and load_grid("pitch").n == load_grid("attitude").n


def test_round_trip_and_corruption(tmp_path):
    g = load_grid("attitude")
    path = save_grid(g, tmp_path / "att.json")
    g2 = load_grid("attitude", path)
    np.testing.assert_allclose(g2.J, g.J)
    assert g2.hash == g.hash
    d = json.loads(path.read_text())
    d["kp"][0] *= 2
    path.write_text(json.dumps(d))
    with pytest.raises(UserError, match="corrupt"):
        load_grid("attitude", path)
    with pytest.raises(UserError, match="no .* grid"):
        load_grid("altitude", tmp_path / "missing.json")


def test_lateral_grid_if_built():
    try:
        g = load_grid("lateral")
    except UserError:
        pytest.skip("lateral grid not built")
    att = load_grid("attitude")
    assert len(g.sub) == att.n
    s = g.lateral(0)
    assert 10 <= s.n <= 20
    p = s.params_of(0)
    assert p.family == "lateral" and p.att_kp == pytest.approx(att.kp[0])
    np.testing.assert_array_equal(np.diag(s.J), 1.0)


def test_report_figures_small():
    rep = grid_report(load_grid("attitude"), n_points=200)
    assert rep["n_classes"] == 48
    assert 1.0 < rep["neighbour_J_across_levels"]["mean"] < 1.2
    assert rep["coverage"]["worst_J"] < 1.10


def test_grid_cli_report_json(monkeypatch, capsys):
    monkeypatch.setattr(cli_main, "_COMMAND_MODULES", ["uavsim.cli.tune_cmd", "uavsim.cli.grid_cmd"])
    assert cli_main.main(["grid", "report", "--loop", "attitude", "--points", "100", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_classes"] == 48 and "coverage" in out


@pytest.mark.slow
def test_grid_cli_build(monkeypatch, tmp_path):
    monkeypatch.setattr(cli_main, "_COMMAND_MODULES", ["uavsim.cli.grid_cmd"])
    out = tmp_path / "att.json"
    assert cli_main.main(["grid", "build", "--loop", "attitude", "--out", str(out)]) == 0
    assert load_grid("attitude", out).n == 48
