"""Study noise models precomputed for whole episodes (dataset generation speed).

The study models of ``uavsim.noise.models`` draw their noise one control sample
at a time; in a batch of ~100 episodes that costs as much Python time per
sample as the rest of the loop together (scipy ``sosfilt`` per sample for the
coloured noise alone: ~0.1 ms), which the physics then waits for. Every model
but quantization *adds* a signal that does not depend on the measurement, so
``NoiseTrace`` draws it for the whole episode at reset with the model's own
vectorized ``trace`` (same model, parameters and statistics), and adds row
``k`` at sample ``k``; quantization (which depends on the measured value) is applied per
sample. The realizations differ from the per-sample models' (the draws are made
in another order); the dataset's determinism only needs its own.

    eff = NoiseTrace(groups=[(idx, make_noise("coloured", 1.0, amp))], samples=2000)
    eff.reset(n, 200.0, rng)          # draws the (samples, n) trace
    y_seen = eff(y_true, k)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from uavsim.model.effects.base import SignalEffect, require
from uavsim.noise.models import ColouredNoise, Outliers, PaperNoise, Quantization, WhiteNoise


def _amp(value, m: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (m,)).copy()


@dataclass
class NoiseTrace(SignalEffect):
    """Per-episode study noise, precomputed at reset (see module docstring).

    Parameters
    ----------
    groups : list of (indices, effect or None)
        As ``uavsim.noise.models.PerEpisode``: ``indices`` (int array) of the batch
        get ``effect`` (a study model); None or no group: clean.
    samples : int
        Control samples to precompute (the episode's length); later samples are clean.
    """

    groups: list = field(default_factory=list)
    samples: int = 0
    name = "noise_trace"
    target = "measurement"

    def validate(self) -> None:
        require(isinstance(self.samples, int) and self.samples >= 0, self.name, "samples must be an int >= 0")
        for idx, eff in self.groups:
            require(np.asarray(idx).ndim == 1, self.name, "indices must be 1-D")
            require(eff is None or isinstance(eff, (WhiteNoise, Outliers, PaperNoise, ColouredNoise, Quantization)),
                    self.name, "effects must be study noise models")

    def params(self) -> dict:
        return {"groups": len(self.groups), "samples": self.samples}

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        super().reset(n, rate_hz, rng)
        self._add = np.zeros((self.samples, n))
        self._quant: list[tuple[np.ndarray, np.ndarray]] = []
        for idx, eff in self.groups:
            idx = np.asarray(idx, dtype=np.int64)
            if eff is None or not len(idx):
                continue
            if isinstance(eff, Quantization):
                self._quant.append((idx, _amp(eff.step, len(idx))))
            else:
                self._add[:, idx] = eff.trace(len(idx), self.samples, rate_hz, rng)

    def __call__(self, x: np.ndarray, k: int) -> np.ndarray:
        out = x + self._add[k] if k < self.samples else np.array(x, dtype=np.float64, copy=True)
        for idx, step in self._quant:
            out[idx] = step * np.round(out[idx] / step)
        return out

    def block(self, x: np.ndarray) -> np.ndarray:
        """``self(x[k], k)`` for every row ``k`` of ``x`` (T, n) at once, (T, n): a whole record after reset."""
        x = np.asarray(x, dtype=np.float64)
        T = min(x.shape[0], self.samples)
        out = np.array(x, dtype=np.float64, copy=True)
        out[:T] += self._add[:T]
        for idx, step in self._quant:
            out[:, idx] = step * np.round(out[:, idx] / step)
        return out
