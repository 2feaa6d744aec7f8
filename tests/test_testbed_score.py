"""``uavsim testbed score``'s log record and summary: what the gap workflow answered, scored against the truth."""

import json
from types import SimpleNamespace

from uavsim.testbed import score


def _truth(tmp_path, kind="single", effects=({"name": "noise", "params": {"std": 3e-4}},)):
    folder = tmp_path / "tb_00001"
    folder.mkdir()
    t = {"name": "tb_00001", "kind": kind, "loop": "roll", "effects": list(effects)}
    (tmp_path / "tb_00001.truth.json").write_text(json.dumps(t))
    return folder


class _Flow:
    answer = "named"
    gap_before = gap_after = 2.5
    absorbed = moved = None
    dropped: list = []
    residual = {"summary": ""}
    identification = None
    steps = [SimpleNamespace(ranking=[])]

    def to_json(self):
        return {"found": [{"name": "noise", "std": 2.6e-4}], "by_level": ["noise"], "from_samples": [], "steps": [],
                "base_model": dict(K=1.0, T_prop=0.05, T1=0.4, tau=0.01, noise_std=2.6e-4)}  # fmt: skip


def test_record_keeps_what_was_named_from_its_level(tmp_path, monkeypatch):
    folder = _truth(tmp_path)
    monkeypatch.setattr(score, "read_session", lambda f: SimpleNamespace(actuator=None))
    monkeypatch.setattr(score, "analyse", lambda *a, **k: _Flow())
    r = score.one(folder, None, "identified", 0)
    assert r["by_level"] == ["noise"] and r["ok"] and abs(r["param_rel_err"] - 0.4 / 3) < 1e-9
    table = score.summary([r])
    assert "noise std 0.00026 (from its level)" in table and "| yes |" in table
    # the model carries the measured noise: no gap to shrink, so it is not one of the gap ratios
    assert "when a single is named: 0/0 (1 more named from their level, no gap to shrink)" in table


def test_summary_of_a_record_without_the_field():
    r = {"name": "tb_9", "condition": "identified", "kind": "none", "loop": "roll", "truth": "none",
         "answer": "none", "found": [], "gap_before": 3.0, "gap_after": 3.0, "ok": True, "seconds": 50.0}  # fmt: skip
    assert "| tb_9 | none | roll | none | none |  | 3.00 -> 3.00 | yes | 50 |" in score.summary([r])


def _record_of_a_read(tmp_path, monkeypatch, truth: dict, found: dict, evidence: str) -> dict:
    """The testbed record of a flow that names ``found`` read off the runs (``evidence``); the truth hides ``truth``."""
    folder = _truth(tmp_path, effects=(truth,))
    flow = _Flow()
    flow.to_json = lambda: {"found": [found], "by_level": [],
                            "from_samples": [{**found, "evidence": evidence, "gap_without": 20.0, "gap_with": 4.0}],
                            "steps": [], "base_model": dict(K=1.0, T_prop=0.05, T1=0.4, tau=0.01, noise_std=0.0)}  # fmt: skip
    monkeypatch.setattr(score, "read_session", lambda f: SimpleNamespace(actuator=None))
    monkeypatch.setattr(score, "analyse", lambda *a, **k: flow)
    return score.one(folder, None, "identified", 0)


def test_record_marks_what_was_read_off_the_samples(tmp_path, monkeypatch):
    r = _record_of_a_read(tmp_path, monkeypatch, {"name": "quantization", "params": {"step": 0.005}},
                          {"name": "quantization", "step": 0.005}, "staircase")  # fmt: skip
    assert r["from_samples"] == ["quantization"] and r["ok"] and r["param_rel_err"] < 1e-12
    assert "quantization step 0.005 (off the samples)" in score.summary([r])


def test_record_marks_a_saturation_read_off_the_relay_amplitudes(tmp_path, monkeypatch):
    r = _record_of_a_read(tmp_path, monkeypatch, {"name": "saturation", "params": {"limit": 2.0}},
                          {"name": "saturation", "limit": 2.2}, "relay amplitudes")  # fmt: skip
    assert r["read_from"] == {"saturation": "relay amplitudes"} and abs(r["param_rel_err"] - 0.1) < 1e-9
    assert "saturation limit 2.2 (off the relay runs' amplitudes)" in score.summary([r])


def test_a_single_with_a_second_name_beside_it_is_wrong():
    t = {"kind": "single", "effects": [{"name": "lag", "params": {"T": 0.05}}]}
    assert score.score(t, "named", [{"name": "lag", "T": 0.05}], 10.0, 2.0)["ok"]
    assert not score.score(t, "named", [{"name": "lag", "T": 0.05}, {"name": "bias", "offset": 0.1}], 10.0, 1.5)["ok"]


