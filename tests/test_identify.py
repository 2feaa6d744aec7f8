"""Identification of sessions: class, gain recovery, the table's gains, JSON, --write-model and clear refusals.

The network is a tiny one trained here on three far-apart altitude classes simulated with the
exact lumped model (``uavsim.lumped.simulate``); the session is a MuJoCo NP-MRFT episode of one
of them with K = 3 and h = 0.5, so the test also checks that the two simulators, the
preprocessing of sessions and of training data, and the gain recovery agree.
"""

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from _learning_fixtures import CLASSES, ClassNetwork, three_model  # noqa: F401 (fixture)

from uavsim.errors import NoOscillation, UserError
from uavsim.formats.session import read_session, write_session
from uavsim.ident.session import identify_session, write_model

ROOT = Path(__file__).resolve().parents[1]
TRUE = 1  # the session's process is CLASSES[TRUE]
K_TRUE, H = 3.0, 0.5


def _mujoco_session(grid, c: int, seconds: float = 8.0, K: float = K_TRUE, h: float = H, bias: float = 0.1):
    from uavsim.control.relay import NPMRFT
    from uavsim.sim.runner import LoopBatch
    from uavsim.sim.sessions import relay_session

    p = replace(grid.params_of(c), K=K)
    lb = LoopBatch([p], dt=0.0005, rate_hz=200.0, seed=5)
    res = lb.run(NPMRFT(grid.beta, h, 0.01, 0.0, 200.0, 1, bias=bias), duration_s=seconds)
    return relay_session(res, 0, p, beta=grid.beta, h=h, rate_hz=200.0, tau_obs=0.01, a_n=0.0, bias=bias,
                         with_model=False)


@pytest.fixture(scope="module")
def setup(three_model):  # noqa: F811 (fixture from _learning_fixtures)
    tmp, model, grid = three_model
    sess = write_session(_mujoco_session(grid, CLASSES[TRUE]), tmp / "session")
    return {"tmp": tmp, "grid": grid, "model": model, "session": sess}


def test_identifies_class_gain_and_table_gains(setup):
    from uavsim.tuning.table import load_table

    g = setup["grid"]
    ans = identify_session(setup["session"], models=setup["model"])
    c = CLASSES[TRUE]
    assert ans["loop"] == "altitude" and ans["class"] == TRUE
    p = g.params_of(c)
    assert ans["params"]["T_prop"] == pytest.approx(p.T_prop) and ans["params"]["T1"] == pytest.approx(p.T1)
    assert ans["class_params"]["tau"] == pytest.approx(p.tau)
    # K and tau fitted to the fundamental response of the MuJoCo loop: bias, tau_obs and
    # sampling do not matter
    assert ans["params"]["K"] == pytest.approx(K_TRUE, rel=0.01)
    assert ans["params"]["tau"] == pytest.approx(p.tau, abs=5e-4)
    # the answer is the grid's table at 200 Hz: the class's robust PD over the identified K
    t = load_table("altitude")
    assert ans["gains_source"] == "table" and ans["table"]["rate_hz"] == 200.0
    assert ans["table"]["K_hat"] == pytest.approx(K_TRUE, rel=0.01)
    assert ans["gains"]["kp"] == pytest.approx(t.robust_kp[c] / K_TRUE, rel=0.01)
    assert ans["gains"]["kd"] == pytest.approx(t.robust_kd[c] / K_TRUE, rel=0.01)
    assert ans["gains"]["derivative_filter_hz"] == pytest.approx(t.derivative_filter_hz[c])
    assert ans["gains_table"] == ans["gains"] and "gains_optimum" not in ans and ans["off_grid"] is False
    assert ans["oscillation"]["period"] == pytest.approx(g.period[c], rel=0.05)
    # the class of least expected J over the bundle's cost matrix, which is the training set's J
    from uavsim.data.h5 import open_dataset
    from uavsim.ident.bundle import load_bundle

    b = load_bundle(setup["model"])
    assert np.array_equal(b.cost, open_dataset(setup["tmp"] / "three.h5").J) and 0 < b.temperature < 50
    d = ans["decision"]  # the inner loops' default: the grid's cost plus the fitted models' (blend)
    assert d["decision"] == "blend" and d["class_argmax"] == TRUE and 1.0 <= d["expected_J"] < 1.5
    bay = identify_session(setup["session"], models=setup["model"], decision="bayes")
    assert bay["class"] == TRUE and bay["decision"]["decision"] == "bayes"
    assert bay["decision"]["expected_J"] == pytest.approx(d["expected_J"])
    arg = identify_session(setup["session"], models=setup["model"], decision="argmax")
    assert arg["class"] == TRUE and arg["decision"]["decision"] == "argmax"
    with pytest.raises(UserError, match="decision"):
        identify_session(setup["session"], models=setup["model"], decision="vote")
    json.dumps(ans)


