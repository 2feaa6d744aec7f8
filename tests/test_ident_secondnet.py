"""The second run's network (``uavsim.ident.secondnet``): found beside the first, checked, read, multiplied in.

The networks are the tiny three-class altitude network of ``_learning_fixtures`` and a copy of it
exported as if trained at beta -0.3, its last layer biased to one class: a second network that is
sure of a class the first is not. The session is a MuJoCo NP-MRFT pair of runs (beta -0.73 and -0.3)
of one class, as ``test_identify`` flies them.
"""

import json
import shutil
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from _learning_fixtures import CLASSES, three_model  # noqa: F401 (fixture)

from uavsim.errors import UserError
from uavsim.formats.session import write_session
from uavsim.ident.bundle import load_bundle
from uavsim.ident.family import unsteady_spread
from uavsim.ident.secondnet import (
    LOST_TEMPER,
    SECOND_NET_SUFFIX,
    UNSTEADY_SPREAD,
    UNSTEADY_TEMPER,
    SecondReading,
    first_weight,
    load_second_bundle,
    multiply_beliefs,
    second_model_dir,
)
from uavsim.ident.session import identify_session
from uavsim.learning.decision import softmax

TRUE, K_TRUE, H = 1, 3.0, 0.5


def _second_copy(model, dst, *, beta=-0.3, favour=None, period_factor=3.0, shift_tau=False):
    """``model`` exported again into ``dst`` as a network of relay runs at ``beta``: its classes' cycle periods
    times ``period_factor`` (a slower relay), its last bias raised on class ``favour``."""
    shutil.copytree(model, dst)
    meta = json.loads((dst / "meta.json").read_text())
    meta["beta"] = beta
    meta["identification"]["rule"]["beta"] = beta
    for k in ("period", "period_sim"):
        if k in meta["classes"]:
            meta["classes"][k] = [None if v is None else v * period_factor for v in meta["classes"][k]]
    if shift_tau:
        meta["classes"]["tau"] = [v * 1.5 for v in meta["classes"]["tau"]]
    (dst / "meta.json").write_text(json.dumps(meta))
    if favour is not None:
        w = dict(np.load(dst / "weights.npz"))
        last = f"b{int(w['n_layers']) - 1}"
        w[last] = w[last].copy()
        w[last][favour] += 1e4
        np.savez(dst / "weights.npz", **w)
    return dst


@pytest.fixture(scope="module")
def two_runs(three_model, tmp_path_factory):  # noqa: F811 (fixture from _learning_fixtures)
    from uavsim.control.relay import NPMRFT
    from uavsim.ident.twopoint import SECOND_BETA
    from uavsim.sim.runner import LoopBatch
    from uavsim.sim.sessions import relay_session

    tmp, model, grid = three_model
    out = tmp_path_factory.mktemp("secondnet")
    p = replace(grid.params_of(CLASSES[TRUE]), K=K_TRUE)
    runs = []
    for beta, seconds, seed, file in ((grid.beta, 8.0, 5, "relay.csv"), (SECOND_BETA, 12.0, 6, "relay_b030.csv")):
        res = LoopBatch([p], dt=0.0005, rate_hz=200.0, seed=seed).run(
            NPMRFT(beta, H, 0.01, 0.0, 200.0, 1, bias=0.1), duration_s=seconds)
        runs.append(relay_session(res, 0, p, beta=beta, h=H, rate_hz=200.0, tau_obs=0.01, a_n=0.0, bias=0.1,
                                  with_model=False, file=file))
    s = replace(runs[0], runs=[runs[0].runs[0], runs[1].runs[0]])
    session = write_session(s, out / "session")
    root = out / "root"
    root.mkdir()
    shutil.copytree(model, root / "altitude")
    wrong = 0 if TRUE != 0 else 2
    _second_copy(model, root / f"altitude{SECOND_NET_SUFFIX}", favour=wrong)
    return {"session": session, "root": root, "wrong": wrong, "model": model, "out": out}


