"""Limit-cycle metrics of relay tests: period, amplitude, false switching.

A relay test (MRFT, NP-MRFT, the baselines) drives the loop into a
self-excited oscillation. These functions read it back from the sampled
record of one episode: the relay output ``u`` is thresholded at its mid-level
(so a bias does not matter), its rising edges delimit cycles, and only the
steady state (after ``settle`` seconds, default the first 30% of the record)
counts. The period is the median of the cycle lengths (robust to an odd cycle
broken by noise), the amplitude the median over cycles of half the
peak-to-peak of ``y`` within each cycle.

False switching is counted against a reference period ``T_ref`` (the
noise-free period of the same process): an interval between consecutive
switches shorter than ``frac * T_ref / 2`` is a switch that should not have
happened, so ``false_switch_rate`` = such intervals per reference period.

    period, amplitude, n_cycles = cycle_stats(t, y, u)
    rate = false_switch_rate(t, u, period_ref=period0)
    ok = sustained(t, y_true, u, a_ref=a0)
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class CycleStats(NamedTuple):
    """Steady-state oscillation summary (unpacks as ``period, amplitude, n_cycles``)."""

    period: float
    """median cycle length, s (nan with fewer than one full cycle)"""
    amplitude: float
    """median over cycles of (max y - min y) / 2, output units (nan likewise)"""
    n_cycles: int
    """number of full cycles (rising edge to rising edge) in the steady state"""


def relay_phase(u: np.ndarray) -> np.ndarray:
    """Boolean "relay high" signal: ``u`` above its mid-level ``(max + min) / 2``. Shape as ``u``."""
    u = np.asarray(u, dtype=np.float64)
    if u.size == 0:
        return np.zeros(0, dtype=bool)
    mid = 0.5 * (np.max(u) + np.min(u))
    return u > mid


def rising_edges(u: np.ndarray) -> np.ndarray:
    """Indices ``i`` where the relay goes high at sample ``i`` (int array)."""
    s = relay_phase(u)
    return np.flatnonzero(s[1:] & ~s[:-1]) + 1


def switch_indices(u: np.ndarray) -> np.ndarray:
    """Indices ``i`` where the relay changes level at sample ``i`` (both directions)."""
    s = relay_phase(u)
    return np.flatnonzero(s[1:] != s[:-1]) + 1


def cycle_harmonic_terms(x: np.ndarray, edges: np.ndarray, orders: tuple[int, ...] = (1,)) -> np.ndarray:
    """Each relay cycle's own harmonics, before ``cycle_harmonics`` averages them.

    For the cycle between ``edges[i]`` and ``edges[i + 1]`` (``N`` samples) the
    ``k``-th harmonic is ``sum_n x[n] exp(-2 pi j k n / N) / N``.

    Returns
    -------
    (len(edges) - 1, len(orders)) complex
    """
    x = np.asarray(x, dtype=np.float64)
    out = np.empty((len(edges) - 1, len(orders)), dtype=complex)
    for c, (i, j) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        n = j - i
        out[c] = np.exp(-2j * np.pi * np.outer(orders, np.arange(n)) / n) @ x[i:j] / n
    return out


def mean_over_cycles(terms: np.ndarray) -> np.ndarray:
    """The mean of per-cycle ``terms`` (c, k), summed cycle by cycle in order (``cycle_harmonics``'s bits)."""
    acc = np.zeros(terms.shape[1], dtype=complex)
    for t in terms:
        acc += t
    return acc / len(terms)


def cycle_harmonics(x: np.ndarray, edges: np.ndarray, orders: tuple[int, ...] = (1,)) -> np.ndarray:
    """Harmonics of a signal over whole relay cycles, each cycle on its own period.

    The mean over cycles of ``cycle_harmonic_terms``. Taken on the samples themselves,
    the ratio of two signals' harmonics is exactly the sampled system's frequency
    response at the cycle's frequency for a periodic cycle (a relay's held command and
    the output sampled with it).

    Parameters
    ----------
    x : (T,) signal
    edges : (m,) int, increasing sample indices delimiting ``m - 1`` cycles (m >= 2)
    orders : harmonic orders

    Returns
    -------
    (len(orders),) complex
    """
    return mean_over_cycles(cycle_harmonic_terms(x, edges, orders))


def _settle_index(t: np.ndarray, settle: float | None) -> int:
    if settle is None:
        settle = 0.3 * (t[-1] - t[0])
    return int(np.searchsorted(t, t[0] + settle))


def cycle_stats(t: np.ndarray, y: np.ndarray, u: np.ndarray, settle: float | None = None) -> CycleStats:
    """Period and amplitude of the steady-state oscillation of one episode.

    Parameters
    ----------
    t : array (T,)
        Sample times, s.
    y : array (T,)
        Signal whose amplitude is measured (measured or true output), output units.
    u : array (T,)
        Relay output, command units.
    settle : float, optional
        Transient to skip, s (default: 30% of the record).

    Returns
    -------
    CycleStats
        ``(period, amplitude, n_cycles)``; period and amplitude are nan
        when the steady state holds no full cycle.
    """
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if t.size < 3:
        return CycleStats(float("nan"), float("nan"), 0)
    i0 = _settle_index(t, settle)
    edges = rising_edges(u)
    edges = edges[edges >= i0]
    if edges.size < 2:
        return CycleStats(float("nan"), float("nan"), 0)
    periods = np.diff(t[edges])
    amps = np.array([0.5 * (np.max(y[a:b]) - np.min(y[a:b])) for a, b in zip(edges[:-1], edges[1:], strict=True)])
    return CycleStats(float(np.median(periods)), float(np.median(amps)), int(periods.size))


def false_switch_rate(t: np.ndarray, u: np.ndarray, period_ref: float, settle: float | None = None,
                      frac: float = 0.5) -> float:
    """Extra relay switches per reference period in the steady state.

    Parameters
    ----------
    t, u : array (T,)
        Sample times (s) and relay output.
    period_ref : float
        Noise-free oscillation period, s.
    settle : float, optional
        Transient to skip, s (default: 30% of the record).
    frac : float
        An interval between switches shorter than ``frac * period_ref / 2`` is false.

    Returns
    -------
    float
        Short intervals per ``period_ref`` of steady-state record (nan if ``period_ref`` is not > 0).
    """
    t = np.asarray(t, dtype=np.float64)
    if not (np.isfinite(period_ref) and period_ref > 0) or t.size < 3:
        return float("nan")
    i0 = _settle_index(t, settle)
    sw = switch_indices(u)
    sw = sw[sw >= i0]
    window = t[-1] - t[i0] if i0 < t.size else 0.0
    if window <= 0:
        return float("nan")
    short = int(np.sum(np.diff(t[sw]) < frac * period_ref / 2)) if sw.size > 1 else 0
    return short / (window / period_ref)


def sustained(t: np.ndarray, y_true: np.ndarray, u: np.ndarray, a_ref: float, settle: float | None = None,
              min_cycles: int = 3, min_amp: float = 0.1) -> bool:
    """Whether the episode holds a sustained oscillation.

    True when the steady state has at least ``min_cycles`` full cycles, ``y_true``
    stays finite, and its amplitude is at least ``min_amp * a_ref`` (chatter at a
    tiny amplitude is not the test's limit cycle).
    """
    y_true = np.asarray(y_true, dtype=np.float64)
    if not np.all(np.isfinite(y_true)):
        return False
    _, amp, n = cycle_stats(t, y_true, u, settle)
    return bool(n >= min_cycles and np.isfinite(amp) and amp >= min_amp * a_ref)


def batch_cycle_stats(t: np.ndarray, y: np.ndarray, u: np.ndarray, settle: float | None = None) -> tuple[
        np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cycle_stats` for each row of ``y``, ``u`` (n, T); returns period, amplitude, n_cycles (n,)."""
    res = [cycle_stats(t, yi, ui, settle) for yi, ui in zip(y, u, strict=True)]
    return (np.array([r.period for r in res]), np.array([r.amplitude for r in res]),
            np.array([r.n_cycles for r in res], dtype=np.int64))
