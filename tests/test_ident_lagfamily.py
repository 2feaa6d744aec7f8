"""The lag family both relay points allow, and the guard factor it asks for (``uavsim.ident.lagfamily``).

Exact 200 Hz relay cycles of grid classes (``uavsim.lumped.simulate``, an independent simulator
of the lumped loop) at the grid's ``beta`` and at ``SECOND_BETA``, as ``test_ident_twopoint``
makes them: the true lags are in the family with their gain and delay recovered and among its
heaviest members, and the family keeps the table's PD of the true class while it backs an
aggressive PD off.
"""

import numpy as np
import pytest
from test_ident_twopoint import _two_runs


@pytest.mark.parametrize("family", ["altitude", "attitude"])
def test_the_true_lags_fit_both_points_and_weigh_among_the_most(family):
    from uavsim.ident.lagfamily import lag_members, lag_weights

    g, b, cs, truth, (first, second) = _two_runs(family, 5)
    for j, c in enumerate(cs):
        m = lag_members(b, [first[j], second[j]])
        own = np.flatnonzero(np.isclose(m["T_prop"], b.classes["T_prop"][c])
                             & np.isclose(m["T1"], b.classes["T1"][c]))
        assert own.size >= 1
        k = own[np.argmin(m["chi2"][own])]
        assert m["chi2"][k] < 1.5
        assert m["K"][k] == pytest.approx(truth["K"][j], rel=0.03)
        assert abs(m["tau"][k] - truth["tau"][j]) < 5e-3  # within one 200 Hz sample
        assert np.all((m["tau"] >= 0) & (m["tau"] <= 0.06))
        # a flat belief: the weight is the points' alone; the true lags are among the five heaviest, and
        # what outweighs them fits both points as well (the box's neighbours of the true lags)
        w = lag_weights(b, np.full(g.n, 1.0 / g.n), m)
        assert w.sum() == pytest.approx(1.0)
        above = w > w[k]
        assert int(above.sum()) <= 4
        assert np.all(m["chi2"][above] < 1.5)


def test_the_family_keeps_the_true_class_table_pd_and_backs_an_aggressive_one_off():
    from uavsim.ident.gains import table_gains
    from uavsim.ident.guard import GUARD_SCALES
    from uavsim.ident.lagfamily import lag_family_scale

    g, b, cs, truth, (first, second) = _two_runs("altitude", 7)
    for j, c in enumerate(cs):
        p = np.full(g.n, 0.2 / (g.n - 1))
        p[c] = 0.8
        t = table_gains(b, [c], [truth["K"][j]])
        kw = {"derivative_filter_hz": float(t["derivative_filter_hz"][0]), "scales": GUARD_SCALES}
        kept = lag_family_scale(b, p, first[j], second[j], kp=float(t["kp"][0]), kd=float(t["kd"][0]), **kw)
        assert kept["scale"] >= 0.94  # the optimum of the true lags, robust to a class's miss
        assert 0 < kept["members"] <= 20 and np.isfinite(kept["expected_log_ratio"])
        hot = lag_family_scale(b, p, first[j], second[j], kp=2.5 * float(t["kp"][0]), kd=2.5 * float(t["kd"][0]),
                               **kw)
        assert hot["scale"] < 0.6 and hot["scale"] in GUARD_SCALES


def test_a_pd_of_the_wrong_shape_is_held_nowhere_and_refused_where_the_loop_says():
    from uavsim.ident.gains import table_gains
    from uavsim.ident.guard import GUARD_SCALES
    from uavsim.ident.lagfamily import UNHELD_REFUSAL, lag_family_scale, unheld_refusal

    g, b, cs, truth, (first, second) = _two_runs("attitude", 4)
    for j, c in enumerate(cs):
        p = np.full(g.n, 1.0 / g.n)
        t = table_gains(b, [c], [truth["K"][j]])
        kw = {"derivative_filter_hz": float(t["derivative_filter_hz"][0]), "scales": GUARD_SCALES}
        kept = lag_family_scale(b, p, first[j], second[j], kp=float(t["kp"][0]), kd=float(t["kd"][0]), **kw)
        assert kept["held_nowhere"] == 0.0
        assert unheld_refusal("attitude", kept, cls=c) is None
        # four times the gain with a tenth of the derivative: half of it is still unstable on these lags
        wrong = lag_family_scale(b, p, first[j], second[j], kp=4.0 * float(t["kp"][0]),
                                 kd=0.1 * float(t["kd"][0]), **kw)
        assert wrong["held_nowhere"] >= UNHELD_REFUSAL["attitude"]
        why = unheld_refusal("attitude", wrong, cls=c, first_spread=1.5)
        assert why is not None and f"class {c}'s PD" in why and "1.5 times" in why
        assert unheld_refusal("altitude", wrong) is None  # a loop not named never refuses so
