"""The relay cycle identification extracts: a run with no pair of equal-length cycles.

Exact 200 Hz relay cycles of attitude grid classes (``test_identify._attitude_cycles``) are
made uneven by stretching every other cycle in time (the last one kept): no two adjacent
cycles are within the preprocessing's steady tolerance, so the training preprocessing
(``uavsim.data.preprocess.features``) refuses the run; identification answers it at its own,
looser tolerance (``uavsim.ident.cycle.IDENT_STEADY_TOL``) with the response of the even run,
and still refuses cycles further apart than that. The mechanism is run on these attitude
cycles with attitude added to ``UNEVEN_CYCLE_LOOPS``; by default only the lateral loops take
uneven cycles, and an inner loop refuses them.
"""

import numpy as np
import pytest
from test_identify import _attitude_cycles

from uavsim.errors import NoOscillation


def _uneven(y: np.ndarray, u: np.ndarray, stretch: float) -> tuple[np.ndarray, np.ndarray]:
    """The run with every other cycle (counted back from the last, which is kept) ``stretch`` times longer."""
    pos = u > 0
    edges = np.flatnonzero(pos[1:] & ~pos[:-1]) + 1
    ys, us = [y[: edges[0]]], [u[: edges[0]]]
    for k, (i, j) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        if (len(edges) - 2 - k) % 2 == 1:
            m = int(round(stretch * (j - i)))
            t = np.arange(m) / stretch
            ys.append(np.interp(i + t, np.arange(i, j + 1), y[i : j + 1]))
            us.append(u[i + np.floor(t).astype(int)])
        else:
            ys.append(y[i:j])
            us.append(u[i:j])
    ys.append(y[edges[-1] :])
    us.append(u[edges[-1] :])
    return np.concatenate(ys), np.concatenate(us)


@pytest.fixture(scope="module")
def cycles():
    g, b, cs, truth, sim, q_opt = _attitude_cycles(4, periods=16)
    return g, b, cs, sim


@pytest.fixture
def uneven_loop(monkeypatch):
    import uavsim.ident.cycle as cy

    monkeypatch.setattr(cy, "UNEVEN_CYCLE_LOOPS", ("attitude",))


def test_uneven_cycles_are_identified_not_refused(cycles, uneven_loop):
    from uavsim.data.preprocess import features
    from uavsim.ident.cycle import extract_cycle

    g, b, cs, sim = cycles
    kw = {"rate_hz": 200.0, "h": 1.0, "bias": 0.0, "bundle": b, "beta": g.beta}
    for j in range(cs.size):
        y, u = -sim["e"][j], sim["u"][j]
        even = extract_cycle(y, u, **kw)
        yu, uu = _uneven(y, u, 1.4)  # adjacent cycles 29 % apart: between the two tolerances
        with pytest.raises(NoOscillation, match="no steady state"):
            features(yu, uu, 200.0, 1.0, 0.0, b.input_length)  # the training sets' preprocessing
        f = extract_cycle(yu, uu, **kw)
        assert f.period == pytest.approx(even.period, rel=0.02)
        assert abs(f.response) == pytest.approx(abs(even.response), rel=0.03)
        assert abs(np.degrees(np.angle(f.response / even.response))) < 3.0
        assert f.response_cycles > 1  # the spread is measured over the uneven cycles, not one


def test_without_the_identification_tolerance_the_uneven_run_is_refused(cycles, uneven_loop, monkeypatch):
    import uavsim.ident.cycle as cy
    from uavsim.data.preprocess import STEADY_TOL

    g, b, cs, sim = cycles
    yu, uu = _uneven(-sim["e"][0], sim["u"][0], 1.4)
    monkeypatch.setattr(cy, "IDENT_STEADY_TOL", STEADY_TOL)
    with pytest.raises(NoOscillation, match="no steady state"):
        cy.extract_cycle(yu, uu, rate_hz=200.0, h=1.0, bias=0.0, bundle=b, beta=g.beta)


def test_cycles_further_apart_than_the_identification_tolerance_are_refused(cycles, uneven_loop):
    from uavsim.ident.cycle import IDENT_STEADY_TOL, extract_cycle

    g, b, cs, sim = cycles
    stretch = 1.0 / (1.0 - IDENT_STEADY_TOL) + 0.1
    yu, uu = _uneven(-sim["e"][0], sim["u"][0], stretch)
    with pytest.raises(NoOscillation, match="no steady state"):
        extract_cycle(yu, uu, rate_hz=200.0, h=1.0, bias=0.0, bundle=b, beta=g.beta)


def test_only_the_lateral_loops_take_uneven_cycles(cycles):
    from uavsim.ident.cycle import UNEVEN_CYCLE_LOOPS, extract_cycle

    assert UNEVEN_CYCLE_LOOPS == ("lateral",)
    g, b, cs, sim = cycles
    yu, uu = _uneven(-sim["e"][0], sim["u"][0], 1.4)
    with pytest.raises(NoOscillation, match="no steady state"):
        extract_cycle(yu, uu, rate_hz=200.0, h=1.0, bias=0.0, bundle=b, beta=g.beta)  # an attitude network


