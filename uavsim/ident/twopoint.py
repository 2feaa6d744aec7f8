"""A second relay run at another ``beta``: a second measured point to weigh the network's belief by.

One NP-MRFT run measures the process's response at one frequency, ``G(j w1)``
(``CycleFeatures.response``, the hold removed). Every class fits that point exactly
with its own lags and a gain and delay of its own (``uavsim.ident.response.fit_response``),
so the point alone does not tell the classes apart: the cycle's shape, which noise
blurs, does. A second run at another ``beta`` (``SECOND_BETA``, ``-0.3``: a slower,
larger cycle, so a cleaner one for the same sensor) measures ``G(j w2)``. A class
with a gain and a delay fitted to both points by weighted least squares (``log |G|``
and the phase are linear in ``log K`` and ``tau``) leaves a residual where its lags
are not the process's, and a class is its delay too: a fit that needs a delay far
from the class's own says the class is not the process.

The belief becomes ``p(c) exp(-chi2(c) / 2)``, with ``chi2`` the fit's weighted squared
residual plus the squared distance of the fitted delay from the class's in
``log(tau + TAU_LOG_OFFSET_S)`` over ``TAU_LOG_SIGMA``. Each point's uncertainty is its
cycles' own spread (``CycleFeatures.response_spread`` over the root of their count),
floored (``SIGMA_FLOOR``), and the second's has ``EXTRAPOLATION_SIGMA`` added: a class
fitted where the network's run measured may miss a point elsewhere by that much and
still be the nearest class. The new belief goes to the loop's decision as activations
(``T log p``), so every decision of ``uavsim.ident.select`` runs on it unchanged; the
gain estimate and the fitted models stay those of the network's run.

On development seeds 11-14 (300 off-grid processes each, noise 0-20 %) it lowered the
inner loops' median J by 0.006-0.017 and the p95 on all eight sets against one run; the
same weighing from the first point alone did not. On report seed 2035 (5-cycle attitude runs,
untrimmed relays, no guard) attitude and lateral answered more unstable gains, so it was opt-in.
With today's identification (trimmed relays, the guard, attitude runs of 13 cycles) it lowered
the p95 on all of development seeds 11-20 of attitude (median over the seeds 1.103 -> 1.083) and
on 9 of 10 of altitude (1.108 -> 1.104; the tenth +0.0007), with fewer unstable answers and a
lower max (docs/results/identification.md), so the inner loops use it by default: identification of a
session takes its relay run at ``SECOND_BETA`` where it holds one (``SECOND_RUN_LOOPS``,
``auto_second_run``; ``uavsim identify --second-run``), and ``uavsim evaluate`` flies one.

Lateral loops use the second point where it counts there: on the family of models the first
point allows (``uavsim.ident.family``: ``other``), averaged over up to 12 steady cycles
(``SECOND_RESPONSE_CYCLES``). The belief weighing alone had moved their p95 either way
(development seeds 11-12: 1.429 -> 1.342, 1.559 -> 1.570); kept to the members both points
allow, the family took it to 1.075 / 1.080 / 1.083 on seeds 11-13.

    from uavsim.ident.twopoint import two_point_activations
    act2 = two_point_activations(bundle, act, f1, f2)   # f1: the network's run, f2: the run at SECOND_BETA
"""

from __future__ import annotations

import math

import numpy as np

from uavsim.data.preprocess import CycleFeatures, process_response
from uavsim.ident.bundle import ModelBundle
from uavsim.ident.response import class_response, measured_phase, point_sigmas
from uavsim.learning.decision import softmax

__all__ = ["SECOND_BETA", "SECOND_RUN_LOOPS", "SECOND_RUN_AUTO", "SIGMA_FLOOR", "EXTRAPOLATION_SIGMA",
           "TAU_LOG_SIGMA", "TAU_LOG_OFFSET_S", "SECOND_RESPONSE_CYCLES", "second_response_cycles",
           "auto_second_run", "point_uncertainty", "two_point_fit", "points_fit", "two_point_activations"]

#: the second run's MRFT parameter a user flies
SECOND_BETA = -0.3
#: loops whose identification takes a session's run at ``SECOND_BETA`` as the second point unless told
#: otherwise, and whose ``uavsim evaluate`` flies one (module docstring)
SECOND_RUN_LOOPS = ("altitude", "attitude", "lateral")
#: ``identify_session(second_run=...)``: find the second run in the session
SECOND_RUN_AUTO = "auto"
#: most steady cycles a second run's point is averaged over, by loop (else ``RESPONSE_CYCLES``, as the inner
#: loops' two-run default was measured); lateral points pin the family's members (``uavsim.ident.family``)
SECOND_RESPONSE_CYCLES: dict[str, int] = {"lateral": 12}
#: floors of each point's measured uncertainty: std of log |G| and of its phase (deg)
SIGMA_FLOOR = (0.01, 0.5)
#: added (in quadrature) to every point after the first: log |G|, phase (deg)
EXTRAPOLATION_SIGMA = (0.05, 3.0)
#: std of the fitted delay's distance from the class's, in log(tau + TAU_LOG_OFFSET_S)
TAU_LOG_SIGMA = 0.5
#: s, keeps the log of the box's sub-millisecond delays from dominating
TAU_LOG_OFFSET_S = 0.001


def second_response_cycles(loop: str | None) -> int:
    """Most steady cycles a second run of ``loop`` is averaged over (``SECOND_RESPONSE_CYCLES``)."""
    from uavsim.data.preprocess import RESPONSE_CYCLES

    return SECOND_RESPONSE_CYCLES.get(loop, RESPONSE_CYCLES)


