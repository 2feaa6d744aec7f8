"""Estimate measurement noise and choose NP-MRFT's ``tau_obs`` and ``a_n`` from a user's data.

Two sources, both what a user has (never the true process):

1. **A hover segment** (:func:`estimate_noise`, :func:`recommend`): paper
   section III-B, "a high-pass filter with a suitable cut-off frequency
   combined with a period estimation through consecutive peaks detection".
   High-pass (4th-order Butterworth, zero phase) at ``cutoff_hz``; the
   extremes of the excursions between zero crossings are the noise peaks;
   ``T_n`` = median time between consecutive peaks, ``a_n`` = the
   ``A_N_QUANTILE`` quantile of ``|x_hp|`` (distribution-aware without knowing
   the distribution: ~``a_n`` for a sinusoid, ``z sigma`` for Gaussian noise,
   ~step/2 for quantization, and outliers rarer than ``1 - A_N_QUANTILE``
   do not inflate it), ``sigma`` its standard deviation. This gives the
   settings of a *first* relay run: ``a_n = A_N_FIRST x`` that amplitude (the
   first run must keep its cycle; its period is allowed to be long) and
   ``tau_obs >= T_n`` capped as for the shortest cycle the paper's box can
   produce (``FIRST_RUN_PERIOD``): without a measured cycle, a longer
   observation could hold back the switches of a fast loop.

2. **A relay run** (:func:`refine`): the run's own record, its measured period
   and amplitude, and the noise as the relay saw it: the residual of the error
   against its smooth part (a zero-phase low-pass at ``OSC_CUTOFF_HARMONIC``
   times the cycle frequency). Per half-cycle it measures, on the smooth part,
   the extremum, the time the error took from it to the noise-free switching
   level ``-beta x extremum`` (what beta allows ``tau_obs`` to be on *this*
   cycle) and how early or late the relay actually switched against that level.
   The refined settings:

   - ``tau_obs = TAU_LEVEL_FRACTION x`` the median time to the level (a
     multiple of the sample time, at least one sample): the longest
     observation that holds back no switch of this cycle, with a margin for
     the noise moving the observed extremum later;
   - ``a_n = a_n_run + A_N_GAIN x median(early switch) / (1 - beta)``,
     clipped to ``[0, A_N_MAX x`` the noise amplitude ``]``: the correction
     ``a_n (1 - beta)`` of both switching levels (eq. 22-23) then matches what
     the noise actually does to the tracked extremum and at the level
     crossing, whatever its distribution, instead of assuming a sinusoid.
     A run that switched falsely (a half-period under a quarter of the
     period: beta held ``tau_obs`` below the noise period on a fast cycle)
     gets at least ``A_N_FALSE_FACTOR x`` its ``a_n`` and ``A_N_FALSE_FLOOR x``
     the noise amplitude: the correction is then the protection left.
     The lower bound ``A_N_MIN`` keeps a protection when a run switched late on
     the median: without it one late run takes ``a_n`` to zero and the next run,
     with a short ``tau_obs`` and no correction, switches early on noise. It is
     not applied when every step of the error is a whole multiple of one step
     (:func:`on_lattice`: a quantized sensor), whose switches are late by the
     quantization itself, not early by chance.

Why two steps. The correction ``a_n (1 - beta)`` is exact for the paper's
noise model only (a sinusoid of amplitude ``a_n``: the confirmed peak
overshoots by ``a_n``, the switch comes early by ``a_n``). For other noise the
two offsets are extreme values of the noise over the samples the relay meets,
which depend on the cycle's speed as much as on the noise; and the period is
very sensitive to them (at beta = -0.73 a level error of 3.5% of the amplitude
moves the period by about 7%). No hover-only ``a_n`` is right for every noise
kind (see ``docs/results/noise.md``); the relay run measures it.

    est = estimate_noise(y_hover, rate_hz=200.0)
    tau_obs, a_n = recommend(est, beta=-0.73)                     # first run
    ref = refine(t, e, u, beta=-0.73, tau_obs=tau_obs, a_n=a_n, rate_hz=200.0, hover=est)
    ref.tau_obs, ref.a_n, ref.period, ref.amplitude               # next run
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal as _signal

from uavsim.control.relay import beta_min, tau_obs_limit
from uavsim.errors import UserError
from uavsim.noise.analysis import relay_phase, switch_indices

#: quantile of |high-passed signal| taken as the noise amplitude
A_N_QUANTILE = 0.90
#: a first run's a_n = A_N_FIRST x the noise amplitude
A_N_FIRST = 1.0
#: tau_obs >= TAU_FACTOR * T_n (paper), when the cycle allows it
TAU_FACTOR = 1.0
#: s: shortest relay cycle of the paper's box at beta = -0.73 (0.089 s); caps a first run's tau_obs
FIRST_RUN_PERIOD = 0.09
#: refined tau_obs = TAU_LEVEL_FRACTION x the measured time from the extremum to the switching level
TAU_LEVEL_FRACTION = 0.85
#: the level time is the median over half-cycles, but at most this times the shorter side's
#: (and where only one side reaches its level, tau_obs is not raised: ``refine_batch``)
LEVEL_SIDE_SLACK = 1.1
#: refined a_n = a_n + A_N_GAIN x median early switch / (1 - beta)
A_N_GAIN = 1.5
#: refined a_n <= A_N_MAX x the noise amplitude
A_N_MAX = 1.0
#: a run that switched falsely: a_n at least A_N_FALSE_FACTOR x its own and A_N_FALSE_FLOOR x the noise amplitude
A_N_FALSE_FACTOR = 1.6
A_N_FALSE_FLOOR = 0.5
#: refined a_n >= A_N_MIN x the noise amplitude, unless the error samples lie on a lattice (quantization)
A_N_MIN = 0.15
#: the settings rule's version (this module's recommend and refine): training sets and their resume
#: state record it, so that a file or chunk made under another rule is made again, not mixed in
SETTINGS_RULE = 2
#: half-cycles a refinement needs, and of them with the extremum beyond its switching level
MIN_HALF_CYCLES = 4
MIN_VALID_HALF_CYCLES = 2
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
        Noise amplitude: the ``A_N_QUANTILE`` quantile of the high-passed
        signal's magnitude, output units (0 when no noise was seen).
    a_n_mean : float
        Paper's "average amplitude": mean |peak| of the high-passed excursions, output units.
    sigma : float
        Standard deviation of the high-passed signal, output units.
    tau_obs : float
        ``TAU_FACTOR x T_n`` rounded up to a multiple of 1/rate_hz, s (one sample when no noise was seen).
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
        return dataclasses.asdict(self)


@functools.lru_cache(maxsize=64)
def _butter_sos(order: int, cutoff_hz: float, btype: str, rate_hz: float) -> np.ndarray:
    return _signal.butter(order, cutoff_hz, btype, fs=rate_hz, output="sos")


def highpass(y: np.ndarray, rate_hz: float, cutoff_hz: float, order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth high-pass of a 1-D signal (mean removed first). Shape as ``y``."""
    y = np.asarray(y, dtype=np.float64)
    sos = _butter_sos(order, float(cutoff_hz), "highpass", float(rate_hz))
    x = y - np.mean(y)
    pad = min(x.size - 1, int(3 * rate_hz / cutoff_hz))
    return _signal.sosfiltfilt(sos, x, padlen=pad)


