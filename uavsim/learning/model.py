"""The paper's classifier: two fully connected hidden layers of 3000 and 1000 units.

Layer order follows the authors' code (NOTES.md section 2):
``FC 3000 -> ReLU -> BatchNorm -> Dropout 0.4 -> FC 1000 -> ReLU -> BatchNorm ->
Dropout 0.4 -> FC n_classes``. The input is one preprocessed cycle of C channels
and L samples (``uavsim.data.preprocess``), flattened to C*L; two departures, both
options of ``NetConfig`` and both computed from the input itself: radial-basis
features of the cycle's length appended (``period_features``), and the output
channel's cycle resampled to a fixed number of points (``phase_samples``,
``phase_resample``). The outputs are the
raw activations ``a``; the J-weighted softmax of ``uavsim.learning.loss`` is
applied only in training, and the predicted class is ``argmax a``.

    from uavsim.learning.model import NetConfig, IdentNet
    net = IdentNet(NetConfig(channels=2, input_length=400, n_classes=208))
    a = net(torch.zeros(8, 2, 400))        # (8, 208)
"""

from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass, field

import torch
from torch import nn

__all__ = ["NetConfig", "IdentNet", "InputMajorLinear", "phase_resample"]


def phase_resample(x: torch.Tensor, m: int) -> torch.Tensor:
    """Inputs (B, C, L) with channel 0's cycle resampled to ``m`` points, right-aligned (``NetConfig.phase_samples``).

    The cycle is where the last channel (the relay, +-1) is non-zero: ``n`` samples
    ending at ``L - 1``. Point ``k`` of ``m`` is the linear interpolation of channel 0
    at sample ``L - n + k (n - 1) / (m - 1)``; the row left of the ``m`` points is zero.
    An input with fewer than 2 cycle samples gets a zero row. The other channels are
    returned unchanged. ``uavsim.learning.export`` does the same in numpy.
    """
    B, C, L = x.shape
    n = (x[:, -1, :] != 0).sum(dim=1)
    step = (n - 1).clamp_min(0).to(x.dtype) / float(max(m - 1, 1))
    t = (L - n).to(x.dtype)[:, None] + torch.arange(m, dtype=x.dtype, device=x.device)[None, :] * step[:, None]
    i0 = t.floor().clamp(0, L - 1)
    w = t - i0
    i0 = i0.long()
    i1 = (i0 + 1).clamp(max=L - 1)
    y = x[:, 0, :]
    yp = torch.gather(y, 1, i0) * (1.0 - w) + torch.gather(y, 1, i1) * w
    yp = torch.where((n >= 2)[:, None], yp, torch.zeros_like(yp))
    row = torch.cat([torch.zeros(B, L - m, dtype=x.dtype, device=x.device), yp], dim=1)
    return torch.cat([row[:, None, :], x[:, 1:, :]], dim=1)