def auto_second_run(runs, first: str, loop: str, network_beta: float) -> str | None:
    """The file of the session's first relay run at ``SECOND_BETA`` other than ``first``, on a loop of
    ``SECOND_RUN_LOOPS``; None where the loop is not one, the network itself was trained at
    ``SECOND_BETA`` (no other point to find), or the session holds no such run.

    ``runs``: the session's runs (``uavsim.formats.session``: each with ``spec.kind``, ``spec.beta``,
    ``spec.file``); ``network_beta``: the beta the network's run flies (``ModelBundle.rule.beta``).
    """
    from uavsim.formats.session import RELAY_KINDS

    if loop not in SECOND_RUN_LOOPS or abs(float(network_beta) - SECOND_BETA) < 1e-6:
        return None
    for r in runs:
        if (r.spec.kind in RELAY_KINDS and r.spec.file != first and r.spec.beta is not None
                and abs(float(r.spec.beta) - SECOND_BETA) < 1e-6):
            return r.spec.file
    return None


def point_uncertainty(f: CycleFeatures, extra: tuple[float, float] = (0.0, 0.0)) -> tuple[float, float]:
    """A point's uncertainty (log gain, phase rad): its standard errors (``point_sigmas``), floored
    (``SIGMA_FLOOR``), with ``extra`` (log gain, deg) added in quadrature."""
    sg, sp = point_sigmas(f.response_spread, f.response_cycles, SIGMA_FLOOR)
    return math.hypot(sg, extra[0]), math.hypot(sp, math.radians(extra[1]))


def two_point_fit(bundle: ModelBundle, cls, points: list[CycleFeatures]) -> dict[str, np.ndarray]:
    """Each class's gain and delay fitted to every measured point by weighted least squares.

    Parameters
    ----------
    cls : (n,) int
        Classes.
    points : list of CycleFeatures
        The runs' cycles, the network's first (each with its ``response`` and ``response_period``).

    Returns
    -------
    dict of (n,) arrays: ``K``, ``tau`` (s, >= 0) and ``chi2`` (the weighted squared residual; a
    class that needs a negative delay is fitted at 0 and keeps that residual).
    """
    cls = np.asarray(cls, dtype=np.int64)
    w = np.array([2.0 * math.pi / f.response_period for f in points])
    mag0, ph0 = class_response(bundle, cls, w)
    return points_fit(bundle, mag0, ph0, points, tau_branch=bundle.column("tau")[cls][:, None], min_tau=0.0)


def points_fit(bundle: ModelBundle, mag0: np.ndarray, ph0: np.ndarray, points: list[CycleFeatures], *,
               tau_branch, min_tau: float | None = 0.0) -> dict[str, np.ndarray]:
    """Delay-free unit models' gain and delay fitted to every measured point by weighted least squares.

    ``mag0``, ``ph0``: (n, k) magnitude and unwrapped phase of n models at the k points' frequencies;
    ``tau_branch``: the delay (s, broadcast to (n, 1)) whose phase picks each measured phase's branch;
    ``min_tau``: the least delay fitted (None: the unconstrained fit). Each point weighs by its
    uncertainty (``point_uncertainty``; ``EXTRAPOLATION_SIGMA`` added on every point after the first).
    Returns (n,) ``K``, ``tau`` (s) and ``chi2``.
    """
    w = np.array([2.0 * math.pi / f.response_period for f in points])
    G = np.array([complex(process_response(f.response, f.response_period, rate_hz=bundle.input_rate_hz))
                  for f in points])
    sg, sp = (np.array(s) for s in zip(*(point_uncertainty(f, EXTRAPOLATION_SIGMA if k else (0.0, 0.0))
                                         for k, f in enumerate(points)), strict=True))
    dg = np.log(np.abs(G))[None, :] - np.log(mag0)
    wg = 1.0 / sg**2
    logK = (dg * wg).sum(axis=1) / wg.sum()
    # each measured phase on the branch nearest the model's with the branch delay; w tau for an exact fit
    d = ph0 - measured_phase(G[None, :], ph0, w[None, :], tau_branch)
    wp = 1.0 / sp**2
    tau = (d * w * wp).sum(axis=1) / (w**2 * wp).sum()
    if min_tau is not None:
        tau = np.maximum(tau, min_tau)
    chi2 = (((dg - logK[:, None]) ** 2) * wg).sum(axis=1) + (((d - w[None, :] * tau[:, None]) ** 2) * wp).sum(axis=1)
    return {"K": np.exp(logK), "tau": tau, "chi2": chi2}


def two_point_activations(bundle: ModelBundle, activations: np.ndarray, first: CycleFeatures,
                          second: CycleFeatures) -> np.ndarray:
    """The network's activations (1, n) with the belief weighed by both points' fit (module docstring).

    Returns activations whose softmax at the bundle's temperature is ``p L / sum(p L)``.
    """
    p = softmax(activations, bundle.temperature)
    n = p.shape[1]
    fit = two_point_fit(bundle, np.arange(n), [first, second])
    d = np.log(fit["tau"] + TAU_LOG_OFFSET_S) - np.log(bundle.column("tau") + TAU_LOG_OFFSET_S)
    chi2 = fit["chi2"] + (d / TAU_LOG_SIGMA) ** 2
    with np.errstate(divide="ignore"):
        logp = np.log(p) - 0.5 * chi2[None, :]
    return bundle.temperature * (logp - logp.max(axis=1, keepdims=True))