def robust_std(x: np.ndarray, center: float | None = None) -> float:
    """1.4826 x the median absolute deviation of ``x`` about ``center`` (its median when None): the std
    of Gaussian samples, which a few outliers do not move."""
    c = float(np.median(x)) if center is None else center
    return 1.4826 * float(np.median(np.abs(x - c)))


def white_std(y: np.ndarray) -> float:
    """Std of the white part of a signal's noise, from its second difference (output units).

    The robust std (MAD x 1.4826) of ``diff(y, 2)`` over sqrt(6), which is the std of
    white noise added sample by sample; a signal smooth at the sample rate (a cycle of
    tens of samples, a filtered estimate such as a Kalman filter's) gives almost none,
    and the few samples around a relay switch or an estimator's correction do not
    count. Zero for fewer than 4 samples.
    """
    d2 = np.diff(np.asarray(y, dtype=np.float64), 2)
    if d2.size < 4:
        return 0.0
    return robust_std(d2) / math.sqrt(6.0)


def smooth_part(x: np.ndarray, rate_hz: float, cutoff_hz: float | np.ndarray, order: int = 4) -> np.ndarray:
    """Zero-phase low-pass of each row: gain ``1 / (1 + (f / cutoff_hz)^(2 order))``.

    The complement of a zero-phase (forward-backward) Butterworth high-pass of
    that order at the same cut-off: ``x - smooth_part(x)`` is the part above it.
    Computed in the frequency domain on the record extended at both ends by
    odd reflection (as ``scipy.signal.filtfilt`` pads), one cut-off per row.

    Parameters
    ----------
    x : (T,) or (m, T) array
    rate_hz : float
        Sample rate, Hz.
    cutoff_hz : float or (m,) array
        Cut-off of each row, Hz (> 0).

    Returns
    -------
    array shaped as ``x``
    """
    x = np.asarray(x, dtype=np.float64)
    one = x.ndim == 1
    X = np.atleast_2d(x)
    m, T = X.shape
    fc = np.broadcast_to(np.asarray(cutoff_hz, dtype=np.float64), (m,))
    pad = int(min(T - 1, math.ceil(3 * rate_hz / float(np.min(fc)))))
    left = 2 * X[:, :1] - X[:, pad:0:-1]
    right = 2 * X[:, -1:] - X[:, -2:-pad - 2:-1]
    ext = np.concatenate([left, X, right], axis=1)
    n = ext.shape[1]
    f = np.fft.rfftfreq(n, 1.0 / rate_hz)
    gain = 1.0 / (1.0 + (f[None, :] / fc[:, None]) ** (2 * order))
    out = np.fft.irfft(np.fft.rfft(ext, axis=1) * gain, n=n, axis=1)[:, pad:pad + T]
    return out[0] if one else out


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
    # drop the first and last excursions: they are cut by the record's ends
    if cuts.size < 2:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    a, b = cuts[0], cuts[-1]
    mag = np.abs(x[a:b])
    starts = cuts[:-1] - a
    seg = np.repeat(np.arange(starts.size), np.diff(cuts))
    top = np.maximum.reduceat(mag, starts)
    # first sample of each excursion at its extreme magnitude
    hit = np.flatnonzero(mag == top[seg])
    _, first = np.unique(seg[hit], return_index=True)
    idx = a + hit[first]
    return idx.astype(np.int64), x[idx]


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
        Quantile of ``|x_hp|`` taken as the noise amplitude ``a_n``.

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
    return _summarize(y, highpass(y, rate_hz, cutoff_hz), rate_hz, float(cutoff_hz), quantile, notes)


