"""Losses that weigh a misclassification by what its controller costs: J.

Two losses over the relative sensitivity matrix ``J`` (rows predicted, columns
true, clipped to [1, 1e3]):

* ``"expected"`` (the default): cross-entropy plus ``w`` times the expected log-J
  of the softmax,

      L = -log p_l + w * sum_i p_i log J_il          p = softmax(a)

  It is shift-invariant in ``a`` (as a classifier's loss must be), equals plain
  cross-entropy when every answer is as good as the truth (``J = 1``), and moves
  probability away from answers whose gains would deteriorate the true process,
  in proportion to the log of how much (an unstable answer, J = 1e3, costs 6.9;
  a 10% worse one 0.1).
* ``"paper"``: the paper's J-weighted softmax cross-entropy (eq. 25-26), below.

Why not the paper's loss by default: ``z_i = J_il a_i`` is not shift-invariant.
Where ``J_il > J_ll`` for every wrong class ``i`` (J of the grid's table at the
control rate: no two classes' answers tie exactly), driving every activation
very negative makes every wrong ``z_i`` more negative than the right one and
the loss falls towards 0 without the network telling classes apart. Measured on
the altitude set with the table's J: validation mean J 47.8 and the best epoch
the first. With the continuous rule's J (ties J = 1 along Omega) that minimum
was masked.

The paper's loss:

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

A set whose samples lie off the class centres carries each sample's own cost
vector (``uavsim.data.costs``): ``loss(a, labels, costs)`` with ``costs`` (B, n)
uses row ``b`` in place of ``J[:, l_b]`` (both losses; clipped alike), so the
same loss weighs each sample by what each answer costs its own process.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

__all__ = ["J_CLIP", "LOSS_KINDS", "JWeightedCE", "jweighted_cross_entropy", "jweighted_cross_entropy_reference",
           "expected_log_j_loss", "JWeightedLoss", "clip_costs"]

#: J is clipped to this range as in the authors' code (an unstable pair is 1e3)
J_CLIP = (1.0, 1e3)
#: the losses ``JWeightedLoss`` knows
LOSS_KINDS = ("expected", "paper")


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


def expected_log_j_loss(a: torch.Tensor, labels: torch.Tensor, J: torch.Tensor, weight: float, *,
                        costs: torch.Tensor | None = None) -> torch.Tensor:
    """Cross-entropy plus ``weight`` times the softmax's expected log J, batch mean.

    Parameters
    ----------
    a : Tensor (B, n)
        Network activations.
    labels : Tensor (B,) int64
        True classes.
    J : Tensor (n, n)
        Relative sensitivity, rows predicted, columns true (already clipped to >= 1).
    weight : float
        Weight of the expected log J (0: plain cross-entropy).
    costs : Tensor (B, n), optional
        Each sample's own cost of every answer (already clipped to >= 1), in place of ``J[:, labels].T``.

    Returns
    -------
    Tensor ()
    """
    logp = torch.log_softmax(a, dim=1)
    ce = -logp.gather(1, labels[:, None]).squeeze(1)
    rows = J[:, labels].T if costs is None else costs
    cost = (logp.exp() * torch.log(rows.to(a.dtype))).sum(dim=1)
    return (ce + weight * cost).mean()


class JWeightedLoss(nn.Module):
    """``nn.Module`` holding the clipped J as a buffer (moves with ``.to(device)``).

    Parameters
    ----------
    J : array (n, n)
        Relative sensitivity, rows predicted, columns true.
    kind : str
        ``"expected"`` (cross-entropy plus ``weight`` x expected log J) or ``"paper"``.
    weight : float
        The expected log J's weight (``"expected"`` only).
    """

    def __init__(self, J: np.ndarray | torch.Tensor, *, kind: str = "expected", weight: float = 5.0):
        super().__init__()
        Jt = torch.as_tensor(np.asarray(J, dtype=np.float32))
        if Jt.ndim != 2 or Jt.shape[0] != Jt.shape[1]:
            raise ValueError(f"J must be square, got shape {tuple(Jt.shape)}")
        if kind not in LOSS_KINDS:
            raise ValueError(f"loss kind {kind!r}: known {', '.join(LOSS_KINDS)}")
        if not weight >= 0:
            raise ValueError(f"loss weight must be >= 0, got {weight}")
        self.kind, self.weight = kind, float(weight)
        self.register_buffer("J", Jt.clamp(*J_CLIP))

    def forward(self, a: torch.Tensor, labels: torch.Tensor, costs: torch.Tensor | None = None) -> torch.Tensor:
        """Batch loss; ``costs`` (B, n): the samples' own cost vectors (inf / NaN: the clip's worst)."""
        if costs is not None:
            costs = clip_costs(costs)
        if self.kind == "paper":
            if costs is None:
                return jweighted_cross_entropy(a, labels, self.J)
            # the paper's weights w_i = cost_i per sample: J whose column l_b is the row (per-sample J)
            return _per_sample_paper(a, labels, costs)
        return expected_log_j_loss(a, labels, self.J, self.weight, costs=costs)


def clip_costs(costs: torch.Tensor) -> torch.Tensor:
    """Per-sample costs clipped to ``J_CLIP``; inf (unstable) and NaN (not computed) to the clip's worst."""
    return torch.nan_to_num(costs, nan=J_CLIP[1], posinf=J_CLIP[1]).clamp(*J_CLIP)


def _per_sample_paper(a: torch.Tensor, labels: torch.Tensor, costs: torch.Tensor) -> torch.Tensor:
    return nn.functional.cross_entropy(costs.to(a.dtype) * a, labels)
