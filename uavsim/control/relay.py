"""MRFT and noise-protected MRFT (NP-MRFT), vectorized over a batch.

The modified relay feedback test switches a relay of amplitude ``h`` at a
level proportional to the last extremum of the error, which places the
self-excited oscillation at the phase ``arg G(j Omega) = -pi + asin(beta)``.
NP-MRFT (paper eq. 19-23) only accepts an extremum once it has stood for
``tau_obs`` and lowers the switching levels by ``a_n (1 - beta)``, so that
measurement noise neither switches the relay early nor fools the extremum.

This module is the normative sampled reading of ``shared/formats/session.md``
("Controller semantics"), used both to generate sessions and to simulate
them. One instance holds the state of ``n`` independent relays in numpy arrays;
call it once per controller sample with the errors ``e`` (shape ``(n,)``).

    relay = NPMRFT(beta=-0.73, h=0.2, tau_obs=0.0325, a_n=0.003, rate_hz=200.0, n=1024)
    for k in range(steps):
        u = relay(r - y)            # (1024,) command, bias included
        switched = relay.switched   # (1024,) bool, True where the relay switched at this sample

Ties do not move the extremum: a plateau (a quantized signal) is timed from
its first sample, which is when it was reached.
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.errors import UserError


def _as_batch(name: str, value: float | np.ndarray, n: int) -> np.ndarray:
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


class NPMRFT:
    """``n`` NP-MRFT relays stepped together at ``rate_hz``.

    Parameters
    ----------
    beta, h, tau_obs, a_n, bias : float or array of shape (n,)
        Test parameters (see ``check_relay_params``); ``bias`` (command units) is
        added to the relay output.
    rate_hz : float
        Controller rate, Hz; one call is one sample.
    n : int
        Number of relays.
    """

    #: name written in sessions
    kind = "np-mrft"

    def __init__(self, beta, h, tau_obs, a_n, rate_hz: float, n: int, bias=0.0):
        check_relay_params(beta, h, tau_obs, a_n, rate_hz)
        self.n = int(n)
        self.rate_hz = float(rate_hz)
        self.beta = _as_batch("beta", beta, n)
        self.h = _as_batch("h", h, n)
        self.a_n = _as_batch("a_n", a_n, n)
        self.bias = _as_batch("bias", bias, n)
        self.tau_obs = _as_batch("tau_obs", tau_obs, n)
        # Confirmation counted in whole samples: t - t_ext >= tau_obs on a grid of
        # Ts, with a tolerance so that tau_obs = 6.5 * Ts is not lost to rounding.
        self.n_obs = np.ceil(self.tau_obs * self.rate_hz - 1e-9).astype(np.int64)
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next call is the first sample."""
        n = self.n
        self.k = 0
        self.sign = np.ones(n)          # +1 while u = +h, -1 while u = -h
        self.e_ext = np.zeros(n)        # running extremum since the last switch
        self.k_ext = np.zeros(n, dtype=np.int64)
        self.switched = np.zeros(n, dtype=bool)
        self.confirmed = np.zeros(n, dtype=bool)

    def _confirmed(self) -> np.ndarray:
        return (self.k - self.k_ext) >= self.n_obs

    def __call__(self, e: np.ndarray) -> np.ndarray:
        """Advance one sample with errors ``e`` (n,); return the commands (n,)."""
        e = np.asarray(e, dtype=np.float64)
        if self.k == 0:
            self.sign = np.where(e >= 0, 1.0, -1.0)
            self.e_ext = e.copy()
            self.k_ext[:] = 0
            self.switched[:] = False
            self.confirmed[:] = False
        else:
            up = self.sign > 0
            # running max while u = +h, running min while u = -h (ties keep the first)
            better = np.where(up, e > self.e_ext, e < self.e_ext)
            self.e_ext = np.where(better, e, self.e_ext)
            self.k_ext = np.where(better, self.k, self.k_ext)
            conf = self._confirmed()
            corr = self.a_n * (1.0 - self.beta)
            # b2 = beta e_max + a_n (1 - beta): switch down when e <= -b2
            down = up & conf & (e <= -(self.beta * self.e_ext + corr))
            # b1 = -beta e_min + a_n (1 - beta): switch up when e >= b1
            upsw = ~up & conf & (e >= -self.beta * self.e_ext + corr)
            sw = down | upsw
            self.sign = np.where(sw, -self.sign, self.sign)
            self.e_ext = np.where(sw, e, self.e_ext)
            self.k_ext = np.where(sw, self.k, self.k_ext)
            self.switched = sw
            self.confirmed = conf & ~sw
        self.k += 1
        return self.sign * self.h + self.bias


class MRFT(NPMRFT):
    """Plain MRFT: NP-MRFT with ``a_n = 0`` and an extremum confirmed one sample after it was set."""

    kind = "mrft"

    def __init__(self, beta, h, rate_hz: float, n: int, bias=0.0):
        super().__init__(beta, h, 0.0, 0.0, rate_hz, n, bias)
        self.n_obs[:] = 1
