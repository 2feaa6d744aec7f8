"""Evaluation: gain recovery, the closed-loop ISE criterion against a time-domain reference, off-grid runs."""

from pathlib import Path

import numpy as np
import pytest
from _learning_fixtures import CLASSES, three_model  # noqa: F401 (fixture)

from uavsim.learning.evaluate import (
    closed_loop_deterioration,
    evaluate_heldout,
    evaluate_offgrid,
    pipeline_gains,
    random_processes,
    summarize_deterioration,
)
from uavsim.lumped.params import LumpedParams
from uavsim.lumped.simulate import simulate_pd_step_batch
from uavsim.tuning.grid import load_grid
from uavsim.tuning.rule import TuningRule

ROOT = Path(__file__).resolve().parents[1]


def test_pipeline_gains_recover_K_exactly_for_exact_amplitude():
    g = load_grid("altitude")
    table = {k: getattr(g, k) for k in ("kp", "kd", "derivative_filter_hz", "amplitude")}
    cls = np.array([3, 100, 200])
    K, h = np.array([0.7, 2.0, 5.0]), 0.4
    out = pipeline_gains(cls, K * h * g.amplitude[cls], h, table)
    np.testing.assert_allclose(out["K_hat"], K, rtol=1e-12)
    np.testing.assert_allclose(out["kp"], g.kp[cls] / K, rtol=1e-12)
    np.testing.assert_allclose(out["N"], 2 * np.pi * g.derivative_filter_hz[cls])


def test_closed_loop_criterion_against_time_domain_ise():
    """Rule gains give 0; 1.4x the gains give the ratio of time-simulated ISEs (independent path)."""
    g = load_grid("altitude")
    rule = TuningRule(g.beta, g.pm_deg)
    ps = [LumpedParams("altitude", 1.7, 0.08, 0.6, 0.02), LumpedParams("altitude", 0.6, 0.2, 1.5, 0.045)]
    gains = [rule.gains(p) for p in ps]
    kp = np.array([x.kp for x in gains])
    kd = np.array([x.kd for x in gains])
    N = np.array([x.N for x in gains])
    same = closed_loop_deterioration(ps, kp, kd, N, g.beta, g.pm_deg)
    np.testing.assert_allclose(same["deterioration"], 0.0, atol=1e-9)
    more = closed_loop_deterioration(ps, 1.4 * kp, 1.4 * kd, N, g.beta, g.pm_deg)
    # independent reference: sampled time simulation of the step (both gain sets in one batch)
    p = ps[0]
    period = 2 * np.pi / gains[0].omega
    dt = 2.5e-4
    n = int(40 * period / dt)
    e = simulate_pd_step_batch("altitude", np.array([kp[0], 1.4 * kp[0]]), np.array([kd[0], 1.4 * kd[0]]),
                               np.array([N[0], N[0]]), dt, n, K=np.full(2, p.K), T_prop=np.full(2, p.T_prop), T1=np.full(2, p.T1),
                               tau=np.full(2, p.tau))["e"]
    q = (e**2).sum(axis=1) * dt
    # time-domain ISE is sampled at its own step: ratios agree to about 1%
    assert 1 + more["deterioration"][0] == pytest.approx(q[1] / q[0], rel=0.02)
    assert more["deterioration"][1] > 0
    unstable = closed_loop_deterioration(ps[:1], 40 * kp[:1], 40 * kd[:1], N[:1], g.beta, g.pm_deg)
    assert not unstable["stable"][0] and np.isinf(unstable["deterioration"][0])
    s = summarize_deterioration(np.array([0.0, 0.1, np.inf]))
    assert s["unstable"] == 1 and s["median"] == pytest.approx(0.1)


def test_random_processes_are_in_the_box_and_seeded():
    a = random_processes("altitude", 50, seed=4)
    b = random_processes("altitude", 50, seed=4)
    assert a == b and all(p.in_range() for p in a)
    assert all(0.5 <= p.K <= 2.0 for p in a)


def test_heldout_and_offgrid_pipeline(three_model):  # noqa: F811 (fixture)
    tmp, model, _ = three_model
    assert evaluate_heldout(model, tmp / "three.h5")["top1"] > 0.9
    # four off-grid processes through MuJoCo and the whole pipeline (structure, seeds, counts)
    res = evaluate_offgrid(model, ROOT / "datasets" / "small.toml", n=4, seed=3)
    assert res["n"] == 4 and res["n_identified"] + res["n_rejected"] == 4 and res["seed"] == 3
    assert res["deterioration"]["n"] == res["n_identified"]
    assert len(CLASSES) == 3