def test_the_second_network_is_found_beside_the_first_and_read(two_runs):
    """The root's ``altitude-second`` reads the second run; its belief multiplies the first's (here it is
    sure of a wrong class, so the answer moves there); ``second_network=False`` and a root without it
    answer as before, and the answer says which network read the run."""
    root = two_runs["root"]
    assert second_model_dir(root / "altitude") == root / f"altitude{SECOND_NET_SUFFIX}"
    assert second_model_dir(two_runs["model"]) is None
    with_net = identify_session(two_runs["session"], models=root)
    without = identify_session(two_runs["session"], models=root, second_network=False)
    alone = identify_session(two_runs["session"], models=two_runs["model"])
    assert "second_network" not in without and "second_network" not in alone
    assert without["class"] == alone["class"] == TRUE and without["gains"] == alone["gains"]
    sn = with_net["second_network"]
    assert sn["model_dir"].endswith(f"altitude{SECOND_NET_SUFFIX}") and sn["beta"] == pytest.approx(-0.3)
    assert sn["class_argmax"] == two_runs["wrong"] and with_net["class"] == two_runs["wrong"]
    # a clean first run is steady: its network's belief is not tempered
    assert sn["first_weight"] == 1.0 and sn["first_unsteady"] < UNSTEADY_SPREAD
    # one run (no second point): the second network has nothing to read
    one = identify_session(two_runs["session"], models=root, second_run=None)
    assert "second_network" not in one and one["class"] == TRUE


def test_a_second_network_of_another_grid_or_the_same_beta_is_refused(two_runs):
    first = load_bundle(two_runs["model"])
    # a second run at another beta than the second network's: that network is not asked
    assert load_second_bundle(two_runs["root"] / "altitude", first, beta=-0.3) is not None
    assert load_second_bundle(two_runs["root"] / "altitude", first, beta=-0.5) is None
    other = _second_copy(two_runs["model"], two_runs["out"] / "grid" / "altitude-second", shift_tau=True)
    shutil.copytree(two_runs["model"], two_runs["out"] / "grid" / "altitude")
    with pytest.raises(UserError, match="not those of"):
        load_second_bundle(two_runs["out"] / "grid" / "altitude", first)
    assert other.is_dir()
    _second_copy(two_runs["model"], two_runs["out"] / "same" / "altitude-second", beta=first.rule.beta)
    shutil.copytree(two_runs["model"], two_runs["out"] / "same" / "altitude")
    with pytest.raises(UserError, match="first network's beta"):
        load_second_bundle(two_runs["out"] / "same" / "altitude", first)
    with pytest.raises(UserError, match="first network's beta"):
        identify_session(two_runs["session"], models=two_runs["out"] / "same")


def test_beliefs_multiply_and_an_unsteady_first_point_is_tempered():
    rng = np.random.default_rng(3)
    a1, a2 = rng.normal(size=(1, 5)) * 3, rng.normal(size=(1, 5)) * 2
    r = SecondReading(activations=a2, temperature=0.7, model_dir="x", beta=-0.3)
    out = multiply_beliefs(a1, 1.5, r)
    want = softmax(a1, 1.5) * softmax(a2, 0.7)
    assert np.allclose(softmax(out, 1.5), want / want.sum())
    # spreads in units of the family's limits, scaled to its four reference cycles
    steady = SimpleNamespace(response_spread=(0.01, np.radians(0.2)), response_cycles=4)
    loose = SimpleNamespace(response_spread=(0.9, np.radians(3.0)), response_cycles=4)
    phase = SimpleNamespace(response_spread=(0.01, np.radians(13.0)), response_cycles=4)
    assert unsteady_spread(steady) == pytest.approx(0.2 / 1.5)
    assert unsteady_spread(loose) == pytest.approx(9.0)
    assert first_weight(steady, steady) == 1.0
    assert first_weight(loose, steady) == first_weight(phase, steady) == UNSTEADY_TEMPER
    # the second run's cycle not steady either: nothing to prefer, no tempering
    assert first_weight(loose, loose) == 1.0
    # a first point that is no limit cycle of the relay: its network is ignored, where the second run is steady
    assert first_weight(steady, steady, lost=True) == first_weight(loose, steady, lost=True) == LOST_TEMPER
    assert first_weight(loose, loose, lost=True) == 1.0


