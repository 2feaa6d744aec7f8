"""Measurement noise for the NP-MRFT study: models, estimation from flight data, cycle metrics.

- ``uavsim.noise.models``: study noise models as measurement effects and
  ``make_noise(kind, level, a0)`` (``NOISE_KINDS``).
- ``uavsim.noise.estimate``: ``estimate_noise`` (T_n, a_n, sigma from a hover or
  oscillation segment) and ``recommend`` (NP-MRFT tau_obs and a_n for a beta).
- ``uavsim.noise.analysis``: ``cycle_stats``, ``false_switch_rate``, ``sustained``.

    from uavsim.noise import estimate_noise, recommend, make_noise
    est = estimate_noise(y_hover, rate_hz=200.0)
    tau_obs, a_n = recommend(est, beta=-0.73, T0_expected=0.8)
"""

from uavsim.noise.analysis import CycleStats, cycle_stats, false_switch_rate, sustained
from uavsim.noise.estimate import NoiseEstimate, estimate_noise, recommend
from uavsim.noise.models import NOISE_KINDS, make_noise, pixel_step

__all__ = [
    "NOISE_KINDS",
    "CycleStats",
    "NoiseEstimate",
    "cycle_stats",
    "estimate_noise",
    "false_switch_rate",
    "make_noise",
    "pixel_step",
    "recommend",
    "sustained",
]
