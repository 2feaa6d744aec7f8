"""MRFT and noise-protected MRFT (NP-MRFT), vectorized over a batch.

The modified relay feedback test switches a relay of amplitude ``h`` at a
level proportional to the last extremum of the error, which places the
self-excited oscillation at the phase ``arg G(j Omega) = -pi + asin(beta)``.
NP-MRFT (paper eq. 19-27) tracks the extremum of each half-wave of the error
*after its zero crossing*, only accepts it once it has stood for ``tau_obs``,
and lowers the switching levels by ``a_n (1 - beta)``, so that measurement
noise neither switches the relay early nor fools the extremum.

This module is the one implementation of the controller semantics of
``docs/formats/session.md``, used to generate sessions and datasets and to
simulate and replay them. Two readings exist:

``reading=2`` (format ``uavsim-session/2``, the default)
    The half-wave reading: after a switch to ``-h`` the minimum is tracked
    only from the first sample with ``e`` at or below the cycle's centre (to
    ``+h``: the maximum from the first at or above it): zero, as in the paper,
    or, for a relay with a bias, the last cycle's mean error
    (:attr:`NPMRFT.centre`). If that half-wave has not started within ``W``
    samples of the switch (``W`` = :func:`guard_fraction` of the longer of the
    two previous half-periods), tracking starts anyway at that sample
    (deadlock guard): a relay whose switch was false is never left waiting for
    a zero crossing that the loop, driven away by that very switch, will not
    make.
``reading=1`` (format ``uavsim-session/1``)
    The tracker restarts at the switch sample (kept to read version-1
    sessions exactly as they were written).

One instance holds the state of ``n`` independent relays in numpy arrays;
call it once per controller sample with the errors ``e`` (shape ``(n,)``).

    relay = NPMRFT(beta=-0.73, h=0.2, tau_obs=0.0325, a_n=0.003, rate_hz=200.0, n=1024)
    for k in range(steps):
        u = relay(r - y)            # (1024,) command, bias included
        switched = relay.switched   # (1024,) bool, True where the relay switched at this sample

Ties do not move the extremum: a plateau (a quantized signal) is timed from
its first sample, which is when it was reached.

A relay run with ``bias_trim="duty"`` trims its own bias (``RELAY_BIAS_TRIMS``):
a constant disturbance at the input (a hover-thrust error, a trim offset) makes
the cycle of an integrating loop asymmetric, with less amplitude for the same
sensor noise, and under noise much less regular (a bias of 0.4 h at 10 % noise:
cycle-to-cycle period spread 0.20 of the period, trimmed 0.03). On these loops the
input's mean over a steady cycle is zero, so the cycle's duty measures the bias:
at every switch to ``+h`` the bias moves by a quarter of the last cycle's duty error
(:meth:`NPMRFT._trim`), from the third cycle on and where its half-waves differ
by more than a sample. Within about ten cycles (an episode's refinement stages
and its own cycles) the bias left is a sample of duty and
the cycle is the bias-free one to that resolution. The recorded ``u`` carries the
moving bias; :func:`relay_sign` and :func:`untrimmed` read the relay's states
back from it, and :func:`relay_command` is how a run is read for identification.
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.errors import UserError
from uavsim.formats.session import MRFT_RUN, NP_MRFT_RUN, RELAY_BIAS_TRIMS

#: relay readings: 1 = tracker restarts at the switch (uavsim-session/1), 2 = half-wave after the zero crossing
READINGS = (1, 2)
#: the reading sessions are written with
READING = 2
#: a trimmed bias's move at a switch to +h, as a fraction of the last cycle's duty error
TRIM_GAIN = 0.25
#: largest move of a trimmed bias at one switch, in units of h: a switch to +h then moves
#: ``u`` by 1.9-2.1 h and a switch to -h by exactly -2 h, so ``relay_sign`` reads both apart
TRIM_STEP_MAX = 0.1
#: half-waves differing by no more than this (samples) are even: a sampled relay's cycle can
#: alternate a sample between them, and trimming that moves the cycle between neighbouring ones
TRIM_DEADBAND = 1
#: switches before the first trim: the start-up half-waves are not a cycle of the loop
TRIM_AFTER_SWITCHES = 5
#: the trim law's version (gain and step above): training sets and their resume state record it,
#: so that a file or chunk made under another law is made again, not mixed in (1: gain 0.5, step h/4)
TRIM_RULE = 2


def as_batch(name: str, value: float | np.ndarray, n: int) -> np.ndarray:
    """A relay parameter (scalar or (n,)) as an (n,) float64 copy; ``UserError`` unless finite."""
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (n,)).copy()
    if not np.all(np.isfinite(arr)):
        raise UserError(f"relay parameter {name} must be finite")
    return arr


def check_relay_params(beta, h, tau_obs=0.0, a_n=0.0, rate_hz: float = 200.0) -> None:
    """Raise ``UserError`` for parameters a relay test cannot use.

    Parameters
    ----------
    beta : float or array
        MRFT parameter, strictly inside (-1, 1).
    h : float or array
        Relay amplitude, command units, > 0.
    tau_obs : float or array
        NP-MRFT observation time, s, >= 0.
    a_n : float or array
        Noise amplitude used in the switching correction, output units, >= 0.
    rate_hz : float
        Controller rate, Hz, > 0.
    """
    beta, h, tau_obs, a_n = (np.asarray(v, dtype=np.float64) for v in (beta, h, tau_obs, a_n))
    if not np.all(np.isfinite(beta)) or np.any(beta <= -1) or np.any(beta >= 1):
        raise UserError(f"MRFT beta must lie in (-1, 1), got {beta.ravel()[:3].tolist()}")
    if not np.all(np.isfinite(h)) or np.any(h <= 0):
        raise UserError(f"relay amplitude h must be > 0, got {h.ravel()[:3].tolist()}")
    if not np.all(np.isfinite(tau_obs)) or np.any(tau_obs < 0):
        raise UserError(f"NP-MRFT tau_obs must be >= 0 s, got {tau_obs.ravel()[:3].tolist()}")
    if not np.all(np.isfinite(a_n)) or np.any(a_n < 0):
        raise UserError(f"NP-MRFT a_n must be >= 0, got {a_n.ravel()[:3].tolist()}")
    if not math.isfinite(rate_hz) or rate_hz <= 0:
        raise UserError(f"controller rate must be > 0 Hz, got {rate_hz}")


def check_reading(reading: int) -> int:
    """``reading`` as an int, or ``UserError`` when it is not one of :data:`READINGS`."""
    if isinstance(reading, bool) or reading not in READINGS:
        raise UserError(f"relay reading must be one of {', '.join(map(str, READINGS))}, got {reading!r}")
    return int(reading)


def beta_min(tau_obs: float | np.ndarray, period: float | np.ndarray) -> np.ndarray:
    """Smallest realizable NP-MRFT beta for an observation time and a cycle period.

    ``beta_min = -1 + sin(2 pi tau_obs / T0)`` (the paper prints the formula
    without the 2 pi; its own example, T_n/T0 = 0.015 -> -0.906, needs it).

    Parameters
    ----------
    tau_obs : float or array
        Observation time, s.
    period : float or array
        Noise-free oscillation period T0, s.
    """
    ratio = np.asarray(tau_obs, dtype=np.float64) / np.asarray(period, dtype=np.float64)
    return -1.0 + np.sin(2.0 * np.pi * np.minimum(ratio, 0.25))


def tau_obs_limit(beta: float | np.ndarray, period: float | np.ndarray) -> np.ndarray:
    """Longest ``tau_obs`` that leaves a sinusoidal cycle's switching unchanged, s.

    On ``e = a0 cos(2 pi t / T0)`` the error reaches the switching level
    ``-beta a0`` at ``t = T0 acos(-beta) / (2 pi)`` after the extremum; an
    extremum confirmed before that moves no switch. :func:`beta_min` (the
    paper's formula) is more conservative: it is the same bound for a
    triangle-like cycle, whose extremum is sharp.

    Parameters
    ----------
    beta : float or array
        MRFT parameter in (-1, 1).
    period : float or array
        Cycle period T0, s.
    """
    b = np.clip(np.asarray(beta, dtype=np.float64), -1.0, 1.0)
    return np.asarray(period, dtype=np.float64) * np.arccos(-b) / (2.0 * np.pi)


def check_bias_trim(bias_trim: str) -> str:
    """``bias_trim`` if it is one of ``RELAY_BIAS_TRIMS`` (``"off"``: the bias stays; ``"duty"``:
    :meth:`NPMRFT._trim`), else ``UserError``."""
    if bias_trim not in RELAY_BIAS_TRIMS:
        raise UserError(f"relay bias_trim must be one of {', '.join(RELAY_BIAS_TRIMS)}, got {bias_trim!r}")
    return bias_trim


def relay_sign(u: np.ndarray, h: float | np.ndarray, bias: float | np.ndarray) -> np.ndarray:
    """The relay state ``s`` of +-1 behind a relay run's command ``u`` (..., T), bias trimmed or not.

    ``u = s h + b`` with ``b`` the run's ``bias`` (shape ``(...)``), constant, or moved at
    switches to ``+h`` by at most :data:`TRIM_STEP_MAX` ``h`` (``bias_trim = "duty"``); so
    ``u`` changes only at switches, by more than ``h``, and the state flips there. ``h`` is
    a scalar or of shape ``(...)``.
    """
    u = np.asarray(u, dtype=np.float64)
    if u.shape[-1] == 0:
        return np.zeros(u.shape)
    h = np.asarray(h, dtype=np.float64)[..., None]
    b = np.asarray(bias, dtype=np.float64)[..., None]
    flips = np.abs(np.diff(u, axis=-1)) > h
    s0 = np.where(u[..., :1] - b >= 0, 1.0, -1.0)
    odd = np.concatenate([np.zeros(flips.shape[:-1] + (1,), np.int64), np.cumsum(flips, axis=-1)], axis=-1) % 2
    return s0 * np.where(odd == 0, 1.0, -1.0)


def untrimmed(u: np.ndarray, h: float | np.ndarray, bias: float | np.ndarray) -> np.ndarray:
    """A trimmed relay run's command ``u`` (..., T) as the relay of constant ``bias`` in the same states.

    ``s h + bias`` (:func:`relay_sign`): what the preprocessing reads a relay run by
    (``uavsim.data.preprocess``), whose fundamental the trim's small steps do not move.
    """
    h_ = np.asarray(h, dtype=np.float64)[..., None]
    return relay_sign(u, h, bias) * h_ + np.asarray(bias, dtype=np.float64)[..., None]


def relay_command(u: np.ndarray, h: float | np.ndarray, bias: float | np.ndarray, bias_trim: str) -> np.ndarray:
    """A relay run's command ``u`` (..., T) as the preprocessing reads it: a trimmed run's (``bias_trim``
    ``"duty"``) as :func:`untrimmed`, any other as recorded. Generation, evaluation and sessions read runs so."""
    return u if bias_trim == "off" else untrimmed(u, h, bias)


def guard_fraction(beta: float | np.ndarray) -> np.ndarray:
    """Deadlock guard of the half-wave reading: ``W = guard_fraction(beta) x`` the longer previous half-period.

    ``1/4 + asin(max(-beta, 0)) / pi``: on a sinusoidal cycle the error crosses
    zero ``asin(-beta) / pi`` of a half-period after the switch (beta < 0; at
    once for beta >= 0), so the guard never acts on an undisturbed cycle (0.51
    at beta = -0.73, at most 0.75); and as it is below 1, a relay driven only
    by the guard cannot lengthen its half-periods without bound.
    """
    b = np.asarray(beta, dtype=np.float64)
    return 0.25 + np.arcsin(np.clip(-b, 0.0, 1.0)) / np.pi


class NPMRFT:
    """``n`` NP-MRFT relays stepped together at ``rate_hz``.

    Parameters
    ----------
    beta, h, tau_obs, a_n, bias : float or array of shape (n,)
        Test parameters (see ``check_relay_params``); ``bias`` (command units) is
        added to the relay output.
    bias_trim : str
        ``"off"`` (default): the bias stays; ``"duty"``: the relay trims it at every
        switch to ``+h`` (:meth:`_trim`).
    rate_hz : float
        Controller rate, Hz; one call is one sample.
    n : int
        Number of relays.
    reading : int
        2 (default): the half-wave reading of ``uavsim-session/2``; 1: the
        version-1 reading (tracker restarted at the switch sample).

    Attributes
    ----------
    switched : (n,) bool
        True where the relay switched at the last sample.
    armed : (n,) bool
        True where the current half-wave's extremum is being tracked.
    guard : (n,) bool
        True where the deadlock guard started the tracking at the last sample.
    """

    #: name written in sessions
    kind = NP_MRFT_RUN

    def __init__(self, beta, h, tau_obs, a_n, rate_hz: float, n: int, bias=0.0, reading: int = READING,
                 bias_trim: str = "off"):
        check_relay_params(beta, h, tau_obs, a_n, rate_hz)
        self.reading = check_reading(reading)
        self.bias_trim = check_bias_trim(bias_trim)
        self.n = int(n)
        self.rate_hz = float(rate_hz)
        self.beta = as_batch("beta", beta, n)
        self.h = as_batch("h", h, n)
        self.a_n = as_batch("a_n", a_n, n)
        self.bias0 = as_batch("bias", bias, n)
        self.tau_obs = as_batch("tau_obs", tau_obs, n)
        # Confirmation counted in whole samples: t - t_ext >= tau_obs on a grid of
        # Ts, with a tolerance so that tau_obs = 6.5 * Ts is not lost to rounding.
        self.n_obs = np.ceil(self.tau_obs * self.rate_hz - 1e-9).astype(np.int64)
        self.rho = guard_fraction(self.beta)
        self._corr = self.a_n * (1.0 - self.beta)
        self._nbeta = -self.beta
        self._trimmed = self.bias_trim == "duty"
        # a trimmed bias is a bias: its cycle's half-waves start at the centre
        self._bias_nz = (self.bias0 != 0) | self._trimmed
        # the centre is zero without a relay bias: its running sums are then not needed
        self._biased = bool(self._bias_nz.any())
        self.reset()

    def retune(self, tau_obs=None, a_n=None) -> None:
        """New ``tau_obs`` and/or ``a_n`` (float or (n,)) from the next sample on; the relay's state is kept.

        How dataset generation runs a user's successive relay runs within one episode.
        """
        check_relay_params(self.beta, self.h, 0.0 if tau_obs is None else tau_obs, 0.0 if a_n is None else a_n,
                           self.rate_hz)
        if tau_obs is not None:
            self.tau_obs = as_batch("tau_obs", tau_obs, self.n)
            self.n_obs = np.ceil(self.tau_obs * self.rate_hz - 1e-9).astype(np.int64)
        if a_n is not None:
            self.a_n = as_batch("a_n", a_n, self.n)
            self._corr = self.a_n * (1.0 - self.beta)

    def reset(self) -> None:
        """Forget everything: the next call is the first sample."""
        n = self.n
        self.k = 0
        self.bias = self.bias0.copy()   # the relay's bias now (moves only when trimmed)
        self.sign = np.ones(n)          # +1 while u = +h, -1 while u = -h
        self.e_ext = np.zeros(n)        # extremum of the current half-wave
        self.k_ext = np.zeros(n, dtype=np.int64)
        # the last switch (0: the start) and the two switches before it, rows of one array
        # so that a switch shifts them in one operation
        self._ksw = np.zeros((3, n), dtype=np.int64)
        self.k_sw, self.k_sw2, self.k_sw3 = self._ksw
        self.half = np.zeros((2, n), dtype=np.int64)  # the two previous half-periods, samples
        self.n_sw = np.zeros(n, dtype=np.int64)      # switches so far
        self.sum_e = np.zeros(n)        # sum of e over samples 0..k-1
        self._sums = np.zeros((3, n))   # sum_e at the last switch and at the two before
        self.sum_sw, self.sum_sw2, self.sum_sw3 = self._sums
        self._se_ext = np.zeros(n)      # sign * e_ext
        self._centre = np.zeros(n)
        self.armed = np.ones(n, dtype=bool)
        self.guard = np.zeros(n, dtype=bool)
        self._guarded = False           # guard has a True
        self.switched = np.zeros(n, dtype=bool)
        self.confirmed = np.zeros(n, dtype=bool)

    @property
    def centre(self) -> np.ndarray:
        """(n,) the level where a half-wave starts: zero, or with a relay bias the last cycle's mean error.

        A relay without bias gives a cycle around zero: its half-waves start at
        the paper's zero crossings. A bias makes the cycle asymmetric and, from
        about a third of ``h``, puts a whole half-wave of it on one side of zero;
        its half-waves start at the crossings of the mean error over the last
        cycle (the last two half-periods; zero until three switches).
        """
        return self._centre

    def _update_centre(self, sw: np.ndarray) -> None:
        # the mean error over the last two half-periods, in the switched rows ``sw`` (bool (n,))
        # of a biased relay that has switched three times; elsewhere it stays zero
        rows = sw & self._bias_nz
        rows &= self.n_sw >= 3
        span = np.subtract(self.k_sw, self.k_sw3)
        np.maximum(span, 1, out=span)
        np.divide(self.sum_sw - self.sum_sw3, span, out=self._centre, where=rows)

    def _confirmed(self) -> np.ndarray:
        return (self.k - self.k_ext) >= self.n_obs

    def __call__(self, e: np.ndarray) -> np.ndarray:
        """Advance one sample with errors ``e`` (n,); return the commands (n,)."""
        e = np.asarray(e, dtype=np.float64)
        if self.k == 0:
            self._first(e)
        else:
            self._update(e, self.k)
        if self._biased:
            self.sum_e += e
        self.k += 1
        return self.sign * self.h + self.bias

    def _first(self, e: np.ndarray) -> None:
        # the start counts as the start of a half-wave on the side of the first error
        self.sign = np.where(e >= 0, 1.0, -1.0)
        self.sum_e = np.zeros(self.n)
        self.e_ext = e.copy()
        self._se_ext = self.sign * e
        self.k_ext[:] = 0
        self._ksw[:] = 0
        self.half[:] = 0
        self.n_sw[:] = 0
        self._sums[:] = 0.0
        self._centre[:] = 0.0
        self.armed[:] = True
        self.guard[:] = False
        self.switched[:] = False
        self.confirmed[:] = False

    def _update(self, e: np.ndarray, k: int) -> None:
        # One sample of every relay in whole-array operations (the per-sample Python cost of
        # dataset generation): the error and the extremum are held times the relay state,
        # s e and s e_ext (s = +-1, exact), so that the running max of u = +h and the running
        # min of u = -h are one comparison, and the switching levels (paper eq. 22-23)
        #   u = +h: e <= -(beta e_max + a_n (1 - beta)),  u = -h: e >= -beta e_min + a_n (1 - beta)
        # are one: s e <= -beta (s e_ext) - a_n (1 - beta), rounded the same (rounding is odd).
        sgn, armed = self.sign, self.armed
        se = sgn * e
        # running max while u = +h, running min while u = -h (ties keep the first)
        upd = se > self._se_ext
        upd &= armed
        if self.reading == 2 and not armed.all():
            # the half-wave of this relay state starts at the first sample on its side of the
            # cycle's centre, or, by the deadlock guard, W samples after the switch; there the
            # extremum is e (rows not armed, so not among the better ones above)
            side = sgn * (e - self._centre) >= 0 if self._biased else se >= 0
            wait = np.ceil(self.rho * np.maximum(self.half[0], self.half[1]))
            start = np.subtract(k, self.k_sw) >= wait
            start |= side
            start &= ~armed
            self.guard = start & ~side
            self._guarded = True
            upd |= start
            armed |= start
        elif self._guarded:
            self.guard[:] = False
            self._guarded = False
        np.copyto(self.e_ext, e, where=upd)
        np.copyto(self._se_ext, se, where=upd)
        np.copyto(self.k_ext, k, where=upd)
        conf = np.subtract(k, self.k_ext) >= self.n_obs
        conf &= armed
        level = self._nbeta * self._se_ext
        level -= self._corr
        sw = se <= level
        sw &= conf
        if sw.any():
            self._switch(e, se, sw, k)
        self.switched = sw
        self.confirmed = conf ^ sw  # sw lies within conf

    def _switch(self, e: np.ndarray, se: np.ndarray, sw: np.ndarray, k: int) -> None:
        # the switch history shifts by one in the switched rows: the last half-period -> the one
        # before, k_sw -> k_sw2 -> k_sw3, sum_sw likewise (copyto buffers the overlapping rows)
        half = self.half
        np.copyto(half[1], half[0], where=sw)
        np.subtract(k, self.k_sw, out=half[0], where=sw)
        np.copyto(self._ksw[1:], self._ksw[:-1], where=sw)
        np.copyto(self.k_sw, k, where=sw)
        np.copyto(self._sums[1:], self._sums[:-1], where=sw)
        np.copyto(self.sum_sw, self.sum_e, where=sw)
        self.n_sw += sw
        sign = self.sign
        np.negative(sign, out=sign, where=sw)
        np.copyto(self.e_ext, e, where=sw)
        np.negative(se, out=self._se_ext, where=sw)  # the new state's s e
        np.copyto(self.k_ext, k, where=sw)
        if self._trimmed:
            self._trim(sw)
        if self.reading == 2:
            # the new half-wave has started if e is already on its side of the centre
            if self._biased:
                self._update_centre(sw)
                np.copyto(self.armed, sign * (e - self._centre) >= 0, where=sw)
            else:
                np.copyto(self.armed, se <= 0, where=sw)  # -s e >= 0 with the old s

    def _trim(self, sw: np.ndarray) -> None:
        # At a switch to +h after a whole cycle (the half-periods are the -h one just ended,
        # half[0], and the +h one before it, half[1]), the bias moves by TRIM_GAIN (2 d - 1) h,
        # d = half[1] / cycle the cycle's duty at +h, at most TRIM_STEP_MAX h. On an integrating
        # loop the input's mean over a steady cycle is zero, so (2 d - 1) h = -(bias +
        # disturbance). The trim is integral action on the cycle's mean: a whole step (gain 1)
        # is deadbeat on a steady cycle but follows a transient cycle's duty too, and a noisy
        # switch time moves it by its full error. Half a step passed a third of the switch
        # noise's variance to the bias (g / (2 - g)) and, clipped at h/4, lost the lateral
        # loops' cycle under noise; a quarter step, at most h/10, passes a seventh and converges
        # from 0.5 h in about ten cycles. The first cycles (start-up, where e = 0 can
        # chatter) are not trimmed from.
        rows = sw & (self.sign > 0) & (self.n_sw >= TRIM_AFTER_SWITCHES)
        rows &= np.abs(self.half[1] - self.half[0]) > TRIM_DEADBAND
        if not rows.any():
            return
        cycle = np.maximum(self.half[0] + self.half[1], 1)
        step = (TRIM_GAIN * self.h) * (2.0 * self.half[1] / cycle - 1.0)
        np.clip(step, -TRIM_STEP_MAX * self.h, TRIM_STEP_MAX * self.h, out=step)
        np.add(self.bias, step, out=self.bias, where=rows)


class MRFT(NPMRFT):
    """Plain MRFT: NP-MRFT with ``a_n = 0`` and an extremum confirmed one sample after it was set."""

    kind = MRFT_RUN

    def __init__(self, beta, h, rate_hz: float, n: int, bias=0.0, reading: int = READING,
                 bias_trim: str = "off"):
        super().__init__(beta, h, 0.0, 0.0, rate_hz, n, bias, reading, bias_trim)
        self.n_obs[:] = 1