def test_summary_scores_the_constant_answers_on_the_same_truths():
    recs = [{"name": "tb_1", "condition": "identified", "kind": "none", "loop": "roll", "truth": "none",
             "answer": "named", "found": [{"name": "bias", "offset": 0.1}], "gap_before": 9.0, "gap_after": 2.0,
             "ok": False, "seconds": 50.0},
            {"name": "tb_2", "condition": "identified", "kind": "single", "loop": "roll", "truth": "lag",
             "truth_params": [{"T": 0.05}], "answer": "none", "found": [], "gap_before": 3.0, "gap_after": 3.0,
             "ok": True, "seconds": 50.0},
            {"name": "tb_3", "condition": "identified", "kind": "outside", "loop": "roll", "truth": "backlash",
             "answer": "none", "found": [], "gap_before": 3.0, "gap_after": 3.0, "ok": False, "seconds": 50.0}]  # fmt: skip
    assert score.controls(recs) == {"none": 2, "unexplained": 1}  # a linear single counts as absorbed under none
    assert "controls on the same truths: always none 2/3, always unexplained 1/3" in score.summary(recs)


def test_record_says_which_run_identified_the_base_and_whether_the_duty_check_was_on(tmp_path, monkeypatch):
    folder = _truth(tmp_path)
    flow = _Flow()
    flow.identification = {"run": "r1.csv", "refused_runs": ["r0.csv: relay duty 0.64 over the cycle"],
                           "duty_check": False, "class": 3, "params": {"K": 1.0}, "n_cycles_internal": 9}  # fmt: skip
    monkeypatch.setattr(score, "read_session", lambda f: SimpleNamespace(actuator=None))
    monkeypatch.setattr(score, "analyse", lambda *a, **k: flow)
    ident = score.one(folder, None, "identified", 0)["identification"]
    assert ident["run"] == "r1.csv" and ident["duty_check"] is False
    assert ident["refused_runs"] == ["r0.csv: relay duty 0.64 over the cycle"] and "n_cycles_internal" not in ident


def test_a_pair_counts_its_absorbable_member_as_a_single_does():
    t = {"kind": "pair", "effects": [{"name": "sample_hold", "params": {}}, {"name": "delay", "params": {}}]}
    r = score.score(t, "named", [{"name": "sample_hold"}], 10.0, 3.0)
    assert r["ok"] and not r["both_named"] and r["one_of_two"]
    assert score.score(t, "named", [{"name": "sample_hold"}, {"name": "delay"}], 10.0, 2.0)["both_named"]
    # the member a linear model cannot take in must be named, and nothing beside the two
    assert not score.score(t, "named", [{"name": "delay"}], 10.0, 3.0)["ok"]
    assert not score.score(t, "none", [], 10.0, 10.0)["ok"]
    assert not score.score(t, "named", [{"name": "sample_hold"}, {"name": "bias"}], 10.0, 2.0)["ok"]
    both_linear = {"kind": "pair", "effects": [{"name": "gain", "params": {}}, {"name": "lowpass", "params": {}}]}
    assert score.score(both_linear, "none", [], 5.0, 5.0)["ok"]
    assert score.score(both_linear, "absorbed", [], 5.0, 5.0)["ok"]
    assert not score.score(both_linear, "unexplained", [], 5.0, 5.0)["ok"]


def test_an_interrupted_score_resumes_from_its_log(tmp_path, monkeypatch):
    sets = tmp_path / "set"
    sets.mkdir()
    for name in ("tb_00001", "tb_00002"):
        (sets / name).mkdir()
        (sets / name / "session.toml").write_text("")
        (sets / f"{name}.truth.json").write_text(json.dumps(
            {"name": name, "kind": "single", "loop": "roll", "effects": [{"name": "noise", "params": {"std": 3e-4}}]}))
    ran = []

    def one(folder, models, cond, seed, nthread=0, screen=False):
        ran.append(folder.name)
        if folder.name == "tb_00002" and len(ran) == 2:
            raise KeyboardInterrupt
        return {"name": folder.name, "condition": cond, "truth": "noise", "answer": "none", "seconds": 1.0, "ok": False}

    monkeypatch.setattr(score, "one", one)
    log = tmp_path / "log.jsonl"
    try:
        score.score_set(sets, conditions=("identified",), log=log)
    except KeyboardInterrupt:
        pass
    assert ran == ["tb_00001", "tb_00002"] and len(log.read_text().splitlines()) == 1
    recs = score.score_set(sets, conditions=("identified",), log=log)
    # the first is read back, the second run: each once in the log
    assert ran == ["tb_00001", "tb_00002", "tb_00002"] and [r["name"] for r in recs] == ["tb_00001", "tb_00002"]
    assert [json.loads(x)["name"] for x in log.read_text().splitlines()] == ["tb_00001", "tb_00002"]
