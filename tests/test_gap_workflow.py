"""Gap workflow: features, the hidden-effect generator, errors, CLI, and small end-to-end runs."""

import json
import math

import numpy as np
import pytest

from uavsim.errors import UserError
from uavsim.formats.session import ModelSpec, RunSpec, read_session
from uavsim.gap.features import compare, gap_value, run_features
from uavsim.gap.hidden import hidden_session, write_hidden
from uavsim.gap.workflow import run_gap


def _relay(period=0.5, amp=1.0, rate=200.0, cycles=10, offset=0.0):
    t = np.arange(int(cycles * period * rate)) / rate
    u = np.where(np.sin(2 * np.pi * t / period) >= 0, 1.0, -1.0)
    y = offset - amp * np.cos(2 * np.pi * t / period)
    return t, y, u


def test_features_identical_runs_have_no_gap():
    spec = RunSpec("a.csv", "mrft", beta=-0.5, h=1.0)
    t, y, u = _relay()
    f = run_features(spec, t, y, u)
    assert math.exp(f["period"]) == pytest.approx(0.5, rel=0.01)
    assert math.exp(f["amplitude"]) == pytest.approx(1.0, rel=0.01)
    assert gap_value(compare([f], [run_features(spec, t, y, u)])) == 0.0


def test_features_see_offset_and_period():
    spec = RunSpec("a.csv", "mrft", beta=-0.5, h=1.0)
    fm = run_features(spec, *_relay(offset=0.2))
    fs = run_features(spec, *_relay(period=0.55))
    z = compare([fm], [fs])
    assert abs(z[(0, "offset")]) > 5 and abs(z[(0, "period")]) > 5


def test_relay_without_cycles_is_none():
    spec = RunSpec("a.csv", "mrft", beta=-0.5, h=1.0)
    t = np.arange(400) / 200.0
    assert run_features(spec, t, np.zeros_like(t), np.ones_like(t)) is None


def test_hidden_session_does_not_leak(tmp_path):
    session, truth = hidden_session(3, effect="delay")
    assert session.effects == [] and truth.effect == "delay" and truth.params["delay"] > 0
    folder = write_hidden(session, truth, tmp_path / "s")
    assert sorted(p.name for p in folder.iterdir() if p.suffix != ".csv") == ["session.toml"]
    assert "delay" not in (folder / "session.toml").read_text()
    assert json.loads((tmp_path / "s.truth.json").read_text())["effect"] == "delay"
    back = read_session(folder)
    assert len(back.runs) == 4 and back.model is not None


def test_no_model_is_a_user_error():
    session, _ = hidden_session(5, effect="none")
    session.model = None
    with pytest.raises(UserError, match="no \\[model\\]"):
        run_gap(session)


def test_model_that_cannot_oscillate_is_a_user_error():
    session, _ = hidden_session(5, effect="none")
    m = session.model
    bad = ModelSpec(K=-m.K, T_prop=m.T_prop, T1=m.T1, tau=m.tau, noise_std=m.noise_std)  # positive feedback
    with pytest.raises(UserError, match="does not even reproduce the oscillation"):
        run_gap(session, model=bad, candidates=("delay",))


def test_lateral_loop_is_refused():
    session, _ = hidden_session(5, effect="none")
    session.loop = "lateral_x"
    with pytest.raises(UserError, match="lateral"):
        run_gap(session)


def test_cli_malformed_session(tmp_path, capsys):
    import argparse

    from uavsim.cli.gap_cmd import register

    (tmp_path / "session.toml").write_text('format = "uavsim-session/1"\nloop = "altitude"\nbogus = 1\n')
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["gap", str(tmp_path)])
    with pytest.raises(UserError):
        args.func(args)


