"""Estimate measurement noise from a flight segment and choose NP-MRFT's ``tau_obs`` and ``a_n``.

Paper section III-B: "To obtain T_n in-flight, we use a high-pass filter with
a suitable cut-off frequency combined with a period estimation through
consecutive peaks detection", and ``a_n`` is "a certain average amplitude" of
the high-passed signal. This module does exactly that on a hover segment (or
on an oscillation, with the cut-off above the oscillation's harmonics):

1. high-pass (4th-order Butterworth, zero phase) at ``cutoff_hz``;
2. split the result into excursions between zero crossings; the extreme of
   each excursion is a peak (positive) or trough (negative);
3. ``T_n`` = median time between consecutive peaks, ``a_n_mean`` = mean
   absolute peak/trough value (the paper's average amplitude),
   ``sigma`` = standard deviation of the high-passed signal.

Calibration of ``a_n`` (why not the average amplitude or 2 sigma)
----------------------------------------------------------------
NP-MRFT corrects both switching levels by ``a_n (1 - beta)`` (eq. 22-23).
That is exact for the paper's noise model (a sinusoid of amplitude ``a_n``):
the confirmed peak then overshoots the true peak by ``a_n`` and the switch
comes early by ``a_n``. For random noise the two offsets are not the noise
amplitude but the *largest noise value the relay meets* while it tracks the
peak and while the error approaches the switching level: an extreme value
over a number of independent noise samples, which for Gaussian noise is well
below ``2 sigma`` most of the time (hence the over-compensation of
``a_n = 2 sigma``: +15..22% period at 10-20% white noise) and well above the
*mean* excursion amplitude. The recommended ``a_n`` is therefore a high
quantile of ``|high-passed signal|``:

    a_n = quantile(|x_hp|, A_N_QUANTILE)

which is distribution-aware without knowing the distribution: for a
sinusoid it is ~``a_n``, for Gaussian noise ``z * sigma``, for quantization
~step/2, and single-sample outliers rarer than ``1 - A_N_QUANTILE`` do not
inflate it; then scaled by ``A_N_SCALE``.

Simulation (``uavsim.bench.noise`` on the exact lumped loops, 8 random
altitude + 8 attitude processes, beta = -0.73, tau_obs as below; median
period error / false switches per period at 10% and 20% noise):

======  ==================  ==================  ==================
scale   paper               white               coloured
======  ==================  ==================  ==================
0.5     -1.7% / 0.14        +0.8% / 0.12        +7.5% / 0.01
        -38% / 1.36         -41% / 1.92         +9.2% / 0.42
0.7     +6.0% / 0.05        +5.7% / 0.07        +10% / 0.00
        -15% / 0.65         -7.7% / 0.60        +16% / 0.18
1.0     +15% / 0.02         +10% / 0.01         +16% / 0.00
        +17% / 0.20         +15% / 0.18         +25% / 0.07
======  ==================  ==================  ==================

There is no unbiased choice at 20%: a small ``a_n`` lets the relay switch
back right after a switch (the spec restarts the extremum tracker at the
switch sample, where ``|e|`` is still about ``-beta a0``; a noise uptick
that stands for ``tau_obs`` is then a "confirmed" extremum and
``e >= -beta e_ext + a_n (1 - beta)`` holds unless ``a_n (1 - beta)``
exceeds about ``(1 + beta)(-beta) a0``), while a large ``a_n`` delays every
switch (the switch waits for a noise trough deep enough to reach the lowered
level) and lengthens the period. ``A_N_SCALE = 0.7`` is the compromise:
within ~6% at 10% noise for paper, white and quantization noise.

Without a known cycle, ``tau_obs`` is the smallest multiple of the control
sample ``Ts`` that is at least ``TAU_FACTOR * T_n``. With the expected period
``T0`` it is the largest multiple of ``Ts`` with
``beta_min(tau_obs, T0) <= beta``: a longer observation rejects more noise
extrema (the noise frequency wanders, so a noise extremum can stand longer
than ``T_n``) and costs nothing while beta allows it; when that is below
``T_n`` the beta limit wins and a note says so.

    est = estimate_noise(y_hover, rate_hz=200.0)
    tau_obs, a_n = recommend(est, beta=-0.73, T0_expected=0.9)
    print(est.T_n, est.sigma, tau_obs, a_n, beta_min(tau_obs, 0.9))
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal as _signal

from uavsim.control.relay import beta_min
from uavsim.errors import UserError

#: quantile of |high-passed signal| used as the NP-MRFT noise amplitude a_n
A_N_QUANTILE = 0.90
#: a_n = A_N_SCALE * quantile(|x_hp|, A_N_QUANTILE)
A_N_SCALE = 0.7
#: tau_obs >= TAU_FACTOR * T_n
TAU_FACTOR = 1.0
#: default high-pass cut-off for a hover segment, Hz
HOVER_CUTOFF_HZ = 2.0
#: for an oscillation, cut-off = this many times its fundamental (above its main harmonics)
OSC_CUTOFF_HARMONIC = 6.0


@dataclass
class NoiseEstimate:
    """Noise measured on one segment.

    Attributes
    ----------
    T_n : float
        Noise period from consecutive peaks of the high-passed signal, s (nan: no noise seen).
    a_n : float
        Recommended NP-MRFT noise amplitude (calibrated quantile), output units.
    a_n_mean : float
        Paper's "average amplitude": mean |peak| of the high-passed excursions, output units.
    sigma : float
        Standard deviation of the high-passed signal, output units.
    tau_obs : float
        Recommended observation time without a cycle constraint, s (multiple of 1/rate_hz).
    cutoff_hz : float
        High-pass cut-off used, Hz.
    rate_hz : float
        Sample rate of the segment, Hz.
    n_peaks : int
        Peaks found.
    notes : list of str
        How the estimate was made and anything doubtful.
    """

    T_n: float
    a_n: float
    a_n_mean: float
    sigma: float
    tau_obs: float
    cutoff_hz: float
    rate_hz: float
    n_peaks: int
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"T_n": self.T_n, "a_n": self.a_n, "a_n_mean": self.a_n_mean, "sigma": self.sigma,
                "tau_obs": self.tau_obs, "cutoff_hz": self.cutoff_hz, "rate_hz": self.rate_hz,
                "n_peaks": self.n_peaks, "notes": list(self.notes)}


def highpass(y: np.ndarray, rate_hz: float, cutoff_hz: float, order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth high-pass of a 1-D signal (mean removed first). Shape as ``y``."""
    y = np.asarray(y, dtype=np.float64)
    sos = _signal.butter(order, cutoff_hz, "highpass", fs=rate_hz, output="sos")
    x = y - np.mean(y)
    pad = min(x.size - 1, int(3 * rate_hz / cutoff_hz))
    return _signal.sosfiltfilt(sos, x, padlen=pad)


