"""Refit of an identified base model on all the session's runs (uavsim.gap.refit)."""

import dataclasses

import pytest

from uavsim.formats.session import ModelSpec
from uavsim.gap import iterate
from uavsim.gap.hidden import hidden_session
from uavsim.gap.refit import PARAMS, refit_base


def _off(model: ModelSpec) -> ModelSpec:
    """What one relay cycle gets wrong: gain high, the lag split between T_prop and tau the wrong way."""
    return dataclasses.replace(model, K=1.5 * model.K, T_prop=0.6 * model.T_prop, tau=model.tau + 0.012)


@pytest.fixture(scope="module")
def clean():
    session, truth = hidden_session(12, effect="none", loop="pitch")
    assert truth.effect == "none"
    return session


def test_refit_recovers_gain_and_delay_of_an_off_model(clean):
    true = clean.model
    start = _off(true)
    fit = refit_base(clean, start, seed=3, nthread=1)
    assert fit.accepted and fit.gap_after < 0.6 * fit.gap_before
    m = fit.model
    # at the cycle (w T1 >> 1) the loop's gain is K / T1: 50% off at the start, within 15% after; the lag
    # (T_prop + tau) one cycle splits the wrong way moves towards the truth
    assert m.K / m.T1 == pytest.approx(true.K / true.T1, rel=0.15)
    assert abs(start.K / start.T1 / (true.K / true.T1) - 1) > 0.4
    lag = lambda p: p.T_prop + p.tau  # noqa: E731
    assert abs(lag(m) - lag(true)) < 0.75 * abs(lag(start) - lag(true))
    assert set(fit.moved) == set(PARAMS) and fit.moved["T_prop"] > 1.1
    assert m.noise_std == start.noise_std


def test_refit_keeps_the_true_model(clean):
    fit = refit_base(clean, clean.model, seed=4, nthread=1, iterations=3)
    m = fit.model
    assert m.K / m.T1 == pytest.approx(clean.model.K / clean.model.T1, rel=0.15)
    assert m.T_prop + m.tau == pytest.approx(clean.model.T_prop + clean.model.tau, rel=0.2)


def test_analyse_flies_the_refit_model_as_base(monkeypatch, clean):
    """The identified model goes through the refit before the search; the refit is logged and recorded."""
    start = _off(clean.model)
    ident = {"run": clean.runs[0].spec.file, "class": 3, "params": dataclasses.asdict(start),
             "class_params": {"tau": start.tau}, "oscillation": {"period": 0.5}, "refused_runs": []}  # fmt: skip
    monkeypatch.setattr(iterate, "identify_base", lambda s, m: (start, ident))
    seen = {}

    def fake_refit(session, model, **kw):
        seen["model"] = model
        return refit_base(session, model, iterations=4, **kw)

    monkeypatch.setattr(iterate, "refit_base", fake_refit)
    s = dataclasses.replace(clean, model=None)
    msgs = []
    flow = iterate.analyse(s, candidates=("gain",), max_effects=1, nthread=1, log=msgs.append)
    assert seen["model"] is start
    assert flow.identification["refit"]["accepted"] and flow.base is not start
    assert flow.base.K == pytest.approx(flow.identification["refit"]["model"]["K"])
    true = clean.model
    assert abs(flow.base.K / flow.base.T1 - true.K / true.T1) < abs(start.K / start.T1 - true.K / true.T1)
    assert any(m.startswith("refit on ") for m in msgs)
    assert "refit on all runs: gap " in iterate.format_flow(flow)
    off = iterate.analyse(s, candidates=("gain",), max_effects=1, nthread=1, refit=False)
    assert off.base is start