def test_bias_named_and_fitted(tmp_path):
    """End to end on a restricted candidate set (the full set is the slow suite)."""
    session, truth = hidden_session(11, effect="bias", loop="roll")
    r = run_gap(session, seed=1, candidates=("bias", "gain", "delay"), coarse=5, fine=5)
    assert r.effect == "bias"
    assert r.params["offset"] == pytest.approx(truth.params["offset"], rel=0.3)
    assert r.gap_after <= r.gap_before / 3
    from uavsim.gap.report import write_report

    out = write_report(session, r, tmp_path / "rep")
    names = {p.name for p in out.iterdir()}
    assert {"gap.rrd", "gap.json", "model.toml"} <= names and any(n.endswith(".png") for n in names)
    assert json.loads((out / "gap.json").read_text())["effect"] == "bias"
    assert 'name = "bias"' in (out / "model.toml").read_text()


def test_a_winner_scored_on_its_grid_alone_is_verified_before_it_is_named(monkeypatch):
    # with no candidate verified up front, the best one still wins only on fresh seeds (it used to
    # be looked up among the verified ones and fail)
    from uavsim.gap import workflow

    session, truth = hidden_session(11, effect="bias", loop="roll")
    monkeypatch.setattr(workflow, "VERIFY", 0)
    r = run_gap(session, seed=1, candidates=("bias", "gain", "delay"), coarse=5, fine=5, name_ratio=0.8)
    assert r.effect == "bias" and r.params["offset"] == pytest.approx(truth.params["offset"], rel=0.3)
    ranked = {x["effect"]: x["gap"] for x in r.ranking}
    assert r.gap_after <= ranked["bias"] and r.gap_after <= r.gap_before / 3


def test_none_on_clean_session():
    session, _ = hidden_session(12, effect="none", loop="pitch")
    r = run_gap(session, seed=2, candidates=("delay", "gain"), coarse=4, fine=4)
    assert r.effect == "none"
    assert r.gap_before < 3.0  # noise alone: an RMS z-score near 1


@pytest.mark.slow
def test_hidden_effect_suite():
    """The issue's goals on 60 hidden-effect sessions of their own (seeds 1000-1059; about 10 min).

    Fewer sessions make a statistical check of a 90% goal a coin toss: the
    first 24 of these name 21 (87.5%), all 60 name 56 (93.3%).
    """
    from uavsim.bench.gap import one, summarize

    s = summarize([one(1000 + i) for i in range(60)])
    assert s["named_correctly"] >= 0.9
    assert s["none_on_none"] in (None, 1.0)
    assert s["param_within_30pct"] is None or s["param_within_30pct"] >= 0.8
    assert s["gap_ratio_max"] is None or s["gap_ratio_max"] <= 1 / 3


def test_model_file(tmp_path):
    from uavsim.gap.workflow import read_model_file

    f = tmp_path / "m.toml"
    f.write_text("[model]\nK = 2.0\nT_prop = 0.1\nT1 = 0.8\ntau = 0.02\n")
    m = read_model_file(f, "altitude")
    assert (m.K, m.noise_std) == (2.0, 0.0)
    f.write_text("[model]\nK = 2.0\nT_prop = 0.1\nT1 = 0.8\ntau = 0.02\nTprop = 3\n")
    with pytest.raises(UserError, match=r"model\.Tprop: unknown key \(did you mean 'T_prop'\?\)"):
        read_model_file(f, "altitude")
    f.write_text("[model]\nK = 2.0\nT_prop = -0.1\nT1 = 0.8\ntau = 0.02\n")
    with pytest.raises(UserError, match="T_prop"):
        read_model_file(f, "altitude")
    with pytest.raises(UserError, match="cannot read"):
        read_model_file(tmp_path / "missing.toml", "altitude")


def test_bench_summary_figures():
    from uavsim.bench.gap import format_summary, summarize

    recs = [
        {"truth": "delay", "answer": "delay", "param_rel_err": 0.1, "gap_before": 9.0, "gap_after": 0.5, "seconds": 20.0},
        {"truth": "delay", "answer": "lag", "param_rel_err": None, "gap_before": 9.0, "gap_after": 1.0, "seconds": 30.0},
        {"truth": "none", "answer": "none", "param_rel_err": None, "gap_before": 0.5, "gap_after": 0.5, "seconds": 10.0},
        {"truth": "bias", "answer": "bias", "param_rel_err": 0.5, "gap_before": 6.0, "gap_after": 3.0, "seconds": 10.0},
    ]
    s = summarize(recs)
    assert s["named_correctly"] == 0.75 and s["none_on_none"] == 1.0
    assert s["param_within_30pct"] == 0.5
    assert s["gap_ratio_max"] == 0.5 and s["seconds_max"] == 30.0
    labels = s["labels"]
    assert s["confusion"][labels.index("delay")][labels.index("lag")] == 1
    assert "named correctly 0.750" in format_summary(s)


