"""Class grids: artefacts, counts, J, round trip and the ``uavsim grid`` command."""

import json

import numpy as np
import pytest

import uavsim.cli.main as cli_main
from uavsim.errors import UserError
from uavsim.lumped import RANGES, LumpedParams
from uavsim.tuning.grid import TARGETS, grid_report, load_grid, save_grid
from uavsim.tuning.rule import TuningRule, rule_constants


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


def _lateral_params(att, T2, tau):
    """Lateral process parameters (unit gain) over attitude class ``att`` (a sub-grid's ``attitude``)."""
    return {"T_prop": att["T_prop"], "T1": att["T1"], "tau": tau, "T2": T2, "tau_in": att["tau_in"],
            "att_kp": att["att_kp"], "att_kd": att["att_kd"], "att_N": 2 * np.pi * att["att_filter_hz"]}


def test_lateral_grid_artefact():
    """One sub-grid per attitude class over its attitude table PD at 200 Hz, a cover with neighbours, each
    with its own beta (NP-MRFT's bound on its fastest cycle) and rule."""
    from uavsim.tuning.grid import attitude_of
    from uavsim.tuning.lateral_grid import TAU_OBS, beta_min
    from uavsim.tuning.table import load_table

    g = load_grid("lateral")
    att, att_table = load_grid("attitude"), load_table("attitude")
    assert len(g.sub) == att.n and g.built["attitude_hash"] == att.hash
    assert g.built["attitude_pd_hash"] == att_table.pd_hash and g.built["rate_hz"] == 200.0
    assert g.built["lateral_rules"] == [[s.beta, s.pm_deg, s.gain_scale] for s in g.sub]
    assert 600 <= sum(s.n for s in g.sub) <= 900
    for a in (0, att.n // 2, att.n - 1):
        s = g.lateral(a)
        assert s.attitude == attitude_of(att, a, att_table) and s.attitude["rate_hz"] == 200.0
        assert 3 <= s.n <= 40 and s.level is None
        assert s.J.shape == (s.n, s.n) and np.all(s.J >= 1.0) and np.all(np.diag(s.J) < 1.2)
        nb = np.asarray(s.neighbours)
        assert np.all(nb[:, 0] < nb[:, 1]) and set(nb.ravel()) == set(range(s.n))
        bc = s.built["beta_choice"]
        assert -0.73 - 1e-9 <= s.beta <= -0.05 and bc["feasible"] and s.beta >= beta_min(TAU_OBS, bc["T0_min"]) - 1e-9
        ch = s.built["rule_choice"]
        assert (ch["pm_deg"], ch["gain_scale"]) == (s.pm_deg, s.gain_scale) and ch["stable_fraction"] == 1.0
        assert (s.c1, s.c3) == pytest.approx(rule_constants(s.beta, s.pm_deg, s.gain_scale))
        for k, (lo, hi) in RANGES["lateral"].items():
            assert np.all((s.params[k] >= lo) & (s.params[k] <= hi))
        p = s.params_of(s.n // 2)
        assert p.family == "lateral" and p.att_kp == pytest.approx(att_table.kp[a])
        assert p.tau_in == pytest.approx(att.params["tau"][a])
        # stored gains are the sub-grid rule's unit-gain gains on the sampled loop
        pp = {**_lateral_params(s.attitude, s.params["T2"], s.params["tau"]), "att_rate_hz": 200.0}
        ref = s.rule.gains_batch("lateral", K=1.0, **pp)
        np.testing.assert_allclose(s.kp, ref["kp"], rtol=1e-6)
        np.testing.assert_allclose(s.omega_df, ref["omega"], rtol=1e-6)
    with pytest.raises(UserError):
        g.params_of(0)
    with pytest.raises(UserError):
        g.lateral(att.n)


def test_lateral_round_trip_keeps_rule_and_neighbours(tmp_path):
    g = load_grid("lateral")
    g2 = load_grid("lateral", save_grid(g, tmp_path / "lat.json"))
    assert g2.hash == g.hash
    assert [s.gain_scale for s in g2.sub] == [s.gain_scale for s in g.sub]
    assert [s.neighbours for s in g2.sub] == [s.neighbours for s in g.sub]
    # the inner grids carry no gain scale or neighbours: their files (and hashes) are as before
    assert "gain_scale" not in load_grid("attitude").to_dict() and "neighbours" not in load_grid("attitude").to_dict()


def test_lateral_cycles_are_the_sampled_loop_s():
    """The stored cycle is the exact 200 Hz relay cycle of the loop flown (recomputed), and its DF
    frequency the sampled loop's; the continuous attitude loop would move the fast classes' MRFT point."""
    from uavsim.lumped.frequency import mrft_prediction_batch
    from uavsim.lumped.lateral import sampled_relay_cycle

    g = load_grid("lateral")
    for a in (2, 47):
        s = g.lateral(a)
        i = np.argsort(s.omega_df)[[0, -1]]
        pp = _lateral_params(s.attitude, s.params["T2"][i], s.params["tau"][i])
        T, amp = sampled_relay_cycle(s.beta, 200.0, **pp)
        np.testing.assert_allclose(s.period[i], T, rtol=1e-6)
        np.testing.assert_allclose(s.amplitude[i], amp, rtol=1e-6)
        w_s = mrft_prediction_batch("lateral", s.beta, 1.0, K=1.0, att_rate_hz=200.0, **pp)[0]
        np.testing.assert_allclose(s.omega_df[i], w_s, rtol=1e-6)
        if a == 47:
            w_c = mrft_prediction_batch("lateral", s.beta, 1.0, K=1.0, **pp)[0]
            assert np.abs(w_c / w_s - 1).max() > 0.03


def test_lateral_neighbour_J():
    """The grid's J is the table's J of the robust answers: neighbours about J = 1.10 apart, none unstable."""
    from uavsim.tuning.grid import _neighbour_J
    from uavsim.tuning.table import load_table

    g, t = load_grid("lateral"), load_table("lateral")
    for a in (0, 30):
        np.testing.assert_allclose(g.lateral(a).J, t.lateral(a).J_robust, rtol=1e-4)  # 5 digits stored
    nb = np.concatenate([_neighbour_J(s)[0] for s in g.sub])
    assert 1.05 <= np.median(nb) <= 1.15
    assert np.quantile(nb, 0.95) < 1.5 and nb.max() < 1e3


def test_lateral_cover_design_small():
    """The greedy cover reaches every point within the cover J; neighbours come from each point's two
    best classes, and a class no point shares takes its nearest by J."""
    from uavsim.tuning.lateral_grid import class_neighbours, cover

    J = np.array([[1.0, 1.04, 1.2, 9.0, 9.0],
                  [1.3, 1.0, 1.03, 1.2, 9.0],
                  [9.0, 1.3, 1.0, 1.04, 9.0],
                  [9.0, 9.0, 1.1, 1.0, 2.0],
                  [9.0, 9.0, 9.0, 1.5, 1.0]])
    cls = cover(J, 1.05)
    # 0, 1 and 2 each cover two points: 1 is nearest optimal on them; then single points, in order
    assert list(cls) == [1, 0, 3, 4]
    assert np.all((J[cls] <= 1.05).any(axis=0))
    nb = class_neighbours(J[cls], J[np.ix_(cls, cls)], 1.25)
    # points 1, 2 and 3 pair their two best classes; point 4's class shares no point: its nearest by J
    assert nb.tolist() == [[0, 1], [0, 2], [2, 3]]


def test_report_figures_small():
    rep = grid_report(load_grid("attitude"), n_points=200)
    assert rep["n_classes"] == 48
    assert 1.0 < rep["neighbour_J_across_levels"]["mean"] < 1.2
    assert rep["coverage"]["worst_J"] < 1.10


def test_grid_cli_report_json(monkeypatch, capsys):
    monkeypatch.setattr(cli_main, "_COMMAND_MODULES", ["uavsim.cli.tune_cmd", "uavsim.cli.grid_cmd"])
    assert cli_main.main(["grid", "report", "--loop", "attitude", "--points", "100", "--table-points", "0", "--json"]) == 0
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
    assert cli_main.main(["grid", "report", "--loop", "lateral", "--table-points", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_subgrids"] == 48 and out["n_classes_total"] >= 48 * 5
    assert out["neighbour_J"]["unstable"] == 0 and out["neighbour_J"]["median"] < 1.2
    assert -0.73 <= out["beta"]["min"] < out["beta"]["max"] <= -0.05
    assert out["design_sample_best_J_max"] <= 1.05 + 1e-9
    assert sum(int(r.rsplit(": ", 1)[1]) for r in out["rules"].split("; ")) == 48