def test_a_point_lagging_far_beyond_the_relays_phase_measured_no_phase():
    """A relay at ``beta`` puts the loop where ``arg G = -pi + asin(beta)``: a point lagging beyond that by more
    than ``PHASE_LAG_MAX_DEG`` is no limit cycle of the relay (``phase_lost``), and ``measured_no_phase`` says so
    for a point of steady cycles too."""
    import math

    from uavsim.data.preprocess import held_response
    from uavsim.ident.cycle import PHASE_LAG_MAX_DEG, phase_lead, phase_lost
    from uavsim.ident.guard import measured_no_phase

    beta, rate, period = -0.73, 200.0, 0.5
    w = 2 * math.pi / period
    hold = held_response(1.0, w, rate)

    def point(lag_deg: float) -> complex:  # a point lagging the relay's phase by lag_deg, hold included
        return 0.3 * np.exp(1j * (-math.pi + math.asin(beta) - math.radians(lag_deg))) * hold

    assert phase_lead(point(0.0), period, beta, rate) == pytest.approx(0.0, abs=1e-9)
    assert phase_lead(point(30.0), period, beta, rate) == pytest.approx(-30.0)
    assert not phase_lost(point(0.5 * PHASE_LAG_MAX_DEG), period, beta, rate)
    assert phase_lost(point(PHASE_LAG_MAX_DEG + 5.0), period, beta, rate)
    b = SimpleNamespace(rule=SimpleNamespace(beta=beta), input_rate_hz=rate)
    steady = dict(response_spread=(0.01, np.radians(0.2)), response_cycles=4, response_period=period)
    assert not measured_no_phase(b, SimpleNamespace(response=point(10.0), **steady))
    assert measured_no_phase(b, SimpleNamespace(response=point(120.0), **steady))


def test_evaluate_reads_the_second_run_with_its_network(two_runs):
    """``uavsim evaluate`` lets the second network read each process's second run as identification of a
    session does, and says so; ``second_network=False`` (``--no-second-network``) the point alone."""
    from pathlib import Path

    import uavsim.ident.evaluate as ev

    recipe = Path(__file__).resolve().parents[1] / "datasets" / "small.toml"
    spec = ev.EvalSpec(loop="altitude", n=3, seed=4)
    on = ev.evaluate(spec, models=two_runs["root"], recipe=recipe, log=lambda m: None)
    off = ev.evaluate(replace(spec, second_network=False), models=two_runs["root"], recipe=recipe,
                      log=lambda m: None)
    sr = on["second_run"]
    assert sr["network"].endswith(f"altitude{SECOND_NET_SUFFIX}") and 1 <= sr["network_read"] <= sr["two_points"]
    assert off["second_run"]["network"] is None and off["second_run"]["network_read"] == 0
    assert off["second_run"]["two_points"] == sr["two_points"]


def test_the_guard_closes_at_the_second_point_where_the_first_measured_no_phase(two_runs):
    """A first point whose cycles scatter beyond ``GUARD_SECOND_POINT_SPREAD`` times the family's limits measured
    no phase: the one-point guard is closed at the (steady) second run's point instead, and says so."""
    from uavsim.control.relay import relay_command
    from uavsim.formats.session import read_session
    from uavsim.ident.cycle import extract_cycle
    from uavsim.ident.guard import GUARD_SECOND_POINT_SPREAD, answer_guard
    from uavsim.ident.session import second_cycle

    s = read_session(two_runs["session"])
    b = load_bundle(two_runs["root"] / "altitude")
    r1, r2 = s.runs
    f1 = extract_cycle(r1.data.y, relay_command(r1.data.u, H, 0.1, r1.spec.bias_trim), rate_hz=200.0, h=H, bias=0.1,
                       bundle=b)
    f2 = second_cycle(r2.data.y, relay_command(r2.data.u, H, 0.1, r2.spec.bias_trim), rate_hz=200.0, h=H, bias=0.1,
                      cycles=b.cycles, loop="altitude")
    ans = identify_session(two_runs["session"], models=two_runs["model"])
    g, p, c = ans["gains_table"], np.full(b.n_classes, 1.0 / b.n_classes), ans["class"]
    kw = {"kp": g["kp"], "kd": g["kd"], "derivative_filter_hz": g["derivative_filter_hz"], "p_network": p}
    loose = replace(f1, response_spread=(0.1 * GUARD_SECOND_POINT_SPREAD * 1.2, 0.3), response_cycles=4)
    assert unsteady_spread(loose) >= GUARD_SECOND_POINT_SPREAD > unsteady_spread(f1)
    at_loose = answer_guard(b, p, c, f1.response, f1.response_period, first=loose, second=f2, **kw)
    steady = answer_guard(b, p, c, f1.response, f1.response_period, first=f1, second=f2, **kw)
    at_second = answer_guard(b, p, c, f2.response, f2.response_period, **kw)
    assert at_loose["one_point"] == "second" and steady["one_point"] == "first"
    assert (at_loose["own_scale"], at_loose["belief_scale"]) == (at_second["own_scale"], at_second["belief_scale"])
    # the point matters here: closed at the first point the same PD holds at another factor
    assert (steady["own_scale"], steady["belief_scale"]) != (at_second["own_scale"], at_second["belief_scale"])
