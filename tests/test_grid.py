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


def test_lateral_grid_artefact():
    g = load_grid("lateral")
    att = load_grid("attitude")
    assert len(g.sub) == att.n and g.built["attitude_hash"] == att.hash
    for a in (0, att.n // 2, att.n - 1):
        s = g.lateral(a)
        assert abs(s.n / TARGETS["lateral"] - 1) <= 0.35
        assert s.J.shape == (s.n, s.n)
        np.testing.assert_array_equal(np.diag(s.J), 1.0)
        assert np.all(s.J >= 1.0)
        # the beta of each attitude class is one of the searched candidates
        assert -0.9 - 1e-9 <= s.beta <= -0.1 + 1e-9
        for k, (lo, hi) in RANGES["lateral"].items():
            assert np.all((s.params[k] >= lo) & (s.params[k] <= hi))
        p = s.params_of(s.n // 2)
        assert p.family == "lateral" and p.att_kp == pytest.approx(att.kp[a]) and p.tau_in == pytest.approx(att.params["tau"][a])
        # stored gains are the sub-grid rule's unit-gain gains at its own beta
        ref = TuningRule(s.beta, s.pm_deg).gains(p)
        assert s.kp[s.n // 2] == pytest.approx(ref.kp, rel=1e-6) and s.kd[s.n // 2] == pytest.approx(ref.kd, rel=1e-6)
    with pytest.raises(UserError):
        g.params_of(0)
    with pytest.raises(UserError):
        g.lateral(att.n)


def test_lateral_classes_are_stable_under_their_own_rule():
    """Every class was drawn from the part of the box its own rule controller stabilizes."""
    from uavsim.lumped.ise import step_ise_batch

    g = load_grid("lateral")
    for a in (0, 10, 30):
        s = g.lateral(a)
        q = step_ise_batch("lateral", s.kp, s.kd, 2 * np.pi * s.derivative_filter_hz, s.omega_df, n=1500, K=1.0,
                           **{k: v for k, v in _lateral_params(s).items()})
        assert np.all(np.isfinite(q))


def _lateral_params(s):
    a = s.attitude
    return {"T_prop": a["T_prop"], "T1": a["T1"], "tau": s.params["tau"], "T2": s.params["T2"], "tau_in": a["tau_in"],
            "att_kp": a["att_kp"], "att_kd": a["att_kd"], "att_N": 2 * np.pi * a["att_filter_hz"]}


def test_lateral_instability_is_real_in_time():
    """Points the Nyquist test calls unstable under their own rule diverge in a time simulation."""
    from uavsim.tuning.grid import _log_box, _omega, attitude_of, own_loop_stable, verify_unstable

    att = attitude_of(load_grid("attitude"), 0)
    rule = TuningRule(-0.1, 20.0)
    lo, hi = _log_box("lateral")
    X = np.exp(lo + (hi - lo) * np.random.default_rng(5).random((60, 2)))
    w = _omega("lateral", X, rule.beta, att)
    X, w = X[np.isfinite(w)], w[np.isfinite(w)]
    st = own_loop_stable("lateral", X, w, rule, att)
    assert 0 < st.sum() < len(st)
    pts = [(att, rule.beta, X[i]) for i in np.flatnonzero(~st)[:2]] + [(att, rule.beta, X[i]) for i in np.flatnonzero(st)[:2]]
    np.testing.assert_array_equal(verify_unstable(pts, 20.0), [True, True, False, False])
    # the build's own check: two unstable points per attitude class (69 of 71 diverged within 30 periods;
    # the others grow more slowly than that window shows)
    chk = load_grid("lateral").built["instability_check"]
    assert chk["n_diverged_in_time"] >= 0.9 * chk["n_points"] > 0


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


def test_lateral_report_small(monkeypatch, capsys):
    monkeypatch.setattr(cli_main, "_COMMAND_MODULES", ["uavsim.cli.grid_cmd"])
    assert cli_main.main(["grid", "report", "--loop", "lateral", "--points", "480", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_subgrids"] == 48 and out["n_classes_total"] >= 48 * 10
    assert 0.0 < out["coverage"]["stable_fraction"] <= 1.0
