"""The actuator's limits of an identified base model, fitted on the steps (uavsim.gap.actuator)."""

import dataclasses
import math

import numpy as np
import pytest

from uavsim.formats.session import STEP_RUN, Run, RunData
from uavsim.gap.actuator import SLEW_SHARE, actuator_floors, fit_actuator
from uavsim.gap.features import run_features
from uavsim.gap.hidden import hidden_session
from uavsim.gap.simulate import Episode, simulate


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