def estimate_noise_batch(y: np.ndarray, rate_hz: float, quantile: float = A_N_QUANTILE) -> list[NoiseEstimate]:
    """:func:`estimate_noise` of ``m`` hover segments of one length, (m, T), high-passed together."""
    y = np.asarray(y, dtype=np.float64)
    if y.ndim != 2 or y.shape[1] < max(32, int(4 * rate_hz / HOVER_CUTOFF_HZ)) or not np.all(np.isfinite(y)):
        raise UserError(f"noise estimation needs finite hover segments (m, T) of at least "
                        f"{max(32, int(4 * rate_hz / HOVER_CUTOFF_HZ))} samples, got shape {y.shape}")
    x = y - np.mean(y, axis=1, keepdims=True)
    sos = _butter_sos(4, HOVER_CUTOFF_HZ, "highpass", float(rate_hz))
    x = _signal.sosfiltfilt(sos, x, axis=1, padlen=min(x.shape[1] - 1, int(3 * rate_hz / HOVER_CUTOFF_HZ)))
    return [_summarize(y[i], x[i], rate_hz, HOVER_CUTOFF_HZ, quantile, []) for i in range(y.shape[0])]


def _summarize(y: np.ndarray, x: np.ndarray, rate_hz: float, cutoff_hz: float, quantile: float,
               notes: list[str]) -> NoiseEstimate:
    """The estimate from a segment ``y`` and its high-passed ``x``."""
    sigma = float(np.std(x))
    idx, val = excursion_peaks(x)
    scale = float(np.max(np.abs(y - np.mean(y)))) or 1.0
    if sigma <= 1e-12 * scale or idx.size < 4:
        notes.append("no noise found in the segment")
        return NoiseEstimate(float("nan"), 0.0, 0.0, sigma, 1.0 / rate_hz, float(cutoff_hz), float(rate_hz),
                             int(idx.size), notes)
    pos = idx[val > 0]
    T_n = float(np.median(np.diff(pos))) / rate_hz if pos.size > 1 else float("nan")
    a_mean = float(np.mean(np.abs(val)))
    a_n = float(np.quantile(np.abs(x), quantile))
    tau = _round_up(TAU_FACTOR * T_n, rate_hz) if math.isfinite(T_n) else 1.0 / rate_hz
    if math.isfinite(T_n) and T_n * cutoff_hz > 0.5:
        notes.append(f"T_n {T_n:.4g} s is close to the high-pass period: noise and motion may not separate")
    return NoiseEstimate(T_n, a_n, a_mean, sigma, tau, float(cutoff_hz), float(rate_hz), int(idx.size), notes)


