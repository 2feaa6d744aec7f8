"""Study noise models precomputed for whole episodes (dataset generation speed).

The study models of ``uavsim.noise.models`` draw their noise one control sample
at a time; in a batch of ~100 episodes that costs as much Python time per
sample as the rest of the loop together (scipy ``sosfilt`` per sample for the
coloured noise alone: ~0.1 ms), which the physics then waits for. Every model
but quantization *adds* a signal that does not depend on the measurement, so
``NoiseTrace`` draws it for the whole episode at reset, vectorized over time,
with the same model, parameters and statistics, and adds row ``k`` at sample
``k``; quantization (which depends on the measured value) is applied per
sample. The realizations differ from the per-sample models' (the draws are made
in another order); the dataset's determinism only needs its own.

    eff = NoiseTrace(groups=[(idx, make_noise("coloured", 1.0, amp))], samples=2000)
    eff.reset(n, 200.0, rng)          # draws the (samples, n) trace
    y_seen = eff(y_true, k)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal as _signal

from uavsim.model.effects.base import SignalEffect, require
from uavsim.noise.models import ColouredNoise, Outliers, PaperNoise, Quantization, WhiteNoise


def _amp(value, m: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (m,)).copy()


def trace(effect: SignalEffect, m: int, T: int, rate_hz: float, rng: np.random.Generator) -> np.ndarray:
    """The additive noise of a study model for ``m`` episodes of ``T`` samples, (T, m).

    Same definitions as ``uavsim.noise.models`` (paper eq. 14 with slow modulations,
    white Gaussian, Butterworth-filtered Gaussian scaled to its std and started in
    its stationary state, sparse +-amplitude spikes).
    """
    if isinstance(effect, WhiteNoise):
        return _amp(effect.std, m) * rng.standard_normal((T, m))
    if isinstance(effect, Outliers):
        hit = rng.random((T, m)) < effect.prob
        sign = np.where(rng.random((T, m)) < 0.5, -1.0, 1.0)
        return np.where(hit, sign * _amp(effect.amplitude, m), 0.0)
    if isinstance(effect, PaperNoise):
        require(effect.freq_hz * (1 + effect.freq_var) < rate_hz / 2, effect.name,
                f"freq_hz {effect.freq_hz} too high for a {rate_hz} Hz sample rate")
        a = _amp(effect.a_n, m)
        phase0, pa, pf = (rng.uniform(0, 2 * np.pi, m) for _ in range(3))
        w = 2 * np.pi * effect.mod_hz * (np.arange(T) / rate_hz)[:, None]
        amp = a * (1 + effect.amp_var * np.sin(w + pa))
        f = effect.freq_hz * (1 + effect.freq_var * np.sin(0.77 * w + pf))
        # the phase integrates the instantaneous frequency; sample k uses the phase before step k
        steps = 2 * np.pi * f / rate_hz
        phase = phase0 + np.concatenate([np.zeros((1, m)), np.cumsum(steps[:-1], axis=0)])
        return amp * np.sin(phase)
    if isinstance(effect, ColouredNoise):
        sos, gain = effect.design(rate_hz)
        # a warm-up history puts the filter in its stationary state at sample 0
        warm = int(10 * rate_hz / (effect.low_hz or effect.high_hz)) + 10
        v = _signal.sosfilt(sos, rng.standard_normal((warm + T, m)), axis=0)[warm:]
        return _amp(effect.std, m) / gain * v
    raise TypeError(f"no precomputed trace for {type(effect).__name__}")


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
                self._add[:, idx] = trace(eff, len(idx), self.samples, rate_hz, rng)

    def __call__(self, x: np.ndarray, k: int) -> np.ndarray:
        out = x + self._add[k] if k < self.samples else np.array(x, dtype=np.float64, copy=True)
        for idx, step in self._quant:
            out[idx] = step * np.round(out[idx] / step)
        return out
