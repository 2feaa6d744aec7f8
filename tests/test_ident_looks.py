"""Every steady cycle of a relay run for the class: the mean cycle and the cycles as independent looks.

Exact 200 Hz relay cycles of attitude grid classes (``test_identify._attitude_cycles``) with white
measurement noise added to the output: the mean of the response cycles
(``features(..., inputs="mean")``) is closer to the noise-free input than the last cycle alone, and
without noise it is the last cycle's input up to the resampling of cycles a sample apart. A
stand-in network that is a Gaussian likelihood of the noise-free inputs (its activations
``-|x - x_c|^2 / 2 s^2`` over the exact cycle with its output moved by a few samples) has the
product of the looks' beliefs (``cycle_activations``, ``"logsum"``) as its posterior: the combined
belief of the run's noisy cycles puts more on the true template than the last cycle's.
"""

import numpy as np
import pytest
from test_identify import _attitude_cycles

from uavsim.data.preprocess import features, mean_cycle
from uavsim.errors import UserError


@pytest.fixture(scope="module")
def cycles():
    g, b, cs, truth, sim, q_opt = _attitude_cycles(5)
    return b, sim


def _noisy(y: np.ndarray, level: float, seed: int) -> np.ndarray:
    """``y`` plus white noise of ``level`` times its steady half peak-to-peak (the relay's switching unchanged)."""
    tail = y[y.size // 2:]
    return y + level * 0.5 * (tail.max() - tail.min()) * np.random.default_rng(seed).standard_normal(y.size)


def _feat(y, u, L, inputs):
    return features(y, u, 200.0, 1.0, 0.0, L, inputs=inputs)


def test_mean_cycle_is_the_last_cycle_without_noise_and_closer_to_it_with_noise(cycles):
    b, sim = cycles
    L = b.input_length
    for j in range(sim["u"].shape[0]):
        y, u = -sim["e"][j], sim["u"][j]
        last, mean = _feat(y, u, L, "last"), _feat(y, u, L, "mean")
        assert mean.response_cycles >= 3 and mean.x.shape == last.x.shape
        n_last = int(np.count_nonzero(last.x[1]))
        assert abs(int(np.count_nonzero(mean.x[1])) - n_last) <= 1
        assert set(np.unique(mean.x[1][mean.x[1] != 0])) <= {-1.0, 1.0}
        # exact cycles: the same input up to cycles a sample apart read at the mean length
        assert np.sqrt(np.mean((mean.x - last.x) ** 2)) < 0.05
        err_last, err_mean = [], []
        for seed in range(5):
            yn = _noisy(y, 0.15, seed)
            err_last.append(np.sqrt(np.mean((_feat(yn, u, L, "last").x[0] - last.x[0]) ** 2)))
            err_mean.append(np.sqrt(np.mean((_feat(yn, u, L, "mean").x[0] - last.x[0]) ** 2)))
        assert np.mean(err_mean) < 0.75 * np.mean(err_last), (err_mean, err_last)


def test_mean_cycle_lines_cycles_up_at_their_rising_edges():
    """Two cycles of one waveform at 40 and 44 samples: their mean read at 42 is that waveform."""
    shape = lambda n: np.sin(2 * np.pi * np.arange(n) / n)  # noqa: E731
    y = np.concatenate([shape(40), shape(44), [0.0]])
    s = np.concatenate([np.where(np.arange(40) < 20, 1.0, -1.0), np.where(np.arange(44) < 22, 1.0, -1.0), [1.0]])
    ym, sm = mean_cycle(y, s, np.array([0, 40, 84]))
    assert ym.size == 42 and np.max(np.abs(ym - shape(42))) < 0.01
    assert np.array_equal(sm, np.where(np.arange(42) < 21, 1.0, -1.0))


def test_each_look_is_a_one_cycle_input_and_the_last_is_the_training_input(cycles):
    b, sim = cycles
    y, u = -sim["e"][0], sim["u"][0]
    last, each = _feat(y, u, b.input_length, "last"), _feat(y, u, b.input_length, "each")
    assert each.looks.shape == (each.response_cycles, 2, b.input_length)
    assert np.array_equal(each.looks[-1], last.x) and np.array_equal(each.x, last.x)
    for x in each.looks:
        assert np.isclose(x[0].max(), 1.0) and np.isclose(x[0].min(), -1.0)
    with pytest.raises(UserError, match="inputs"):
        features(y, u, 200.0, 1.0, 0.0, b.input_length, inputs="median")
    with pytest.raises(UserError, match="inputs"):
        features(y, u, 200.0, 1.0, 0.0, b.input_length, cycles=2, inputs="mean")


class _Likelihood:
    """A stand-in network: activations ``-|x - x_c|^2 / 2 s^2`` over templates ``x_c`` (tests only)."""

    def __init__(self, templates: np.ndarray, s: float):
        self.templates, self.s = templates.reshape(len(templates), -1).astype(np.float64), s
        self.n_classes, self.input_length = len(templates), templates.shape[-1]

    def activations(self, x):
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.templates.shape[1])
        d = ((x[:, None, :] - self.templates[None]) ** 2).sum(axis=-1)
        return (-d / (2 * self.s**2)).astype(np.float32)