def _relay_through(b, a, period=0.5, rate=200.0, cycles=12):
    """A square relay output of 50% duty and a plant's response to it (digital filter ``b``, ``a``)."""
    from scipy import signal

    t = np.arange(int(cycles * period * rate)) / rate
    u = np.where(np.sin(2 * np.pi * t / period + 1e-9) >= 0, 1.0, -1.0)
    return t, signal.lfilter(b, a, u), u


def _response(b, a, f_hz, rate=200.0):
    from scipy import signal

    return signal.freqz(b, a, worN=[f_hz], fs=rate)[1][0]


def test_r3_is_the_plants_harmonic_ratio():
    """R3 = G(3jw)/G(jw) of the plant, here against scipy's exact digital frequency response."""
    spec = RunSpec("a.csv", "mrft", beta=-0.5, h=1.0)
    rate, period = 200.0, 0.5
    p = math.exp(-1.0 / (rate * period / 6))  # two first-order stages: a smooth cycle
    base_b, base_a = np.convolve([1 - p], [1 - p]), np.convolve([1, -p], [1, -p])
    d = 6  # samples of pure delay
    q = math.exp(-1.0 / (rate * 0.03))  # an extra 30 ms lag
    plants = {
        "base": (base_b, base_a),
        "delay": (np.concatenate([np.zeros(d), base_b]), base_a),
        "lag": (np.convolve(base_b, [1 - q]), np.convolve(base_a, [1, -q])),
    }
    r3 = {}
    for name, (b, a) in plants.items():
        f = run_features(spec, *_relay_through(b, a, period, rate))
        r3[name] = np.exp(f["r3mag"] + 1j * f["r3arg"])
        want = _response(b, a, 3 / period) / _response(b, a, 1 / period)
        assert abs(r3[name] - want) < 0.03 * abs(want), (name, r3[name], want)
    # a delay turns R3 by -2 w d and keeps its magnitude; a lag also shrinks it
    w = 2 * np.pi / period
    assert abs(r3["delay"]) == pytest.approx(abs(r3["base"]), rel=0.02)
    assert np.angle(r3["delay"] / r3["base"]) == pytest.approx(-2 * w * d / rate, abs=0.03)
    assert abs(r3["lag"]) < 0.9 * abs(r3["base"])


def test_r3_undefined_when_the_relay_lacks_a_third_harmonic():
    spec = RunSpec("a.csv", "mrft", beta=-0.5, h=1.0)
    t = np.arange(2400) / 200.0
    u = np.where((t % 0.6) < 0.2, 1.0, -1.0)  # duty 1/3: no 3rd harmonic
    y = np.cumsum(u) / 200.0
    f = run_features(spec, t, y - y.mean(), u)
    assert math.isnan(f["r3mag"]) and math.isnan(f["r3arg"])
    z = compare([f], [f])
    assert (0, "r3mag") not in z and (0, "duty") in z


def test_step_onset_is_dead_time_from_the_level_at_the_step():
    spec = RunSpec("s.csv", "step", kp=1.0, kd=0.0, derivative_filter_hz=10.0, step=1.0, step_time=1.0)
    t = np.arange(800) / 200.0
    for dead in (0.05, 0.15):
        y = 0.2 + np.where(t >= 1.0 + dead, 1 - np.exp(-(t - 1.0 - dead) / 0.05), 0.0)  # starts from 0.2
        f = run_features(spec, t, y, np.zeros_like(t))
        assert math.exp(f["onset"]) == pytest.approx(dead + 0.05 * math.log(1 / 0.95), abs=0.02)


