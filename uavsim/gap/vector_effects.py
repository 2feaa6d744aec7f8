"""Per-episode (vectorized) versions of the session's effect vocabulary, for batched fitting.

The registry effects of :mod:`uavsim.model.effects` take one scalar parameter
for a whole batch (only ``noise`` accepts an (n,) array). The gap workflow
fits each candidate effect by simulating many parameter values -- and many
candidates -- in one :class:`~uavsim.sim.runner.LoopBatch`, so it needs every
episode of a batch to carry its own effect and its own value. This module
reimplements the sampled semantics of each vocabulary effect with (n,)
parameter arrays, where an episode that does not use an effect gets its
identity value (delay 0, gain 1, limit inf, width 0, rate inf, offset 0, step
0, hold rate = control rate, no filter, std 0). ``tests/test_gap_effects.py``
checks sample by sample that each one equals its registry effect for scalar
parameters.

Order of the chains (the same in the session generator, which uses the
registry effects in this order): on the measurement, the model's noise, then
the extra ``noise``, quantization, sample-and-hold and low-pass; on the
command, lag, rate limit, dead zone, saturation, bias.

    chains = batch_effects("altitude", names=["delay", "lag"], values=[0.02, 0.05],
                           noise_std=0.001, rate_hz=200.0)
    lb = LoopBatch(params, effects=chains, rate_hz=200.0)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import signal

from uavsim.model.effects.base import Effect, SignalEffect

__all__ = ["VecModel", "VecCommand", "VecMeasurement", "batch_effects", "IDENTITY"]

# Parameter value of each effect that leaves the loop unchanged.
IDENTITY: dict[str, float] = {
    "delay": 0.0,
    "lag": 0.0,
    "gain": 1.0,
    "saturation": math.inf,
    "dead_zone": 0.0,
    "rate_limit": math.inf,
    "bias": 0.0,
    "quantization": 0.0,
    "sample_hold": math.nan,  # the control rate, filled in by batch_effects
    "lowpass": math.inf,
    "noise": 0.0,
}


@dataclass
class VecModel(Effect):
    """A model effect (``delay`` or ``gain``) with one value per episode.

    Attributes
    ----------
    kind : str
        ``"delay"`` (attribute ``delay``, s) or ``"gain"`` (attribute ``factor``).
    value : ndarray (n,)
    """

    kind: str = "delay"
    value: np.ndarray | None = None
    target = "model"

    def __post_init__(self) -> None:
        # the runner recognises model effects by ``name`` and reads ``delay`` / ``factor``
        self.name = self.kind
        if self.kind == "delay":
            self.delay = np.asarray(self.value, dtype=np.float64)
        else:
            self.factor = np.asarray(self.value, dtype=np.float64)

    def validate(self) -> None:  # values come from the workflow's own grids
        pass


@dataclass
class VecCommand(SignalEffect):
    """The command chain: lag T, rate limit, dead zone width, saturation limit, bias offset; each (n,)."""

    T: np.ndarray
    rate: np.ndarray
    width: np.ndarray
    limit: np.ndarray
    offset: np.ndarray
    name = "vec_command"
    target = "command"

    def validate(self) -> None:
        pass

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        T = np.asarray(self.T, dtype=np.float64)
        self._has_lag = T > 0
        # a = exp(-Ts/T) exactly as the registry Lag; identity episodes bypass it
        self._a = np.where(self._has_lag, np.exp(-1.0 / (rate_hz * np.where(self._has_lag, T, 1.0))), 0.0)
        self._x = np.zeros(n)
        self._prev = np.zeros(n)
        self._has_rate = np.isfinite(self.rate)
        self._step = np.where(self._has_rate, np.asarray(self.rate, dtype=np.float64) / rate_hz, np.inf)

    def __call__(self, u: np.ndarray, k: int) -> np.ndarray:
        out = np.where(self._has_lag, self._x, u)
        self._x = self._a * self._x + (1.0 - self._a) * u
        u = out
        slewed = self._prev + np.clip(u - self._prev, -self._step, self._step)
        self._prev = slewed
        u = np.where(self._has_rate, slewed, u)
        w = self.width
        u = np.where(w > 0, np.sign(u) * np.maximum(np.abs(u) - w, 0.0), u)
        u = np.clip(u, -self.limit, self.limit)
        return u + self.offset


@dataclass
class VecMeasurement(SignalEffect):
    """The measurement chain: noise std, quantization step, hold rate, low-pass cut-off; each (n,)."""

    std: np.ndarray
    qstep: np.ndarray
    hold_hz: np.ndarray
    cutoff_hz: np.ndarray
    name = "vec_measurement"
    target = "measurement"

    def validate(self) -> None:
        pass

    def reset(self, n, rate_hz, rng):
        super().reset(n, rate_hz, rng)
        self._held = None
        cut = np.asarray(self.cutoff_hz, dtype=np.float64)
        self._has_lp = np.isfinite(cut)
        b = np.zeros((n, 3))
        a = np.zeros((n, 3))
        zi = np.zeros((n, 2))
        b[:, 0], a[:, 0] = 1.0, 1.0
        for i in np.flatnonzero(self._has_lp):
            sos = signal.butter(2, cut[i], fs=rate_hz, output="sos")
            b[i], a[i] = sos[0, :3], sos[0, 3:]
            zi[i] = signal.sosfilt_zi(sos)[0]
        self._b, self._a, self._zi0 = b, a, zi
        self._z = None

    def __call__(self, y: np.ndarray, k: int) -> np.ndarray:
        std = np.asarray(self.std, dtype=np.float64)
        if np.any(std > 0):
            y = y + std * self.rng.standard_normal(y.shape)
        q = self.qstep
        y = np.where(q > 0, np.round(y / np.where(q > 0, q, 1.0)) * q, y)
        frame = np.floor(k * self.hold_hz / self.rate_hz + 1e-9)
        prev = np.floor((k - 1) * self.hold_hz / self.rate_hz + 1e-9)
        if self._held is None:
            self._held = np.array(y, dtype=np.float64, copy=True)
        else:
            self._held = np.where(frame != prev, y, self._held)
        y = self._held.copy()
        if self._z is None:
            # settled at the first sample, as the registry Lowpass
            self._z = self._zi0 * y[:, None]
        b, a, z = self._b, self._a, self._z
        out = b[:, 0] * y + z[:, 0]
        z0 = b[:, 1] * y - a[:, 1] * out + z[:, 1]
        z1 = b[:, 2] * y - a[:, 2] * out
        self._z = np.stack([z0, z1], axis=1)
        return np.where(self._has_lp, out, y)


def batch_effects(
    names: Sequence[str],
    values: Sequence[float],
    noise_std: float | np.ndarray,
    rate_hz: float,
    base: dict[str, float] | None = None,
) -> list[Effect]:
    """Effects for a batch whose episode ``i`` has the effect ``names[i]`` at ``values[i]``.

    Parameters
    ----------
    names : sequence of str, length n
        A vocabulary name per episode (``"none"`` for the bare model).
    values : sequence of float, length n
        That effect's single parameter, in the vocabulary's units (ignored for ``none``).
    noise_std : float or (n,)
        The model's measurement noise, output units.
    rate_hz : float
        Control rate, Hz.
    base : dict of str to float, optional
        Effects every episode has (the session's ``[[effects]]``), name -> value;
        an episode's own effect of the same name replaces it.

    Returns
    -------
    list of Effect
        Model, command and measurement effects for :class:`~uavsim.sim.runner.LoopBatch`.
    """
    n = len(names)
    par = {k: np.full(n, v, dtype=np.float64) for k, v in IDENTITY.items()}
    par["sample_hold"][:] = rate_hz
    for name, v in (base or {}).items():
        par[name][:] = float(v)
    for i, (name, v) in enumerate(zip(names, values, strict=True)):
        if name != "none":
            par[name][i] = float(v)
    std = np.sqrt(np.broadcast_to(np.asarray(noise_std, dtype=np.float64), (n,)) ** 2 + par["noise"] ** 2)
    fx: list[Effect] = []
    if np.any(par["delay"] != 0):
        fx.append(VecModel("delay", par["delay"]))
    if np.any(par["gain"] != 1):
        fx.append(VecModel("gain", par["gain"]))
    fx.append(VecCommand(par["lag"], par["rate_limit"], par["dead_zone"], par["saturation"], par["bias"]))
    fx.append(VecMeasurement(std, par["quantization"], par["sample_hold"], par["lowpass"]))
    return fx