def _round_up(tau: float, rate_hz: float) -> float:
    """Smallest multiple of 1/rate_hz that is >= tau (tolerant to rounding)."""
    return math.ceil(tau * rate_hz - 1e-9) / rate_hz


def _round_down(tau: float, rate_hz: float) -> float:
    """Largest multiple of 1/rate_hz that is <= tau (tolerant to rounding), at least one sample."""
    return max(math.floor(tau * rate_hz + 1e-9), 1) / rate_hz


def tau_obs_max(beta: float, period: float, rate_hz: float) -> float:
    """Largest multiple of 1/rate_hz with ``beta_min(tau_obs, period) <= beta``, s (may be 0)."""
    if not -1 < beta < 1:
        raise UserError(f"MRFT beta must lie in (-1, 1), got {beta}")
    if not (math.isfinite(period) and period > 0):
        raise UserError(f"cycle period must be > 0 s, got {period}")
    # -1 + sin(2 pi tau / T0) <= beta  <=>  tau <= T0 asin(1 + beta) / (2 pi)  (beta <= 0)
    ratio = 0.25 if beta >= 0 else math.asin(1 + beta) / (2 * math.pi)
    return math.floor(ratio * period * rate_hz + 1e-9) / rate_hz


def synthetic_hover(n: int, seconds: float, rate_hz: float, a0: np.ndarray, effect, rng: np.random.Generator
                    ) -> np.ndarray:
    """Hover records of ``n`` episodes as their sensor shows them, (n, T).

    A slow drift of ``0.2 a0`` (0.05-0.3 Hz, random phase: the vehicle holding
    position) through the measurement ``effect`` (a ``SignalEffect`` reset here for
    ``n`` episodes, or None for a clean sensor).
    """
    steps = int(round(seconds * rate_hz))
    t = np.arange(steps) / rate_hz
    f = rng.uniform(0.05, 0.3, (n, 1))
    ph = rng.uniform(0, 2 * np.pi, (n, 1))
    drift = 0.2 * np.asarray(a0, dtype=np.float64).reshape(-1, 1) * np.sin(2 * np.pi * f * t + ph)
    if effect is None:
        return drift
    effect.reset(n, rate_hz, rng)
    block = getattr(effect, "block", None)
    if block is not None:  # a precomputed trace (uavsim.data.noise_trace): the same samples in one call
        return np.ascontiguousarray(block(drift.T).T)
    return np.stack([effect(drift[:, k], k) for k in range(steps)], axis=1)


def recommend(noise: NoiseEstimate, beta: float, T0_expected: float | None = None) -> tuple[float, float]:
    """NP-MRFT ``(tau_obs, a_n)`` of a first relay run, from a hover estimate.

    Parameters
    ----------
    noise : NoiseEstimate
        From :func:`estimate_noise` on a hover segment.
    beta : float
        Planned MRFT parameter, in (-1, 1).
    T0_expected : float, optional
        Expected cycle period, s, if the user knows it; default
        ``FIRST_RUN_PERIOD`` (the fastest cycle of the paper's box).

    Returns
    -------
    tau_obs : float
        ``TAU_FACTOR x T_n`` rounded up to a sample, but no longer than
        ``TAU_LEVEL_FRACTION x tau_obs_limit(beta, T0)`` (at least one
        sample), s; a note says when that cap wins.
    a_n : float
        ``A_N_FIRST x`` the noise amplitude, output units.

    A run with these settings is then refined with :func:`refine`.
    """
    if not -1 < beta < 1:
        raise UserError(f"MRFT beta must lie in (-1, 1), got {beta}")
    T0 = FIRST_RUN_PERIOD if T0_expected is None else float(T0_expected)
    if not (math.isfinite(T0) and T0 > 0):
        raise UserError(f"expected cycle period must be > 0 s, got {T0_expected}")
    cap = _round_down(TAU_LEVEL_FRACTION * float(tau_obs_limit(beta, T0)), noise.rate_hz)
    tau = noise.tau_obs
    if cap < tau:
        what = "the expected" if T0_expected is not None else "the shortest"
        noise.notes.append(f"tau_obs {tau:.4g} s >= T_n capped at {cap:.4g} s: {what} cycle ({T0:.4g} s) at beta "
                           f"{beta} reaches its switching level sooner")
        tau = cap
    return tau, A_N_FIRST * noise.a_n


