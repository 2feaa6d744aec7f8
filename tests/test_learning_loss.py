"""J-weighted softmax loss: value, the paper's gradient J_il (p_i - y_i), finite differences, autograd."""

import numpy as np
import pytest
import torch

from uavsim.learning.loss import (
    JWeightedLoss,
    expected_log_j_loss,
    jweighted_cross_entropy,
    jweighted_cross_entropy_reference,
)
from uavsim.learning.model import IdentNet, NetConfig


def _case(B=5, n=7, seed=0):
    g = torch.Generator().manual_seed(seed)
    a = torch.randn(B, n, generator=g, dtype=torch.float64)
    labels = torch.randint(0, n, (B,), generator=g)
    J = 1.0 + 3.0 * torch.rand(n, n, generator=g, dtype=torch.float64)
    J.fill_diagonal_(1.0)
    return a, labels, J


def _numpy_loss(a, labels, J):
    """Independent numpy value of mean_b -log(exp(J_lb,l a_l) / sum_j exp(J_j,l a_j))."""
    total = 0.0
    for b, lab in enumerate(labels):
        z = J[:, lab] * a[b]
        z = z - z.max()
        total += -(z[lab] - np.log(np.exp(z).sum()))
    return total / len(labels)


def test_value_matches_numpy():
    a, labels, J = _case()
    got = float(jweighted_cross_entropy(a, labels, J))
    assert got == pytest.approx(_numpy_loss(a.numpy(), labels.numpy(), J.numpy()), rel=1e-12)


def test_gradient_is_paper_term():
    """dL/da_i = J_il (p_i - y_i) / B with p the J-weighted softmax (paper eq. 26, batch mean)."""
    a, labels, J = _case()
    a.requires_grad_(True)
    jweighted_cross_entropy(a, labels, J).backward()
    an, ln, Jn = a.detach().numpy(), labels.numpy(), J.numpy()
    expected = np.zeros_like(an)
    for b, lab in enumerate(ln):
        z = Jn[:, lab] * an[b]
        p = np.exp(z - z.max())
        p /= p.sum()
        y = np.zeros_like(p)
        y[lab] = 1.0
        expected[b] = Jn[:, lab] * (p - y) / len(ln)
    np.testing.assert_allclose(a.grad.numpy(), expected, rtol=1e-12, atol=1e-15)


def test_gradient_matches_finite_differences():
    a, labels, J = _case(B=3, n=5, seed=3)
    a.requires_grad_(True)
    jweighted_cross_entropy(a, labels, J).backward()
    eps = 1e-6
    fd = np.zeros(a.shape)
    an = a.detach().numpy().copy()
    for idx in np.ndindex(*an.shape):
        hi, lo = an.copy(), an.copy()
        hi[idx] += eps
        lo[idx] -= eps
        fd[idx] = (_numpy_loss(hi, labels.numpy(), J.numpy()) - _numpy_loss(lo, labels.numpy(), J.numpy())) / (2 * eps)
    np.testing.assert_allclose(a.grad.numpy(), fd, rtol=1e-6, atol=1e-9)


def test_gradcheck_and_reference_autograd_agree():
    a, labels, J = _case(B=4, n=6, seed=5)
    a.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: jweighted_cross_entropy(x, labels, J), (a,))
    g1 = torch.autograd.grad(jweighted_cross_entropy(a, labels, J), a)[0]
    g2 = torch.autograd.grad(jweighted_cross_entropy_reference(a, labels, J), a)[0]
    torch.testing.assert_close(g1, g2)


def test_identity_J_is_plain_cross_entropy():
    a, labels, _ = _case()
    ones = torch.ones(a.shape[1], a.shape[1], dtype=torch.float64)
    ce = torch.nn.functional.cross_entropy(a, labels)
    assert float(jweighted_cross_entropy(a, labels, ones)) == pytest.approx(float(ce), rel=1e-12)


def test_costly_confusion_costs_more():
    """Same activations: the loss is larger when the runner-up class has the larger J."""
    a = torch.tensor([[1.0, 0.9, -5.0]])
    labels = torch.tensor([0])
    cheap = torch.tensor([[1.0, 1.0, 1.0], [1.1, 1.0, 1.0], [50.0, 1.0, 1.0]])
    costly = torch.tensor([[1.0, 1.0, 1.0], [3.0, 1.0, 1.0], [50.0, 1.0, 1.0]])
    assert float(jweighted_cross_entropy(a, labels, costly)) > float(jweighted_cross_entropy(a, labels, cheap))


def test_module_clips_J_and_trains_network():
    J = np.array([[1.0, 5e3], [0.5, 1.0]])
    loss = JWeightedLoss(J)
    assert float(loss.J.max()) == 1e3 and float(loss.J.min()) == 1.0
    net = IdentNet(NetConfig(channels=2, input_length=8, n_classes=2, hidden=[16, 8]))
    x = torch.randn(4, 2, 8)
    out = net(x)
    assert out.shape == (4, 2)
    loss(out, torch.tensor([0, 1, 0, 1])).backward()
    assert all(p.grad is not None for p in net.parameters())


