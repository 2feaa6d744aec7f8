"""The actuator's limits of an identified base model, fitted on the steps (uavsim.gap.actuator)."""

import dataclasses
import math

import numpy as np
import pytest

from uavsim.formats.session import STEP_RUN, ModelSpec, Run, RunData
from uavsim.gap.actuator import SLEW_SHARE, actuator_floors, fit_actuator
from uavsim.gap.features import run_features
from uavsim.gap.hidden import hidden_session
from uavsim.gap.simulate import Episode, SimRun, simulate


@pytest.fixture(scope="module")
def clean():
    session, truth = hidden_session(12, effect="none", loop="pitch")
    assert truth.effect == "none"
    return session


def _hmax(session) -> float:
    return max(abs(r.spec.h) for r in session.runs if r.spec.kind != STEP_RUN)


def _flown_with(session, limits: dict[str, float], seed: int = 5):
    """The session's runs flown again by its own model with ``limits`` on the command (the 'vehicle')."""
    sims = simulate(session, session.model, [Episode(i) for i in range(len(session.runs))], seed=seed, nthread=1,
                    base_effects=limits, dt=0.001)  # fmt: skip
    runs = [Run(r.spec, RunData(s.t, s.r, s.y, s.u)) for r, s in zip(session.runs, sims, strict=True)]
    return dataclasses.replace(session, runs=runs)


def test_floors_leave_the_relays_alone(clean):
    meas = [run_features(r.spec, r.data.t, r.data.y, r.data.u) for r in clean.runs]
    fl = actuator_floors(clean, meas)
    hmax = _hmax(clean)
    assert fl["saturation"] == pytest.approx(hmax)
    pmin = min(math.exp(f["period"]) for r, f in zip(clean.runs, meas, strict=True) if r.spec.kind != STEP_RUN)
    # the largest relay switch (2 h) within SLEW_SHARE of the shortest period
    assert fl["rate_limit"] == pytest.approx(2 * hmax / (SLEW_SHARE * pmin))
    relays = dataclasses.replace(clean, runs=[r for r in clean.runs if r.spec.kind != STEP_RUN])
    assert fit_actuator(relays, clean.model, nthread=1).limits == {}  # no step: nothing to fit on


def test_the_steps_kick_clipped_by_the_actuator_is_found_and_leaves_the_relay_alone(clean):
    """A vehicle whose actuator clips the step's derivative kick at 2 x the relay's largest command: the
    model without the limit overshoots the steps; the fitted limit takes that gap away, the relays unchanged."""
    hmax = _hmax(clean)
    step = next(r for r in clean.runs if r.spec.kind == STEP_RUN)
    assert np.abs(step.data.u).max() > 3 * hmax  # the kick reaches far beyond the relay's command
    vehicle = _flown_with(clean, {"saturation": 2.0 * hmax})
    fit = fit_actuator(vehicle, clean.model, seed=1, nthread=1)
    assert 1.4 * hmax <= fit.limits.get("saturation", math.inf) <= 3.3 * hmax
    assert fit.gap < 0.7 * fit.gap_none
    # the control: the same aircraft without the limit gets none
    assert fit_actuator(clean, clean.model, seed=1, nthread=1).limits == {}
    # the limit leaves the relay runs' simulation as it was (it is above every relay command), not the step's
    plans = [Episode(i) for i in range(len(vehicle.runs))]
    plain = simulate(vehicle, clean.model, plans, seed=9, nthread=1, dt=0.001)
    limited = simulate(vehicle, clean.model, plans, seed=9, nthread=1, dt=0.001,
                       base_effects={"saturation": fit.limits["saturation"]})  # fmt: skip
    for r, a, b in zip(vehicle.runs, plain, limited, strict=True):
        same = np.allclose(a.y, b.y)
        assert same == (r.spec.kind != STEP_RUN), r.spec.file


def test_analyse_fits_the_limits_before_and_after_the_refit_and_every_search_flies_them(monkeypatch):
    """The identified model gets the limits before the refit (the refit flies them), again on the refit
    model, and the searches fly the last ones; ``actuator=False`` leaves them out."""
    from uavsim.gap import iterate
    from uavsim.gap.actuator import ActuatorFit
    from uavsim.gap.refit import PARAMS, RefitResult
    from uavsim.gap.workflow import GapResult

    start = ModelSpec(K=1.0, T_prop=0.05, T1=0.4, tau=0.01, noise_std=0.0)
    refit = dataclasses.replace(start, K=1.2)
    ident = {"run": "r0.csv", "class": 3, "params": {"tau": 0.01}, "class_params": {"tau": 0.01},
             "oscillation": {"period": 0.5}, "refused_runs": []}  # fmt: skip
    monkeypatch.setattr(iterate, "identify_base", lambda s, m: (start, dict(ident)))
    seen = {"fit": [], "refit": [], "gap": []}

    def fake_fit(session, model, **kw):
        seen["fit"].append(model)
        return ActuatorFit(limits={"saturation": 3.0 if model is start else 4.0}, gap_none=2.0, gap=1.0)

    def fake_refit(session, model, actuator=None, **kw):
        seen["refit"].append(actuator)
        return RefitResult(model=refit, start=model, gap_before=2.0, gap_after=1.0, moved=dict.fromkeys(PARAMS, 1.0),
                           accepted=True, iterations=1, episodes=0, seconds=0.0)  # fmt: skip

    def fake_gap(session, model=None, seed=0, actuator=None, **kw):
        seen["gap"].append(actuator)
        sims = [SimRun(r.data.t, r.data.r, r.data.y, r.data.u, False) for r in session.runs]
        ranking = [{"effect": "none", "params": {}, "gap": 1.0, "score": 1.0}]
        return GapResult("none", {}, 1.0, 1.0, ranking, [], model, list(session.effects), seed, 0.1,
                         sims_before=sims, sims_after=sims)  # fmt: skip

    monkeypatch.setattr(iterate, "fit_actuator", fake_fit)
    monkeypatch.setattr(iterate, "refit_base", fake_refit)
    monkeypatch.setattr(iterate, "run_gap", fake_gap)
    session, _ = hidden_session(3, effect="none", loop="pitch")
    s = dataclasses.replace(session, model=None)
    flow = iterate.analyse(s)
    assert seen["fit"] == [start, refit] and seen["refit"] == [{"saturation": 3.0}]
    assert seen["gap"] == [{"saturation": 4.0}]
    assert flow.identification["actuator"]["limits"] == {"saturation": 4.0}
    assert "actuator limits (fitted on the steps): saturation 4" in iterate.format_flow(flow)
    seen = {"fit": [], "refit": [], "gap": []}
    iterate.analyse(s, actuator=False)
    assert seen["fit"] == [] and seen["refit"] == [{}] and seen["gap"] == [{}]