def recommended_beta_min(tau_obs: float, T0: float | None) -> float:
    """``beta_min(tau_obs, T0)`` as a float (nan when ``T0`` is unknown)."""
    if T0 is None or not math.isfinite(T0) or T0 <= 0:
        return float("nan")
    return float(beta_min(tau_obs, T0))


@dataclass
class RelayRefinement:
    """NP-MRFT settings refined from a relay run, and what the run showed.

    Attributes
    ----------
    tau_obs : float
        Refined observation time, s (a multiple of the sample time, >= one sample).
    a_n : float
        Refined switching correction, output units.
    period : float
        Median cycle period of the run's steady state, s.
    amplitude : float
        Median over cycles of half the peak-to-peak of the error's smooth part, output units.
    level_time : float
        Median time from a half-cycle's smooth extremum to its noise-free switching level, s.
    switch_error : float
        Median over half-cycles of how early the relay switched against that level, in the
        error's units (negative: late), net of the half-sample a sampled relay is late on average.
    noise : NoiseEstimate
        The residual of the error against its smooth part (the noise as the relay saw it).
    half_cycles : int
        Half-cycles measured.
    refined : bool
        False when the run had too few steady half-cycles: the settings are the run's own.
    notes : list of str
        How the settings were obtained and anything doubtful.
    """

    tau_obs: float
    a_n: float
    period: float
    amplitude: float
    noise: NoiseEstimate
    notes: list[str] = field(default_factory=list)
    level_time: float = float("nan")
    switch_error: float = float("nan")
    half_cycles: int = 0
    refined: bool = False

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def _settle_start(t: np.ndarray, settle: float | None) -> int:
    if settle is None:
        settle = 0.3 * (t[-1] - t[0])
    return int(np.searchsorted(t, t[0] + settle))


def half_cycles(e_smooth: np.ndarray, u: np.ndarray, beta: float, start: int = 0) -> dict[str, np.ndarray]:
    """Per half-cycle of a relay record: its smooth extremum, switching error and time to the level.

    A half-cycle runs from one switch of ``u`` to the next (at or after ``start``);
    its extremum is the maximum of ``e_smooth`` when the relay switched down at its
    end, the minimum when it switched up. Its noise-free switching level is
    ``-beta x extremum``; when that level is not beyond the extremum (a relay bias
    can put a whole half-wave on the other side of zero) the switch is due as soon
    as the extremum is confirmed: the half-cycle is *degenerate*.

    Parameters
    ----------
    e_smooth : (T,) the error's smooth part, output units
    u : (T,) relay output
    beta : MRFT parameter
    start : first sample considered

    Returns
    -------
    dict of (m,) arrays: ``down`` (bool, the half-cycle ended with a switch down),
    ``valid`` (bool, not degenerate), ``extremum``; ``early`` (how far the smooth error
    was still before the level at the switch sample, output units, > 0 early);
    ``late_half_sample`` (half the smooth error's change over the switch sample: how
    late a noise-free sampled relay is on average); ``level_samples`` (samples from the
    extremum to the first sample at or beyond the level, 0 when degenerate, -1 when
    not reached in the record).
    """
    s = np.asarray(e_smooth, dtype=np.float64)
    return _half_cycles(s, relay_phase(u), switch_indices(u), beta, start)


def _first_beyond(s: np.ndarray, i: int, near: int, lvl: float, down: bool) -> int:
    """Samples from ``i`` to the first of ``s[i:]`` at or beyond ``lvl`` (below when ``down``), -1 if none.

    Searches ``s[i:near]`` first: the level is usually reached within the half-cycle.
    """
    for lo, hi in ((i, near), (near, s.size)):
        seg = s[lo:hi]
        hit = np.flatnonzero(seg <= lvl) if down else np.flatnonzero(seg >= lvl)
        if hit.size:
            return lo - i + int(hit[0])
    return -1