class InputMajorLinear(nn.Module):
    """``x W^T + b`` with ``W`` stored transposed, (in, out): for one input row at a time
    (identification) torch's matmul on this layout runs about twice as fast as ``nn.Linear``
    on one CPU thread (measured with ``uavsim bench infer``).

    ``weight_t`` (in_features, out_features), ``bias`` (out_features,).
    """

    def __init__(self, weight_t: torch.Tensor, bias: torch.Tensor):
        super().__init__()
        self.weight_t = nn.Parameter(weight_t.contiguous(), requires_grad=False)
        self.bias = nn.Parameter(bias.clone(), requires_grad=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.addmm(self.bias, x, self.weight_t)


@dataclass
class NetConfig:
    """Shape of the network.

    Attributes
    ----------
    channels : int
        Input channels C (y and u).
    input_length : int
        Samples per channel L.
    n_classes : int
        Output classes (grid size).
    hidden : list of int
        Hidden layer widths (paper: 3000, 1000).
    dropout : float
        Dropout probability after each hidden layer (authors' code: 0.4).
    period_features : int
        Number of radial-basis features of the log cycle length appended to
        the flattened input (0: none, the paper's network). The cycle length
        is read off the input itself (the u channel is +-1 over the cycle, 0
        in the padding), so the preprocessing is unchanged. Not in the paper:
        on our altitude sets a plain nearest-period rule beat the paper's
        network trained for the 5-minute CPU budget, because a fully connected
        layer must otherwise learn where the zero padding ends.
    period_range_s : tuple of float
        Period span (s at 200 Hz) the basis covers.
    phase_samples : int
        0: the output channel as preprocessed (right-aligned samples, the paper's
        input). ``m > 0``: the output channel's cycle (where the relay channel is
        non-zero) resampled to ``m`` points by linear interpolation and
        right-aligned in a zero row (``phase_resample``), so that one sample
        position is one phase of the cycle whatever its length; the relay
        channel and the period features keep the cycle's length. Not in the
        paper: on raw samples two processes whose periods differ by a few
        percent show their cycles' edges several samples apart, and a fully
        connected layer trained on the grid's classes reads that shift as
        another class (docs/results/identification.md).
    """

    channels: int
    input_length: int
    n_classes: int
    hidden: list[int] = field(default_factory=lambda: [3000, 1000])
    dropout: float = 0.4
    period_features: int = 0
    period_range_s: tuple[float, float] = (0.05, 3.0)
    phase_samples: int = 0

    def as_dict(self) -> dict:
        return asdict(self)


class IdentNet(nn.Module):
    """Fully connected classifier, input (B, C, L) float32 -> class activations (B, n_classes)."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        layers: list[nn.Module] = []
        width = cfg.channels * cfg.input_length + cfg.period_features
        for h in cfg.hidden:
            # ReLU before BatchNorm, as in the authors' MATLAB layer stack
            layers += [nn.Linear(width, h), nn.ReLU(), nn.BatchNorm1d(h), nn.Dropout(cfg.dropout)]
            width = h
        layers.append(nn.Linear(width, cfg.n_classes))
        self.layers = nn.Sequential(*layers)
        k = max(cfg.period_features, 1)
        lo, hi = (math.log(p * 200.0) for p in cfg.period_range_s)
        self.register_buffer("centres", torch.linspace(lo, hi, k))
        self.width = (hi - lo) / max(k - 1, 1)

    @torch.no_grad()
    def fold_batchnorm(self) -> IdentNet:
        """An inference copy: each BatchNorm folded into the next Linear, Dropout dropped.

        In eval mode a BatchNorm is the affine map ``z = a x + s`` per feature
        (``a = gamma / sqrt(var + eps)``, ``s = beta - mean a``), so the Linear
        after it takes ``W diag(a)`` and ``b + W s``: the same outputs (up to
        rounding) with two fewer passes over the hidden activations. The linear
        layers become ``InputMajorLinear``. This is what the exported network runs.
        """
        layers: list[nn.Module] = []
        pending: tuple[torch.Tensor, torch.Tensor] | None = None
        for m in self.layers:
            if isinstance(m, nn.BatchNorm1d):
                a = m.weight / torch.sqrt(m.running_var + m.eps)
                pending = (a, m.bias - m.running_mean * a)
            elif isinstance(m, nn.Linear):
                W, b = m.weight.clone(), m.bias.clone()
                if pending is not None:
                    b, W = b + W @ pending[1], W * pending[0][None, :]
                    pending = None
                layers.append(InputMajorLinear(W.T, b))
            elif not isinstance(m, nn.Dropout):
                layers.append(copy.deepcopy(m))
        if pending is not None:
            raise ValueError("a BatchNorm after the last Linear cannot be folded")
        folded = copy.deepcopy(self)
        folded.layers = nn.Sequential(*layers)
        return folded.eval()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.cfg.phase_samples:
            x = phase_resample(x, self.cfg.phase_samples)
        flat = x.flatten(1)
        if self.cfg.period_features:
            # cycle length in samples: the relay channel (last) is +-1 on the cycle, 0 in the padding
            n = x[:, -1, :].abs().sum(dim=1).clamp_min(1.0).log()
            rbf = torch.exp(-0.5 * ((n[:, None] - self.centres[None, :]) / self.width) ** 2)
            flat = torch.cat([flat, rbf], dim=1)
        return self.layers(flat)
