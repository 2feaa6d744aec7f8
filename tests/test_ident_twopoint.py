"""A second relay run's measured point weighs the belief (``uavsim.ident.twopoint``).

Exact 200 Hz relay cycles (``uavsim.lumped.simulate``, an independent simulator of the lumped
loop) of attitude and altitude grid classes at the grid's ``beta`` and at ``SECOND_BETA``: each
true class fits both points (its gain and delay recovered), while the classes that fit the first
point alone as well (every class does, with its own gain and delay) mostly do not fit both.
"""

import numpy as np
import pytest
from test_identify import _grid_bundle


def _two_runs(family: str, seed: int, n: int = 4):
    from uavsim.data.preprocess import features, input_length
    from uavsim.ident.twopoint import SECOND_BETA
    from uavsim.lumped.simulate import simulate_relay_batch

    g, b = _grid_bundle(family, 0)
    b.input_length = b.predictor.input_length = input_length(g)
    rng = np.random.default_rng(seed)
    cs = rng.choice(g.n, n, replace=False)
    K = np.exp(rng.uniform(np.log(0.5), np.log(2.0), cs.size))
    truth = {"K": K, **{k: b.classes[k][cs] for k in ("T_prop", "T1", "tau")}}
    steps = int(10 * g.period[cs].max() * 200)
    runs = []
    for beta in (g.beta, SECOND_BETA):
        sim = simulate_relay_batch(family, beta, 1.0, 0.005, steps, **truth)
        runs.append([features(-sim["e"][j], sim["u"][j], 200.0, 1.0, 0.0, steps) for j in range(n)])
    return g, b, cs, truth, runs


@pytest.mark.parametrize("family", ["attitude", "altitude"])
def test_the_true_class_fits_both_points_and_the_second_point_rejects_others(family):
    from uavsim.ident.twopoint import two_point_fit

    g, b, cs, truth, (first, second) = _two_runs(family, 5)
    fits_one = rejected = 0
    for j, c in enumerate(cs):
        fit = two_point_fit(b, np.arange(g.n), [first[j], second[j]])
        assert fit["chi2"][c] < 1.5
        assert abs(fit["K"][c] / truth["K"][j] - 1) < 0.03
        assert abs(fit["tau"][c] - truth["tau"][j]) < 5e-3  # within one 200 Hz sample
        # the first point alone: every class that needs no negative delay fits it exactly
        one = two_point_fit(b, np.arange(g.n), [first[j]])
        ok = one["chi2"] < 1e-9
        assert ok[c]
        fits_one += int(ok.sum())
        rejected += int(np.sum(fit["chi2"][ok] > 9.0))
    # of those, the second point rejects a share at 3 sigma (exact cycles: 35-44 % on these seeds)
    assert rejected >= 0.25 * fits_one


def test_a_flat_belief_weighed_by_both_points_ranks_the_true_class_near_the_top():
    from uavsim.ident.twopoint import two_point_activations
    from uavsim.learning.decision import softmax

    g, b, cs, truth, (first, second) = _two_runs("attitude", 6)
    for j, c in enumerate(cs):
        act = two_point_activations(b, np.zeros((1, g.n)), first[j], second[j])
        p = softmax(act, b.temperature)[0]
        assert np.isclose(p.sum(), 1.0)
        assert int(np.sum(p > p[c])) <= g.n // 8  # near-equal fits of neighbouring classes above it


def test_the_second_run_found_in_a_session_is_the_first_other_relay_run_at_second_beta():
    from types import SimpleNamespace as NS

    from uavsim.ident.twopoint import SECOND_BETA, auto_second_run

    def run(file, kind="np-mrft", beta=-0.73):
        return NS(spec=NS(file=file, kind=kind, beta=beta))

    runs = [run("a.csv"), run("step.csv", kind="step", beta=None), run("b.csv", beta=SECOND_BETA),
            run("c.csv", beta=SECOND_BETA)]
    assert auto_second_run(runs, "a.csv", "altitude", -0.73) == "b.csv"
    assert auto_second_run(runs, "b.csv", "attitude", -0.73) == "c.csv"  # never the first run itself
    assert auto_second_run(runs, "a.csv", "lateral", -0.73) == "b.csv"
    assert auto_second_run(runs, "a.csv", "roll", -0.73) is None  # not a loop family
    assert auto_second_run(runs[:2], "a.csv", "altitude", -0.73) is None
    assert auto_second_run([run("s.csv", kind="step", beta=SECOND_BETA), *runs[:1]], "a.csv", "altitude",
                           -0.73) is None
    assert auto_second_run(runs, "a.csv", "altitude", SECOND_BETA) is None  # a network trained at SECOND_BETA