def _half_cycles(s: np.ndarray, high: np.ndarray, sw: np.ndarray, beta: float, start: int) -> dict[str, np.ndarray]:
    """:func:`half_cycles` from the relay phase ``high`` and switch indices ``sw`` of ``u``."""
    sw = sw[sw >= max(start, 1)]
    cols: dict[str, list] = {k: [] for k in ("down", "valid", "extremum", "early", "late_half_sample",
                                             "level_samples")}
    for a, b in zip(sw[:-1].tolist(), sw[1:].tolist(), strict=True):
        down = not high[b]
        seg = s[a:b]
        j = int(np.argmax(seg) if down else np.argmin(seg))
        x = float(seg[j])
        lvl = -beta * x
        valid = (x > lvl) if down else (x < lvl)
        cols["down"].append(down)
        cols["valid"].append(valid)
        cols["extremum"].append(x)
        cols["early"].append((s[b] - lvl) if down else (lvl - s[b]))
        cols["late_half_sample"].append(0.5 * abs(s[b] - s[b - 1]))
        cols["level_samples"].append(_first_beyond(s, a + j, b + 1, lvl, down) if valid else 0)
    out = {k: np.asarray(v, dtype=float) for k, v in cols.items()}
    out["down"] = out["down"].astype(bool)
    out["valid"] = out["valid"].astype(bool)
    out["level_samples"] = out["level_samples"].astype(np.int64)
    return out


def on_lattice(x: np.ndarray, *, tol: float = 1e-6, share: float = 0.99) -> np.ndarray:
    """Whether each row's samples lie on a lattice: its steps whole multiples of its smallest step.

    Parameters
    ----------
    x : (m, T) signals (a quantized measurement less a constant reference)
    tol : how far from a whole multiple a step may be, as a fraction of the smallest step
    share : the share of the nonzero steps that must be whole multiples

    Returns
    -------
    (m,) bool; False for a row with fewer than 8 nonzero steps (nothing to judge).
    """
    x = np.atleast_2d(np.asarray(x, dtype=np.float64))
    out = np.zeros(x.shape[0], dtype=bool)
    for i, row in enumerate(x):
        d = np.abs(np.diff(row))
        scale = float(np.max(np.abs(row))) if row.size else 0.0
        d = d[d > 1e-12 * scale]
        if d.size < 8:
            continue
        r = d / d.min()
        out[i] = float(np.mean(np.abs(r - np.round(r)) <= tol * np.maximum(r, 1.0))) >= share
    return out