def _noisy_features(noise, rng, repeat_every=1):
    spec = RunSpec("a.csv", "mrft", beta=-0.5, h=1.0)
    t, y, u = _relay(cycles=20)
    y = y + noise
    if repeat_every > 1:  # a staircase: every sample repeated
        y = np.repeat(y[::repeat_every], repeat_every)[: t.size]
    return run_features(spec, t, y, u)


def test_smoother_measurement_is_the_sensors_rougher_stays_evidence():
    from uavsim.gap.features import noise_offsets, noise_scales

    rng = np.random.default_rng(0)
    n = int(20 * 0.5 * 200)
    white = [_noisy_features(0.02 * rng.standard_normal(n), rng) for _ in range(3)]
    scales = noise_scales([[f] for f in white])
    # the same std, filtered (a sensor's low-pass): much smaller second difference
    k = np.ones(8) / 8
    smooth = np.convolve(0.02 * rng.standard_normal(n + 7) * math.sqrt(8), k, mode="valid")
    fm = _noisy_features(smooth, rng)
    off = noise_offsets([fm], [[f] for f in white], scales)
    assert off[0]["resid"] < -0.5
    z = compare([fm], [white[0]], scales, off)
    assert abs(z[(0, "resid")]) < 3 < abs(compare([fm], [white[0]], scales)[(0, "resid")])
    # rougher than the model (extra noise) is kept as evidence
    rough = _noisy_features(0.08 * rng.standard_normal(n), rng)
    assert noise_offsets([rough], [[f] for f in white], scales) == [{}]
    # a staircase's flat second difference is quantization or a hold, not a filter
    stair = _noisy_features(0.02 * rng.standard_normal(n), rng, repeat_every=3)
    assert stair["repeat"] > 0.5 and noise_offsets([stair], [[f] for f in white], scales) == [{}]


def test_lag_like_candidates_and_a_rate_limit_take_their_phase_out_of_tau():
    from uavsim.gap.workflow import GapEvaluator, candidate_phase

    assert candidate_phase("lag", 0.05, 1.0 / (2 * math.pi * 0.05)) == pytest.approx(math.pi / 4)
    assert candidate_phase("lowpass", 10.0, 10.0) == pytest.approx(math.pi / 2)
    assert candidate_phase("delay", 0.05, 2.0) == 0.0
    session, _ = hidden_session(3, effect="none")
    model = ModelSpec(K=1.0, T_prop=0.05, T1=0.4, tau=0.02, noise_std=0.0)
    ev = GapEvaluator(session, model, {}, 0, 1, 0.001, anchor_hz=2.0)
    w = 2 * math.pi * 2.0
    assert ev.tau_shift("lag", 0.01) == pytest.approx(math.atan(w * 0.01) / w)
    assert ev.tau_shift("lag", 1.0) == pytest.approx(0.02)  # never below tau = 0
    assert ev.tau_shift("delay", 0.01) == 0.0
    assert ev.tau_shift("none", 0.0) == 0.0  # the bare model's episodes of an identified session
    assert GapEvaluator(session, model, {}, 0, 1, 0.001).tau_shift("lag", 0.01) == 0.0
    # a slew limit turns the relay's +-h square wave into a trapezoid centred h / rate after each switch
    assert candidate_phase("rate_limit", 40.0, 2.0, h=0.5) == pytest.approx(2 * math.pi * 2.0 * 0.5 / 40.0)
    assert candidate_phase("rate_limit", 1.0, 2.0, h=0.5) == pytest.approx(math.pi / 2)  # a triangle at most
    ev_h = GapEvaluator(session, model, {}, 0, 1, 0.001, anchor_hz=2.0, anchor_h=0.5)
    assert ev_h.tau_shift("rate_limit", 40.0) == pytest.approx(0.5 / 40.0)
    assert ev_h.tau_shift("rate_limit", 1.0) == pytest.approx(0.02)  # never below tau = 0
    assert ev.tau_shift("rate_limit", 40.0) == 0.0  # no relay amplitude given: no phase


