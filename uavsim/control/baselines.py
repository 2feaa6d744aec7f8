"""Baseline noise-tolerant relay tests from Boiko's book, for comparison with NP-MRFT.

Boiko (*Non-parametric Tuning of PID Controllers*, Springer 2013) discusses two
practical ways of running a relay test on a noisy loop; this module reads
them as follows (both vectorized over ``n`` episodes, called once per
controller sample like :class:`uavsim.control.relay.NPMRFT`):

``InhibitedMRFT`` -- MRFT with switching inhibited for a fixed time.
    Plain MRFT (running extremum since the last switch, switching at
    ``-beta e_max`` / ``-beta e_min``, an extremum confirmed one sample after
    it was set), except that after each switch no further switch is allowed
    for ``t_inhibit`` seconds. This is the classic anti-chattering "hysteresis
    in time": it suppresses the burst of back-and-forth switches that noise
    causes right after a switch, but neither the advance switching on a noise
    excursion nor the noise on the extremum.

``TwoRelayMRFT`` -- the two-relay controller.
    ``u = h0 sign(e) + h1 sign(de/dt)``: one relay acts on the error, a second
    one on the sign of its slope (the sampled difference ``e_k - e_{k-1}``; a
    zero difference keeps the previous sign, so a quantization plateau does not
    switch it). With ``h0 = h sqrt(1 - beta^2)`` and ``h1 = -beta h`` its
    describing function ``4/(pi a) (h0 + j h1)`` equals the MRFT's
    ``4h/(pi a) (sqrt(1 - beta^2) - j beta)``, so noise-free it excites the
    same frequency and amplitude. Read as relays for the two phases of the
    cycle (the error relay for the positive/negative half-waves, the slope
    relay for the rising/falling half-waves): it needs no extremum memory, but
    the slope relay sees every noise wiggle.

    relay = InhibitedMRFT(beta=-0.73, h=0.2, t_inhibit=0.1, rate_hz=200.0, n=64)
    relay = TwoRelayMRFT(beta=-0.73, h=0.2, rate_hz=200.0, n=64)
    u = relay(e)                      # (64,) commands, bias included
    relay.switched                    # (64,) True where the output changed
"""

from __future__ import annotations

import numpy as np

from uavsim.control.relay import as_batch, check_relay_params
from uavsim.errors import UserError


