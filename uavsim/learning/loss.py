"""J-weighted softmax cross-entropy (paper eq. 25-26).

For activations ``a`` (n,) of a sample of true class ``l`` and the relative
sensitivity matrix ``J`` (rows predicted, columns true, clipped to [1, 1e3]):

    p_i = exp(J_il a_i) / sum_j exp(J_jl a_j)          L = -log p_l
    dL/da_i = J_il (p_i - y_i)                          (y one-hot at l)

A misclassification into a class whose controller would deteriorate the true
process a lot (large ``J_il``) is punished harder. The loss is a
``torch.autograd.Function`` whose backward is exactly the paper's term (averaged
over the batch), so training uses the published gradient rather than whatever
autograd would derive; ``jweighted_cross_entropy_reference`` is the same loss by
plain autograd, kept as an independent check.

    loss = JWeightedLoss(J)(a, labels)          # a (B, n) float, labels (B,) int64
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

__all__ = ["J_CLIP", "JWeightedCE", "jweighted_cross_entropy", "jweighted_cross_entropy_reference", "JWeightedLoss"]

#: J is clipped to this range as in the authors' code (an unstable pair is 1e3)
J_CLIP = (1.0, 1e3)


class JWeightedCE(torch.autograd.Function):
    """Mean over the batch of ``-log softmax(J[:, l] * a)_l`` with the paper's backward."""

    @staticmethod
    def forward(ctx, a: torch.Tensor, labels: torch.Tensor, J: torch.Tensor) -> torch.Tensor:
        w = J[:, labels].T.to(a.dtype)  # (B, n): J_il for each sample's label l
        z = w * a
        logp = torch.log_softmax(z, dim=1)
        loss = -logp.gather(1, labels[:, None]).mean()
        ctx.save_for_backward(w, logp, labels)
        return loss

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        w, logp, labels = ctx.saved_tensors
        p = logp.exp()
        p[torch.arange(p.shape[0]), labels] -= 1.0  # p - y
        grad = w * p * (grad_out / p.shape[0])
        return grad, None, None


def jweighted_cross_entropy(a: torch.Tensor, labels: torch.Tensor, J: torch.Tensor) -> torch.Tensor:
    """J-weighted loss, batch mean.

    Parameters
    ----------
    a : Tensor (B, n)
        Network activations.
    labels : Tensor (B,) int64
        True classes.
    J : Tensor (n, n)
        Relative sensitivity, rows predicted, columns true (already clipped).

    Returns
    -------
    Tensor ()
    """
    return JWeightedCE.apply(a, labels, J)


def jweighted_cross_entropy_reference(a: torch.Tensor, labels: torch.Tensor, J: torch.Tensor) -> torch.Tensor:
    """The same loss by plain autograd (reference for tests)."""
    z = J[:, labels].T.to(a.dtype) * a
    return nn.functional.cross_entropy(z, labels)


class JWeightedLoss(nn.Module):
    """``nn.Module`` wrapper holding the clipped J as a buffer (moves with ``.to(device)``)."""

    def __init__(self, J: np.ndarray | torch.Tensor):
        super().__init__()
        Jt = torch.as_tensor(np.asarray(J, dtype=np.float32))
        if Jt.ndim != 2 or Jt.shape[0] != Jt.shape[1]:
            raise ValueError(f"J must be square, got shape {tuple(Jt.shape)}")
        self.register_buffer("J", Jt.clamp(*J_CLIP))

    def forward(self, a: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        return jweighted_cross_entropy(a, labels, self.J)
