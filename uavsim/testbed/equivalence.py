"""How close the testbed vehicle is to a lumped model: relay cycles measured against the nearest one.

Identification can only work if the richer vehicle's small-signal behaviour
is close to some lumped model ``K e^{-tau s} / (s (T_prop s + 1)(T1 s + 1))``.
For one vehicle and loop, with no hidden effect, this hovers, sets NP-MRFT from the hover's noise as
the sessions do, and flies it at beta -0.73 and -0.3 (relay ``h`` as in the
sessions) through the vehicle's own sensors and measures each steady cycle's period, amplitude and the loop's
response ``Y1 / U1`` (first harmonics over whole cycles,
``uavsim.noise.analysis.cycle_harmonics``). The reference is the vehicle's
analytic equivalent (``uavsim.testbed.vehicle.lumped_equivalent``), with the
200 Hz hold's ``sinc(w Ts/2) e^{-j w Ts/2}`` on its response:

- ``period_err``, ``amp_err``: the measured cycle against the equivalent's
  exact limit cycle (``uavsim.lumped.exact_limit_cycle``, a plain MRFT:
  NP-MRFT's ``tau_obs`` and ``a_n`` lengthen the cycle a little), relative;
  ``amp_true_err`` the same with the true output's amplitude;
- ``K_fit``, ``tau_fit``: the gain and delay that put the equivalent's
  response (with its T_prop and T1) exactly on the beta -0.73 point, the way
  identification fits them (``tau_fit_true_output``: the same on the true
  output, to tell the sensors' share from the vehicle's);
- ``gain_err_b030``, ``phase_err_b030_deg``: that fitted model against the
  measured beta -0.3 point (a second frequency it was not fitted on).

    rows = measure_equivalence(seed=3)      # one row per loop
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.control.relay import NPMRFT
from uavsim.lumped import exact_limit_cycle, freq_response
from uavsim.lumped.params import LumpedParams
from uavsim.noise.analysis import cycle_harmonics, rising_edges
from uavsim.testbed.flight import Flight
from uavsim.testbed.sessions import RATE_HZ, hover_noise_settings, plan_session
from uavsim.testbed.vehicle import TESTBED_LOOPS, lumped_equivalent

__all__ = ["measure_equivalence", "measured_cycle"]


def measured_cycle(y: np.ndarray, u: np.ndarray, settle: float = 0.4) -> tuple[float, float, complex]:
    """Period (s), amplitude and ``Y1/U1`` of the steady cycles after the first ``settle`` of the record."""
    i0 = int(settle * y.size)
    e = rising_edges(u)
    e = e[e >= i0]
    if e.size < 3:
        return float("nan"), float("nan"), complex("nan")
    period = float(np.median(np.diff(e))) / RATE_HZ
    amp = float(np.median([0.5 * np.ptp(y[a:b]) for a, b in zip(e[:-1], e[1:], strict=True)]))
    y1 = cycle_harmonics(y, e)[0]
    u1 = cycle_harmonics(u, e)[0]
    return period, amp, complex(y1 / u1)


def _held(p: LumpedParams, w: float) -> complex:
    x = w / (2 * RATE_HZ)
    return complex(freq_response(p, np.array([w]))[0] * np.sinc(x / np.pi) * np.exp(-1j * x))


def measure_equivalence(seed: int, loops: tuple[str, ...] = TESTBED_LOOPS, duration_s: float = 12.0) -> list[dict]:
    """Measured cycles of the vehicle of ``seed`` against its lumped equivalent, one dict per loop."""
    rows = []
    for loop in loops:
        plan = plan_session(seed, loop=loop)
        v, h = plan.vehicle, plan.h
        p = lumped_equivalent(v, loop)
        meas, truth = {}, {}
        for beta in (-0.73, -0.3):
            fl = Flight(v, loop, [], np.random.default_rng([seed, 7]))
            _, settings = hover_noise_settings(fl, plan)
            tau_obs, a_n = settings[beta]
            rec = fl.fly(NPMRFT(beta, h, tau_obs, a_n, RATE_HZ, 1), duration_s)
            meas[beta] = measured_cycle(rec.y, rec.u)
            truth[beta] = measured_cycle(rec.y_true, rec.u)
        P, A, R = meas[-0.73]
        Pe, Ae = exact_limit_cycle(p, -0.73, h)
        At = truth[-0.73][1]
        w1 = 2 * math.pi / P
        Gm = _held(p, w1)
        K_fit = p.K * abs(R) / abs(Gm)
        # phase left to explain by the delay (unwrapped near the relay's phase)
        dphi = (np.angle(R) - np.angle(Gm) + math.pi) % (2 * math.pi) - math.pi
        tau_fit = p.tau - dphi / w1
        Rt = truth[-0.73][2]
        dphi_t = (np.angle(Rt) - np.angle(_held(p, 2 * math.pi / truth[-0.73][0])) + math.pi) % (2 * math.pi) - math.pi
        tau_fit_true = p.tau - dphi_t / (2 * math.pi / truth[-0.73][0])
        fit = LumpedParams(loop, K=K_fit, T_prop=p.T_prop, T1=p.T1, tau=max(tau_fit, 0.0))
        P3, A3, R3 = meas[-0.3]
        G3 = _held(fit, 2 * math.pi / P3)
        ph3 = math.degrees((np.angle(R3) - np.angle(G3) + math.pi) % (2 * math.pi) - math.pi)
        rows.append({
            "seed": seed, "loop": loop, "K": p.K, "T_prop": p.T_prop, "T1": p.T1, "tau": p.tau, "h": h,
            "period": P, "period_exact": Pe, "period_err": P / Pe - 1, "amp": A, "amp_exact": Ae, "amp_err": A / Ae - 1,
            "amp_true": At, "amp_true_err": At / Ae - 1,
            "K_fit": K_fit, "K_fit_err": K_fit / p.K - 1, "tau_fit": float(tau_fit), "tau_fit_true_output": float(tau_fit_true),
            "gain_err_b030": abs(R3) / abs(G3) - 1, "phase_err_b030_deg": ph3,
        })  # fmt: skip
    return rows
