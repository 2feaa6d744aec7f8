"""The model noise's colour: a staircase's roughness, coloured model noise in the simulation, its screen."""

import dataclasses
import math

import numpy as np
import pytest

from uavsim.errors import UserError
from uavsim.formats.session import (
    EffectSpec,
    Run,
    RunData,
    RunSpec,
    SessionError,
    read_session,
    write_session,
)
from uavsim.gap.colour import noise_colour
from uavsim.gap.features import run_features
from uavsim.gap.hidden import hidden_session
from uavsim.gap.simulate import Episode, batch_effects, simulate
from uavsim.noise.models import ColouredNoise


def _step_features(y: np.ndarray, t: np.ndarray) -> dict:
    spec = RunSpec("s.csv", "step", kp=1.0, kd=0.1, derivative_filter_hz=10.0, step=1.0, step_time=0.5)
    return run_features(spec, t, y, np.zeros_like(t))


def test_a_staircases_roughness_moves_smoothly_as_its_stairs_lengthen():
    # slow noise quantized ever more coarsely: once half the samples repeat, a MAD of the second
    # difference drops to zero (log 1e-9, ~15 below its neighbours); the level of the moving samples
    # weighted by their share does not jump
    rng = np.random.default_rng(1)
    rate = 200.0
    t = np.arange(int(6 * rate)) / rate
    y0 = np.where(t >= 0.5, 1 - np.exp(-(t - 0.5) / 0.1), 0.0)
    slow = np.convolve(rng.standard_normal(t.size + 19), np.ones(20) / math.sqrt(20), mode="valid") * 0.01
    feats = [_step_features(np.round((y0 + slow) / q) * q, t) for q in np.geomspace(0.002, 0.04, 14)]
    rep = np.array([f["repeat"] for f in feats])
    lvl = np.array([f["resid"] for f in feats])
    assert rep[0] < 0.3 and rep[-1] > 0.85  # from a few repeats to long stairs
    assert np.all(lvl > -8) and np.max(np.abs(np.diff(lvl))) < 1.0
    # the first repeats move the level by little from the unquantized noise's
    assert abs(lvl[0] - _step_features(y0 + slow, t)["resid"]) < 0.5


def test_coloured_model_noise_sits_where_the_vocabularys_noise_does():
    fx = batch_effects(["none", "quantization", "noise"], [0.0, 0.01, 0.002], 0.003, 200.0, noise_corner_hz=4.0)
    names = [type(e).__name__ for e in fx]
    i = names.index("ColouredNoise")
    assert names[i + 1:] and names.index("Quantization") > i
    coloured = fx[i]
    assert isinstance(coloured, ColouredNoise) and coloured.high_hz == 4.0 and coloured.order == 2
    np.testing.assert_allclose(coloured.std, 0.003)
    # the extra noise of the third episode stays white beside it, not folded into the coloured std
    white = fx[i + 1]
    np.testing.assert_allclose(np.asarray(white.std), [0.0, 0.0, 0.002])
    # without a corner: one white draw of both, as before
    plain = batch_effects(["none", "noise"], [0.0, 0.004], 0.003, 200.0)
    assert not any(isinstance(e, ColouredNoise) for e in plain)
    np.testing.assert_allclose(np.asarray(plain[-1].std), [0.003, 0.005])


def _measured(session, model, effect, value, seed):
    """The session's runs replaced by the model's flights with ``effect`` (the 'vehicle')."""
    sims = simulate(session, model, [Episode(i, effect, value) for i in range(len(session.runs))], seed=seed,
                    nthread=1)
    runs = [Run(r.spec, RunData(s.t, s.r, s.y, s.u)) for r, s in zip(session.runs, sims, strict=True)]
    return dataclasses.replace(session, runs=runs)


def test_the_screen_colours_the_noise_of_a_filtered_sensor_and_keeps_white_noise_white():
    base, truth = hidden_session(3, effect="quantization", loop="altitude")
    step = float(truth.params["step"])
    model = dataclasses.replace(base.model, noise_std=max(base.model.noise_std, 0.6 * step))
    with_it = dataclasses.replace(base, effects=[EffectSpec("quantization", {"step": step})])
    slow = _measured(base, dataclasses.replace(model, noise_corner_hz=3.0), "quantization", step, seed=11)
    white = _measured(base, model, "quantization", step, seed=11)
    got_slow = noise_colour(dataclasses.replace(slow, effects=with_it.effects), model, seed=0, nthread=1)
    got_white = noise_colour(dataclasses.replace(white, effects=with_it.effects), model, seed=0, nthread=1)
    assert got_slow.corner_hz in (2.0, 3.0, 5.0), got_slow
    assert got_white.corner_hz is None or got_white.corner_hz >= 10.0, got_white
    assert got_slow.gaps["white"] > 2 * min(got_slow.gaps.values())


def test_noise_corner_round_trips_in_the_session_and_is_checked(tmp_path):
    s, _ = hidden_session(1, effect="none", loop="pitch")
    s = dataclasses.replace(s, model=dataclasses.replace(s.model, noise_corner_hz=4.5))
    write_session(s, tmp_path / "s")
    back = read_session(tmp_path / "s")
    assert back.model.noise_corner_hz == 4.5
    plain = dataclasses.replace(s, model=dataclasses.replace(s.model, noise_corner_hz=None))
    write_session(plain, tmp_path / "p")
    assert "noise_corner_hz" not in (tmp_path / "p" / "session.toml").read_text()
    assert read_session(tmp_path / "p").model.noise_corner_hz is None
    toml = tmp_path / "s" / "session.toml"
    toml.write_text(toml.read_text().replace("noise_corner_hz = 4.5", "noise_corner_hz = 0.0"))
    with pytest.raises((SessionError, UserError), match="noise_corner_hz"):
        read_session(tmp_path / "s")