def test_combined_looks_believe_the_true_class_more_than_the_last_cycle(cycles):
    from dataclasses import replace

    from uavsim.ident.select import cycle_activations
    from uavsim.learning.decision import softmax

    b, sim = cycles
    L = b.input_length
    p_last, p_each = [], []
    for j in range(sim["u"].shape[0]):
        clean = _feat(-sim["e"][j], sim["u"][j], L, "last")
        # templates: the exact cycle with its output moved -3..3 samples against the relay (delay classes)
        net = _Likelihood(np.stack([_shifted(clean.x, k) for k in range(-3, 4)]), s=0.3)
        b = replace(b, predictor=net, temperature=1.0)
        for seed in range(6):
            yn = _noisy(-sim["e"][j], 0.3, 10 * j + seed)
            one = _feat(yn, sim["u"][j], L, "last")
            each = _feat(yn, sim["u"][j], L, "each")
            assert np.array_equal(cycle_activations(b, one), net.activations(one.x))
            a = cycle_activations(b, each, combine="logsum")
            # the normalized product of the looks' beliefs
            pl = softmax(net.activations(each.looks))
            prod = np.prod(pl, axis=0) / np.prod(pl, axis=0).sum()
            assert np.allclose(softmax(a)[0], prod, atol=1e-6)
            p_last.append(softmax(net.activations(one.x))[0, 3])
            p_each.append(softmax(a)[0, 3])
            for how in ("logmean", "mean"):
                assert np.isclose(softmax(cycle_activations(b, each, combine=how)).sum(), 1.0)
    assert np.mean(p_each) > np.mean(p_last) + 0.15, (p_each, p_last)
    with pytest.raises(UserError, match="combine"):
        cycle_activations(b, each, combine="max")


def _shifted(x: np.ndarray, k: int) -> np.ndarray:
    """An input with its output channel rolled by ``k`` samples within the cycle."""
    x = x.copy()
    n = int(np.count_nonzero(x[1]))
    x[0, -n:] = np.roll(x[0, -n:], k)
    return x


def test_only_the_response_cycles_that_fit_the_input_are_looked_at():
    """Steady cycles of 44, 44, 40 and 40 samples with an input of 42: the looks and the mean are the two last."""
    shape = lambda n: np.sin(2 * np.pi * np.arange(n) / n)  # noqa: E731
    relay = lambda n: np.where(np.arange(n) < n // 2, 1.0, -1.0)  # noqa: E731
    lens = (40, 44, 44, 40, 40)
    y = np.concatenate([shape(n) for n in lens] + [[0.0, 0.1]])
    u = np.concatenate([relay(n) for n in lens] + [[1.0, 1.0]])
    u = np.concatenate([[-1.0], u])
    y = np.concatenate([[0.0], y])
    last = features(y, u, 200.0, 1.0, 0.0, 42)
    each = features(y, u, 200.0, 1.0, 0.0, 42, inputs="each")
    mean = features(y, u, 200.0, 1.0, 0.0, 42, inputs="mean")
    assert last.response_cycles == 4 and each.input_cycles == mean.input_cycles == 2
    assert each.looks.shape == (2, 2, 42) and np.array_equal(each.looks[-1], last.x)
    assert np.allclose(mean.x, last.x, atol=1e-6) and mean.inputs == "mean"


def test_identification_records_what_the_network_saw(cycles):
    """By default (``IDENT_INPUTS`` empty) the network sees the last cycle, as in training; asked for more,
    the answer says what it saw and from how many cycles."""
    from uavsim.ident.cycle import IDENT_INPUTS, extract_cycle
    from uavsim.ident.session import identify_cycle

    b, sim = cycles
    y, u = -sim["e"][0], sim["u"][0]
    assert b.loop not in IDENT_INPUTS
    assert extract_cycle(y, u, rate_hz=200.0, h=1.0, bias=0.0, bundle=b).inputs == "last"
    for inputs in ("last", "mean", "each"):
        f = extract_cycle(y, u, rate_hz=200.0, h=1.0, bias=0.0, bundle=b, inputs=inputs)
        ans = identify_cycle(f, b, decision="argmax", combine="mean")
        osc = ans["oscillation"]
        assert osc["inputs"] == inputs and osc["input_cycles"] == (1 if inputs == "last" else f.response_cycles)
