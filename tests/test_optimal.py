"""The ISE-optimal PD at the control rate, and the grids' tables of it.

The tables' gains are checked against a direct optimization of the exact
sampled ISE (scipy Nelder-Mead from several starts) on classes of each grid,
and the optimizer's answers against the rule it starts from.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.optimize import minimize

from uavsim.cli import main as cli_main
from uavsim.errors import UserError
from uavsim.lumped.params import LumpedParams
from uavsim.lumped.sampled import lift, sampled_ise
from uavsim.tuning.grid import load_grid
from uavsim.tuning.optimal import FILTER_CAP_FRACTION, derivative_filter, optimal_gains, optimal_pd
from uavsim.tuning.table import load_table


def nelder_mead(proc, N, kp, kd) -> tuple[float, float, float]:
    """Best of Nelder-Mead runs on log ISE from the rule-like gains x {0.5, 1, 2} (and kd x 3)."""
    def f(z):
        q = sampled_ise(proc, math.exp(z[0]), math.exp(z[1]), N)[0]
        return math.log(q) if np.isfinite(q) else 50.0

    best = None
    for a, b in ((1.0, 1.0), (0.5, 0.5), (2.0, 1.0), (1.0, 3.0)):
        r = minimize(f, [math.log(a * kp), math.log(b * kd)], method="Nelder-Mead",
                     options={"xatol": 1e-9, "fatol": 1e-13, "maxiter": 3000})
        if best is None or r.fun < best.fun:
            best = r
    return math.exp(best.x[0]), math.exp(best.x[1]), math.exp(best.fun)


def _check(proc, N, kp_rule, kd_rule, kp, kd, ise):
    kp_nm, kd_nm, q_nm = nelder_mead(proc, N, 0.8 * kp_rule, 0.8 * kd_rule)
    assert ise <= q_nm * (1 + 1e-9), (ise, q_nm)
    assert kp == pytest.approx(kp_nm, rel=1e-4) and kd == pytest.approx(kd_nm, rel=1e-4)


@pytest.mark.parametrize("loop,classes", [("attitude", [0, 30, 47]), ("altitude", [5, 120, 207])])
def test_inner_table_gains_are_the_direct_optimum(loop, classes):
    g, t = load_grid(loop), load_table(loop)
    for i in classes:
        p = g.params_of(i)
        proc = lift(loop, t.rate_hz, K=1.0, T_prop=p.T_prop, T1=p.T1, tau=p.tau)
        _check(proc, t.N[i], g.kp[i], g.kd[i], t.kp[i], t.kd[i], t.ise[i])
        assert sampled_ise(proc, t.kp[i], t.kd[i], t.N[i])[0] == pytest.approx(t.ise[i], rel=1e-9)


def test_lateral_table_gains_are_the_direct_optimum():
    g, t = load_grid("lateral"), load_table("lateral")
    for a, i in ((3, 0), (40, 9)):
        st, sg = t.lateral(a), g.lateral(a)
        att = st.attitude
        proc = lift("lateral", t.rate_hz, K=1.0, T_prop=att["T_prop"], T1=att["T1"], tau=sg.params["tau"][i],
                    T2=sg.params["T2"][i], tau_in=att["tau_in"], att_kp=att["att_kp"], att_kd=att["att_kd"],
                    att_N=2 * np.pi * att["att_filter_hz"])
        _check(proc, st.N[i], st.kp[i], st.kd[i], st.kp[i], st.kd[i], st.ise[i])


def test_optimum_beats_the_rule_and_is_stable_everywhere():
    for loop in ("attitude", "altitude"):
        t = load_table(loop)
        assert np.all(np.isfinite(t.ise)) and np.all(t.kp > 0) and np.all(t.kd > 0)
        assert np.all(t.ise <= t.rule_ise * (1 + 1e-12))
    # the rule (a continuous-time design) is unstable at 200 Hz on the fastest classes: the optimum is not
    assert np.sum(~np.isfinite(load_table("altitude").rule_ise)) > 0
    lat = load_table("lateral")
    assert all(np.all(np.isfinite(s.ise)) for s in lat.sub)


def test_gains_scale_with_K_exactly():
    p = LumpedParams("altitude", 1.0, 0.12, 0.7, 0.023)
    g = optimal_pd(p).row(0)
    proc = lift("altitude", 200.0, K=4.0, T_prop=p.T_prop, T1=p.T1, tau=p.tau)
    q = sampled_ise(proc, g["kp"] / 4.0, g["kd"] / 4.0, 2 * np.pi * g["derivative_filter_hz"])[0]
    assert q == pytest.approx(g["ise"], rel=1e-10)
    g4 = optimal_pd(p.with_gain(4.0)).row(0)
    assert g4["kp"] == pytest.approx(g["kp"] / 4, rel=1e-5) and g4["kd"] == pytest.approx(g["kd"] / 4, rel=1e-5)


def test_filter_rule_and_cap():
    N = derivative_filter([5.0, 100.0], 200.0)
    assert N[0] == pytest.approx(50.0) and N[1] == pytest.approx(2 * np.pi * FILTER_CAP_FRACTION * 200.0)


def test_start_gains_do_not_change_the_answer():
    kw = {"K": 1.0, "T_prop": 0.08, "T1": 1.1, "tau": 0.041}
    a = optimal_gains("altitude", 200.0, **kw)
    b = optimal_gains("altitude", 200.0, start=(1.3 * a.kp, 0.7 * a.kd), **kw)
    c = optimal_gains("altitude", 200.0, start=(1e6, 1e6), **kw)  # unstable start: the scan takes over
    assert b.ise[0] == pytest.approx(a.ise[0], rel=1e-10) and c.ise[0] == pytest.approx(a.ise[0], rel=1e-10)


def test_other_rate():
    """At 50 Hz the optimum is a different, lower-gain PD, still better than the rule."""
    p = LumpedParams("roll", 1.0, 0.05, 0.4, 0.008)
    g200, g50 = optimal_pd(p, 200.0).row(0), optimal_pd(p, 50.0).row(0)
    assert g50["kp"] < g200["kp"] and g50["ise"] > g200["ise"]
    assert g50["ise"] <= g50["rule_ise"]


def test_unstabilizable_is_an_error():
    """A lateral loop over an attitude loop its PD does not hold: no outer PD stabilizes it."""
    p = LumpedParams("lateral_x", 1.0, 0.1, 0.4, 0.05, T2=1.5, tau_in=0.01, att_kp=5000.0, att_kd=10.0,
                     att_filter_hz=20.0)
    with pytest.raises(UserError, match="no stable PD"):
        optimal_pd(p)


@pytest.fixture
def cli(monkeypatch):
    monkeypatch.setattr(cli_main, "_COMMAND_MODULES", ["uavsim.cli.tune_cmd", "uavsim.cli.grid_cmd"])
    return cli_main.main


def test_tune_cli_optimal(cli, capsys):
    args = ["tune", "--loop", "altitude", "--T-prop", "0.3", "--T1", "0.2", "--tau", "0.0128"]
    assert cli([*args, "--optimal", "--rate", "200", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    g = optimal_pd(LumpedParams("altitude", 1.0, 0.3, 0.2, 0.0128)).row(0)
    assert out["optimal_kp"] == pytest.approx(g["kp"]) and out["rate_hz"] == 200.0
    assert out["rule_J"] >= 1.0 and out["kp"] > 0
    assert cli([*args, "--optimal"]) == 0
    assert "optimal at 200 Hz" in capsys.readouterr().out
    assert cli([*args, "--optimal", "--rate", "-1"]) == 2
    lat = ["tune", "--loop", "lateral_x", "--T-prop", "0.1", "--T1", "0.4", "--tau", "0.05", "--T2", "1.5",
           "--tau-in", "0.01", "--gain-scale", "0.6", "--optimal", "--json"]
    assert cli(lat) == 0
    out = json.loads(capsys.readouterr().out)
    att = optimal_pd(LumpedParams("roll", 1.0, 0.1, 0.4, 0.01)).row(0)
    assert out["attitude"]["att_kp"] == pytest.approx(att["kp"]) and out["optimal_kp"] > 0
