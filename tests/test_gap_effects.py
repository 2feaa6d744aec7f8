"""Registry effects with one parameter per episode equal running each episode alone with a scalar.

The gap workflow fits effects by simulating many parameter values in one
batch with the registry effects themselves (``uavsim.gap.simulate.batch_effects``);
these tests pin that an (n,) parameter array is exactly n independent scalar
episodes, that identity values leave a signal untouched, and that validation
names the bad element.
"""

import numpy as np
import pytest

from uavsim.errors import UserError
from uavsim.gap.simulate import IDENTITY, batch_effects
from uavsim.lumped.params import LumpedParams
from uavsim.model.effects import make_effect
from uavsim.sim.runner import LoopBatch

RATE = 200.0
# name -> per-episode values (the last one the identity where the effect has one)
CASES = {
    "lag": [0.05, 0.013, 0.0],
    "rate_limit": [30.0, 4.0, np.inf],
    "dead_zone": [0.3, 0.05, 0.0],
    "saturation": [0.6, 1.5, np.inf],
    "bias": [-0.2, 0.3, 0.0],
    "quantization": [0.07, 0.3, 0.0],
    "sample_hold": [60.0, 100.0, 200.0],
    "lowpass": [12.0, 40.0, np.inf],
}
PARAM = {"lag": "T", "rate_limit": "rate", "dead_zone": "width", "saturation": "limit", "bias": "offset",
         "quantization": "step", "sample_hold": "rate_hz", "lowpass": "cutoff_hz"}  # fmt: skip


def _signal(n: int, T: int = 300) -> np.ndarray:
    rng = np.random.default_rng(1)
    return np.cumsum(rng.standard_normal((T, n)), axis=0) * 0.1  # (T, n): n episodes


@pytest.mark.parametrize("name", sorted(CASES))
def test_array_parameter_equals_separate_scalar_episodes(name):
    values = CASES[name]
    n = len(values)
    x = _signal(n)
    batch = make_effect(name, **{PARAM[name]: np.array(values)})
    batch.reset(n, RATE, np.random.default_rng(0))
    alone = [make_effect(name, **{PARAM[name]: v}) for v in values]
    for e in alone:
        e.reset(1, RATE, np.random.default_rng(0))
    for k in range(x.shape[0]):
        got = batch(x[k].copy(), k)
        want = np.concatenate([e(x[k, i:i + 1].copy(), k) for i, e in enumerate(alone)])
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("name", sorted(CASES))
def test_identity_value_leaves_the_signal_unchanged(name):
    ident = {**IDENTITY, "sample_hold": RATE}[name]
    x = _signal(2)
    e = make_effect(name, **{PARAM[name]: ident})
    e.reset(2, RATE, np.random.default_rng(0))
    for k in range(x.shape[0]):
        np.testing.assert_array_equal(e(x[k].copy(), k), x[k])


def test_scalar_lowpass_matches_scipy():
    from scipy import signal

    x = _signal(2)
    e = make_effect("lowpass", cutoff_hz=15.0)
    e.reset(2, RATE, np.random.default_rng(0))
    got = np.array([e(x[k].copy(), k) for k in range(x.shape[0])])
    sos = signal.butter(2, 15.0, fs=RATE, output="sos")
    want, _ = signal.sosfilt(sos, x, axis=0, zi=signal.sosfilt_zi(sos)[:, :, None] * x[0][None, None, :])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)


def test_noise_array_scales_one_draw_per_episode():
    std = np.array([0.0, 0.002, 0.01])
    e = make_effect("noise", std=std)
    e.reset(3, RATE, np.random.default_rng(3))
    z = np.random.default_rng(3).standard_normal((50, 3))
    got = np.array([e(np.zeros(3), k) for k in range(50)])
    np.testing.assert_array_equal(got, std * z)


def test_force_effects_take_per_episode_parameters():
    drag = np.full((3, 3), 2.0)
    vel = np.zeros((3, 3))
    wind = make_effect("wind", speed=[0.0, 3.0, 5.0], direction_deg=[0.0, 90.0, 30.0])
    wind.reset(3, RATE, np.random.default_rng(0), drag)
    pull = make_effect("pull", force_N=[5.0, 10.0, 0.0], t_start=[0.0, 1.0, 0.0], t_release=[2.0, 3.0, 1.0],
                       ramp_s=[0.0, 0.5, 0.0])  # fmt: skip
    pull.reset(3, RATE, np.random.default_rng(0), drag)
    for i in range(3):
        w1 = make_effect("wind", speed=wind.speed[i], direction_deg=wind.direction_deg[i])
        w1.reset(1, RATE, np.random.default_rng(0), drag[:1])
        np.testing.assert_allclose(wind.force(0.0, vel)[i], w1.force(0.0, vel[:1])[0], atol=1e-12)
        p1 = make_effect("pull", force_N=pull.force_N[i], t_start=pull.t_start[i], t_release=pull.t_release[i],
                         ramp_s=pull.ramp_s[i])  # fmt: skip
        p1.reset(1, RATE, np.random.default_rng(0), drag[:1])
        for t in (0.5, 1.2, 1.9, 2.5):
            np.testing.assert_array_equal(pull.force(t, vel)[i], p1.force(t, vel[:1])[0])