def excursion_peaks(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Extremes of the excursions of ``x`` between zero crossings.

    Returns
    -------
    idx : int array (m,)
        Sample index of each excursion's extreme (max of a positive one, min of a negative one).
    val : array (m,)
        Their values (signed).
    """
    x = np.asarray(x, dtype=np.float64)
    s = np.sign(x)
    nz = np.flatnonzero(s != 0)
    if nz.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    # fill exact zeros with the previous sign so they do not split an excursion
    s = s[nz][np.maximum(np.searchsorted(nz, np.arange(x.size), side="right") - 1, 0)]
    cuts = np.flatnonzero(s[1:] != s[:-1]) + 1
    bounds = np.concatenate(([0], cuts, [x.size]))
    idx, val = [], []
    # drop the first and last excursions: they are cut by the record's ends
    for a, b in zip(bounds[1:-2], bounds[2:-1], strict=True):
        seg = x[a:b]
        i = int(np.argmax(seg) if s[a] > 0 else np.argmin(seg))
        idx.append(a + i)
        val.append(seg[i])
    return np.asarray(idx, dtype=np.int64), np.asarray(val)


def estimate_noise(y: np.ndarray, rate_hz: float, cutoff_hz: float | None = None,
                   period: float | None = None, quantile: float = A_N_QUANTILE) -> NoiseEstimate:
    """Estimate the noise period and amplitude of a hover or oscillation segment.

    Parameters
    ----------
    y : array (T,)
        Measured signal (or error) of the segment, output units, sampled at ``rate_hz``.
    rate_hz : float
        Sample rate, Hz.
    cutoff_hz : float, optional
        High-pass cut-off, Hz. Default: ``HOVER_CUTOFF_HZ`` for a hover,
        ``OSC_CUTOFF_HARMONIC / period`` when the segment oscillates with ``period``.
    period : float, optional
        Period of the oscillation in the segment, s (None for a hover).
    quantile : float
        Quantile of ``|x_hp|`` used as ``a_n`` (see the module docstring).

    Returns
    -------
    NoiseEstimate
    """
    y = np.asarray(y, dtype=np.float64)
    if y.ndim != 1:
        raise UserError(f"noise estimation needs a 1-D segment, got shape {y.shape}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise UserError(f"sample rate must be > 0 Hz, got {rate_hz}")
    if not np.all(np.isfinite(y)):
        raise UserError("noise estimation: the segment has non-finite samples")
    if not 0 < quantile < 1:
        raise UserError(f"quantile must be in (0, 1), got {quantile}")
    notes: list[str] = []
    if cutoff_hz is None:
        if period is not None and period > 0:
            cutoff_hz = OSC_CUTOFF_HARMONIC / period
            notes.append(f"oscillation of period {period:.4g} s: high-pass at {OSC_CUTOFF_HARMONIC:g}x its frequency")
        else:
            cutoff_hz = HOVER_CUTOFF_HZ
    nyq = rate_hz / 2
    if cutoff_hz > 0.4 * nyq:
        notes.append(f"cut-off {cutoff_hz:.4g} Hz too close to Nyquist; clipped to {0.4 * nyq:.4g} Hz")
        cutoff_hz = 0.4 * nyq
    if cutoff_hz <= 0:
        raise UserError(f"high-pass cut-off must be > 0 Hz, got {cutoff_hz}")
    if y.size < max(32, int(4 * rate_hz / cutoff_hz)):
        raise UserError(f"segment too short for noise estimation: {y.size} samples "
                        f"(need {max(32, int(4 * rate_hz / cutoff_hz))} at cut-off {cutoff_hz:.3g} Hz)")
    x = highpass(y, rate_hz, cutoff_hz)
    sigma = float(np.std(x))
    idx, val = excursion_peaks(x)
    scale = float(np.max(np.abs(y - np.mean(y)))) or 1.0
    if sigma <= 1e-12 * scale or idx.size < 4:
        notes.append("no noise found in the segment")
        return NoiseEstimate(float("nan"), 0.0, 0.0, sigma, 0.0, float(cutoff_hz), float(rate_hz),
                             int(idx.size), notes)
    pos = idx[val > 0]
    T_n = float(np.median(np.diff(pos))) / rate_hz if pos.size > 1 else float("nan")
    a_mean = float(np.mean(np.abs(val)))
    a_n = A_N_SCALE * float(np.quantile(np.abs(x), quantile))
    tau = _round_up(TAU_FACTOR * T_n, rate_hz) if math.isfinite(T_n) else 1.0 / rate_hz
    if math.isfinite(T_n) and T_n * cutoff_hz > 0.5:
        notes.append(f"T_n {T_n:.4g} s is close to the high-pass period: noise and motion may not separate")
    return NoiseEstimate(T_n, a_n, a_mean, sigma, tau, float(cutoff_hz), float(rate_hz), int(idx.size), notes)


def _round_up(tau: float, rate_hz: float) -> float:
    """Smallest multiple of 1/rate_hz that is >= tau (tolerant to rounding)."""
    return math.ceil(tau * rate_hz - 1e-9) / rate_hz


def tau_obs_max(beta: float, period: float, rate_hz: float) -> float:
    """Largest multiple of 1/rate_hz with ``beta_min(tau_obs, period) <= beta``, s (may be 0)."""
    if not -1 < beta < 1:
        raise UserError(f"MRFT beta must lie in (-1, 1), got {beta}")
    if not (math.isfinite(period) and period > 0):
        raise UserError(f"cycle period must be > 0 s, got {period}")
    # -1 + sin(2 pi tau / T0) <= beta  <=>  tau <= T0 asin(1 + beta) / (2 pi)  (beta <= 0)
    ratio = 0.25 if beta >= 0 else math.asin(1 + beta) / (2 * math.pi)
    return math.floor(ratio * period * rate_hz + 1e-9) / rate_hz


def recommend(noise: NoiseEstimate, beta: float, T0_expected: float | None = None) -> tuple[float, float]:
    """NP-MRFT ``(tau_obs, a_n)`` for measured noise, a test ``beta`` and an expected cycle period.

    Parameters
    ----------
    noise : NoiseEstimate
        From :func:`estimate_noise`.
    beta : float
        Planned MRFT parameter, in (-1, 1).
    T0_expected : float, optional
        Expected noise-free period of the test, s; when given, ``tau_obs`` is
        capped so that ``beta_min(tau_obs, T0_expected) <= beta``.

    Returns
    -------
    tau_obs : float
        s, a multiple of ``1/noise.rate_hz``.
    a_n : float
        Output units.
    """
    if not -1 < beta < 1:
        raise UserError(f"MRFT beta must lie in (-1, 1), got {beta}")
    tau = noise.tau_obs
    if T0_expected is not None:
        cap = tau_obs_max(beta, T0_expected, noise.rate_hz)
        if cap < tau:
            noise.notes.append(
                f"tau_obs {tau:.4g} s >= T_n would need beta >= {float(beta_min(tau, T0_expected)):.3f}; "
                f"capped at {cap:.4g} s for beta {beta}")
        # Use the whole observation time beta allows: a random noise extremum is
        # superseded later than T_n when the noise frequency wanders, and a longer
        # tau_obs costs nothing while beta_min(tau_obs, T0) <= beta.
        tau = cap
    return tau, noise.a_n


def recommended_beta_min(tau_obs: float, T0: float | None) -> float:
    """``beta_min(tau_obs, T0)`` as a float (nan when ``T0`` is unknown)."""
    if T0 is None or not math.isfinite(T0) or T0 <= 0:
        return float("nan")
    return float(beta_min(tau_obs, T0))
