"""Tuning rule, J matrix and the ``uavsim tune`` command."""

import json
import math

import control
import numpy as np
import pytest

import uavsim.cli.main as cli_main
from uavsim.errors import UserError
from uavsim.lumped import LumpedParams, freq_response, step_ise
from uavsim.tuning.jmatrix import deterioration, j_matrix, symmetrize
from uavsim.tuning.rule import TuningRule, rule_constants


def test_flight_constants_reproduced():
    # published c1 = 0.3849, c3 = 0.3817 are a consistent pair of the rule ...
    c3 = 0.3817
    assert 1 / math.sqrt(1 + 4 * math.pi**2 * c3**2) == pytest.approx(0.3849, abs=1e-4)
    # ... and come from asin(-beta) + pm = 67.37 deg: beta = -0.7357 at pm = 20 deg
    c1, c3 = rule_constants(-0.7357, 20.0)
    assert c1 == pytest.approx(0.3849, abs=2e-4) and c3 == pytest.approx(0.3817, abs=2e-4)
    # (-0.73, 20 deg) itself (beta rounded in the paper)
    c1, c3 = rule_constants(-0.73, 20.0)
    assert c1 == pytest.approx(0.3926, abs=1e-4) and c3 == pytest.approx(0.3729, abs=1e-4)


@pytest.mark.parametrize("beta,pm", [(-0.73, 20.0), (-0.5, 45.0), (0.2, 60.0)])
def test_rule_gives_its_phase_margin_at_omega(beta, pm):
    p = LumpedParams("altitude", 3.0, 0.1, 0.8, 0.02)
    g = TuningRule(beta, pm).gains(p)
    # ideal PD (no filter): |C G| = 1 and arg = -180 + pm at Omega
    L = (g.kp + 1j * g.omega * g.kd) * freq_response(p, np.array([g.omega]))[0]
    assert abs(L) == pytest.approx(1.0, rel=1e-9)
    assert math.degrees(np.angle(L)) == pytest.approx(-180 + pm, abs=1e-6)
    assert g.derivative_filter_hz == pytest.approx(10 * g.omega / (2 * math.pi))


def test_gain_scaling():
    p1 = LumpedParams("altitude", 1.0, 0.1, 0.8, 0.02)
    g1, g5 = TuningRule().gains(p1), TuningRule().gains(p1.with_gain(5.0))
    assert g5.kp == pytest.approx(g1.kp / 5) and g5.kd == pytest.approx(g1.kd / 5)


def test_rule_rejects_invalid():
    with pytest.raises(UserError):
        rule_constants(-1.0, 20.0)
    with pytest.raises(UserError):
        rule_constants(-0.73, -5.0)
    with pytest.raises(UserError):
        rule_constants(0.9, 10.0)  # pm < asin(beta): negative derivative time