def test_a_lag_like_candidate_takes_the_phase_tau_cannot_hold_out_of_t_prop_at_the_same_gain():
    from uavsim.gap.workflow import T_PROP_KEEP, GapEvaluator, candidate_phase

    session, _ = hidden_session(3, effect="none")
    f, w = 2.0, 2 * math.pi * 2.0
    model = ModelSpec(K=1.3, T_prop=0.15, T1=0.4, tau=0.002, noise_std=0.0)
    ev = GapEvaluator(session, model, {}, 0, 1, 0.001, anchor_hz=f)

    def response(m, shift=0.0):  # the inner loops' K e^{-jw tau} / (jw (T_prop jw + 1)(T1 jw + 1))
        s = 1j * w
        return m.K * np.exp(-s * (m.tau - shift)) / (s * (m.T_prop * s + 1) * (m.T1 * s + 1))

    phase = candidate_phase("lowpass", 5.0, f)
    assert phase > w * model.tau  # more than tau holds
    cut = ev.trimmed("lowpass", 5.0)
    assert cut is not None and cut.T_prop < model.T_prop and cut.tau == model.tau
    g0, g1 = response(model), response(cut, ev.tau_shift("lowpass", 5.0))
    assert abs(g1) == pytest.approx(abs(g0), rel=1e-12)  # the gain at the cycle stays
    assert np.angle(g1 / g0) == pytest.approx(phase, abs=1e-9)  # the candidate's whole phase is taken out
    # what tau holds alone needs no cut; without an anchor, or for a delay, nothing moves
    assert ev.trimmed("lag", 1e-4) is None
    assert GapEvaluator(session, model, {}, 0, 1, 0.001).trimmed("lowpass", 5.0) is None
    assert ev.trimmed("delay", 0.05) is None
    # a phase beyond what T_prop holds leaves it at its floor
    assert ev.trimmed("lag", 10.0).T_prop == pytest.approx(T_PROP_KEEP * model.T_prop)


def test_a_frame_hold_takes_its_half_frame_beyond_the_control_rates_out_of_tau():
    from uavsim.gap.workflow import GapEvaluator, candidate_phase

    f = 2.0
    # half a frame's delay as against the unheld signal; a loop at 200 Hz already holds half a control period
    assert candidate_phase("sample_hold", 20.0, f) == pytest.approx(2 * math.pi * f * 0.5 / 20.0)
    assert candidate_phase("sample_hold", 20.0, f, rate_hz=200.0) == pytest.approx(
        2 * math.pi * f * 0.5 * (1 / 20.0 - 1 / 200.0))
    assert candidate_phase("sample_hold", 200.0, f, rate_hz=200.0) == 0.0  # its identity holds nothing
    session, _ = hidden_session(3, effect="none")
    model = ModelSpec(K=1.0, T_prop=0.05, T1=0.4, tau=0.05, noise_std=0.0)
    ev = GapEvaluator(session, model, {}, 0, 1, 0.001, anchor_hz=f)
    rate = session.control_rate_hz
    assert ev.tau_shift("sample_hold", 20.0) == pytest.approx(0.5 * (1 / 20.0 - 1 / rate))


def test_simulated_step_runs_follow_their_derivative():
    # the gap workflow's simulation flies each step run's own PD: the error form kicks the
    # command on the step sample, the measurement form sends kp e there (the output is at rest)
    from uavsim.formats.session import Run, RunData, Session
    from uavsim.gap.simulate import Episode, simulate

    rate, T = 200.0, 120
    t = np.arange(T) / rate
    data = RunData(t, np.zeros(T), np.zeros(T), np.zeros(T))
    spec = dict(kind="step", kp=2.0, kd=0.3, derivative_filter_hz=10.0, step=0.05, step_time=0.2)
    runs = [Run(RunSpec("e.csv", **spec), data), Run(RunSpec("m.csv", **spec, derivative="measurement"), data)]
    session = Session(loop="pitch", control_rate_hz=rate, runs=runs)
    model = ModelSpec(K=20.0, T_prop=0.05, T1=0.4, tau=0.01, noise_std=0.0)
    err, meas = simulate(session, model, [Episode(0), Episode(1)], seed=0, nthread=1)
    k = int(0.2 * rate)
    assert np.array_equal(err.u[:k], meas.u[:k])
    assert meas.u[k] == pytest.approx(2.0 * 0.05, rel=1e-9)
    a = (2 * math.pi * 10.0 / rate) / (1 + 2 * math.pi * 10.0 / rate)
    assert err.u[k] - meas.u[k] == pytest.approx(0.3 * a * 0.05 * rate, rel=1e-9)  # the kick, 7x kp e here


