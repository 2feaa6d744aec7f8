"""The belief kept to the classes the measured point allows (``uavsim.ident.consistent``).

Exact 200 Hz relay cycles (``uavsim.lumped.simulate``, an independent simulator of the lumped
loop) of attitude grid classes: the phase the true class's delay must supply is its own delay's,
``w tau`` (an analytic result); classes whose lags alone lag more than the point are taken out
of the belief, the others keep their relative belief.
"""

import math
from dataclasses import replace

import numpy as np
import pytest
from test_identify import _grid_bundle


def _cycles(family: str, seed: int, n: int = 4):
    from uavsim.data.preprocess import features, input_length
    from uavsim.lumped.simulate import simulate_relay_batch

    g, b = _grid_bundle(family, 0)
    rng = np.random.default_rng(seed)
    cs = rng.choice(g.n, n, replace=False)
    truth = {"K": np.exp(rng.uniform(np.log(0.5), np.log(2.0), n)),
             **{k: b.classes[k][cs] for k in ("T_prop", "T1", "tau")}}
    steps = int(10 * g.period[cs].max() * 200)
    sim = simulate_relay_batch(family, g.beta, 1.0, 0.005, steps, **truth)
    b.input_length = b.predictor.input_length = input_length(g)
    return g, b, cs, truth, [features(-sim["e"][j], sim["u"][j], 200.0, 1.0, 0.0, steps) for j in range(n)], sim


def test_the_true_class_needs_its_own_delay_and_is_allowed():
    from uavsim.ident.consistent import consistent_classes, delay_phase_deg

    g, b, cs, truth, fs, _ = _cycles("attitude", 3)
    excluded = 0
    for j, c in enumerate(cs):
        f = fs[j]
        d = delay_phase_deg(b, f.response, f.response_period)
        assert d.shape == (g.n,)
        w = 2 * math.pi / f.response_period
        assert abs(d[c] - math.degrees(w * truth["tau"][j])) < 1.0
        ok = consistent_classes(b, f)
        assert ok[c]
        # exact cycles: no spread, so the tolerance is the loop's floor
        assert np.array_equal(ok, d >= -5.0)
        excluded += int((~ok).sum())
    assert excluded > 0  # the point rules some classes out on these cycles


def test_excluded_classes_lose_their_belief_and_the_others_keep_their_ratios():
    from uavsim.ident.consistent import consistent_activations, consistent_classes
    from uavsim.learning.decision import softmax

    g, b, cs, _, fs, _ = _cycles("attitude", 4, n=2)
    f = fs[0]
    ok = consistent_classes(b, f)
    assert ok.any() and not ok.all()
    rng = np.random.default_rng(0)
    act = rng.normal(0.0, 1.0, (1, g.n))
    act[0, np.flatnonzero(~ok)[0]] = 20.0  # the network sure of a class the point rules out
    p0 = softmax(act, b.temperature)[0]
    p = softmax(consistent_activations(b, act, f)[0], b.temperature)[0]
    assert p[~ok].max() < 1e-15
    assert p[ok].sum() == pytest.approx(1.0)
    np.testing.assert_allclose(p[ok] / p[ok].sum(), p0[ok] / p0[ok].sum(), rtol=1e-9)


def test_the_tolerance_is_the_loops_floor_or_the_points_standard_error():
    from uavsim.ident.consistent import POINT_PHASE_TOL_DEG, phase_tolerance_deg

    floor = POINT_PHASE_TOL_DEG["attitude"]
    assert phase_tolerance_deg("attitude", 0.0, 4) == floor
    assert phase_tolerance_deg("attitude", math.radians(30.0), 4) == pytest.approx(15.0)
    assert phase_tolerance_deg("attitude", math.radians(30.0), 100) == floor
    assert phase_tolerance_deg("lateral", 1.0, 4) is None


def test_a_spread_point_allows_more_and_other_loops_keep_the_networks_belief(monkeypatch):
    from uavsim.ident.consistent import consistent_activations, consistent_classes

    g, b, _, _, fs, _ = _cycles("attitude", 3, n=1)
    f = fs[0]
    tight = consistent_classes(b, f)
    loose = consistent_classes(b, replace(f, response_spread=(0.1, math.radians(60.0)), response_cycles=4))
    assert loose.sum() > tight.sum() and np.all(loose[tight])
    # a point no class allows: the belief stays as it was
    import uavsim.ident.consistent as cons

    monkeypatch.setattr(cons, "consistent_classes", lambda bundle, f: np.zeros(g.n, bool))
    act = np.arange(g.n, dtype=float)[None, :]
    np.testing.assert_array_equal(cons.consistent_activations(b, act, f)[0], act)
    # altitude keeps the network's belief
    ga, ba, _, _, fa, _ = _cycles("altitude", 3, n=1)
    acta = np.arange(ga.n, dtype=float)[None, :]
    assert consistent_classes(ba, fa[0]) is None
    np.testing.assert_array_equal(consistent_activations(ba, acta, fa[0])[0], acta)


def test_identification_answers_no_class_the_point_rules_out_and_says_how_many():
    """End to end on an exact cycle: a network sure of a class the point rules out does not get it,
    and the answer's ``decision.ruled_out`` counts the classes taken out; sure of the true class, the
    true class is answered with the same count."""
    from uavsim.ident.consistent import consistent_classes
    from uavsim.ident.session import identify_arrays

    g, b, cs, _, fs, sim = _cycles("attitude", 4, n=2)
    for j, c in enumerate(cs):
        ok = consistent_classes(b, fs[j])
        assert ok[c] and not ok.all()
        kw = {"rate_hz": 200.0, "h": 1.0, "bias": 0.0, "bundle": b, "beta": g.beta}
        b.predictor.cls = int(np.flatnonzero(~ok)[0])
        ans = identify_arrays(-sim["e"][j], sim["u"][j], **kw)
        assert ok[ans["class"]] and ans["decision"]["ruled_out"] == int((~ok).sum())
        b.predictor.cls = int(c)
        ans = identify_arrays(-sim["e"][j], sim["u"][j], **kw)
        assert ans["class"] == c and ans["decision"]["ruled_out"] == int((~ok).sum())
