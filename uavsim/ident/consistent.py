"""The network's belief kept to the classes the measured point allows.

A relay run measures the process's response at one frequency, ``G(j w)``
(``CycleFeatures.response``, the hold removed). Every inner-loop class fits it with
its own lags and a gain and delay of its own (``uavsim.ident.response.fit_response``),
but only with a delay of at least zero: a class whose lags alone (the integrator,
``T_prop`` and ``T1``) already lag more than the measured phase is no process the
measurement allows, whatever its delay. ``fit_response`` clips such a delay to 0, and
that class's table PD, over a gain fitted to a point it cannot reach, answers a
process the run has ruled out.

Under 15-20 % noise the network sometimes puts most of its belief on such classes
(development seed 12, attitude: 0.83 on classes that need -28 to -30 degrees of delay;
the answer's J 7.1). ``consistent_activations`` takes them out of the belief before
the decision: a class stays where the phase its delay must supply
(``delay_phase_deg``) is at least minus the tolerance, the larger of the loop's
``POINT_PHASE_TOL_DEG`` (room for the grid's spacing and the vehicle's own misfit of the
lumped model; set on development seeds 11-20 against 0, 7.5 and 20 degrees) and the point's standard error (its cycles' phase spread over the root of their
count). Where no class is within it, the belief is left as it is. A loop not named
keeps the network's belief (lateral loops answer over the family of models the point
allows: ``uavsim.ident.family``).

Measured on development seeds 11-20 (3,000 off-grid attitude processes, noise 0-20 %,
docs/results/identification.md): J p95 1.126 -> 1.118, max 7.12 -> 1.69, answers above
1.1 230 -> 207, unstable or refused 21 -> 21; report seed 2044, run once: p95 1.117 -> 1.111
on the same processes. On altitude the same rule moved answers both ways without a gain
(p95 1.110 -> 1.111), and on lateral loops (each class's ``T2`` over the attitude loop) it
changed a few answers each way (development seeds 11-12), so both are off.

    from uavsim.ident.consistent import consistent_activations
    act, n_out = consistent_activations(bundle, cycle_activations(bundle, f), f)   # n_out: classes ruled out
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.data.preprocess import CycleFeatures, process_response
from uavsim.ident.bundle import ModelBundle
from uavsim.ident.response import class_response, measured_phase, phase_se_deg

__all__ = ["POINT_PHASE_TOL_DEG", "EXCLUDED_LOGIT", "delay_phase_deg", "phase_tolerance_deg",
           "consistent_classes", "consistent_activations"]

#: the least tolerance (deg) on a class's delay-free phase beyond the measured one, per loop; a loop not
#: named keeps the network's belief (module docstring)
POINT_PHASE_TOL_DEG: dict[str, float] = {"attitude": 5.0}
#: a class the point rules out gets this many temperatures below the least activation (belief ~e^-50 of it)
EXCLUDED_LOGIT = 50.0


def delay_phase_deg(bundle: ModelBundle, response: complex, response_period: float) -> np.ndarray:
    """The phase (deg) each class's delay must supply to reach the measured point, (n_classes,).

    ``degrees(arg G0_c(j w) - arg G(j w))`` with ``G0_c`` the class's delay-free model
    (``class_response``) and the measured phase on the branch nearest the class's own
    (``measured_phase``); negative where the class's lags alone lag more than the measurement.
    """
    per = float(response_period)
    w = 2.0 * math.pi / per
    G = complex(process_response(complex(response), per, rate_hz=bundle.input_rate_hz))
    _, ph0 = class_response(bundle, np.arange(bundle.n_classes), [w])
    return np.degrees(ph0[:, 0] - measured_phase(G, ph0[:, 0], w, bundle.column("tau")))


def phase_tolerance_deg(loop: str, phase_spread_rad: float, cycles: int) -> float | None:
    """The loop's tolerance (deg): its ``POINT_PHASE_TOL_DEG`` or the point's standard error
    (``point_sigmas``), the larger (``phase_spread_rad``: std of the cycles' phases; ``cycles``: their
    count); None for a loop not named."""
    floor = POINT_PHASE_TOL_DEG.get(loop)
    if floor is None:
        return None
    return max(float(floor), phase_se_deg(phase_spread_rad, cycles))


def consistent_classes(bundle: ModelBundle, f: CycleFeatures) -> np.ndarray | None:
    """Which classes the cycle's measured point allows, (n_classes,) bool; None for a loop that keeps the
    network's belief."""
    tol = phase_tolerance_deg(bundle.loop, f.response_spread[1], f.response_cycles)
    if tol is None:
        return None
    return delay_phase_deg(bundle, f.response, f.response_period) >= -tol


def consistent_activations(bundle: ModelBundle, activations: np.ndarray, f: CycleFeatures
                           ) -> tuple[np.ndarray, int]:
    """``activations`` (1, n) or (n,) with the classes the point rules out taken down by
    ``EXCLUDED_LOGIT`` temperatures below the least, as (1, n) float64, and how many it took out.
    Unchanged (0 out) where the loop is not named, or where the point allows every class or none."""
    a = np.atleast_2d(np.asarray(activations, dtype=np.float64))
    ok = consistent_classes(bundle, f)
    if ok is None or ok.all() or not ok.any():
        return a, 0
    return np.where(ok[None, :], a, a.min() - EXCLUDED_LOGIT * bundle.temperature), int((~ok).sum())
