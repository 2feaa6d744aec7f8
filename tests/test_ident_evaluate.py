"""``uavsim evaluate``: the figure's semantics (refusals fail, J against the optimum) and a small run."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _learning_fixtures import three_model  # noqa: F401 (fixture)

from uavsim.ident.evaluate import LEVELS, draw_processes, noise_plan, summarize

ROOT = Path(__file__).resolve().parents[1]


def test_summary_counts_refusals_and_instability_as_failures():
    J = np.array([1.0, 1.01, 1.02, 1.05, np.inf, 1.2])
    refused = np.array([False, False, False, False, False, True])
    s = summarize(J, refused)
    assert s == {"n": 6, "refused": 1, "unstable": 1, "median": pytest.approx(1.035), "p95": float("inf"),
                 "max": pytest.approx(1.05)}
    s = summarize(np.array([1.0, 1.1, 1.2, 1.3]))
    assert s["p95"] == pytest.approx(1.285) and s["refused"] == 0 and s["max"] == pytest.approx(1.3)
    # half refused: the median is a failure too
    assert summarize(np.ones(4), np.array([True, True, True, False]))["median"] == float("inf")
    # the rows keep an unstable answer unstable (not the largest float) and a refused one refused
    from uavsim.ident.evaluate import _rows

    J = {"answer": np.array([1.0, np.inf, np.nan, 1.1]), "rule_on_truth": np.array([1.0, np.inf, 1.2, np.nan])}
    rows = _rows(J, np.array([False, False, True, False]), np.zeros(4), lateral=False)["all"]
    assert rows["answer"]["unstable"] == 1 and rows["answer"]["refused"] == 1 and rows["answer"]["max"] == 1.1
    assert rows["rule_on_truth"] == {"n": 3, "refused": 0, "unstable": 1, "median": 1.2, "p95": float("inf"),
                                     "max": 1.2}


def test_noise_plan_and_processes_are_seeded_and_balanced():
    kinds = ("none", "white", "paper", "coloured", "quantization", "outliers")
    k1, l1 = noise_plan(100, kinds, LEVELS, np.random.default_rng(1))
    k2, l2 = noise_plan(100, kinds, LEVELS, np.random.default_rng(1))
    assert np.array_equal(k1, k2) and np.array_equal(l1, l2)
    assert sorted(np.unique(l1)) == list(LEVELS) and all(np.sum(l1 == lv) == 20 for lv in LEVELS)
    assert np.all((k1 == 0) == (l1 == 0))  # level 0 is the noise-free kind, every other level is noisy
    for lv in LEVELS[1:]:  # every noisy kind meets every noisy level
        assert set(k1[l1 == lv]) == {1, 2, 3, 4, 5}
    a = draw_processes("attitude", 30, np.random.default_rng(4), K=(0.5, 2.0))
    b = draw_processes("attitude", 30, np.random.default_rng(4), K=(0.5, 2.0))
    assert a == b and all(p.in_range() and 0.5 <= p.K <= 2.0 and p.loop == "roll" for p in a)


def test_the_optimum_scores_one_and_a_detuning_more():
    from uavsim.ident.evaluate import _score
    from uavsim.tuning.optimal import optimal_gains

    truth = {"K": np.array([1.3, 0.7]), "T_prop": np.array([0.05, 0.2]), "T1": np.array([0.5, 1.5]),
             "tau": np.array([0.01, 0.04])}
    g = optimal_gains("altitude", 200.0, **truth)
    idx = np.arange(2)
    np.testing.assert_allclose(_score("altitude", 200.0, truth, g.ise, idx, g.kp, g.kd, g.derivative_filter_hz), 1.0,
                               rtol=1e-9)
    J = _score("altitude", 200.0, truth, g.ise, idx, 0.85 * g.kp, 0.85 * g.kd, g.derivative_filter_hz)
    assert np.all(J > 1.005)
    assert np.isinf(_score("altitude", 200.0, truth, g.ise, idx, 50 * g.kp, 50 * g.kd, g.derivative_filter_hz)).all()


def test_cli_small_run(three_model, tmp_path):  # noqa: F811 (fixture)
    _, model, _ = three_model
    md = tmp_path / "rows.md"
    cmd = [sys.executable, "-m", "uavsim.cli.main", "evaluate", "--loop", "altitude", "--models", str(model),
           "--recipe", str(ROOT / "datasets" / "small.toml"), "--n", "5", "--seed", "3", "--json", "--markdown",
           str(md), "--out", str(tmp_path / "full.json")]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["spec"]["seed"] == 3 and out["spec"]["n"] == 5 and out["rate_hz"] == 200.0
    rows = out["rows"]
    assert set(rows) >= {"all", "0%", "20%", "goal"}
    assert set(rows["all"]) >= {"answer", "answer_x0.85", "answer_guarded", "rule_on_truth", "table_best_class",
                            "table_nearest_class"}
    a = rows["all"]["answer"]
    assert a["n"] == 5 and a["refused"] == sum(out["refusals"].values())
    assert rows["all"]["rule_on_truth"]["n"] == 5
    full = json.loads((tmp_path / "full.json").read_text())
    assert len(full["episodes"]) == 5 and all("J" in e and "noise_level" in e for e in full["episodes"])
    # the class decisions scored on the same episodes; the one identification made (the inner loops'
    # default, blend) is the answer
    assert {"answer_bayes", "answer_argmax", "answer_fitted", "answer_blend"} <= set(rows["all"])
    assert rows["all"]["answer_blend"] == a
    assert rows["all"]["answer_fitted"]["n"] == 5 and rows["all"]["answer_fitted"]["refused"] == a["refused"]
    for e in full["episodes"]:
        if e["class"] is not None:
            assert e["decision"]["decision"] == "blend" and e["J"]["answer_blend"] == e["J"]["answer"]
            # the guard the answer took, as identification reported it (the inner loops' default: on)
            g = e["guard"]
            one = g.get("scale_one_point", g["scale"])  # with a second run, the lag family's factor
            assert one == min(g["own_scale"], g["belief_scale"]) and 0.5 <= g["scale"] <= 1.0
            if "lag_family" in g:
                assert g["scale"] == max(one, g["lag_family"]["scale"])
            assert e["J"]["answer_guarded"] == e["J"]["answer"] and "latency_ms" not in g
    assert "| answer |" in md.read_text()
    bad = tmp_path / "fixed.toml"
    bad.write_text((ROOT / "datasets" / "small.toml").read_text().replace('settings = "recommended"',
                                                                          'settings = "fixed"'))
    res = subprocess.run(cmd[:9] + [str(bad), "--n", "2"], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("given, expected", [(None, "1"), ("2", "2")])
def test_cli_runs_blas_on_one_thread_unless_told(monkeypatch, given, expected):
    # BLAS threads only contend on evaluate's small matrices; a user's own setting is kept
    from uavsim.cli.main import build_parser
    from uavsim.errors import UserError

    if given is None:
        monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    else:
        monkeypatch.setenv("OPENBLAS_NUM_THREADS", given)
    args = build_parser(["evaluate"]).parse_args(["evaluate", "--loop", "altitude", "--n", "0"])
    with pytest.raises(UserError):
        args.func(args)
    assert os.environ["OPENBLAS_NUM_THREADS"] == expected


def test_cli_second_run(three_model, tmp_path):  # noqa: F811 (fixture)
    """An inner loop's processes also fly a relay run at ``SECOND_BETA`` by default (the same noise in
    output units), and the answer weighs its belief by both measured points; ``--second-beta none``
    flies one run; a beta outside (-1, 1) or a word is a one-line error."""
    _, model, _ = three_model
    cmd = [sys.executable, "-m", "uavsim.cli.main", "evaluate", "--loop", "altitude", "--models", str(model),
           "--recipe", str(ROOT / "datasets" / "small.toml"), "--n", "3", "--seed", "4", "--json"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["spec"]["second_beta"] == -0.3 and out["second_run"]["beta"] == -0.3
    answered = out["rows"]["all"]["answer"]["n"] - out["rows"]["all"]["answer"]["refused"]
    assert 1 <= out["second_run"]["two_points"] <= answered
    assert out["second_run"]["network"] is None and out["second_run"]["network_read"] == 0  # none beside it
    one = subprocess.run(cmd + ["--second-beta", "none"], capture_output=True, text=True, cwd=ROOT, env=env)
    assert one.returncode == 0, one.stderr
    out1 = json.loads(one.stdout)
    assert out1["spec"]["second_beta"] is None and "second_run" not in out1
    for word in ("1.5", "twice"):
        bad = subprocess.run(cmd + ["--second-beta", word], capture_output=True, text=True, cwd=ROOT, env=env)
        assert bad.returncode == 2 and "Traceback" not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def test_second_beta_for_each_loop():
    from uavsim.errors import UserError
    from uavsim.ident.evaluate import second_beta_for
    from uavsim.ident.twopoint import SECOND_BETA

    for loop in ("altitude", "attitude", "lateral"):
        assert second_beta_for(loop, "auto") == SECOND_BETA
    assert second_beta_for("altitude", None) is None
    assert second_beta_for("lateral", -0.5) == -0.5
    with pytest.raises(UserError, match="second_beta"):
        second_beta_for("altitude", 1.0)


def test_cycles_set_the_relay_runs_length(three_model, monkeypatch, tmp_path):  # noqa: F811 (fixture)
    """``--cycles`` flies every relay run that many cycles of its chunk's slowest class instead of the
    recipe's ``[episodes] cycles``; fewer than 3 is a one-line error before any flight."""
    import uavsim.ident.evaluate as ev

    _, model, _ = three_model
    seen = []
    real = ev._simulate

    def spy(params, recipe, *a, **kw):
        seen.append((recipe.episodes.cycles, recipe.episodes.duration_s))
        return real(params, recipe, *a, **kw)

    monkeypatch.setattr(ev, "_simulate", spy)
    res = ev.evaluate(ev.EvalSpec(loop="altitude", n=2, seed=5, cycles=9, second_beta=None), models=model,
                      recipe=ROOT / "datasets" / "small.toml", log=lambda m: None)
    assert seen == [(9.0, None)] and res["spec"]["cycles"] == 9
    cmd = [sys.executable, "-m", "uavsim.cli.main", "evaluate", "--loop", "altitude", "--models", str(model),
           "--recipe", str(ROOT / "datasets" / "small.toml"), "--n", "2", "--cycles", "2"]
    bad = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    assert "3" in bad.stderr


def test_an_answer_without_a_class_counts_for_the_answer_and_as_refused_by_the_class_controls():
    """A lateral episode answered from its second run alone (no class): the answer's rows score it, the
    table's answer (a class decision's control) counts it refused, not unstable."""
    from uavsim.ident.evaluate import _rows

    J = {"answer": np.array([1.0, 1.05, np.inf]), "answer_x0.85": np.array([1.05, 1.1, np.inf]),
         "answer_table": np.array([1.02, np.inf, np.inf])}
    rows = _rows(J, np.array([False, False, True]), np.zeros(3), lateral=True,
                 no_class=np.array([False, True, False]))["all"]
    assert rows["answer"]["refused"] == 1 and rows["answer"]["unstable"] == 0 and rows["answer"]["max"] == 1.05
    assert rows["answer_x0.85"]["refused"] == 1 and rows["answer_x0.85"]["max"] == 1.1
    assert rows["answer_table"]["refused"] == 2 and rows["answer_table"]["unstable"] == 0