def test_optimum_of_the_fitted_model(setup):
    """``optimum="always"``: the fitted model's own optimum at the control rate, with its latency; the
    same as optimizing that model directly. ``auto`` on a cycle of a grid class keeps the table."""
    from uavsim.lumped.params import LumpedParams
    from uavsim.tuning.optimal import optimal_pd

    ans = identify_session(setup["session"], models=setup["model"], optimum="always")
    o = ans["gains_optimum"]
    assert ans["gains_source"] == "optimum" and ans["gains"] == {k: o[k] for k in ans["gains"]}
    assert 0 < o["latency_ms"] < 2000
    p = ans["params"]
    ref = optimal_pd(LumpedParams("altitude", p["K"], p["T_prop"], p["T1"], p["tau"]), 200.0).row(0)
    for k in ("kp", "kd", "derivative_filter_hz"):
        assert o[k] == pytest.approx(ref[k], rel=1e-3)
    # on the class's own process the table's robust answer is within a percent or two of it
    assert ans["gains_table"]["kp"] == pytest.approx(o["kp"], rel=0.15)
    auto = identify_session(setup["session"], models=setup["model"], optimum="auto")
    assert auto["gains_source"] == "table" and "gains_optimum" not in auto
    with pytest.raises(UserError, match="optimum must be one of"):
        identify_session(setup["session"], models=setup["model"], optimum="sometimes")


def test_write_model_round_trip(setup, tmp_path):
    import shutil

    dst = tmp_path / "s"
    shutil.copytree(setup["session"], dst)
    ans = identify_session(dst, models=setup["model"])
    write_model(dst, ans)
    s = read_session(dst)
    assert s.model is not None and s.model.K == pytest.approx(ans["params"]["K"]) and s.model.T1 == pytest.approx(
        ans["params"]["T1"])
    with pytest.raises(UserError, match="already has a \\[model\\]"):
        write_model(dst, ans)


def _variant(setup, tmp_path, name, fn):
    s = read_session(setup["session"])
    run = s.runs[0]
    fn(run)
    return write_session(s, tmp_path / name)


def test_refuses_too_short(setup, tmp_path):
    def cut(run):
        k = int(0.4 * 200)
        for a in ("t", "r", "y", "u"):
            setattr(run.data, a, getattr(run.data, a)[:k])

    with pytest.raises(UserError, match="cycles"):
        identify_session(_variant(setup, tmp_path, "short", cut), models=setup["model"])


def test_refuses_no_switching(setup, tmp_path):
    def flat(run):
        run.data.u = np.full_like(run.data.u, H + run.spec.bias)

    with pytest.raises(UserError, match="cycles|switching"):
        identify_session(_variant(setup, tmp_path, "flat", flat), models=setup["model"])


def test_refuses_saturated_output(setup, tmp_path):
    def clip(run):
        y = run.data.y
        mid = 0.5 * (y.max() + y.min())
        half = 0.5 * (y.max() - y.min())
        run.data.y = np.clip(y, mid - 0.3 * half, mid + 0.3 * half)

    with pytest.raises(UserError, match="saturated"):
        identify_session(_variant(setup, tmp_path, "sat", clip), models=setup["model"])


def test_refuses_other_beta(setup, tmp_path):
    def beta(run):
        run.spec.beta = -0.5

    with pytest.raises(UserError, match="beta"):
        identify_session(_variant(setup, tmp_path, "beta", beta), models=setup["model"])


def test_a_second_run_at_another_beta_weighs_the_belief(setup, tmp_path, monkeypatch):
    """A session with a second NP-MRFT run at beta -0.3 of the same process: identification with
    ``second_run`` answers the same class, says which run gave the second point and its frequency
    (the slower cycle), and refuses a missing run or one at the network's beta in one line."""
    from uavsim.control.relay import NPMRFT
    from uavsim.ident.twopoint import SECOND_BETA
    from uavsim.sim.runner import LoopBatch
    from uavsim.sim.sessions import relay_session

    g = setup["grid"]
    p = replace(g.params_of(CLASSES[TRUE]), K=K_TRUE)
    lb = LoopBatch([p], dt=0.0005, rate_hz=200.0, seed=6)
    res = lb.run(NPMRFT(SECOND_BETA, H, 0.01, 0.0, 200.0, 1, bias=0.1), duration_s=12.0)
    second = relay_session(res, 0, p, beta=SECOND_BETA, h=H, rate_hz=200.0, tau_obs=0.01, a_n=0.0, bias=0.1,
                           with_model=False, file="relay_b030.csv").runs[0]
    s = read_session(setup["session"])
    path = write_session(replace(s, runs=[*s.runs, second]), tmp_path / "two")
    one = identify_session(path, models=setup["model"], second_run=None)
    two = identify_session(path, models=setup["model"], second_run="relay_b030.csv")
    auto = identify_session(path, models=setup["model"])  # the default finds the run at SECOND_BETA
    assert "second_run" not in one and one["run"] == "relay.csv"
    assert two["class"] == one["class"] == TRUE
    sr = two["second_run"]
    assert sr["run"] == "relay_b030.csv" and sr["beta"] == SECOND_BETA and sr["n_cycles"] >= 1
    assert sr["omega"] < two["response"]["omega"]
    assert auto["second_run"] == sr and auto["gains"] == two["gains"]
    # an altitude guard backs off no further than the lag family of both points asks (uavsim.ident.lagfamily)
    gd = two["guard"]
    assert "lag_family" not in one["guard"] and gd["lag_family"]["members"] > 0
    assert gd["scale"] == max(gd["scale_one_point"], gd["lag_family"]["scale"])
    assert two["gains"]["kp"] == pytest.approx(gd["scale"] * two["gains_table"]["kp"])
    # a run found (not named) that holds no cycle leaves one point and says why; named, it is an error
    d = second.data
    short = replace(second, data=replace(d, t=d.t[:100], r=d.r[:100], y=d.y[:100], u=d.u[:100]))
    path_short = write_session(replace(s, runs=[*s.runs, short]), tmp_path / "short")
    skipped = identify_session(path_short, models=setup["model"])
    assert skipped["second_run"]["run"] == "relay_b030.csv" and skipped["second_run"]["skipped"]
    assert skipped["gains"] == one["gains"]
    with pytest.raises(UserError, match="second run relay_b030.csv"):
        identify_session(path_short, models=setup["model"], second_run="relay_b030.csv")
    with pytest.raises(UserError, match="no np-mrft/mrft run with file 'nope.csv'"):
        identify_session(path, models=setup["model"], second_run="nope.csv")
    with pytest.raises(UserError, match="another beta"):
        identify_session(path, models=setup["model"], second_run="relay.csv")
    # a loop whose lag family refuses a PD held nowhere: at a limit of 0 every answer is refused, in one line
    import uavsim.ident.lagfamily as lagfamily

    monkeypatch.setitem(lagfamily.UNHELD_REFUSAL, "altitude", 0.0)
    with pytest.raises(UserError, match=f"class {TRUE}'s PD is unstable at every back-off on 0 % of the models"):
        identify_session(path, models=setup["model"], second_run="relay_b030.csv")
    assert identify_session(path, models=setup["model"], second_run=None)["gains"] == one["gains"]