def test_model_effects_in_one_batch_equal_separate_batches():
    p = LumpedParams("altitude", K=1.0, T_prop=0.05, T1=0.8, tau=0.01)
    relay = lambda e: np.where(e >= 0, 1.0, -1.0)  # noqa: E731  deterministic, noise-free
    fx = [make_effect("delay", delay=[0.0, 0.03]), make_effect("gain", factor=[1.5, 0.7])]
    both = LoopBatch([p, p], dt=0.001, effects=fx, seed=0, nthread=1).run(relay, 1.0, reference=0.1)
    for i, (d, g) in enumerate(((0.0, 1.5), (0.03, 0.7))):
        fx1 = [make_effect("delay", delay=d), make_effect("gain", factor=g)]
        one = LoopBatch([p], dt=0.001, effects=fx1, seed=0, nthread=1).run(relay, 1.0, reference=0.1)
        np.testing.assert_allclose(both.y[i], one.y[0], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize(
    ("name", "params", "message"),
    [
        ("lag", {"T": [0.05, -0.01, 0.02]}, r"T must be >= 0 s .*got -0.01 \(episode 1\)"),
        ("saturation", {"limit": [1.0, 0.0]}, r"limit must be > 0, got 0.0 \(episode 1\)"),
        ("dead_zone", {"width": [0.1, np.nan]}, r"width must be a finite number, got nan \(episode 1\)"),
        ("delay", {"delay": [0.1, 1.5]}, r"delay 1.5 s is longer than the 1 s the buffers hold \(episode 1\)"),
        ("gain", {"factor": -1.0}, r"factor must be > 0, got -1.0$"),
        ("quantization", {"step": "big"}, r"step must be a finite number, got 'big'"),
        ("lowpass", {"cutoff_hz": [[1.0, 2.0]]}, r"cutoff_hz must be a number \(or inf\) or an \(n,\) array"),
    ],
)
def test_validation_names_the_bad_element(name, params, message):
    with pytest.raises(UserError, match=message):
        make_effect(name, **params)


def test_batch_size_mismatch_is_a_user_error():
    e = make_effect("bias", offset=[0.1, 0.2])
    with pytest.raises(UserError, match="offset has 2 values, the batch has 3 episodes"):
        e.reset(3, RATE, np.random.default_rng(0))
    e = make_effect("sample_hold", rate_hz=[60.0, 300.0])
    with pytest.raises(UserError, match=r"rate_hz 300.0 exceeds the control rate 200.0 Hz \(episode 1\)"):
        e.reset(2, RATE, np.random.default_rng(0))


def test_batch_effects_builds_per_episode_registry_effects():
    fx = batch_effects(["delay", "gain", "lag", "none"], [0.02, 1.5, 0.04, 0.0], 0.001, RATE,
                       base={"bias": 0.1})  # fmt: skip
    by = {e.name: e for e in fx}
    assert [e.name for e in fx] == ["delay", "gain", "lag", "bias", "noise"]  # unused effects are left out
    np.testing.assert_array_equal(by["delay"].delay, [0.02, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(by["gain"].factor, [1.0, 1.5, 1.0, 1.0])
    np.testing.assert_array_equal(by["lag"].T, [0.0, 0.0, 0.04, 0.0])
    np.testing.assert_array_equal(by["bias"].offset, [0.1] * 4)


def test_noise_level_adds_in_quadrature():
    fx = batch_effects(["noise", "none"], [0.004, 0.0], 0.003, RATE)
    (meas,) = fx
    np.testing.assert_allclose(meas.std, [0.005, 0.003])
    meas.reset(2, RATE, np.random.default_rng(3))
    y = np.array([meas(np.zeros(2), k) for k in range(20000)])
    np.testing.assert_allclose(y.std(axis=0), [0.005, 0.003], rtol=0.03)