def test_network_layout_is_papers():
    net = IdentNet(NetConfig(channels=2, input_length=400, n_classes=208))
    kinds = [type(m).__name__ for m in net.layers]
    assert kinds == ["Linear", "ReLU", "BatchNorm1d", "Dropout", "Linear", "ReLU", "BatchNorm1d",
                     "Dropout", "Linear"]
    lin = [m for m in net.layers if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in lin] == [(800, 3000), (3000, 1000), (1000, 208)]
    assert all(m.p == 0.4 for m in net.layers if isinstance(m, torch.nn.Dropout))


def _numpy_expected(a, labels, J, w):
    """Independent numpy value of mean_b [-log p_l + w sum_i p_i log J_il]."""
    total = 0.0
    for b, lab in enumerate(labels):
        z = a[b] - a[b].max()
        p = np.exp(z) / np.exp(z).sum()
        total += -np.log(p[lab]) + w * (p * np.log(J[:, lab])).sum()
    return total / len(labels)


def test_expected_matches_numpy_and_autograd():
    a, labels, J = _case(seed=3)
    got = float(expected_log_j_loss(a, labels, J, 2.5))
    assert got == pytest.approx(_numpy_expected(a.numpy(), labels.numpy(), J.numpy(), 2.5), rel=1e-12)
    a.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: expected_log_j_loss(x, labels, J, 2.5), (a,), eps=1e-6, atol=1e-8)


def test_expected_is_shift_invariant_and_ce_at_identity():
    a, labels, J = _case(seed=4)
    assert float(expected_log_j_loss(a - 40.0, labels, J, 5.0)) == pytest.approx(
        float(expected_log_j_loss(a, labels, J, 5.0)), rel=1e-12)
    ones = torch.ones_like(J)
    assert float(expected_log_j_loss(a, labels, ones, 5.0)) == pytest.approx(
        float(torch.nn.functional.cross_entropy(a, labels)), rel=1e-12)


def test_paper_loss_has_a_degenerate_minimum_the_expected_loss_has_not():
    """With J > 1 off the diagonal, sinking every activation lowers the paper's loss without separating
    classes (the reason it is not the default); the expected loss does not move."""
    a, labels, J = _case(B=6, n=5, seed=5)
    J = J + 0.01
    J.fill_diagonal_(1.0)
    paper = [float(jweighted_cross_entropy(a - s, labels, J)) for s in (0.0, 10.0, 100.0)]
    assert paper[0] > paper[1] > paper[2] and paper[2] < 1e-3
    exp = [float(expected_log_j_loss(a - s, labels, J, 5.0)) for s in (0.0, 10.0, 100.0)]
    assert exp == pytest.approx([exp[0]] * 3, rel=1e-9)


def test_expected_costly_confusion_costs_more_and_kinds_checked():
    a = torch.tensor([[1.0, 0.9, -5.0]])
    labels = torch.tensor([0])
    cheap = torch.tensor([[1.0, 1.0, 1.0], [1.1, 1.0, 1.0], [50.0, 1.0, 1.0]])
    costly = torch.tensor([[1.0, 1.0, 1.0], [3.0, 1.0, 1.0], [50.0, 1.0, 1.0]])
    assert float(JWeightedLoss(costly)(a, labels)) > float(JWeightedLoss(cheap)(a, labels))
    with pytest.raises(ValueError, match="loss kind"):
        JWeightedLoss(cheap, kind="focal")
    with pytest.raises(ValueError, match="weight"):
        JWeightedLoss(cheap, weight=-1.0)


def test_per_sample_costs_equal_the_J_loss_at_J_columns():
    # a set with costs uses them in place of J's columns: the same loss when they are those columns
    a, labels, J = _case(B=6, n=5, seed=6)
    costs = J[:, labels].T.clone()
    for kind in ("expected", "paper"):
        fn = JWeightedLoss(J, kind=kind, weight=2.0)
        assert float(fn(a, labels, costs)) == pytest.approx(float(fn(a, labels)), rel=1e-6)
    ga = a.clone().requires_grad_(True)
    JWeightedLoss(J, weight=2.0)(ga, labels, costs).backward()
    gb = a.clone().requires_grad_(True)
    JWeightedLoss(J, weight=2.0)(gb, labels).backward()
    assert torch.allclose(ga.grad, gb.grad, rtol=1e-6, atol=1e-9)


def test_per_sample_costs_move_the_loss_and_unstable_is_the_clip():
    # a sample whose own process finds the second class's answer unstable costs more than J says,
    # and an unstable (inf) or uncomputed (nan) cost is the clip's worst, never a nan loss
    a = torch.tensor([[1.0, 0.9, -5.0]], dtype=torch.float64)
    labels = torch.tensor([0])
    J = torch.tensor([[1.0, 1.0, 1.0], [1.1, 1.0, 1.0], [50.0, 1.0, 1.0]], dtype=torch.float64)
    fn = JWeightedLoss(J, weight=5.0)
    own = torch.tensor([[1.0, float("inf"), 50.0]], dtype=torch.float64)
    assert float(fn(a, labels, own)) > float(fn(a, labels)) + 1.0
    clipped = torch.tensor([[1.0, 1e3, 50.0]], dtype=torch.float64)
    assert float(fn(a, labels, own)) == pytest.approx(float(fn(a, labels, clipped)), rel=1e-12)
    nan = torch.tensor([[1.0, float("nan"), 50.0]], dtype=torch.float64)
    assert float(fn(a, labels, nan)) == pytest.approx(float(fn(a, labels, clipped)), rel=1e-12)