def test_simulated_runs_clip_the_command_to_the_stated_actuator_range():
    # a session's [actuator] clips the command as the ESCs do: a symmetric range flies exactly as the
    # vocabulary's saturation at that limit, one wider than any command as no range, and the
    # kick of the step's error-form PD is what it clips
    import dataclasses

    from uavsim.formats.session import ActuatorSpec, Run, RunData, Session
    from uavsim.gap.simulate import Episode, simulate

    rate, T = 200.0, 120
    t = np.arange(T) / rate
    data = RunData(t, np.zeros(T), np.zeros(T), np.zeros(T))
    spec = dict(kind="step", kp=2.0, kd=0.3, derivative_filter_hz=10.0, step=0.05, step_time=0.2)
    bare = Session(loop="pitch", control_rate_hz=rate, runs=[Run(RunSpec("e.csv", **spec), data)])
    model = ModelSpec(K=20.0, T_prop=0.05, T1=0.4, tau=0.01, noise_std=0.0)

    def fly(session, effect="none", value=0.0):
        return simulate(session, model, [Episode(0, effect, value)], seed=0, nthread=1)[0]

    free = fly(bare)
    assert free.u.max() > 0.5  # the kick: 0.3 a 0.05 rate + kp e
    narrow = fly(dataclasses.replace(bare, actuator=ActuatorSpec(command_min=-0.2, command_max=0.2)))
    assert np.array_equal(narrow.y, fly(bare, "saturation", 0.2).y)
    assert not np.allclose(narrow.y, free.y)
    wide = fly(dataclasses.replace(bare, actuator=ActuatorSpec(command_min=-1e3, command_max=1e3)))
    assert np.array_equal(wide.y, free.y)
    # asymmetric: only the upper bound bites on a positive kick
    upper = fly(dataclasses.replace(bare, actuator=ActuatorSpec(command_min=-1e3, command_max=0.2)))
    assert not np.allclose(upper.y, free.y)
    below = np.flatnonzero(narrow.u < -0.2)
    j = below[0] + 1 if below.size else T  # the two ranges differ from the first command below -0.2 on
    assert np.array_equal(upper.y[:j], narrow.y[:j]) and j > int(0.2 * rate) + 2


def test_staircase_cause_read_off_the_samples():
    """A quantized measurement passes lone samples on a level lattice, a held frame repeats off any lattice."""
    from types import SimpleNamespace

    from uavsim.gap.workflow import data_hints, ruled_out

    quant, tq = hidden_session(2, effect="quantization", loop="roll")
    held, th = hidden_session(1, effect="sample_hold", loop="roll")
    clean, _ = hidden_session(1, effect="none", loop="roll")
    assert ruled_out(quant, 200.0) == {"sample_hold"}
    assert data_hints(quant, 200.0)["quantization"] == pytest.approx(tq.params["step"], rel=1e-9)
    assert ruled_out(held, 200.0) == {"quantization"}
    assert data_hints(held, 200.0)["sample_hold"] == pytest.approx(th.params["rate_hz"], rel=0.02)
    assert ruled_out(clean, 200.0) == set() and data_hints(clean, 200.0) == {}
    # a quantized hold shows both causes and keeps both
    t = np.arange(4000) / 200.0
    y = np.sin(2 * np.pi * t / 0.5) + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    y = np.round(np.repeat(y[::5], 5)[: t.size] / 0.05) * 0.05
    both = SimpleNamespace(runs=[SimpleNamespace(data=SimpleNamespace(y=y))])
    assert ruled_out(both, 200.0) == set() and set(data_hints(both, 200.0)) == {"quantization", "sample_hold"}