@pytest.fixture(scope="module")
def long_run():
    """Exact 200 Hz relay runs of 16 periods of two attitude grid classes, and their exact responses."""
    from test_identify import _grid_bundle

    from uavsim.data.preprocess import input_length
    from uavsim.lumped.simulate import simulate_relay_batch

    g, b = _grid_bundle("attitude", 0)
    b.input_length = b.predictor.input_length = input_length(g)
    cs = np.array([3, 30])
    truth = {"K": np.ones(cs.size), **{k: b.classes[k][cs] for k in ("T_prop", "T1", "tau")}}
    sim = simulate_relay_batch("attitude", g.beta, 1.0, 0.005, int(16 * g.period[cs].max() * 200), **truth)
    return g, b, sim


def test_a_longer_run_measures_its_point_better(long_run):
    """The fundamental response over 12 steady cycles of a run with noise on its output: about
    the root of 3 times closer to the noise-free run's than over the default 4 (mean over 40
    noise draws; the switching is the noise-free run's, so only the measurement differs)."""
    from uavsim.data.preprocess import RESPONSE_CYCLES, features

    g, b, sim = long_run
    rng = np.random.default_rng(7)
    for j in range(2):
        y, u = -sim["e"][j], sim["u"][j]
        clean = {m: features(y, u, 200.0, 1.0, 0.0, b.input_length, response_cycles=m) for m in (RESPONSE_CYCLES, 12)}
        assert clean[12].response_cycles == 12 and clean[RESPONSE_CYCLES].response_cycles == RESPONSE_CYCLES
        # noise-free, the point does not depend on how many steady cycles measure it
        assert abs(clean[12].response / clean[RESPONSE_CYCLES].response - 1) < 1e-3
        amp = clean[12].amplitude
        err = {m: [] for m in (RESPONSE_CYCLES, 12)}
        for _ in range(40):
            yn = y + 0.2 * amp * rng.standard_normal(y.size)
            for m in err:
                err[m].append(abs(features(yn, u, 200.0, 1.0, 0.0, b.input_length, response_cycles=m).response
                                  / clean[m].response - 1))
        ratio = np.mean(err[RESPONSE_CYCLES]) / np.mean(err[12])
        assert 1.3 < ratio < 2.5, ratio


def test_identification_averages_the_point_over_the_loop_s_cycles(long_run, monkeypatch):
    """``extract_cycle`` takes the loop's ``IDENT_RESPONSE_CYCLES`` (the lateral and attitude loops': 12);
    a loop not named keeps ``RESPONSE_CYCLES``. Run here on the attitude cycles, named and not."""
    import uavsim.ident.cycle as cy
    from uavsim.data.preprocess import RESPONSE_CYCLES

    g, b, sim = long_run
    assert cy.IDENT_RESPONSE_CYCLES["lateral"] == cy.IDENT_RESPONSE_CYCLES["attitude"] == 12 > RESPONSE_CYCLES
    kw = {"rate_hz": 200.0, "h": 1.0, "bias": 0.0, "bundle": b, "beta": g.beta}
    y, u = -sim["e"][0], sim["u"][0]
    assert cy.extract_cycle(y, u, **kw).response_cycles == 12
    monkeypatch.setattr(cy, "IDENT_RESPONSE_CYCLES", {"lateral": 12})
    assert cy.extract_cycle(y, u, **kw).response_cycles == RESPONSE_CYCLES


def test_response_cycles_must_be_positive(long_run):
    from uavsim.data.preprocess import features
    from uavsim.errors import UserError

    g, b, sim = long_run
    with pytest.raises(UserError, match="response_cycles"):
        features(-sim["e"][0], sim["u"][0], 200.0, 1.0, 0.0, b.input_length, response_cycles=0)


def test_a_point_that_scatters_beyond_the_loop_s_limit_is_refused(cycles, uneven_loop, monkeypatch):
    """``scatter_refusal`` reads the phase's standard error off the cycles' spread (``point_sigmas``): a
    spread of 0.6 rad over 4 cycles is 17 degrees, under attitude's 20; over 1 cycle, beyond it; a loop
    without a limit never refuses. ``extract_cycle`` applies it: the uneven run's point (its phase
    spread over the stretched cycles is finite) is refused at a limit below its own standard error."""
    import math

    import uavsim.ident.cycle as cy
    from uavsim.ident.response import point_sigmas

    assert cy.POINT_PHASE_SE_LIMIT_DEG == {"attitude": 20.0}
    assert cy.scatter_refusal("attitude", (0.0, 0.6), 4) is None
    why = cy.scatter_refusal("attitude", (0.0, 0.6), 1)
    assert why is not None and "beyond 20" in why
    assert cy.scatter_refusal("altitude", (0.0, 3.0), 1) is None
    g, b, cs, sim = cycles
    kw = {"rate_hz": 200.0, "h": 1.0, "bias": 0.0, "bundle": b, "beta": g.beta}
    yu, uu = _uneven(-sim["e"][0], sim["u"][0], 1.4)
    f = cy.extract_cycle(yu, uu, **kw)
    se = math.degrees(point_sigmas((0.0, f.response_spread[1]), f.response_cycles)[1])
    assert se > 0.0
    monkeypatch.setattr(cy, "POINT_PHASE_SE_LIMIT_DEG", {"attitude": 0.5 * se})
    with pytest.raises(NoOscillation, match="scatters from cycle to cycle"):
        cy.extract_cycle(yu, uu, **kw)
    monkeypatch.setattr(cy, "POINT_PHASE_SE_LIMIT_DEG", {"attitude": 2.0 * se})
    assert cy.extract_cycle(yu, uu, **kw).response == f.response