def test_a_trimmed_relay_run_is_read_by_its_states(setup, tmp_path):
    """A session whose relay trimmed its bias (``bias_trim = "duty"``): its recorded ``u`` moves at
    switches, identification reads it by the relay's states and answers the class and gain; the same
    run declared untrimmed is refused in one line (``u`` is not a relay of constant bias)."""
    from uavsim.control.relay import NPMRFT
    from uavsim.sim.runner import LoopBatch
    from uavsim.sim.sessions import relay_session

    g = setup["grid"]
    p = replace(g.params_of(CLASSES[TRUE]), K=K_TRUE)
    lb = LoopBatch([p], dt=0.0005, rate_hz=200.0, seed=5)
    res = lb.run(NPMRFT(g.beta, H, 0.01, 0.0, 200.0, 1, bias=0.3 * H, bias_trim="duty"), duration_s=8.0)
    s = relay_session(res, 0, p, beta=g.beta, h=H, rate_hz=200.0, tau_obs=0.01, a_n=0.0, bias=0.3 * H,
                      with_model=False)
    s.runs[0].spec.bias_trim = "duty"
    u = s.runs[0].data.u
    assert np.unique(np.round(u, 9)).size > 2  # the bias moved
    ans = identify_session(write_session(s, tmp_path / "trim"), models=setup["model"])
    assert ans["class"] == TRUE
    assert ans["params"]["K"] == pytest.approx(K_TRUE, rel=0.01)
    s.runs[0].spec.bias_trim = "off"
    with pytest.raises(NoOscillation, match="not a relay command"):
        identify_session(write_session(s, tmp_path / "off"), models=setup["model"])


def test_a_network_of_trimmed_runs_refuses_an_asymmetric_cycle(setup):
    """A network trained on bias-trimmed relay runs (``bias_trim`` in its bundle) has never seen a biased
    cycle: an untrimmed run at a bias of 0.35 h is refused in one line naming the duty and the cure, the same
    run trimmed is answered, and a network of untrimmed runs answers both (the export says which it is)."""
    from dataclasses import replace as dc_replace

    from uavsim.control.relay import NPMRFT, untrimmed
    from uavsim.ident.bundle import load_bundle
    from uavsim.ident.cycle import DUTY_LIMIT
    from uavsim.ident.session import identify_arrays
    from uavsim.sim.runner import LoopBatch

    g = setup["grid"]
    off = load_bundle(setup["model"])
    assert off.bias_trim == "off" and off.meta["identification"]["relay"] == {"bias_trim": "off"}
    duty = dc_replace(off, bias_trim="duty")
    p = replace(g.params_of(CLASSES[TRUE]), K=K_TRUE)
    b = 0.35 * H
    runs = {}
    for trim in ("off", "duty"):
        res = LoopBatch([p], dt=0.0005, rate_hz=200.0, seed=5).run(
            NPMRFT(g.beta, H, 0.01, 0.0, 200.0, 1, bias=b, bias_trim=trim), duration_s=8.0)
        u = res.u[0] if trim == "off" else untrimmed(res.u[0], H, b)
        runs[trim] = (res.y[0], u)
    kw = {"rate_hz": 200.0, "h": H, "bias": b, "beta": g.beta}
    with pytest.raises(NoOscillation, match=r"relay duty 0\.\d\d over the cycle .*bias_trim = \"duty\""):
        identify_arrays(*runs["off"], bundle=duty, **kw)
    assert 0.35 > DUTY_LIMIT
    assert identify_arrays(*runs["duty"], bundle=duty, **kw)["class"] == TRUE
    assert identify_arrays(*runs["off"], bundle=off, **kw)["class"] == TRUE