def test_staircase_cause_is_read_with_its_parameter_only_where_the_samples_show_it_alone():
    from types import SimpleNamespace

    from uavsim.gap.workflow import read_off_samples

    quant, tq = hidden_session(2, effect="quantization", loop="roll")
    held, th = hidden_session(1, effect="sample_hold", loop="roll")
    clean, _ = hidden_session(1, effect="none", loop="roll")
    (q,) = read_off_samples(quant, 200.0)
    assert q.name == "quantization" and q.params["step"] == pytest.approx(tq.params["step"], rel=1e-9)
    (h,) = read_off_samples(held, 200.0)
    assert h.name == "sample_hold" and h.params["rate_hz"] == pytest.approx(th.params["rate_hz"], rel=0.02)
    assert read_off_samples(clean, 200.0) == []
    # a quantized hold shows both causes: neither is read, the search keeps both
    t = np.arange(4000) / 200.0
    y = np.sin(2 * np.pi * t / 0.5) + 0.01 * np.random.default_rng(0).standard_normal(t.size)
    y = np.round(np.repeat(y[::5], 5)[: t.size] / 0.05) * 0.05
    both = SimpleNamespace(runs=[SimpleNamespace(data=SimpleNamespace(y=y))])
    assert read_off_samples(both, 200.0) == []


def test_saturation_is_read_off_two_relay_runs_whose_cycles_grow_less_than_their_amplitude():
    from uavsim.gap.workflow import SEEDS, GapEvaluator, base_effects, read_off_relays

    def read(effect, loop, seed):
        s, truth = hidden_session(seed, effect=effect, loop=loop)
        ev = GapEvaluator(s, s.model, base_effects(s), 0, 1, 0.001)
        flown = ev.sims([("none", 0.0)], seeds=SEEDS)
        return read_off_relays(s, ev.meas, [ev.features(f) for f in flown]), truth

    # limits of 0.58 and 0.50 of the larger run's h: the larger cycle grows as the limit does
    for loop, seed in (("altitude", 2), ("pitch", 3)):
        (sat,), truth = read("saturation", loop, seed)
        assert sat.name == "saturation" and sat.params["limit"] == pytest.approx(truth.params["limit"], rel=0.1)
    # a linear loop, with or without a gain, and an effect that moves the period too (a rate limit) read nothing
    for effect, loop, seed in (("none", "roll", 1), ("none", "altitude", 2), ("gain", "pitch", 3),
                               ("rate_limit", "altitude", 5)):  # fmt: skip
        assert read(effect, loop, seed)[0] == []
    # a dead zone of 0.44 h: the larger cycle grows more than h does, by as much as the square wave
    # loses to the dead zone at each h, and the step run settles as the model's does
    (dz,), truth = read("dead_zone", "roll", 1)
    assert dz.name == "dead_zone" and dz.params["width"] == pytest.approx(truth.params["width"], rel=0.15)


def test_a_rate_limit_is_read_off_two_relay_runs_whose_period_grows_with_the_relay_amplitude():
    import dataclasses

    from uavsim.gap.workflow import (
        RL_PERIOD_RATIO,
        SEEDS,
        GapEvaluator,
        base_effects,
        read_off_relays,
    )

    def read(effect, seed):
        s, truth = hidden_session(seed, effect=effect, loop="altitude")
        model = s.model
        if truth.params.get("rate"):
            # as identified from the smaller relay run: its tau holds that run's delay of the ramps' centre
            model = dataclasses.replace(model, tau=model.tau + s.runs[0].spec.h / truth.params["rate"])
        ev = GapEvaluator(s, model, base_effects(s), 0, 1, 0.001)
        feats = [ev.features(f) for f in ev.sims([("none", 0.0)], seeds=SEEDS)]
        return read_off_relays(s, ev.meas, feats, model=model), read_off_relays(s, ev.meas, feats), truth

    # exact lumped loops with a slew limit, relays at h and 2 h: the larger cycle's period grows 1.14-1.16
    # times beyond the model's, and the harmonic balance on the model gives the rate back
    for seed in (1, 6):
        got, without_model, truth = read("rate_limit", seed)
        assert [e.name for e in got] == ["rate_limit"] and without_model == []
        assert got[0].params["rate"] == pytest.approx(truth.params["rate"], rel=0.2)
    # linear loops, clean, with a lag or a delay: their periods do not move with the amplitude
    for effect, seed in (("none", 2), ("none", 4), ("lag", 2), ("delay", 3)):
        assert read(effect, seed)[0] == []
    assert RL_PERIOD_RATIO["attitude"] is None  # not studied there: never read on the attitude loops


