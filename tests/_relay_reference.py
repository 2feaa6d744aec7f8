"""The relay's per-sample update as it was written before it was fused (commit 60ce03c), kept verbatim.

``tests/test_relay_fused.py`` checks the fused ``NPMRFT.__call__`` against it,
state and output, bit for bit.
"""

import numpy as np

from uavsim.control.relay import NPMRFT


class ReferenceNPMRFT(NPMRFT):
    """``NPMRFT`` with the unfused update (same state, same parameters)."""

    def _update_centre(self, rows: np.ndarray) -> None:
        span = np.maximum(self.k_sw[rows] - self.k_sw3[rows], 1)
        mean = (self.sum_sw[rows] - self.sum_sw3[rows]) / span
        self._centre[rows] = np.where((self.bias[rows] != 0) & (self.n_sw[rows] >= 3), mean, 0.0)

    def __call__(self, e: np.ndarray) -> np.ndarray:
        """Advance one sample with errors ``e`` (n,); return the commands (n,)."""
        e = np.asarray(e, dtype=np.float64)
        k = self.k
        if k == 0:
            # the start counts as the start of a half-wave on the side of the first error
            self.sign = np.where(e >= 0, 1.0, -1.0)
            self.sum_e = np.zeros(self.n)
            self.e_ext = e.copy()
            self.k_ext[:] = 0
            self.k_sw[:] = 0
            self.half[:] = 0
            self.k_sw2[:] = 0
            self.k_sw3[:] = 0
            self.n_sw[:] = 0
            self.sum_sw[:] = 0.0
            self.sum_sw2[:] = 0.0
            self.sum_sw3[:] = 0.0
            self._centre[:] = 0.0
            self.armed[:] = True
            self.guard[:] = False
            self.switched[:] = False
            self.confirmed[:] = False
        else:
            sgn = self.sign
            up = sgn > 0
            e_ext, k_ext = self.e_ext, self.k_ext
            start = None
            self.guard[:] = False
            if self.reading == 2:
                waiting = ~self.armed
                if waiting.any():
                    # the half-wave of this relay state starts at the first sample on its side of the
                    # cycle's centre, or, by the deadlock guard, W samples after the switch
                    side = sgn * (e - self._centre) >= 0 if self._biased else sgn * e >= 0
                    wait = np.ceil(self.rho * np.maximum(self.half[0], self.half[1]))
                    start = waiting & (side | (k - self.k_sw >= wait))
                    if start.any():
                        self.guard = start & ~side
                        e_ext[start] = e[start]
                        k_ext[start] = k
                        self.armed |= start
            # running max while u = +h, running min while u = -h (ties keep the first)
            better = np.where(up, e > e_ext, e < e_ext)
            better &= self.armed
            if start is not None:
                better &= ~start
            if better.any():
                e_ext[better] = e[better]
                k_ext[better] = k
            conf = self.armed & ((k - k_ext) >= self.n_obs)
            corr = self._corr
            t = self.beta * e_ext
            # b2 = beta e_max + a_n (1 - beta): switch down when e <= -b2;
            # b1 = -beta e_min + a_n (1 - beta): switch up when e >= b1
            sw = conf & np.where(up, e <= -(t + corr), e >= -t + corr)
            if sw.any():
                self.sign = np.where(sw, -sgn, sgn)
                self.half[1, sw] = self.half[0, sw]
                self.half[0, sw] = k - self.k_sw[sw]
                self.k_sw3[sw] = self.k_sw2[sw]
                self.k_sw2[sw] = self.k_sw[sw]
                self.k_sw[sw] = k
                self.sum_sw3[sw] = self.sum_sw2[sw]
                self.sum_sw2[sw] = self.sum_sw[sw]
                self.sum_sw[sw] = self.sum_e[sw]
                self.n_sw += sw
                e_ext[sw] = e[sw]
                k_ext[sw] = k
                if self.reading == 2:
                    # the new half-wave has started if e is already on its side of the centre
                    if self._biased:
                        self._update_centre(sw)
                        self.armed[sw] = (self.sign * (e - self._centre) >= 0)[sw]
                    else:
                        self.armed[sw] = (self.sign * e >= 0)[sw]
            self.switched = sw
            self.confirmed = conf & ~sw
        if self._biased:
            self.sum_e += e
        self.k += 1
        return self.sign * self.h + self.bias
