"""The paper's classifier: two fully connected hidden layers of 3000 and 1000 units.

Layer order follows the authors' code (NOTES.md section 2):
``FC 3000 -> ReLU -> BatchNorm -> Dropout 0.4 -> FC 1000 -> ReLU -> BatchNorm ->
Dropout 0.4 -> FC n_classes``. The input is one preprocessed cycle of C channels
and L samples (``uavsim.data.preprocess``), flattened to C*L. The outputs are the
raw activations ``a``; the J-weighted softmax of ``uavsim.learning.loss`` is
applied only in training, and the predicted class is ``argmax a``.

    from uavsim.learning.model import NetConfig, IdentNet
    net = IdentNet(NetConfig(channels=2, input_length=400, n_classes=208))
    a = net(torch.zeros(8, 2, 400))        # (8, 208)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import torch
from torch import nn

__all__ = ["NetConfig", "IdentNet"]


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
    """

    channels: int
    input_length: int
    n_classes: int
    hidden: list[int] = field(default_factory=lambda: [3000, 1000])
    dropout: float = 0.4

    def as_dict(self) -> dict:
        return asdict(self)


class IdentNet(nn.Module):
    """Fully connected classifier, input (B, C, L) float32 -> activations (B, n_classes)."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        layers: list[nn.Module] = [nn.Flatten()]
        width = cfg.channels * cfg.input_length
        for h in cfg.hidden:
            # ReLU before BatchNorm, as in the authors' MATLAB layer stack
            layers += [nn.Linear(width, h), nn.ReLU(), nn.BatchNorm1d(h), nn.Dropout(cfg.dropout)]
            width = h
        layers.append(nn.Linear(width, cfg.n_classes))
        self.layers = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x)
