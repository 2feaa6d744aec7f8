"""The colour of a model's measurement noise, chosen by the gap when the samples are a staircase.

The workflow's model noise is white at the measured std, and the sensor's own
filtering is taken off the comparison (:func:`uavsim.gap.features.noise_offsets`).
That fails on a staircase: a camera behind a Kalman filter gives slow noise, which
quantized or held sits on one level for many samples, while white noise of the same
std hops every sample. The repeated samples and the roughness of the stairs then
carry a gap that no effect explains, and the search names a second, false one.

:func:`noise_colour` flies the model with the staircase in the loop once per corner
of :data:`CORNERS_HZ` (white, then 2nd-order low-passes, at the model's std) and
keeps the corner of least gap; the model carries it as ``noise_corner_hz``. It is a
nuisance parameter of the sensor, not an effect: nothing is named by it.

    colour = noise_colour(session_with_staircase, model, seed=0)
    model = dataclasses.replace(model, noise_corner_hz=colour.corner_hz)
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from uavsim.formats.session import ModelSpec, Session
from uavsim.gap.workflow import GapEvaluator, base_effects

__all__ = ["CORNERS_HZ", "ColourResult", "noise_colour"]

#: corners screened, Hz (None: white). The altitude camera + Kalman filter of the testbed vehicle
#: fitted 2-5 Hz on its quantized sessions with the true model (docs/results/gap-workflow.md);
#: attitude's IMU chain stayed white
CORNERS_HZ: tuple[float | None, ...] = (None, 10.0, 5.0, 3.0, 2.0)
#: noise seeds per corner
SEEDS = 3


@dataclass(frozen=True)
class ColourResult:
    """The screened corners and the one kept.

    Attributes
    ----------
    corner_hz : float or None
        The corner of least gap, Hz (None: white).
    gaps : dict of str to float
        Mean gap over :data:`SEEDS` noise seeds per corner (key ``"white"`` or the corner in Hz).
    """

    corner_hz: float | None
    gaps: dict[str, float]

    def to_json(self) -> dict:
        return {"corner_hz": self.corner_hz, "gaps": dict(self.gaps)}


def _key(c: float | None) -> str:
    return "white" if c is None else f"{c:g}"


def noise_colour(
    session: Session,
    model: ModelSpec,
    *,
    seed: int = 0,
    nthread: int = 0,
    dt: float = 0.001,
    corners: tuple[float | None, ...] = CORNERS_HZ,
) -> ColourResult:
    """Fly ``model`` with each noise corner and keep the one of least gap.

    Parameters
    ----------
    session : Session
        The runs, with the effects read off the samples in its ``[[effects]]``.
    model : ModelSpec
        The base model; its ``noise_std`` is kept, its ``noise_corner_hz`` replaced.
    seed, nthread, dt :
        As :func:`uavsim.gap.workflow.run_gap`.
    corners : tuple of float or None
        Corners to try, Hz; those at or above the control rate's Nyquist are skipped.

    Returns
    -------
    ColourResult
        Each corner scored on its own seed spread (the scales a model of that noise explains).
    """
    nyquist = 0.5 * float(session.control_rate_hz)
    gaps: dict[str, float] = {}
    best, best_gap = None, math.inf
    ev = GapEvaluator(session, model, base_effects(session), seed, nthread, dt)  # the measured features once
    for c in corners:
        if c is not None and not 0 < c < nyquist:
            continue
        # every corner flies the same draws of the white noise it filters
        ev.model, ev.calls = dataclasses.replace(model, noise_corner_hz=c), 0
        fb = [ev.features(s) for s in ev.sims([("none", 0.0)], seeds=SEEDS)]
        if any(f is None for run in fb for f in run):
            gaps[_key(c)] = math.inf
            continue
        ev.calibrate(fb)
        g = float(np.mean([ev.gap(f) for f in fb]))
        gaps[_key(c)] = g
        if g < best_gap:
            best, best_gap = c, g
    return ColourResult(corner_hz=best, gaps=gaps)