def test_missing_model_is_user_error(setup, tmp_path):
    with pytest.raises(UserError, match="no trained altitude network"):
        identify_session(setup["session"], models=tmp_path)


def test_a_broken_last_cycle_falls_back_to_the_steady_ones_before(setup, tmp_path):
    """Noise that breaks the run's last cycle (a chattering burst): the steady cycles before it are used,
    and the answer is that of the run cut before the burst."""
    s = read_session(setup["session"])
    run = s.runs[0]
    u = run.data.u
    pos = (u - run.spec.bias) > 0
    up = np.flatnonzero(pos[1:] & ~pos[:-1]) + 1
    cut = int(up[-2]) + 1  # just after the last-but-one rising edge

    def burst(r):
        r.data.u = r.data.u.copy()
        r.data.u[cut + 3 : cut + 40 : 2] = r.spec.bias - H  # the relay chatters
        r.data.u[cut + 4 : cut + 40 : 2] = r.spec.bias + H

    def before(r):
        for a in ("t", "r", "y", "u"):
            setattr(r.data, a, getattr(r.data, a)[:cut])

    a = identify_session(_variant(setup, tmp_path, "burst", burst), models=setup["model"])
    b = identify_session(_variant(setup, tmp_path, "before", before), models=setup["model"])
    assert a["oscillation"]["stop"] < cut and a["class"] == b["class"]
    assert a["gains"]["kp"] == pytest.approx(b["gains"]["kp"], rel=0.02)