def test_saturation_read_needs_the_clipped_cycle_to_stay_symmetric():
    from types import SimpleNamespace

    from uavsim.gap.workflow import SAT_DUTY_SHIFT, read_off_relays

    spec = lambda h: SimpleNamespace(kind="np-mrft", beta=-0.73, h=h)  # noqa: E731
    session = SimpleNamespace(runs=[SimpleNamespace(spec=spec(1.0)), SimpleNamespace(spec=spec(3.0))])
    feats = lambda amp3, duty3: [{"amplitude": 0.0, "period": 0.0, "duty": 0.5},  # noqa: E731
                                 {"amplitude": math.log(amp3), "period": 0.0, "duty": duty3}]
    sims = [feats(3.0, 0.5)] * 3
    # the larger cycle grew 1.8 times where the model's grew 3 times: a limit of 0.6 * 3 h
    (sat,) = read_off_relays(session, feats(1.8, 0.5), sims)
    assert sat.params["limit"] == pytest.approx(1.8)
    # the same growth with the duty moved by 0.1 (asymmetric limits moved it 0.06-0.16 on the testbed):
    # limits unequal both ways, not the vocabulary's saturation
    assert SAT_DUTY_SHIFT < 0.06
    assert read_off_relays(session, feats(1.8, 0.6), sims) == []
    # a cycle that grew as the model's (or more) reads nothing
    assert read_off_relays(session, feats(2.9, 0.5), sims) == []


def test_dead_zone_read_needs_the_step_runs_to_settle():
    from types import SimpleNamespace

    from uavsim.gap.workflow import HUNT_SWING, read_off_relays, step_hunting

    spec = lambda h: SimpleNamespace(kind="np-mrft", beta=-0.73, h=h)  # noqa: E731
    step = SimpleNamespace(kind="step", beta=None, h=None)
    session = SimpleNamespace(runs=[SimpleNamespace(spec=spec(1.0)), SimpleNamespace(spec=spec(3.0)),
                                    SimpleNamespace(spec=step)])  # fmt: skip
    k = np.arange(800)
    settled = 1.0 - np.exp(-k / 40.0)
    # play in the loop: a relay's square wave passes as through a dead zone, but the held command
    # keeps the steps' PD loop swinging (testbed backlashes: 0.49-1.56 of the step beyond the model)
    hunting = settled + 0.3 * np.sin(2 * np.pi * k / 60.0)
    feats = lambda amp3, trace: [{"amplitude": 0.0, "period": 0.0, "duty": 0.5},  # noqa: E731
                                 {"amplitude": math.log(amp3), "period": 0.0, "duty": 0.5}, {"_trace": trace}]
    sims = [feats(3.0, settled)] * 3
    # the larger cycle grew 4 times where the model's grew 3 times: r = 4 / 3 = (3 - w) / (3 (1 - w))
    (dz,) = read_off_relays(session, feats(4.0, settled), sims)
    assert dz.name == "dead_zone" and dz.params["width"] == pytest.approx(1.0 / 3.0)
    assert step_hunting(session, feats(4.0, settled), sims) == pytest.approx(0.0, abs=1e-12)
    swing = step_hunting(session, feats(4.0, hunting), sims)
    assert swing == pytest.approx(0.6, rel=0.05) and swing > HUNT_SWING
    assert read_off_relays(session, feats(4.0, hunting), sims) == []
    # a cycle that grew only a little more than the model's reads nothing
    assert read_off_relays(session, feats(3.3, settled), sims) == []
    # the same growth with the duty moved (a bias moved it 0.09-0.10 on the testbed): not a dead zone
    moved = feats(4.0, settled)
    moved[1]["duty"] = 0.6
    assert read_off_relays(session, moved, sims) == []