class InhibitedMRFT:
    """``n`` MRFT relays whose switching is inhibited for ``t_inhibit`` s after each switch.

    Parameters
    ----------
    beta : float or array (n,)
        MRFT parameter in (-1, 1).
    h : float or array (n,)
        Relay amplitude, command units, > 0.
    t_inhibit : float or array (n,)
        Inhibition time after each switch, s, >= 0 (0 gives plain MRFT).
    rate_hz : float
        Controller rate, Hz.
    n : int
        Number of relays.
    bias : float or array (n,)
        Added to the output, command units.
    """

    kind = "mrft-inhibit"

    def __init__(self, beta, h, t_inhibit, rate_hz: float, n: int, bias=0.0):
        check_relay_params(beta, h, 0.0, 0.0, rate_hz)
        t_inh = np.asarray(t_inhibit, dtype=np.float64)
        if not np.all(np.isfinite(t_inh)) or np.any(t_inh < 0):
            raise UserError(f"inhibition time must be >= 0 s, got {t_inh.ravel()[:3].tolist()}")
        self.n = int(n)
        self.rate_hz = float(rate_hz)
        self.beta = as_batch("beta", beta, n)
        self.h = as_batch("h", h, n)
        self.bias = as_batch("bias", bias, n)
        self.t_inhibit = as_batch("t_inhibit", t_inhibit, n)
        # t - t_switch >= t_inhibit on the sample grid, tolerant to rounding
        self.n_inh = np.ceil(self.t_inhibit * self.rate_hz - 1e-9).astype(np.int64)
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next call is the first sample."""
        n = self.n
        self.k = 0
        self.sign = np.ones(n)
        self.e_ext = np.zeros(n)
        self.k_ext = np.zeros(n, dtype=np.int64)
        self.k_sw = np.zeros(n, dtype=np.int64)
        self.switched = np.zeros(n, dtype=bool)

    def __call__(self, e: np.ndarray) -> np.ndarray:
        """Advance one sample with errors ``e`` (n,); return the commands (n,)."""
        e = np.asarray(e, dtype=np.float64)
        if self.k == 0:
            self.sign = np.where(e >= 0, 1.0, -1.0)
            self.e_ext = e.copy()
            self.k_ext[:] = 0
            self.k_sw[:] = 0
            self.switched[:] = False
        else:
            up = self.sign > 0
            better = np.where(up, e > self.e_ext, e < self.e_ext)
            self.e_ext = np.where(better, e, self.e_ext)
            self.k_ext = np.where(better, self.k, self.k_ext)
            # plain MRFT confirmation (one sample) plus the time inhibition
            ok = ((self.k - self.k_ext) >= 1) & ((self.k - self.k_sw) >= self.n_inh)
            down = up & ok & (e <= -self.beta * self.e_ext)
            upsw = ~up & ok & (e >= -self.beta * self.e_ext)
            sw = down | upsw
            self.sign = np.where(sw, -self.sign, self.sign)
            self.e_ext = np.where(sw, e, self.e_ext)
            self.k_ext = np.where(sw, self.k, self.k_ext)
            self.k_sw = np.where(sw, self.k, self.k_sw)
            self.switched = sw
        self.k += 1
        return self.sign * self.h + self.bias


class TwoRelayMRFT:
    """``n`` two-relay controllers ``h0 sign(e) + h1 sign(de)`` with the MRFT's describing function.

    Parameters
    ----------
    beta : float or array (n,)
        MRFT parameter in (-1, 1): ``h0 = h sqrt(1 - beta^2)``, ``h1 = -beta h``.
    h : float or array (n,)
        Equivalent MRFT amplitude, command units, > 0.
    rate_hz : float
        Controller rate, Hz.
    n : int
        Number of relays.
    bias : float or array (n,)
        Added to the output, command units.

    Attributes
    ----------
    sign : array (n,)
        State of the error relay (+1/-1).
    dsign : array (n,)
        State of the slope relay (+1/-1).
    switched : array (n,) bool
        True where either relay switched at this sample.
    """

    kind = "two-relay"

    def __init__(self, beta, h, rate_hz: float, n: int, bias=0.0):
        check_relay_params(beta, h, 0.0, 0.0, rate_hz)
        self.n = int(n)
        self.rate_hz = float(rate_hz)
        self.beta = as_batch("beta", beta, n)
        self.h = as_batch("h", h, n)
        self.bias = as_batch("bias", bias, n)
        self.h0 = self.h * np.sqrt(1.0 - self.beta**2)
        self.h1 = -self.beta * self.h
        self.reset()

    def reset(self) -> None:
        """Forget everything: the next call is the first sample."""
        self.k = 0
        self.sign = np.ones(self.n)
        self.dsign = np.ones(self.n)
        self.e_prev = np.zeros(self.n)
        self.switched = np.zeros(self.n, dtype=bool)

    def __call__(self, e: np.ndarray) -> np.ndarray:
        """Advance one sample with errors ``e`` (n,); return the commands (n,)."""
        e = np.asarray(e, dtype=np.float64)
        if self.k == 0:
            self.sign = np.where(e >= 0, 1.0, -1.0)
            # no slope yet: start the slope relay like the error relay
            self.dsign = self.sign.copy()
            self.switched[:] = False
        else:
            s = np.where(e > 0, 1.0, np.where(e < 0, -1.0, self.sign))
            de = e - self.e_prev
            d = np.where(de > 0, 1.0, np.where(de < 0, -1.0, self.dsign))
            self.switched = (s != self.sign) | (d != self.dsign)
            self.sign, self.dsign = s, d
        self.e_prev = e.copy()
        self.k += 1
        return self.h0 * self.sign + self.h1 * self.dsign + self.bias
