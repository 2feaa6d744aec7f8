"""What is left between the measurement and a model: the residual's character, in words and numbers.

When no effect of the vocabulary explains the gap, the workflow answers
``unexplained`` and says what the residual looks like instead of forcing a
name: in which runs it is (relay amplitude ``h``, ``beta``, steps), at which
amplitude (measured over simulated oscillation amplitude and period), where in
the relay cycle (the phase where the mean cycle waveforms differ most,
relative to the relay's switching), and in which harmonics (the waveform
harmonics whose difference is largest).

    ch = residual_character(session, sims)    # sims: one SimRun per run (the model's seed-0 simulation)
    ch["summary"]                             # one line: "runs 0, 1 (h 0.02-0.06, beta -0.73); amplitude ..."
    ch["runs"][0]["where"]                    # e.g. "just after the rising switch (phase 0.05)"
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from uavsim.formats.session import STEP_RUN, Session
from uavsim.gap.features import cycle_edges, run_features, step_swings
from uavsim.gap.simulate import SimRun
from uavsim.noise.analysis import relay_phase

__all__ = ["residual_character", "run_residual", "steps_keep_swinging", "periods_wander", "third_harmonic_rise"]

#: harmonics of the mean cycle examined (1 = the fundamental)
HARMONICS = (1, 2, 3, 4, 5)
#: a run is listed as carrying the residual when its share of the total (over the relay runs,
#: or over the steps) is at least this
RUN_SHARE = 0.15
#: a step run's :func:`uavsim.gap.features.tail_swing` (in steps) between these for the steps'
#: swing to count as a limit cycle: over what noise and a settling loop leave, under a loop that
#: grows until a limit stops it. Development testbed attitude sessions (seeds 0-39, 30000-30063 to
#: 80000-80063): the larger step of every backlash 0.16-0.55, of clean sessions at most 0.01, of two
#: delays and a hold whose loop the steps' PD did not hold 3.3-6.2 (docs/results/gap-workflow.md)
PLAY_SWING = (0.1, 1.0)
#: and the two step runs' swings, in output units, equal within this factor: a limit cycle's size
#: is the nonlinearity's own, not the step's (backlashes 0.89-1.08; loops ringing from a lag,
#: low-pass or delay 0.10-0.76, since a linear loop's ringing scales with its step)
PLAY_SAME = 1.15


def _where(phase: float, duty: float) -> str:
    """Words for a point of the relay cycle (phase 0 = the relay's rising switch, ``duty`` = its falling one)."""
    near = 0.08
    if min(phase, 1.0 - phase) <= near:
        return f"at the rising switch (phase {phase:.2f})"
    if abs(phase - duty) <= near:
        return f"at the falling switch (phase {phase:.2f})"
    if phase < duty:
        return f"while the relay is high, between switches (phase {phase:.2f})"
    return f"while the relay is low, between switches (phase {phase:.2f})"


def run_residual(spec, t: np.ndarray, y_meas: np.ndarray, u_meas: np.ndarray, sim: SimRun) -> dict:
    """Residual character of one run: measured against one simulation of the same run.

    Returns
    -------
    dict
        ``file``, ``kind``, ``h``, ``beta``, ``size`` (RMS of the residual over the measured
        amplitude, or over the step for steps), ``amp_ratio`` and ``period_ratio`` (measured
        over simulated, relay runs), ``where`` and ``phase`` (where the mean cycles differ
        most), ``harmonics`` (k -> |C_meas - C_sim| over the fundamental's size, relay runs),
        ``third_rise`` (the loop's ``|G(3jw) / G(jw)|`` read off the measured run over the same read
        off the simulation, relay runs; None where either read is undefined:
        :func:`third_harmonic_rise`).
    """
    out: dict = {"file": spec.file, "kind": spec.kind, "h": None if spec.h is None else float(spec.h),
                 "beta": None if spec.beta is None else float(spec.beta)}  # fmt: skip
    fm = run_features(spec, t, y_meas, u_meas)
    fs = None if sim.diverged else run_features(spec, sim.t, sim.y, sim.u)
    if fm is None:
        out.update(size=math.nan, where="the measured run holds no analysable cycle")
        return out
    if fs is None:
        out.update(
            size=math.inf, where="the model does not reproduce this run (no cycle or diverged)"
        )
        return out
    if "_wave" not in fm:  # step: the smoothed responses, normalized by the step
        d = (
            fm["_trace"][: min(fm["_trace"].size, fs["_trace"].size)]
            - fs["_trace"][: fm["_trace"].size]
        )
        k = int(np.argmax(np.abs(d))) if d.size else 0
        out.update(size=float(np.sqrt(np.mean(d * d))) if d.size else math.nan,
                   where=f"in the step response, {k / max(d.size, 1):.0%} of the way through")  # fmt: skip
        return out
    d = fm["_wave"] - fs["_wave"]
    k = int(np.argmax(np.abs(d)))
    phase = k / d.size
    cm, cs = np.fft.rfft(fm["_wave"]) / d.size, np.fft.rfft(fs["_wave"]) / d.size
    c1 = abs(cm[1]) + 1e-12
    out.update(
        size=float(np.sqrt(np.mean(d * d))),
        amp_ratio=math.exp(fm["amplitude"] - fs["amplitude"]),
        period_ratio=math.exp(fm["period"] - fs["period"]),
        offset_diff=float(fm["offset"] - fs["offset"]),
        phase=phase,
        where=_where(phase, float(fm["duty"])),
        harmonics={h: float(abs(cm[h] - cs[h]) / c1) for h in HARMONICS if h < cm.size},
        third_rise=math.exp(d3) if math.isfinite(d3 := float(fm["r3mag"] - fs["r3mag"])) else None,
    )
    return out


def residual_character(session: Session, sims: Sequence[SimRun]) -> dict:
    """The residual of ``session`` against ``sims`` (one simulation per run), per run and in one line.

    Returns
    -------
    dict
        ``runs`` (list of :func:`run_residual` dicts), ``carried_by`` (indices of the relay runs
        holding at least :data:`RUN_SHARE` of the relay runs' residual, then the same for steps), ``harmonics`` (the two largest,
        over those runs), ``third_rise`` (the largest of the relay runs', None without one), ``summary`` (str).
    """
    runs = [
        run_residual(r.spec, r.data.t, r.data.y, r.data.u, s)
        for r, s in zip(session.runs, sims, strict=True)
    ]
    size = np.array([r["size"] if math.isfinite(r["size"]) else (1e3 if r["size"] == math.inf else 0.0)
                     for r in runs])  # fmt: skip
    # relay waveforms and step traces are normalized differently: each kind is shared out on its own
    step = np.array([r["kind"] == STEP_RUN for r in runs])
    carried = []
    for mask in (~step, step):
        total = float(size[mask].sum())
        carried += [i for i in np.flatnonzero(mask) if total > 0 and size[i] / total >= RUN_SHARE]
    carried = [int(i) for i in carried]
    harm: dict[int, float] = {}
    for i in carried:
        for h, v in runs[i].get("harmonics", {}).items():
            harm[h] = harm.get(h, 0.0) + v
    top = sorted(harm, key=lambda h: -harm[h])[:2]
    parts = []
    for i in carried:
        r = runs[i]
        what = f"run {i} {Path(r['file']).stem} ({r['kind']}"
        what += f", h {r['h']:.3g}" if r["h"] is not None else ""
        what += f", beta {r['beta']:.2g})" if r["beta"] is not None else ")"
        if "amp_ratio" in r:
            what += (f": amplitude x{r['amp_ratio']:.2f}, period x{r['period_ratio']:.2f}, "
                     f"waveform off by {r['size']:.0%} of the amplitude, most {r['where']}")  # fmt: skip
        else:
            what += f": {r['where']}"
        parts.append(what)
    summary = "; ".join(parts) or "no run departs"
    if top:
        summary += "; largest in harmonics " + ", ".join(str(h) for h in top)
    rises = [r["third_rise"] for r in runs if r.get("third_rise") is not None]
    return {"runs": runs, "carried_by": carried, "harmonics": top, "third_rise": max(rises, default=None),
            "summary": summary}


def steps_keep_swinging(session: Session) -> dict | None:
    """The step runs' swing when both keep swinging at one size whatever their step, else None.

    A PD loop around play (a backlash) hunts: the command held between reversals keeps it
    swinging in a limit cycle whose size is the play's, so two steps of different sizes swing
    alike in output units. A linear loop settles, or rings in proportion to its step. The
    largest and smallest steps (at least 1.5 apart) are compared: the larger's swing must lie
    within :data:`PLAY_SWING` of its step and the two sizes agree within :data:`PLAY_SAME`.

    Returns
    -------
    dict or None
        ``{"swing_small", "swing_large"}`` (each in its run's steps), ``amplitude`` (their
        mean in output units, peak to peak) and ``summary`` (words for the residual's).
    """
    specs = [r.spec for r in session.runs]
    feats = [run_features(r.spec, r.data.t, r.data.y, r.data.u) if r.spec.kind == STEP_RUN else None
             for r in session.runs]  # fmt: skip
    sw = sorted((abs(float(specs[k].step)), w) for k, w in step_swings(specs, feats).items() if specs[k].step)
    if len(sw) < 2:
        return None
    (s_small, w_small), (s_large, w_large) = sw[0], sw[-1]
    if s_large < 1.5 * s_small or not PLAY_SWING[0] <= w_large <= PLAY_SWING[1]:
        return None
    a_small, a_large = w_small * s_small, w_large * s_large
    if not 1.0 / PLAY_SAME <= a_small / a_large <= PLAY_SAME:
        return None
    amplitude = 0.5 * (a_small + a_large)
    summary = (f"the step runs keep swinging, {amplitude:.3g} peak to peak whatever their step "
               f"({w_small:.2f} and {w_large:.2f} of it): a limit cycle under the steps' PD, as play in the loop makes")
    return {"swing_small": w_small, "swing_large": w_large, "amplitude": amplitude, "summary": summary}


def periods_wander(session: Session, limit: float) -> dict | None:
    """The relay runs' cycle-period spread when one of them wanders beyond ``limit``, else None.

    A fixed loop under a relay repeats its cycle; noise jitters each switch, and a
    delay that varies in time (or any effect that does) makes the period wander
    from cycle to cycle, which no vocabulary effect, all of them fixed, flies. The
    spread is the std of a run's cycle periods over their mean, over the cycles the
    features analyse (:func:`uavsim.gap.features.cycle_edges`; runs of 4 cycles or more).

    Returns
    -------
    dict or None
        ``{"spread"}`` (the largest), ``runs`` (file -> spread) and ``summary`` (words for the residual's).
    """
    spread = {}
    for r in session.runs:
        if r.spec.kind == STEP_RUN:
            continue
        t, u = (np.asarray(v, dtype=np.float64) for v in (r.data.t, r.data.u))
        p = np.diff(t[cycle_edges(relay_phase(u))])
        if p.size >= 4:
            spread[r.spec.file] = float(np.std(p) / np.mean(p))
    if not spread or max(spread.values()) <= limit:
        return None
    top = max(spread, key=spread.get)
    summary = (f"the relay cycles' period wanders by {spread[top]:.1%} (std over mean) in {Path(top).stem}, over "
               f"the {limit:.1%} a fixed loop's jitter stays within: an effect that varies in time")
    return {"spread": spread[top], "runs": spread, "summary": summary}


def third_harmonic_rise(residual: dict, limit: float) -> dict | None:
    """The relay runs' third-harmonic rise over the model's when one of them exceeds ``limit`` (a factor), else None.

    Under a relay the loop's gain at the cycle's third harmonic over its gain at the
    fundamental, ``|G(3jw) / G(jw)|``, is read off each run (the output's harmonics over
    the relay's: ``r3mag`` of :func:`uavsim.gap.features.relay_features`). A lightly damped
    mode above the cycle (a resonance) passes the third harmonic more than the lumped
    model's lags do; the vocabulary's effects are memoryless, delays or low-pass. Not
    zero without a resonance: a model that took a delay or a low-pass into its lags
    passes less of the third harmonic than the loop (testbed attitude sessions: a delay
    x1.11, a low-pass x1.34), so the limit is set on sessions. The rise is the measured
    ratio over the model's, per relay run, as :func:`residual_character` (``residual``)
    read it against the model's simulation.

    Returns
    -------
    dict or None
        ``{"rise"}`` (the largest, as a factor), ``runs`` (file -> factor) and ``summary`` (words for
        the residual's).
    """
    rise = {r["file"]: r["third_rise"] for r in residual["runs"] if r.get("third_rise") is not None}
    if not rise or max(rise.values()) <= limit:
        return None
    top = max(rise, key=rise.get)
    summary = (f"the loop passes its third harmonic x{rise[top]:.2f} more than the model's (over the fundamental) "
               f"in {Path(top).stem}, beyond the x{limit:.2f} a clean loop stays within: a lightly damped "
               "mode above the cycle (a resonance)")
    return {"rise": rise[top], "runs": rise, "summary": summary}