def refine_batch(t: np.ndarray, e: np.ndarray, u: np.ndarray, *, beta: float | np.ndarray,
                 tau_obs: float | np.ndarray, a_n: float | np.ndarray, rate_hz: float, settle: float | None = None,
                 hover_a_n: float | np.ndarray | None = None) -> dict[str, np.ndarray]:
    """:func:`refine` for ``m`` runs of one length at once (the arithmetic of the refinement).

    Parameters
    ----------
    t : (T,) time, s
    e, u : (m, T) errors ``r - y`` and relay outputs
    beta, tau_obs, a_n : float or (m,) the runs' settings
    rate_hz : controller rate, Hz
    settle : transient to skip, s (default: 30% of the record)
    hover_a_n : float or (m,), optional: a hover's noise amplitude (``NoiseEstimate.a_n``)

    Returns
    -------
    dict of (m,) arrays: ``tau_obs``, ``a_n`` (refined; the run's own where ``refined``
    is False), ``period``, ``amplitude``, ``level_time``, ``switch_error``,
    ``noise_amplitude`` (the ``A_N_QUANTILE`` quantile of the residual above the cycle's
    harmonics), ``cutoff_hz``, ``half_cycles`` (int), ``false_switches`` (int: half-periods
    shorter than a quarter of the period), ``refined`` (bool), and ``smooth`` (m, T), the
    errors' smooth parts.
    """
    t = np.asarray(t, dtype=np.float64)
    E = np.atleast_2d(np.asarray(e, dtype=np.float64))
    U = np.atleast_2d(np.asarray(u, dtype=np.float64))
    m, T = E.shape
    if U.shape != (m, T) or t.shape != (T,):
        raise UserError(f"refine needs t (T,) and e, u (m, T), got {t.shape}, {E.shape}, {U.shape}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise UserError(f"sample rate must be > 0 Hz, got {rate_hz}")
    beta, tau0, an0 = (np.broadcast_to(np.asarray(v, dtype=np.float64), (m,)) for v in (beta, tau_obs, a_n))
    if np.any(~(np.abs(beta) < 1)):
        raise UserError(f"MRFT beta must lie in (-1, 1), got {beta[~(np.abs(beta) < 1)][0]}")
    i0 = _settle_start(t, settle)
    nan = np.full(m, np.nan)
    out = {"tau_obs": tau0.copy(), "a_n": an0.copy(), "period": nan.copy(), "amplitude": nan.copy(),
           "level_time": nan.copy(), "switch_error": nan.copy(), "noise_amplitude": nan.copy(),
           "cutoff_hz": nan.copy(), "half_cycles": np.zeros(m, dtype=np.int64), "refined": np.zeros(m, dtype=bool),
           "false_switches": np.zeros(m, dtype=np.int64),
           "smooth": np.full((m, T), np.nan)}
    finite = np.all(np.isfinite(E), axis=1)
    # the relay phase of every run at once (relay_phase row by row: the same comparisons)
    high = U > (0.5 * (np.max(U, axis=1) + np.min(U, axis=1)))[:, None] if T else np.zeros((m, 0), bool)
    change = high[:, 1:] != high[:, :-1]
    rise = high[:, 1:] & ~high[:, :-1]
    switches: dict[int, np.ndarray] = {}
    for i in np.flatnonzero(finite):
        # the period from every span of two half-cycles: a short record still gives several
        switches[i] = np.flatnonzero(change[i]) + 1
        sw = switches[i][switches[i] >= i0]
        if sw.size >= MIN_HALF_CYCLES + 1:
            out["period"][i] = float(np.median(t[sw[2:]] - t[sw[:-2]]))
    ok = np.flatnonzero(np.isfinite(out["period"]))
    if ok.size == 0:
        return out
    cutoff = np.minimum(OSC_CUTOFF_HARMONIC / out["period"][ok], 0.2 * rate_hz)
    out["cutoff_hz"][ok] = cutoff
    S = smooth_part(E[ok], rate_hz, cutoff)
    out["smooth"][ok] = S
    out["noise_amplitude"][ok] = np.quantile(np.abs(E[ok, i0:] - S[:, i0:]), A_N_QUANTILE, axis=1)
    q = out["noise_amplitude"].copy()
    if hover_a_n is not None:
        q = np.minimum(q, np.broadcast_to(np.asarray(hover_a_n, dtype=np.float64), (m,)))
    floor = np.zeros(m)
    floor[ok] = np.where(on_lattice(E[ok, i0:]), 0.0, A_N_MIN * q[ok])
    for j, i in enumerate(ok):
        edges = np.flatnonzero(rise[i]) + 1
        edges = edges[edges >= i0]
        if edges.size >= 2:
            # cycles between consecutive rising edges (reduceat's last segment runs to the end: dropped)
            lo = np.minimum.reduceat(S[j], edges)[:-1]
            hi = np.maximum.reduceat(S[j], edges)[:-1]
            out["amplitude"][i] = float(np.median(0.5 * (hi - lo)))
        hc = _half_cycles(S[j], high[i], switches[i], float(beta[i]), i0)
        valid = hc["valid"]
        out["half_cycles"][i] = int(valid.sum())
        if hc["down"].size < MIN_HALF_CYCLES or valid.sum() < MIN_VALID_HALF_CYCLES:
            continue
        # a noise-free sampled relay switches half a sample's change past the level on average
        err = float(np.median((hc["early"] + hc["late_half_sample"])[valid]))
        out["switch_error"][i] = err
        a_n_new = an0[i] + A_N_GAIN * err / (1.0 - beta[i])
        # false switches (half-periods under a quarter of the period: beta held tau_obs below the
        # noise period) make the half-cycles' errors meaningless: the correction is the protection left
        sw = switches[i][switches[i] >= i0]
        out["false_switches"][i] = int(np.sum(np.diff(t[sw]) < 0.25 * out["period"][i]))
        if out["false_switches"][i]:
            a_n_new = max(a_n_new, A_N_FALSE_FACTOR * an0[i], A_N_FALSE_FLOOR * q[i])
        out["a_n"][i] = float(np.clip(a_n_new, floor[i], A_N_MAX * q[i]))
        # the observation must hold back neither switch: the median over the half-cycles, but
        # no more than LEVEL_SIDE_SLACK x the shorter side's (a relay bias makes the sides differ)
        # (degenerate half-cycles, whose switch is due at the extremum, cannot be spared: they do not count)
        lv = hc["level_samples"]
        use = valid & (lv >= 0)
        sides = [np.median(lv[use & (hc["down"] == d)]) for d in (True, False) if np.any(use & (hc["down"] == d))]
        if sides:
            level = min(float(np.median(lv[use])), LEVEL_SIDE_SLACK * float(min(sides)))
            out["level_time"][i] = level / rate_hz
            tau_new = _round_down(TAU_LEVEL_FRACTION * out["level_time"][i], rate_hz)
            if len(sides) == 1:
                # one side's half-waves never reach beyond zero (a strong relay bias): their switch
                # waits for tau_obs alone, so a longer window only lengthens the cycle, and the
                # other side's level time grows with it (run after run, until the cycle runs away)
                tau_new = min(tau_new, float(tau0[i]))
            out["tau_obs"][i] = tau_new
        out["refined"][i] = True
    return out


def refine(t: np.ndarray, e: np.ndarray, u: np.ndarray, *, beta: float, tau_obs: float, a_n: float, rate_hz: float,
           settle: float | None = None, hover: NoiseEstimate | None = None) -> RelayRefinement:
    """NP-MRFT settings for the next run, from a relay run (see the module docstring).

    Parameters
    ----------
    t, e, u : (T,) arrays
        The run: time (s), error ``r - y`` as the controller saw it, relay output.
    beta, tau_obs, a_n : float
        The run's NP-MRFT settings (``tau_obs = 0, a_n = 0`` for a plain MRFT run).
    rate_hz : float
        Controller rate, Hz.
    settle : float, optional
        Transient to skip, s (default: 30% of the record).
    hover : NoiseEstimate, optional
        A hover estimate of the same sensor: ``a_n`` never exceeds ``A_N_MAX`` times
        the smaller of its noise amplitude and the run's.

    Returns
    -------
    RelayRefinement
    """
    t, e, u = (np.asarray(v, dtype=np.float64) for v in (t, e, u))
    if not (t.ndim == e.ndim == u.ndim == 1 and t.size == e.size == u.size):
        raise UserError(f"refine needs 1-D t, e, u of one length, got {t.shape}, {e.shape}, {u.shape}")
    if not -1 < beta < 1:
        raise UserError(f"MRFT beta must lie in (-1, 1), got {beta}")
    if not np.all(np.isfinite(e)):
        raise UserError("refine: the run has non-finite samples")
    r = refine_batch(t, e[None], u[None], beta=beta, tau_obs=tau_obs, a_n=a_n, rate_hz=rate_hz, settle=settle,
                     hover_a_n=None if hover is None else hover.a_n)
    g = {k: v[0] for k, v in r.items()}
    period = float(g["period"])
    if not math.isfinite(period):
        est = NoiseEstimate(float("nan"), 0.0, 0.0, 0.0, tau_obs, float("nan"), float(rate_hz), 0, [])
        return RelayRefinement(tau_obs, a_n, period, float("nan"), est,
                               notes=["no steady relay cycle in the run: settings kept"])
    i0 = _settle_start(t, settle)
    residual = e[i0:] - g["smooth"][i0:]
    noise = estimate_noise(residual, rate_hz, cutoff_hz=float(g["cutoff_hz"]))
    noise.a_n = float(g["noise_amplitude"])
    m = int(g["half_cycles"])
    notes = [f"{m} half-cycles of period {period:.4g} s; noise = the residual above {g['cutoff_hz']:.3g} Hz"]
    if not g["refined"]:
        notes.append(f"too few half-cycles ({m} with the extremum beyond its switching level, need "
                     f"{MIN_VALID_HALF_CYCLES} of {MIN_HALF_CYCLES}): settings kept")
    elif not math.isfinite(g["level_time"]):
        notes.append("the switching level was never reached after an extremum: tau_obs kept")
    T_n = hover.T_n if hover is not None and math.isfinite(hover.T_n) else noise.T_n
    if g["refined"] and math.isfinite(T_n) and g["tau_obs"] < T_n:
        notes.append(f"tau_obs {g['tau_obs']:.4g} s < T_n {T_n:.4g} s: beta {beta} does not allow more on this cycle")
    return RelayRefinement(float(g["tau_obs"]), float(g["a_n"]), period, float(g["amplitude"]), noise,
                           level_time=float(g["level_time"]), switch_error=float(g["switch_error"]), half_cycles=m,
                           refined=bool(g["refined"]), notes=notes)