def test_cli_json_and_errors(setup, tmp_path):
    cmd = [sys.executable, "-m", "uavsim.cli.main", "identify"]
    res = subprocess.run(cmd + [str(setup["session"]), "--models", str(setup["model"]), "--json"],
                         capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    ans = json.loads(res.stdout)
    assert set(ans) >= {"loop", "class", "params", "gains", "gains_source"} and ans["class"] == TRUE
    # the inner loops' default applies the guard (DEFAULT_GUARD); --no-guard answers the table's PD
    g = identify_session(setup["session"], models=setup["model"], guard=True)  # what --guard asks for
    s = g["guard"]["scale"]
    assert 0.5 <= s <= 1.0 and g["gains"]["kp"] == pytest.approx(s * ans["gains_table"]["kp"])
    assert ans["guard"]["scale"] == s and ans["gains"] == g["gains"]
    res = subprocess.run(cmd + [str(setup["session"]), "--models", str(setup["model"]), "--no-guard", "--json"],
                         capture_output=True, text=True, cwd=ROOT)
    plain = json.loads(res.stdout)
    assert res.returncode == 0 and "guard" not in plain and plain["gains"] == plain["gains_table"]

    def cut(run):
        for a in ("t", "r", "y", "u"):
            setattr(run.data, a, getattr(run.data, a)[:60])

    bad = _variant(setup, tmp_path, "short", cut)
    res = subprocess.run(cmd + [str(bad), "--models", str(setup["model"]), "--json"], capture_output=True,
                         text=True, cwd=ROOT)
    assert res.returncode == 2 and res.stdout == "" and "Traceback" not in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


def _grid_bundle(family: str, L: int):
    from uavsim.data.generate import class_table_gains
    from uavsim.ident.bundle import ModelBundle
    from uavsim.tuning.grid import load_grid

    g = load_grid(family)
    classes = {k: np.asarray(g.params[k], float) for k in ("T_prop", "T1", "tau")}
    classes["period"] = np.asarray(g.period, float)
    classes.update({k: v for k, v in class_table_gains(family, 200.0, None).items() if k != "J"})
    # sure of its class, as lateral_grid_bundle's stand-in is: with logit 1 the other classes held most of the
    # belief between them, and a rule that takes some out of it would hand the rest to the guard
    net = ClassNetwork(g.n, logit=8.0)
    net.input_length = L
    return g, ModelBundle(dir=Path("grid"), loop=family, rate_hz=200.0, rule=g.rule, input_length=L, cycles=1,
                          input_rate_hz=200.0, classes=classes, predictor=net, meta={})


@pytest.mark.parametrize("family", ["altitude", "attitude"])
def test_exact_cycles_of_grid_classes_give_the_tables_gains(family):
    """Exact lumped relay cycles at 200 Hz (an independent simulator) of grid classes with random K:
    given the class, identification answers the table's robust PD over K within a percent."""
    from uavsim.data.preprocess import input_length
    from uavsim.ident.session import identify_arrays
    from uavsim.lumped.simulate import simulate_relay_batch

    rng = np.random.default_rng(7)
    g, b = _grid_bundle(family, 0)
    L = input_length(g)
    b.input_length = b.predictor.input_length = L
    cs = rng.choice(g.n, 6, replace=False)
    K = np.exp(rng.uniform(np.log(0.3), np.log(5.0), cs.size))
    n = int(8 * g.period[cs].max() * 200)
    sim = simulate_relay_batch(family, g.beta, 1.0, 0.005, n, K=K, **{k: b.classes[k][cs] for k in
                                                                      ("T_prop", "T1", "tau")})
    for j, c in enumerate(cs):
        b.predictor.cls = int(c)
        ans = identify_arrays(-sim["e"][j], sim["u"][j], rate_hz=200.0, h=1.0, bias=0.0, bundle=b, beta=g.beta)
        assert ans["class"] == c
        assert ans["params"]["K"] == pytest.approx(K[j], rel=0.01)
        assert ans["gains"]["kp"] == pytest.approx(b.classes["table_robust_kp"][c] / K[j], rel=0.01)
        assert ans["gains"]["kd"] == pytest.approx(b.classes["table_robust_kd"][c] / K[j], rel=0.01)


def test_response_fit_against_exact_simulation():
    """K and tau fitted to the fundamental response are exact whatever the relay does.

    An exact (ZOH) simulation of known processes under NP-MRFT at 200 Hz with relay bias,
    observation time and a_n, with and without noise: the true lags fitted to the response over
    the last cycles give K back within 1% and the delay's phase at the cycle within 0.005 rad
    without noise, within 4% and 0.03 rad with noise of 5% of the cycle amplitude. The rule at the
    measured point crosses over there with at least the rule's phase margin.
    """
    from uavsim.control.relay import NPMRFT
    from uavsim.data.preprocess import features
    from uavsim.ident.gains import measured_point_gains
    from uavsim.ident.response import fit_response
    from uavsim.lumped.frequency import freq_response_batch, mrft_prediction_batch
    from uavsim.lumped.reference import LumpedDiscrete
    from uavsim.tuning.rule import TuningRule

    K = np.array([0.6, 1.8, 3.0, 1.0])
    T_prop, T1, tau = np.array([0.02, 0.1, 0.25, 0.05]), np.array([0.3, 1.2, 2.0, 0.6]), np.array([0.002, 0.02, 0.05, 0.01])
    h, bias = 0.5, np.array([0.0, 0.1, -0.15, 0.05])
    w0, a0 = mrft_prediction_batch("altitude", -0.73, h, K=K, T_prop=T_prop, T1=T1, tau=tau)
    tau_obs = 0.03 * 2 * np.pi / w0
    for noise_frac, tol, phase_tol in ((0.0, 0.01, 0.005), (0.05, 0.04, 0.03)):
        proc = LumpedDiscrete.inner(K, T_prop, T1, tau, 1.0 / 200.0)
        relay = NPMRFT(-0.73, h, tau_obs, 2 * noise_frac * a0, 200.0, 4, bias=bias)
        rng = np.random.default_rng(5)
        Y, U = np.empty((4, 2400)), np.empty((4, 2400))
        y = proc.reset()
        for k in range(2400):
            Y[:, k] = y + noise_frac * a0 * rng.standard_normal(4)
            U[:, k] = relay(-Y[:, k])
            y = proc.step(U[:, k])
        fs = [features(Y[i], U[i], 200.0, h, float(bias[i]), 1200) for i in range(4)]
        resp, rper = np.array([f.response for f in fs]), np.array([f.response_period for f in fs])
        model = fit_response(resp, rper, T_prop=T_prop, T1=T1, tau_class=tau)
        np.testing.assert_allclose(model["K"], K, rtol=tol)
        np.testing.assert_array_less(np.abs(model["tau"] - tau) * 2 * np.pi / rper, phase_tol)
        w = 2 * np.pi / rper
        mp = measured_point_gains(resp, rper, rule=TuningRule(-0.73, 20.0))
        L = (mp["kp"] + 1j * w * mp["kd"]) * freq_response_batch("altitude", w[:, None], K=K, T_prop=T_prop, T1=T1,
                                                                  tau=tau)[:, 0]
        np.testing.assert_allclose(np.abs(L), 1.0, rtol=tol)
        assert np.all(np.degrees(np.pi + np.angle(L)) >= 20.0 - 1.0)


def test_lateral_fit_recovers_gain_and_outer_delay():
    """The lateral fit against a frequency response built with python-control (delays as exact
    phase): with the class's T2 right, K and the outer delay come back exactly."""
    import control

    from uavsim.data.preprocess import held_response
    from uavsim.ident.response import fit_response_lateral
    from uavsim.tuning.grid import load_grid
    from uavsim.tuning.table import load_table

    sub = load_grid("lateral").lateral(5)
    att = dict(load_table("lateral").lateral(5).attitude)
    att.pop("rate_hz")  # the attitude PD continuous, as python-control's loop below
    i = 3
    T2, tau_out, K = float(sub.params["T2"][i]), float(sub.params["tau"][i]) * 1.3 + 0.004, 0.8
    w = np.array([0.9, 1.7, 2.6])
    s = control.tf("s")
    N = 2 * np.pi * att["att_filter_hz"]
    C = att["att_kp"] + att["att_kd"] * s / (1 + s / N)
    Ga = 1 / (s * (att["T_prop"] * s + 1) * (att["T1"] * s + 1))
    L = np.array([control.evalfr(C * Ga, 1j * x) for x in w]) * np.exp(-1j * w * att["tau_in"])
    G = K * (L / (1 + L)) * np.exp(-1j * w * tau_out) / np.array([control.evalfr(s * (T2 * s + 1), 1j * x) for x in w])
    fit = fit_response_lateral(held_response(G, w, 200.0), 2 * np.pi / w, T2=np.full(3, T2),
                               tau_class=np.full(3, float(sub.params["tau"][i])), attitude=att, rate_hz=200.0)
    np.testing.assert_allclose(fit["K"], K, rtol=1e-9)
    np.testing.assert_allclose(fit["tau"], tau_out, atol=1e-9)


def test_lateral_fit_over_the_attitude_pd_at_the_control_rate():
    """The attitude PD flown at 200 Hz (the table's, ``rate_hz`` in the attitude dict): the fit
    against the exact response of the lifted sampled loop (``lateral_response_sampled``, holds and
    both PDs' sampling included) recovers K and the outer delay; the continuous attitude loop's fit
    of the same response is off by several percent in K."""
    from uavsim.ident.response import fit_response_lateral
    from uavsim.lumped.lateral import lateral_response_sampled
    from uavsim.tuning.grid import load_grid
    from uavsim.tuning.table import load_table

    a = 40  # a fast attitude class: the sampled loop differs most
    sub = load_grid("lateral").lateral(a)
    att = load_table("lateral").lateral(a).attitude
    assert att["rate_hz"] == 200.0
    i = int(np.argmax(sub.omega))  # its fastest lateral cycle
    T2, tau_c = float(sub.params["T2"][i]), float(sub.params["tau"][i])
    K, tau_out = 0.8, 1.2 * tau_c + 0.003
    w = np.asarray(sub.omega[i]) * np.array([0.8, 1.0, 1.25])
    G = lateral_response_sampled(w, 200.0, K=K, T_prop=att["T_prop"], T1=att["T1"], tau=tau_out, T2=T2,
                                 tau_in=att["tau_in"], att_kp=att["att_kp"], att_kd=att["att_kd"],
                                 att_N=2 * np.pi * att["att_filter_hz"])[0]
    kw = {"T2": np.full(3, T2), "tau_class": np.full(3, tau_c), "rate_hz": 200.0}
    fit = fit_response_lateral(G, 2 * np.pi / w, attitude=att, **kw)
    np.testing.assert_allclose(fit["K"], K, rtol=1e-8)
    np.testing.assert_allclose(fit["tau"], tau_out, atol=1e-9)
    continuous = {k: v for k, v in att.items() if k != "rate_hz"}
    off = fit_response_lateral(G, 2 * np.pi / w, attitude=continuous, **kw)
    assert np.max(np.abs(off["K"] / K - 1)) > 0.02


def test_lateral_session_needs_attitude_class_and_network(tmp_path):
    from uavsim.control.relay import NPMRFT
    from uavsim.sim.runner import LoopBatch
    from uavsim.sim.sessions import relay_session
    from uavsim.tuning.grid import load_grid

    sub = load_grid("lateral").lateral(2)
    p = replace(sub.params_of(0), K=1.0, loop="lateral_y")
    res = LoopBatch([p], dt=0.001, rate_hz=200.0, seed=1).run(NPMRFT(sub.beta, 0.05, 0.01, 0.0, 200.0, 1), 4.0)
    sess = write_session(relay_session(res, 0, p, beta=sub.beta, h=0.05, rate_hz=200.0, tau_obs=0.01, a_n=0.0,
                                       with_model=False), tmp_path / "lat")
    with pytest.raises(UserError, match="--attitude-class"):
        identify_session(sess, models=tmp_path / "none")
    with pytest.raises(UserError, match="no trained lateral network under .*a02"):
        identify_session(sess, models=tmp_path / "none", attitude_class=2)


def test_cycles_no_class_can_produce_are_refused():
    """A relay switching on noise cycles at a fraction of the period: refused, not classified."""
    from uavsim.ident.bundle import PERIOD_RANGE, period_bounds
    from uavsim.ident.cycle import period_refusal

    bounds = period_bounds([0.5, 0.8, 1.2])
    assert bounds == pytest.approx((0.5 * PERIOD_RANGE[0], 1.2 * PERIOD_RANGE[1]))
    per = [0.5 * PERIOD_RANGE[0] * 0.99, 0.5 * PERIOD_RANGE[0], 1.0, 1.2 * PERIOD_RANGE[1], 1.2 * PERIOD_RANGE[1] * 1.01]
    assert [period_refusal(p, bounds) is None for p in per] == [False, True, True, True, False]
    assert period_refusal(0.2, (0.5, 1.2)).startswith("cycle period 0.2 s is outside what the grid's classes give")


def test_phase_lead_of_relay_cycles_and_early_switching():
    """A relay at beta puts an exact lumped loop at ``arg G = -pi + asin(beta)`` (sampled at 200 Hz:
    within a few degrees); a relay that switches much earlier (beta 0.6 where -0.73 was asked) leads
    by what asin says, and identification refuses it as switched by noise."""
    from uavsim.data.preprocess import features, held_response
    from uavsim.ident.cycle import PHASE_LEAD_MAX_DEG, phase_lead, phase_refusal
    from uavsim.lumped.simulate import simulate_relay_batch

    leads = {}
    for b in (-0.73, 0.6):
        r = simulate_relay_batch("altitude", b, 1.0, 0.005, 3000, K=np.full(2, 1.5), T_prop=np.array([0.05, 0.1]),
                                 T1=np.array([0.4, 1.2]), tau=np.array([0.01, 0.03]))
        for j in range(2):
            f = features(-r["e"][j], r["u"][j], 200.0, 1.0, 0.0, 3000)
            leads[(b, j)] = phase_lead(f.response, f.response_period, -0.73)
            why = phase_refusal(f.response, f.response_period, -0.73)
            assert (why is None) == (b == -0.73) and (why is None or "switched early" in why)
    want = np.degrees(np.arcsin(0.6) - np.arcsin(-0.73))  # 83.7 deg
    for j in range(2):
        assert abs(leads[(-0.73, j)]) < 6.0
        assert leads[(0.6, j)] == pytest.approx(want, abs=6.0)
    assert want > PHASE_LEAD_MAX_DEG
    # the analytic case: a response of known phase
    G = np.exp(1j * (-np.pi + np.arcsin(-0.73) + np.radians(40.0)))
    assert phase_lead(G * held_response(1.0, 2 * np.pi / 0.5, 200.0), 0.5, -0.73) == pytest.approx(40.0)
    assert phase_refusal(1j, 0.5, None) is None  # no beta: no check


def test_no_oscillation_is_a_user_error():
    assert issubclass(NoOscillation, UserError)


def _attitude_cycles(seed: int, periods: float = 8.0):
    """Exact 200 Hz relay cycles of 4 attitude grid classes with K log-uniform in 0.5-2, and their optima.

    The run lasts ``periods`` periods of the slowest class; a run from rest is a few cycles off its
    limit cycle, so where the 12 cycles the attitude point averages must all be past that start, 16.
    """
    from uavsim.data.preprocess import input_length
    from uavsim.lumped.simulate import simulate_relay_batch
    from uavsim.tuning.optimal import optimal_gains

    g, b = _grid_bundle("attitude", 0)
    b.input_length = b.predictor.input_length = input_length(g)
    rng = np.random.default_rng(seed)
    cs = rng.choice(g.n, 4, replace=False)
    K = np.exp(rng.uniform(np.log(0.5), np.log(2.0), cs.size))
    truth = {"K": K, **{k: b.classes[k][cs] for k in ("T_prop", "T1", "tau")}}
    sim = simulate_relay_batch("attitude", g.beta, 1.0, 0.005, int(periods * g.period[cs].max() * 200), **truth)
    return g, b, cs, truth, sim, optimal_gains("attitude", 200.0, rule=b.rule, **truth).ise


def test_fitted_decision_judges_candidates_on_the_measured_process():
    """Exact relay cycles of grid classes, a belief sure of the true class: the fitted decision
    answers the candidate of least ISE on the process fitted to the cycle, so its answer's J on the
    true process is no worse than the grid decision's (both exact sampled ISEs at 200 Hz). Unguarded:
    the guard's back-off of either answer is a later step, tested on its own below."""
    from dataclasses import replace as dc_replace

    from uavsim.data.generate import class_table_gains
    from uavsim.ident.evaluate import _score
    from uavsim.ident.session import identify_arrays

    g, b, cs, truth, sim, q_opt = _attitude_cycles(3, periods=16)
    b = dc_replace(b, cost=class_table_gains("attitude", 200.0, None)["J"], temperature=0.05)
    for j, c in enumerate(cs):
        b.predictor.cls = int(c)
        J = {}
        for dec in ("bayes", "fitted"):
            ans = identify_arrays(-sim["e"][j], sim["u"][j], rate_hz=200.0, h=1.0, bias=0.0, bundle=b,
                                  beta=g.beta, decision=dec, guard=False)
            assert ans["decision"]["decision"] == dec
            gn = ans["gains"]
            J[dec] = _score("attitude", 200.0, truth, q_opt, np.array([j]), gn["kp"], gn["kd"],
                            gn["derivative_filter_hz"])[0]
        assert np.isfinite(J["fitted"]) and J["fitted"] <= J["bayes"] * (1 + 1e-6) and J["fitted"] < 1.05


def test_guard_backs_off_only_a_pd_the_measured_process_cannot_hold():
    """Exact relay cycles of attitude grid classes (the true process is the class, K random): the
    table's robust PD holds 5 degrees more lag, so the guard leaves it (factor 1, identification's
    gains unchanged); the same PD 1.8 times too aggressive is backed off, and the guarded PD's J on
    the true process (exact sampled ISE at 200 Hz) is finite and below the unguarded one's."""
    from uavsim.ident.evaluate import _score
    from uavsim.ident.gains import table_gains
    from uavsim.ident.guard import guard_scale
    from uavsim.ident.session import identify_arrays

    g, b, cs, truth, sim, q_opt = _attitude_cycles(11)
    for j, c in enumerate(cs):
        b.predictor.cls = int(c)
        ans = identify_arrays(-sim["e"][j], sim["u"][j], rate_hz=200.0, h=1.0, bias=0.0, bundle=b, beta=g.beta,
                              guard=True)
        assert ans["guard"]["scale"] == 1.0 and ans["gains"] == ans["gains_table"] and ans["guard"]["latency_ms"] > 0
        resp, per = [ans["response"]["gain"] * np.exp(1j * np.radians(ans["response"]["phase_deg"]))], \
            [2 * np.pi / ans["response"]["omega"]]
        t = table_gains(b, [c], [ans["table"]["K_hat"]])
        hot = {"kp": 1.8 * t["kp"], "kd": 1.8 * t["kd"], "derivative_filter_hz": t["derivative_filter_hz"]}
        s = guard_scale(b, [c], resp, per, **hot)
        assert s.shape == (1,) and s[0] < 1.0
        J_hot, J_guarded = (_score("attitude", 200.0, truth, q_opt, np.array([j]), f * hot["kp"], f * hot["kd"],
                                   hot["derivative_filter_hz"])[0] for f in (1.0, s[0]))
        assert np.isfinite(J_guarded) and J_guarded < J_hot


def test_belief_guard_backs_off_a_pd_the_belief_s_other_classes_cannot_hold():
    """The answer is a wrong class (the belief also holds the true class at 0.3): a PD 1.6 times the
    true class's table PD (J 1.15 to unstable on the truth) is backed off by what the true class's fitted
    model with 7.5 degrees more lag holds, to a J within 7 % of the optimum; the table PD itself is backed
    off less. A belief under ``GUARD_BELIEF_MIN`` and a loop without a belief phase check nothing."""
    from dataclasses import replace as dc_replace

    from uavsim.ident.evaluate import _score
    from uavsim.ident.gains import fitted_model, table_gains
    from uavsim.ident.guard import GUARD_BELIEF_MIN, answer_guard, belief_guard_scale
    from uavsim.ident.session import identify_arrays

    g, b, cs, truth, sim, q_opt = _attitude_cycles(11)
    for j, c in enumerate(cs):
        b.predictor.cls = int(c)
        ans = identify_arrays(-sim["e"][j], sim["u"][j], rate_hz=200.0, h=1.0, bias=0.0, bundle=b, beta=g.beta,
                              guard=False)
        resp = ans["response"]["gain"] * np.exp(1j * np.radians(ans["response"]["phase_deg"]))
        per = 2 * np.pi / ans["response"]["omega"]
        other = int((c + 7) % g.n)
        p = np.zeros(g.n)
        p[other], p[c] = 0.7, 0.3
        t = table_gains(b, [c], fitted_model(b, [c], np.array([resp]), np.array([per]))["K"])
        hot = {k: float(1.6 * t[k][0]) for k in ("kp", "kd")}
        fhz = float(t["derivative_filter_hz"][0])
        s, top = belief_guard_scale(b, p, other, resp, per, derivative_filter_hz=fhz, **hot)
        assert top == [int(c)] and s < 1.0
        J_hot, J_guarded = (_score("attitude", 200.0, truth, q_opt, np.array([j]), f * hot["kp"], f * hot["kd"], fhz)[0]
                            for f in (1.0, s))
        assert J_hot > 1.1 and J_guarded < 1.07
        same = {k: float(t[k][0]) for k in ("kp", "kd")}
        assert belief_guard_scale(b, p, other, resp, per, derivative_filter_hz=fhz, **same)[0] > s
        gd = answer_guard(b, p, other, resp, per, derivative_filter_hz=fhz, **hot)
        assert gd["scale"] == min(gd["own_scale"], gd["belief_scale"]) and gd["belief_classes"] == [int(c)]
        p[other], p[c] = 1.0 - 0.5 * GUARD_BELIEF_MIN, 0.5 * GUARD_BELIEF_MIN
        assert belief_guard_scale(b, p, other, resp, per, derivative_filter_hz=fhz, **hot) == (1.0, [])
        assert belief_guard_scale(dc_replace(b, loop="lateral"), p, other, resp, per, derivative_filter_hz=fhz,
                                  **hot) == (1.0, [])


def test_the_gap_refits_starts_are_every_other_class_on_the_cycle(setup):
    """``uavsim.gap.iterate.class_starts``: the answer's cycle read back fits the answer's own class as
    identification did, and every other class of the network is a start with its own lags."""
    from uavsim.formats.session import read_session
    from uavsim.gap.iterate import class_starts, cycle_response, identify_base
    from uavsim.ident.bundle import load_bundle
    from uavsim.ident.gains import fitted_model

    model, ans = identify_base(read_session(setup["session"]), setup["model"])
    b = load_bundle(ans["model_dir"])
    resp, period = cycle_response(ans)
    own = fitted_model(b, [ans["class"]], [resp], [period])
    assert own["K"][0] == pytest.approx(ans["params"]["K"], rel=1e-9)
    assert own["tau"][0] == pytest.approx(ans["params"]["tau"], rel=1e-9, abs=1e-12)
    starts = class_starts(ans, model)
    others = [c for c in range(b.n_classes) if c != ans["class"]]
    assert len(starts) == len(others)
    for c, s in zip(others, starts, strict=True):
        assert (s.T_prop, s.T1) == pytest.approx((b.column("T_prop")[c], b.column("T1")[c]))
        assert s.K > 0 and s.tau >= 0 and s.noise_std == model.noise_std
    assert class_starts({k: v for k, v in ans.items() if k != "response"}, model) == []
