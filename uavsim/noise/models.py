"""Measurement-noise models for the NP-MRFT noise study.

Each model is a measurement :class:`~uavsim.model.effects.base.SignalEffect`:
a dataclass of its parameters, validated on construction, ``reset(n, rate_hz,
rng)`` once per batch of ``n`` episodes, then called once per control sample
with the clean measurement ``x`` (shape ``(n,)``), returning the noisy one.
Each additive model also draws its whole-episode noise at once, vectorized
over time (``trace(m, T, rate_hz, rng)``, shape ``(T, m)``), for dataset
generation. ``white`` and ``quantization`` are the session vocabulary's
``noise`` and ``quantization`` effects under their study names.
Every random number comes from the ``rng`` given to ``reset``. Amplitude-like
parameters accept a scalar or a per-episode array of shape ``(n,)`` (the noise
level is relative to each process's own oscillation amplitude ``a0``).

Models (the study names, not registered in the session vocabulary, whose
``noise`` and ``quantization`` belong to ``uavsim.model.effects``):

``paper``
    Paper eq. 14: ``a_n sin(Omega_n t + psi)``, amplitude and frequency slowly
    varying (sinusoidal modulation of relative depth ``amp_var``/``freq_var``),
    random phases per episode. Noise amplitude = ``a_n``.
``white``
    Zero-mean white Gaussian, ``std``. Noise amplitude = 2 std.
``quantization``
    Rounded to multiples of ``step`` (pixelation, ``pixel_step``). Amplitude = step.
``coloured``
    White Gaussian through a 2nd-order Butterworth low-pass (or band-pass),
    scaled to ``std`` at its output. Noise amplitude = 2 std.
``outliers``
    Sparse spikes: each sample with probability ``prob`` gets ``+-amplitude``.
    Noise amplitude = ``amplitude``.

    eff = make_noise("white", level=0.1, a0=np.array([0.05, 0.2]))   # std = 0.1 a0 / 2
    eff.reset(n=2, rate_hz=200.0, rng=np.random.default_rng(0))
    y_seen = eff(y_true, k)                                           # (2,) -> (2,)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal as _signal

from uavsim.errors import UserError
from uavsim.model.effects.base import SignalEffect, require
from uavsim.model.effects.noise import Noise
from uavsim.model.effects.quantization import Quantization as _Quantization

#: study noise kinds, in table order
NOISE_KINDS = ("paper", "white", "quantization", "coloured", "outliers")

Amp = float | np.ndarray


def _check_amp(effect: str, name: str, value: Amp, positive: bool = False) -> None:
    arr = np.asarray(value, dtype=np.float64)
    require(arr.ndim <= 1 and np.all(np.isfinite(arr)), effect, f"{name} must be finite (scalar or (n,) array)")
    if positive:
        require(bool(np.all(arr > 0)), effect, f"{name} must be > 0")
    else:
        require(bool(np.all(arr >= 0)), effect, f"{name} must be >= 0")


def _batch(value: Amp, n: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] != n:
        raise UserError(f"noise parameter {name} has {arr.shape[0]} episodes, the batch has {n}")
    return np.broadcast_to(arr, (n,)).copy()


def _per_episode(value: Amp, m: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (m,)).copy()


def pixel_step(distance_m: float, focal_px: float) -> float:
    """Metres per pixel of a pinhole camera looking at a target ``distance_m`` away.

    Parameters
    ----------
    distance_m : float
        Camera-to-target distance, m, > 0.
    focal_px : float
        Focal length in pixels, > 0.

    Returns
    -------
    float
        Size of one pixel on the target plane, m (``distance_m / focal_px``).
    """
    if not (math.isfinite(distance_m) and distance_m > 0 and math.isfinite(focal_px) and focal_px > 0):
        raise UserError(f"pixel_step needs distance_m > 0 and focal_px > 0, got {distance_m}, {focal_px}")
    return distance_m / focal_px


@dataclass
class PaperNoise(SignalEffect):
    """Paper eq. 14 noise ``a(t) sin(phi(t))``, ``phi' = Omega_n (1 + freq_var sin(...))``.

    Parameters
    ----------
    a_n : float or array (n,)
        Mean noise amplitude, output units.
    freq_hz : float
        Mean noise frequency ``Omega_n / 2 pi``, Hz (below the Nyquist rate).
    amp_var, freq_var : float
        Relative depth of the slow amplitude and frequency modulation, in [0, 1).
    mod_hz : float
        Frequency of the slow modulations, Hz (each with a random phase).
    """

    a_n: Amp = 0.0
    freq_hz: float = 40.0
    amp_var: float = 0.2
    freq_var: float = 0.2
    mod_hz: float = 0.3
    name = "paper"
    target = "measurement"

    def validate(self) -> None:
        _check_amp(self.name, "a_n", self.a_n)
        require(math.isfinite(self.freq_hz) and self.freq_hz > 0, self.name, "freq_hz must be > 0")
        require(0 <= self.amp_var < 1 and 0 <= self.freq_var < 1, self.name, "amp_var, freq_var must be in [0, 1)")
        require(math.isfinite(self.mod_hz) and self.mod_hz >= 0, self.name, "mod_hz must be >= 0")

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        super().reset(n, rate_hz, rng)
        require(self.freq_hz * (1 + self.freq_var) < rate_hz / 2, self.name,
                f"freq_hz {self.freq_hz} too high for a {rate_hz} Hz sample rate")
        self._a = _batch(self.a_n, n, "a_n")
        self._phase = rng.uniform(0, 2 * np.pi, n)
        self._pa = rng.uniform(0, 2 * np.pi, n)
        self._pf = rng.uniform(0, 2 * np.pi, n)

    def __call__(self, x: np.ndarray, k: int) -> np.ndarray:
        t = k / self.rate_hz
        w = 2 * np.pi * self.mod_hz * t
        amp = self._a * (1 + self.amp_var * np.sin(w + self._pa))
        out = x + amp * np.sin(self._phase)
        # integrate the instantaneous frequency so that frequency changes stay smooth
        f = self.freq_hz * (1 + self.freq_var * np.sin(0.77 * w + self._pf))
        self._phase = self._phase + 2 * np.pi * f / self.rate_hz
        return out

    def trace(self, m, T, rate_hz, rng):
        require(self.freq_hz * (1 + self.freq_var) < rate_hz / 2, self.name,
                f"freq_hz {self.freq_hz} too high for a {rate_hz} Hz sample rate")
        a = _per_episode(self.a_n, m)
        phase0, pa, pf = (rng.uniform(0, 2 * np.pi, m) for _ in range(3))
        w = 2 * np.pi * self.mod_hz * (np.arange(T) / rate_hz)[:, None]
        amp = a * (1 + self.amp_var * np.sin(w + pa))
        f = self.freq_hz * (1 + self.freq_var * np.sin(0.77 * w + pf))
        # the phase integrates the instantaneous frequency; sample k uses the phase before step k
        steps = 2 * np.pi * f / rate_hz
        phase = phase0 + np.concatenate([np.zeros((1, m)), np.cumsum(steps[:-1], axis=0)])
        return amp * np.sin(phase)


@dataclass(eq=False)
class WhiteNoise(Noise):
    """Zero-mean white Gaussian noise of standard deviation ``std`` (output units).

    The session vocabulary's ``noise`` effect under its study name (one implementation).
    """

    name = "white"
    session = None


@dataclass(eq=False)
class Quantization(_Quantization):
    """Measurement rounded to the nearest multiple of ``step`` (output units, > 0).

    The session vocabulary's ``quantization`` effect under its study name, where a step of 0
    (no quantization) is not a noise level.
    """

    step: Amp = 1.0
    name = "quantization_study"
    session = None

    def validate(self) -> None:
        _check_amp(self.name, "step", self.step, positive=True)


@dataclass
class ColouredNoise(SignalEffect):
    """Band-limited Gaussian noise: white noise through a Butterworth filter, output std ``std``.

    Parameters
    ----------
    std : float or array (n,)
        Standard deviation of the filtered noise, output units.
    high_hz : float
        Upper corner (low-pass cut-off), Hz.
    low_hz : float
        Lower corner, Hz; 0 for a plain low-pass.
    order : int
        Butterworth order (per corner).
    """

    std: Amp = 0.0
    high_hz: float = 20.0
    low_hz: float = 0.0
    order: int = 2
    name = "coloured"
    target = "measurement"

    def validate(self) -> None:
        _check_amp(self.name, "std", self.std)
        require(math.isfinite(self.high_hz) and self.high_hz > 0, self.name, "high_hz must be > 0")
        require(math.isfinite(self.low_hz) and 0 <= self.low_hz < self.high_hz, self.name,
                "low_hz must be in [0, high_hz)")
        require(isinstance(self.order, int) and 1 <= self.order <= 8, self.name, "order must be 1..8")

    def design(self, rate_hz: float) -> tuple[np.ndarray, float]:
        """The shaping filter at ``rate_hz``: (sos, gain), gain = RMS of its output for unit white input."""
        require(self.high_hz < rate_hz / 2, self.name, f"high_hz {self.high_hz} must be below Nyquist {rate_hz / 2}")
        if self.low_hz > 0:
            sos = _signal.butter(self.order, [self.low_hz, self.high_hz], "bandpass", fs=rate_hz, output="sos")
        else:
            sos = _signal.butter(self.order, self.high_hz, "lowpass", fs=rate_hz, output="sos")
        # unit-variance output for unit white input: divide by the impulse response's energy
        imp = np.zeros(int(50 * rate_hz / max(self.low_hz or self.high_hz, 1e-3)) + 1000)
        imp[0] = 1.0
        return sos, math.sqrt(float(np.sum(_signal.sosfilt(sos, imp) ** 2)))

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        super().reset(n, rate_hz, rng)
        sos, gain = self.design(rate_hz)
        self._sos = sos
        self._scale = _batch(self.std, n, "std") / gain
        self._zi = np.zeros((sos.shape[0], 2, n))
        # start in the filter's stationary state: run it on a noise history first
        warm = int(10 * rate_hz / (self.low_hz or self.high_hz)) + 10
        _, self._zi = _signal.sosfilt(sos, rng.standard_normal((warm, n)), axis=0, zi=self._zi)

    def __call__(self, x: np.ndarray, k: int) -> np.ndarray:
        w = self.rng.standard_normal((1, self.n))
        v, self._zi = _signal.sosfilt(self._sos, w, axis=0, zi=self._zi)
        return x + self._scale * v[0]

    def trace(self, m, T, rate_hz, rng):
        sos, gain = self.design(rate_hz)
        # a warm-up history puts the filter in its stationary state at sample 0
        warm = int(10 * rate_hz / (self.low_hz or self.high_hz)) + 10
        v = _signal.sosfilt(sos, rng.standard_normal((warm + T, m)), axis=0)[warm:]
        return _per_episode(self.std, m) / gain * v


@dataclass
class Outliers(SignalEffect):
    """Sparse spikes: with probability ``prob`` per sample, add ``+-amplitude`` (random sign)."""

    amplitude: Amp = 0.0
    prob: float = 0.01
    name = "outliers"
    target = "measurement"

    def validate(self) -> None:
        _check_amp(self.name, "amplitude", self.amplitude)
        require(math.isfinite(self.prob) and 0 <= self.prob <= 1, self.name, "prob must be in [0, 1]")

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        super().reset(n, rate_hz, rng)
        self._amp = _batch(self.amplitude, n, "amplitude")

    def __call__(self, x: np.ndarray, k: int) -> np.ndarray:
        hit = self.rng.random(self.n) < self.prob
        sign = np.where(self.rng.random(self.n) < 0.5, -1.0, 1.0)
        return x + np.where(hit, sign * self._amp, 0.0)

    def trace(self, m, T, rate_hz, rng):
        hit = rng.random((T, m)) < self.prob
        sign = np.where(rng.random((T, m)) < 0.5, -1.0, 1.0)
        return np.where(hit, sign * _per_episode(self.amplitude, m), 0.0)


@dataclass
class PerEpisode(SignalEffect):
    """Apply a different measurement effect to each group of episodes.

    Parameters
    ----------
    groups : list of (indices, effect or None)
        ``indices`` (int array) selects episodes of the batch; ``effect`` is reset
        for ``len(indices)`` episodes and applied to them; None leaves them clean.
        Episodes in no group are left clean.
    """

    groups: list = field(default_factory=list)
    name = "per_episode"
    target = "measurement"

    def validate(self) -> None:
        for idx, eff in self.groups:
            require(np.asarray(idx).ndim == 1, self.name, "indices must be 1-D")
            require(eff is None or isinstance(eff, SignalEffect), self.name, "effects must be SignalEffects")

    def params(self) -> dict:
        return {"groups": len(self.groups)}

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        super().reset(n, rate_hz, rng)
        for idx, eff in self.groups:
            if eff is not None:
                eff.reset(len(idx), rate_hz, rng)

    def __call__(self, x: np.ndarray, k: int) -> np.ndarray:
        out = np.array(x, dtype=np.float64, copy=True)
        for idx, eff in self.groups:
            if eff is not None and len(idx):
                out[idx] = eff(out[idx], k)
        return out


def noise_amplitude_to_param(kind: str, amplitude: Amp) -> dict[str, Amp]:
    """Model parameters giving noise ``amplitude`` (2 std for Gaussian, the step for quantization)."""
    amp = np.asarray(amplitude, dtype=np.float64)
    amp = float(amp) if amp.ndim == 0 else amp
    if kind == "paper":
        return {"a_n": amp}
    if kind in ("white", "coloured"):
        return {"std": amp / 2}
    if kind == "quantization":
        return {"step": amp}
    if kind == "outliers":
        return {"amplitude": amp}
    raise UserError(f"unknown noise kind {kind!r} (known: {', '.join(NOISE_KINDS)})")


def make_noise(kind: str, level: float, a0: Amp, **kw) -> SignalEffect | None:
    """Build a study noise model at ``level`` = noise amplitude / oscillation amplitude ``a0``.

    Parameters
    ----------
    kind : str
        One of :data:`NOISE_KINDS`.
    level : float
        Relative noise level, >= 0 (0.05 for 5%).
    a0 : float or array (n,)
        Noise-free oscillation amplitude of each episode, output units.
    **kw
        Extra model parameters (``freq_hz``, ``high_hz``, ``prob``, ...).

    Returns
    -------
    SignalEffect or None
        None when ``level`` is 0 (no noise).
    """
    if kind not in NOISE_KINDS:
        raise UserError(f"unknown noise kind {kind!r} (known: {', '.join(NOISE_KINDS)})")
    if not (math.isfinite(level) and level >= 0):
        raise UserError(f"noise level must be >= 0, got {level}")
    if level == 0:
        return None
    a0 = np.asarray(a0, dtype=np.float64)
    if not (np.all(np.isfinite(a0)) and np.all(a0 > 0)):
        raise UserError("noise a0 (oscillation amplitude) must be > 0")
    params = noise_amplitude_to_param(kind, level * a0)
    cls = {"paper": PaperNoise, "white": WhiteNoise, "quantization": Quantization,
           "coloured": ColouredNoise, "outliers": Outliers}[kind]
    try:
        return cls(**params, **kw)
    except TypeError as exc:
        raise UserError(f"noise {kind}: {exc}") from None