def test_absorbed_reads_the_refits_phase_at_the_cycle():
    cls = {"T_prop": 0.03, "T1": 0.5, "tau": 0.01}
    ident = {"params": {"tau": 0.01}, "class_params": cls, "oscillation": {"period": 0.4}}
    # the refit put a lag in T_prop, not in tau: identify's tau alone shows nothing
    lagged = {"accepted": True, "model": {**cls, "T_prop": 0.06}, "moved": {"K": 1.0, "T_prop": 2.0, "T1": 1.0,
                                                                           "tau": 1.0}}  # fmt: skip
    assert iterate.absorbed_by(ident) is None
    a = iterate.absorbed_by({**ident, "refit": lagged})
    assert a is not None and a["moved_s"] > iterate.ABSORB_REFIT_SHARE * 0.4 and a["refit"]["T_prop"] == 2.0
    # a refit that stays at the class's phase absorbed nothing, whatever identify's tau said
    same = {**lagged, "model": dict(cls)}
    assert iterate.absorbed_by({**ident, "params": {"tau": 0.05}, "refit": same}) is None
    # a refit that was not kept leaves identify's reading
    assert iterate.absorbed_by({**ident, "params": {"tau": 0.05}, "refit": {**lagged, "accepted": False}}) is not None


def test_refit_starts_from_the_screened_start_of_least_gap(clean):
    """The search begins from the screened start that flies the runs best (here the truth, against
    a gain twice too high and the off start), and the result is still judged against the model
    it was given."""
    true = clean.model
    far = _off(true)
    other = dataclasses.replace(true, K=2.0 * true.K)
    fit = refit_base(clean, far, seed=5, nthread=1, iterations=2, starts=[other, true])
    assert fit.screened == {"start": 1, "gap": pytest.approx(fit.screened["gap"]), "model_gap":
                            pytest.approx(fit.screened["model_gap"]), "n": 2}
    assert fit.screened["gap"] < 0.5 * fit.screened["model_gap"]
    assert fit.accepted and fit.start is far and fit.gap_after < 0.5 * fit.gap_before
    assert fit.model.T_prop + fit.model.tau == pytest.approx(true.T_prop + true.tau, rel=0.2)
    assert fit.moved["T_prop"] > 1.3 and fit.to_json()["screened"]["start"] == 1
    # without starts nothing is screened
    assert refit_base(clean, true, seed=5, nthread=1, iterations=1).screened is None


def test_analyse_screens_the_class_starts_only_when_asked(monkeypatch, clean):
    start = _off(clean.model)
    ident = {"run": clean.runs[0].spec.file, "class": 3, "params": dataclasses.asdict(start),
             "class_params": {"tau": start.tau}, "oscillation": {"period": 0.5}, "refused_runs": []}  # fmt: skip
    monkeypatch.setattr(iterate, "identify_base", lambda s, m: (start, ident))
    monkeypatch.setattr(iterate, "class_starts", lambda i, m: [clean.model])
    seen = []

    def fake_refit(session, model, **kw):
        seen.append(kw.get("starts"))
        return refit_base(session, model, **{**kw, "iterations": 1})

    monkeypatch.setattr(iterate, "refit_base", fake_refit)
    s = dataclasses.replace(clean, model=None)
    iterate.analyse(s, candidates=("gain",), max_effects=1, nthread=1)
    assert seen == [None]
    flow = iterate.analyse(s, candidates=("gain",), max_effects=1, nthread=1, screen=True)
    assert seen[-1] == [clean.model] and flow.identification["refit"]["screened"]["start"] == 0


def test_refit_starts_on_the_k_t1_ridge_where_it_flies_best(clean):
    """A start with K and T1 both halved has the truth's gain at the cycle; the ridge screen finds the
    factor the steps ask for, which a search of one batch from the start does not reach."""
    true = clean.model
    half = dataclasses.replace(true, K=0.5 * true.K, T1=0.5 * true.T1)
    on = refit_base(clean, half, seed=6, nthread=1, iterations=1, ridge=(0.5, 2.0))
    off = refit_base(clean, half, seed=6, nthread=1, iterations=1, ridge=())
    assert on.accepted and on.model.T1 == pytest.approx(true.T1, rel=0.25)
    assert abs(on.model.T1 / true.T1 - 1) < abs(off.model.T1 / true.T1 - 1)
    assert on.gap_after < off.gap_after
