"""The class decision: least expected J under the softmax (Bayes) against the most likely class."""

import numpy as np
import pytest

from uavsim.errors import UserError
from uavsim.learning.decision import (
    COST_CLIP,
    TEMPERATURE_RANGE,
    decide,
    expected_cost,
    fit_temperature,
    softmax,
)


def _toy():
    """Class 0 is the most likely, but its gains are unstable on class 1 (the second most likely);
    class 2 is near-optimal on both."""
    J = np.array([[1.0, np.inf, 1.5],
                  [1.3, 1.0, 1.4],
                  [1.05, 1.08, 1.0]])
    p = np.array([0.55, 0.40, 0.05])
    return J, np.log(p)


def test_bayes_avoids_the_class_unstable_on_the_runner_up():
    J, a = _toy()
    arg = decide(a, J, decision="argmax")
    bay = decide(a, J)
    assert arg.cls.tolist() == [0] and bay.cls.tolist() == [2]
    # geometric-mean clipped J by hand: the unstable pair costs the clip's 1e3
    p = np.array([0.55, 0.40, 0.05])
    assert arg.expected_J[0] == pytest.approx(COST_CLIP[1] ** 0.40 * 1.5**0.05)
    assert bay.expected_J[0] == pytest.approx(1.05**0.55 * 1.08**0.40)
    assert bay.p[0] == pytest.approx(p)
    assert expected_cost(p, J)[0].argmin() == 2


def test_bayes_equals_argmax_where_classes_are_far_apart():
    """A confident network on a J that punishes every miss: the two decisions agree."""
    rng = np.random.default_rng(0)
    n = 7
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    J = 1.0 + 0.5 * (i - j) ** 2
    a = rng.normal(size=(50, n))
    a[np.arange(50), rng.integers(0, n, 50)] += 8.0
    assert np.array_equal(decide(a, J).cls, decide(a, J, decision="argmax").cls)
    # batched expected cost is the loop over inputs
    p = softmax(a)
    assert np.allclose(expected_cost(p, J), np.stack([np.log(np.clip(J, *COST_CLIP)) @ q for q in p]))


def test_the_decision_clips_as_the_loss_does():
    pytest.importorskip("torch")
    from uavsim.learning.loss import J_CLIP

    assert COST_CLIP == J_CLIP


def test_decision_errors():
    J, a = _toy()
    with pytest.raises(UserError, match="decision"):
        decide(a, J, decision="vote")
    with pytest.raises(UserError, match="cost matrix"):
        decide(a, None)
    with pytest.raises(UserError, match="shape"):
        decide(a, J[:2, :2])
    assert decide(a, None, decision="argmax").cls.tolist() == [0]


def test_temperature_recovered_from_labels_drawn_from_the_belief():
    """Labels drawn from softmax(a / 0.4): the fitted temperature is 0.4; a set the network never
    misclassifies ends at the sharp end of the range."""
    rng = np.random.default_rng(1)
    a = rng.normal(size=(4000, 5))
    p = softmax(a, 0.4)
    y = (rng.random((4000, 1)) > np.cumsum(p, axis=1)).sum(axis=1)
    assert fit_temperature(a, y) == pytest.approx(0.4, rel=0.1)
    assert fit_temperature(a, a.argmax(axis=1)) == pytest.approx(TEMPERATURE_RANGE[0], rel=0.01)
    # the temperature moves the Bayes decision, never argmax
    J, act = _toy()
    assert decide(act, J, temperature=0.01).cls.tolist() == [0]  # sure of class 0: (0.4 / 0.55)^100
    assert decide(act, J, decision="argmax", temperature=5.0).cls.tolist() == [0]


@pytest.mark.parametrize("p_runner_up_true,expected", [(0.4, "bayes"), (0.0, "argmax")])
def test_trainer_takes_bayes_unless_argmax_is_better_on_validation(p_runner_up_true, expected):
    """The toy belief on every input; the truth is class 1 (where class 0 is unstable) on a fraction of them.
    When it is, Bayes (class 2) costs less; when the network is always right, argmax does."""
    torch = pytest.importorskip("torch")
    from uavsim.learning.train import TrainData, _val_metrics

    J, a = _toy()
    n_in = 50
    y = np.zeros(n_in, np.int64)
    y[: int(round(p_runner_up_true * n_in))] = 1
    act = np.repeat(a[None, :], n_in, axis=0)
    data = TrainData(X=act.astype(np.float32), labels=y, J=J, attrs={}, classes={})
    m = _val_metrics(torch.nn.Identity(), torch.from_numpy(data.X), np.arange(n_in), data, torch.device("cpu"),
                     temperature=1.0)
    assert m["decision"] == expected and m["mean_J"] == min(m["mean_J_bayes"], m["mean_J_argmax"])
    assert m["mean_J_bayes"] == pytest.approx(np.mean(np.clip(J[2, y], *COST_CLIP)))