def _procs(n, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = np.log([0.015, 0.2, 0.0005]), np.log([0.3, 2.0, 0.06])
    X = np.exp(lo + (hi - lo) * rng.random((n, 3)))
    from uavsim.lumped.frequency import mrft_prediction_batch

    w, _ = mrft_prediction_batch("altitude", -0.73, 1.0, K=1.0, T_prop=X[:, 0], T1=X[:, 1], tau=X[:, 2])
    return X, w


def test_j_matrix_properties_and_entry():
    X, w = _procs(12)
    c1, c3 = rule_constants(-0.73, 20.0)
    J = j_matrix("altitude", w, c1, c3, T_prop=X[:, 0], T1=X[:, 1], tau=X[:, 2])
    assert J.shape == (12, 12)
    np.testing.assert_array_equal(np.diag(J), 1.0)
    assert np.all(J >= 1.0) and np.all(J <= 1e3)
    assert np.all(symmetrize(J) >= J)
    # one entry against an independent Pade step response of the normalized pair
    i, j = int(np.argsort(w)[5]), int(np.argsort(w)[6])
    Kn = 1 / abs(freq_response(LumpedParams("altitude", 1.0, *X[j]), np.array([w[j]]))[0])
    Tp, T1, tau = X[j]
    G = control.tf([Kn], [Tp * T1, Tp + T1, 1, 0]) * control.tf(*control.pade(tau, 5))

    def q(wc):
        N, kd = 10 * wc, c1 * c3 * 2 * math.pi / wc
        S = control.feedback(1, control.tf([kd + c1 / N, c1], [1 / N, 1]) * G)
        t = np.linspace(0, 80 * 2 * math.pi / w[j], 400001)
        return np.trapezoid(control.step_response(S, t)[1] ** 2, t)

    assert J[i, j] == pytest.approx(max(1.0, q(w[i]) / q(w[j])), rel=0.01)


def test_unstable_pair_gets_jmax():
    X, w = _procs(2)
    c1, c3 = rule_constants(-0.73, 20.0)
    # a controller tuned for a 30x faster class destabilizes the slow process
    D = deterioration("altitude", w[:1], np.array([30 * w[0]]), c1, c3, T_prop=X[:1, 0], T1=X[:1, 1], tau=X[:1, 2])
    assert D[0, 0] == 1e3


def test_step_ise_of_normalized_rule_is_gain_invariant():
    p = LumpedParams("altitude", 1.0, 0.1, 0.8, 0.02)
    g = TuningRule().gains(p)
    q1 = step_ise(p, g.kp, g.kd, g.N)
    q2 = step_ise(p.with_gain(7.0), g.kp / 7, g.kd / 7, g.N)
    assert q1 == pytest.approx(q2, rel=1e-9)


@pytest.fixture
def cli(monkeypatch):
    monkeypatch.setattr(cli_main, "_COMMAND_MODULES", ["uavsim.cli.tune_cmd", "uavsim.cli.grid_cmd"])
    return cli_main.main


def test_tune_cli_json(cli, capsys):
    assert cli(["tune", "--loop", "altitude", "--T-prop", "0.3", "--T1", "0.2", "--tau", "0.0128", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"beta", "pm_deg", "omega", "kp", "kd", "derivative_filter_hz"} <= set(out)
    g = TuningRule().gains(LumpedParams("altitude", 1.0, 0.3, 0.2, 0.0128))
    assert out["kp"] == pytest.approx(g.kp) and out["omega"] == pytest.approx(g.omega)


def test_tune_cli_invalid(cli, capsys):
    assert cli(["tune", "--loop", "altitude", "--T-prop", "0.3", "--T1", "0", "--tau", "0.01", "--json"]) == 2
    assert "time constants" in capsys.readouterr().err
    assert cli(["tune", "--loop", "lateral_x", "--T-prop", "0.05", "--T1", "0.5", "--tau", "0.1"]) == 2


def test_gain_scale_sets_loop_gain_at_omega():
    c1, c3 = rule_constants(-0.6, 25.0)
    assert rule_constants(-0.6, 25.0, 0.6) == pytest.approx((0.6 * c1, c3))
    p = LumpedParams("altitude", 2.0, 0.1, 0.8, 0.02)
    g = TuningRule(-0.6, 25.0, 0.6).gains(p)
    L = (g.kp + 1j * g.omega * g.kd) * freq_response(p, np.array([g.omega]))[0]
    assert abs(L) == pytest.approx(0.6, rel=1e-9)
    assert math.degrees(np.angle(L)) == pytest.approx(-180 + 25.0, abs=1e-6)
    assert g.gain_scale == 0.6 and g.c1 == pytest.approx(0.6 * c1)
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(UserError, match="gain scale"):
            rule_constants(-0.6, 25.0, bad)


def _lateral_case(a):
    from uavsim.tuning.grid import attitude_of, load_grid
    from uavsim.tuning.lateral_grid import _sample
    from uavsim.tuning.table import load_table

    return attitude_of(load_grid("attitude"), a, load_table("attitude")), _sample(np.random.default_rng(3), 8)


def test_lateral_beta_is_the_lowest_np_mrft_allows():
    """A slow attitude class keeps the inner loops' beta; a fast one's lateral cycles (0.2 s) need a
    higher beta for tau_obs = 0.03 s, and the next lower candidate would not allow it."""
    from uavsim.tuning.lateral_grid import TAU_OBS, _df_omega, beta_min, choose_beta

    att, X = _lateral_case(0)
    assert choose_beta(att, X)["beta"] == -0.73
    att, X = _lateral_case(47)
    ch = choose_beta(att, X)
    assert ch["feasible"] and -0.5 < ch["beta"] < -0.1
    T0 = 2 * np.pi / _df_omega(X, att, ch["beta"])
    assert ch["beta"] >= beta_min(TAU_OBS, T0.min()) - 1e-12
    T0_lower = 2 * np.pi / _df_omega(X, att, ch["beta"] - 0.05)
    assert ch["beta"] - 0.05 < beta_min(TAU_OBS, T0_lower.min())


def test_lateral_rule_choice_at_the_control_rate():
    """The chosen (pm, gain_scale) holds the sample at 200 Hz; the classic rule (scale 1) at that beta
    does not, and no choice beats the sample's own optima."""
    from uavsim.tuning.lateral_grid import _params, choose_rule
    from uavsim.tuning.optimal import optimal_gains
    from uavsim.tuning.sensitivity import controller_ise

    att, X = _lateral_case(47)
    beta = -0.18
    o = optimal_gains("lateral", 200.0, rule=TuningRule(beta, 20.0), **_params(X, att))
    ch = choose_rule(att, X, o.ise, beta, 200.0)
    assert ch["stable_fraction"] == 1.0 and ch["gain_scale"] < 1.0 and 1.0 <= ch["median_J"] <= ch["worst_J"] < 5.0
    g = TuningRule(beta, 20.0).gains_batch("lateral", **_params(X, att))
    q = controller_ise("lateral", 200.0, _params(X, att), g["kp"], g["kd"], g["N"])
    assert not np.all(np.isfinite(q))
