"""The sim-vs-measured gap workflow: which effect does the model lack?

1. **Gap before.** Every run of the session is simulated on the MuJoCo loop
   with the session's ``[model]`` (and its ``[[effects]]``), the run's own
   controller and the model's noise, with several noise seeds. Each run is
   reduced to features (:mod:`uavsim.gap.features`), measured and simulated
   features are turned into z-scores scaled by what noise explains, and the
   gap is their RMS (about 1 or less when only noise separates them). A
   measured noise smoother than the model's white noise is the sensor's
   filtering, taken off every comparison
   (:func:`uavsim.gap.features.noise_offsets`).
2. **Candidates.** Every vocabulary effect has one parameter. A coarse
   log-spaced grid of each (scaled to the session: period, relay amplitudes,
   oscillation amplitude, noise level) is simulated in *one* batch, then the
   best three candidates get a finer grid around their best value. The best
   value is refined by a parabola through the three best grid points (in the
   parameter's log). Each candidate's score is its remaining gap plus a
   complexity penalty of :data:`PENALTY` per parameter. With an identified
   model (``phase_anchor_hz``, ``phase_anchor_h``), lag-like candidates (a frame
   hold's half frame, and a rate limit, whose phase depends on the relay's amplitude) take the phase they add at
   the identified cycle out of its ``tau``; with ``credit`` (what each
   candidate already removes from a clean session), the gap a candidate
   leaves is first given back that much (:func:`credited_gap`).
3. **Decision.** ``none`` when the gap before is within what noise explains
   (:data:`NONE_GAP`), when no candidate's score beats it, or when the best
   candidate leaves more than :data:`NAME_RATIO` of it (no single effect of
   the vocabulary explains the gap; rare noise-triggered relay orbits also
   land here); otherwise the best-scoring candidate. Its value is fitted once
   more on a few points around it (:data:`POLISH`), each averaged over noise
   seeds, and the best is re-simulated with fresh seeds to give the gap after
   (kept only if it beats the first fit's).

    result = run_gap(read_session("flights/thermal_kf"))
    result.effect, result.params, result.gap_before, result.gap_after
    print(format_table(result))
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uavsim.errors import UserError
from uavsim.formats.session import (
    EFFECT_PARAMS,
    STEP_RUN,
    EffectSpec,
    ModelSpec,
    Session,
    SessionError,
    validate_model,
)
from uavsim.gap.features import (
    compare,
    gap_value,
    noise_offsets,
    noise_scales,
    run_features,
    step_swings,
    worst_window,
)
from uavsim.gap.simulate import Episode, SimRun, model_params, simulate
from uavsim.lumped.frequency import mrft_prediction_batch
from uavsim.lumped.params import INNER_LOOPS, loop_family
from uavsim.model.effects import vocabulary

__all__ = ["CANDIDATES", "GapResult", "GapEvaluator", "UnflownRun", "base_effects", "run_gap", "format_table", "ruled_out", "read_off_samples",
           "credited_gap", "read_model_file", "candidate_grid", "candidate_phase", "take_out_phase", "read_off_relays", "rate_from_periods",
           "step_hunting"]

#: candidate effects, in the vocabulary's order (a live view of the registered vocabulary effects)
CANDIDATES = vocabulary.NAMES
#: score added per fitted parameter (in gap units)
PENALTY = 0.25
#: a gap at or below this is what noise explains: the answer is ``none``
NONE_GAP = 1.5
#: an effect is named only if its gap is at most this fraction of the gap before
NAME_RATIO = 0.4
#: noise seeds for the gap before and after
SEEDS = 3
#: candidates whose fitted value is re-simulated with fresh seeds before deciding
VERIFY = 3
#: factors around the winner's value for its final, seed-averaged fit
POLISH = (0.85, 0.92, 1.0, 1.08, 1.17)
#: least share of an identified model's ``T_prop`` a lag-like candidate leaves when it takes its phase
#: out of the model beyond ``tau`` (:meth:`GapEvaluator.trimmed`)
T_PROP_KEEP = 0.05


def credited_gap(name: str, gap: float, credit: dict[str, float] | None) -> float:
    """The gap candidate ``name`` leaves, given back the squared gap ``credit[name]`` it removes from a clean session.

    The gap is an RMS of z-scores, so independent misfits add in squares: a candidate
    that also takes out part of the base model's own misfit (an actuator limit that
    clips the steps' first sample, on every session) is judged by what it removes
    beyond that part.
    """
    extra = (credit or {}).get(name, 0.0)
    return math.sqrt(gap * gap + extra) if extra > 0 else gap


def candidate_phase(name: str, value: float, freq_hz: float, h: float = 0.0, rate_hz: float | None = None) -> float:
    """Phase lag, rad, that candidate ``name`` = ``value`` adds to a relay cycle at ``freq_hz`` whose relay
    swings +-``h`` (its vocabulary term's ``phase``; 0 for effects without one and for the bare model, ``none``).

    A rate effect (a frame hold) is taken against its identity, the control rate ``rate_hz``: a loop
    sampled at that rate already has the phase of a hold at it."""
    term = vocabulary.term(name) if name in vocabulary.names() else None
    if term is None or term.phase is None:
        return 0.0
    phase = float(term.phase(value, freq_hz, h))
    if term.identity_is_rate and rate_hz:
        phase = max(phase - float(term.phase(rate_hz, freq_hz, h)), 0.0)
    return phase


def take_out_phase(model: ModelSpec, phase: float, w: float, *, t_prop_min: float) -> tuple[float, ModelSpec | None]:
    """Take ``phase`` (rad, at ``w`` rad/s) out of an identified inner-loop model's lags: ``tau`` first,
    then ``T_prop``.

    The first-order factor ``1 / (T_prop s + 1)`` gets shorter down to ``t_prop_min`` (s), and ``K``
    is scaled so that the model's gain at ``w`` stays the same.

    Returns
    -------
    tau_cut : float
        What comes off ``tau``, s (at most ``tau``).
    trimmed : ModelSpec or None
        The model with ``T_prop`` and ``K`` moved (its ``tau`` as it was), or None when ``tau`` holds
        the whole phase.
    """
    cut = min(phase / w, float(model.tau))
    rest = phase - w * cut
    if not (rest > 1e-9 and model.T_prop > 0):
        return cut, None
    tp = max(math.tan(max(math.atan(w * model.T_prop) - rest, 0.0)) / w, t_prop_min)
    k = model.K * math.hypot(1.0, w * tp) / math.hypot(1.0, w * model.T_prop)
    return cut, dataclasses.replace(model, K=k, T_prop=tp)


class UnflownRun(UserError):
    """The base model cannot fly run ``run`` (no oscillation, a diverging step): the gap of that run is undefined."""

    def __init__(self, run: int, message: str):
        super().__init__(message)
        self.run = run


@dataclass
class Disagreement:
    """Where measurement and model disagree: one (run, feature) with its z-score and worst window."""

    run: str
    feature: str
    z: float
    window_s: tuple[float, float]


@dataclass
class GapResult:
    """Answer of the gap workflow.

    Attributes
    ----------
    effect : str
        The winner (``"none"`` when noise explains the gap).
    params : dict of str to float
        Its fitted parameters (vocabulary units).
    gap_before, gap_after : float
        RMS z-score of the features, session model vs. with the winner.
    ranking : list of dict
        ``{"effect", "params", "gap", "score"}`` per candidate, best first (``none`` included).
    disagreements : list of Disagreement
        The largest z-scores of the gap before.
    model : ModelSpec
        The model the session was simulated with.
    effects : list of EffectSpec
        The updated model's effects (the session's plus the winner).
    seed : int
    seconds : float
    sims_before, sims_after : per run, the seed-0 simulation (for plots)
    ruled_out : list of str
        Candidates not searched because the measured samples exclude them (:func:`ruled_out`).
    """

    effect: str
    params: dict[str, float]
    gap_before: float
    gap_after: float
    ranking: list[dict]
    disagreements: list[Disagreement]
    model: ModelSpec
    effects: list[EffectSpec]
    seed: int
    seconds: float
    sims_before: list[SimRun] = field(default_factory=list, repr=False)
    sims_after: list[SimRun] = field(default_factory=list, repr=False)
    ruled_out: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        """The spec's JSON answer (effect, params, gap_before, gap_after, ranking) plus details."""
        return {
            "effect": self.effect,
            "params": self.params,
            "gap_before": self.gap_before,
            "gap_after": self.gap_after,
            "ranking": self.ranking,
            "disagreements": [dataclasses.asdict(d) for d in self.disagreements],
            "model": dataclasses.asdict(self.model),
            "effects": [{"name": e.name, **e.params} for e in self.effects],
            "seed": self.seed,
            "seconds": self.seconds,
            "ruled_out": list(self.ruled_out),
        }


def read_model_file(path: str | Path, loop: str) -> ModelSpec:
    """Read a model TOML (a ``[model]`` table, or its keys at top level) and check it for ``loop``."""
    from uavsim.schema import load_toml

    p = Path(path)
    where = str(p)
    doc = load_toml(p, "gap-model")  # keys, types and ranges (uavsim.schema.gap)
    table = doc.get("model", doc)
    keys = [f.name for f in dataclasses.fields(ModelSpec)]
    model = ModelSpec(**{k: table[k] for k in keys if k in table})
    if model.noise_std is None:
        model.noise_std = 0.0
    validate_model(model, loop, where)
    return model


def _session_scales(session: Session, feats: list[dict | None]) -> dict[str, float]:
    """Scales that place the candidate grids: period, relay amplitudes, oscillation amplitude, max |u|."""
    relays = [(r, f) for r, f in zip(session.runs, feats, strict=True) if r.spec.kind != STEP_RUN and f is not None]
    hs = [float(r.spec.h) for r, _ in relays] or [float(np.max(np.abs(session.runs[0].data.u)))]
    period = float(np.exp(np.median([f["period"] for _, f in relays]))) if relays else 1.0
    amp = float(np.exp(min(f["amplitude"] for _, f in relays))) if relays else 1.0
    umax = max(float(np.max(np.abs(r.data.u))) for r in session.runs)
    return {"period": period, "h_min": min(hs), "h_max": max(hs), "amp": amp, "umax": umax}


#: repeated samples (a share of all) above which the measurement is read as a staircase
STAIR_REPEATS = 0.2
#: a staircase is on a level lattice (quantization) when at least this share of the gaps between
#: its distinct levels are whole multiples (within 5 %) of the smallest one
STAIR_LATTICE = 0.5
#: and held in frames (sample-and-hold) when at least this share of its runs of equal samples are two
#: samples or longer (a frame rate holds every value; a quantizer passes lone samples where the signal
#: moves faster than a step a sample)
STAIR_HELD_SHARE = 0.9


def _equal_runs(y: np.ndarray) -> np.ndarray:
    """Lengths (samples) of the runs of equal consecutive samples of ``y`` (n,), a 1 for every lone sample."""
    change = np.flatnonzero(np.diff(y) != 0)
    return np.diff(np.concatenate([[-1], change, [y.size - 1]]))


def data_hints(session: Session, rate_hz: float) -> dict[str, float]:
    """Parameters read straight off the measured samples, where the data shows them.

    Quantization and sample-and-hold leave the measurement in runs of repeated
    values; their gap landscapes are rugged (each step or frame rate gives its
    own relay orbits), so a coarse grid can miss the basin. When at least
    :data:`STAIR_REPEATS` of the samples repeat the one before, the hints join the candidate grids:

    * ``quantization``: the smallest gap between distinct measured values;
    * ``sample_hold``: the control rate over the mean length of runs of equal
      samples, when that is at least 1.5 samples.

    A staircase whose levels lie on that lattice (:data:`STAIR_LATTICE`) and which
    passes lone samples is not held in frames, and one held in frames
    (:data:`STAIR_HELD_SHARE`) off any lattice is not quantized: :func:`ruled_out`
    names the effect the data exclude (a quantized hold shows both and keeps both;
    a staircase that shows neither keeps both, with their hints).

    Returns
    -------
    dict name -> value (vocabulary units), for the effects with a hint.
    """
    hints, _ = _staircase(session, rate_hz)
    return hints


def ruled_out(session: Session, rate_hz: float) -> set[str]:
    """Vocabulary effects the measured samples exclude (:func:`data_hints`): of a staircase's two causes, the one it does not show."""
    return _staircase(session, rate_hz)[1]


def read_off_samples(session: Session, rate_hz: float) -> list[EffectSpec]:
    """The staircase's cause with its parameter, where the measured samples show that cause alone.

    A staircase on a level lattice that passes lone samples is quantization with
    the lattice's step; one held in frames off any lattice is a sample-and-hold at
    the frames' rate (:func:`data_hints`, :func:`ruled_out`). Both are read to the
    sample, where a gap search on an identified base model (itself fitted to the
    staircase) drifts off them. A staircase that shows both or neither reads nothing.
    """
    hints, out = _staircase(session, rate_hz)
    if out == {"sample_hold"} and hints.get("quantization", 0.0) > 0:
        return [EffectSpec("quantization", {"step": float(hints["quantization"])})]
    if out == {"quantization"} and hints.get("sample_hold", 0.0) > 0:
        return [EffectSpec("sample_hold", {"rate_hz": float(hints["sample_hold"])})]
    return []


#: a relay run's cycle amplitude over that of a run of the same beta and a smaller ``h``, measured
#: over simulated on the (linear) base model, at or below which the loop's gain falls with the
#: relay's amplitude: a saturation between the two ``h``. Set on the testbed sessions of development
#: seeds 0-39 and the spent held-out sets 30000-30063, 40000-40063 and 50000-50063: clean sessions
#: 0.86-1.21, saturation singles 0.43-0.86 (docs/results/gap-workflow.md)
SAT_AMP_RATIO = 0.8
#: the two runs' period ratio (measured over simulated) within this factor either way. A relay's
#: square wave clipped is a square wave of the limit's amplitude, so a saturation moves the cycle's
#: amplitude, not its period (the same sessions: saturation singles 0.96-1.09, with a second effect
#: 0.91-1.13); a bias or a noise-driven orbit moves both (a bias with a ratio of 0.72: 0.76)
SAT_PERIOD_BAND = 1.15
#: and the larger run's relay duty within this of the smaller's (measured less simulated), for a
#: saturation as for a dead zone: limits, or a dead zone, alike both ways keep the square wave
#: symmetric, where unequal limits or a bias move the duty (the same sessions: saturation singles at
#: most 0.025, asymmetric saturations 0.060-0.155; dead-zone singles at most 0.027, the bias single
#: and the bias + dead zone pair of 90000-90063 that the dead-zone read took for dead zones 0.087-0.102)
SAT_DUTY_SHIFT = 0.04
#: smallest ratio of the two runs' relay amplitudes ``h`` for the comparison
SAT_H_RATIO = 1.5
#: the same amplitude ratio at or above which the loop's gain grows with the relay's amplitude:
#: a dead zone, through which a square wave of amplitude ``h`` passes as one of ``h - width``.
#: Development testbed sessions (seeds 0-39, 30000-30063 to 70000-70063): clean 0.86-1.21,
#: dead-zone singles 0.99-1.53, backlashes 0.88-1.49 (docs/results/gap-workflow.md)
DZ_AMP_RATIO = 1.3
#: and the period ratio within this factor either way (dead-zone singles 0.85-1.05; rate limits,
#: whose larger cycle also grows more than ``h`` does, 1.13-1.46)
DZ_PERIOD_BAND = 1.1
#: the step runs' :func:`uavsim.gap.features.tail_swing` beyond the base model's (in steps) above
#: which the loop hunts under the steps' PD. Play (a backlash) passes a relay's square wave as a
#: dead zone does, but holds the command between reversals: the held command keeps a PD loop
#: swinging where a dead zone lets it settle. Set between the development sessions' attitude dead
#: zones (at most 0.015) and backlashes (0.49-1.56); on altitude the camera swings every step run
#: as much (dead zones 0.09-0.47), so no altitude dead zone is read (docs/results/gap-workflow.md)
HUNT_SWING = 0.1
#: per loop family, the larger relay run's period over the smaller's (measured over simulated) at or
#: above which the loop's phase lag grows with the relay's amplitude, as a slew-rate limit's does
#: (its ramps delay the square wave's centre by ``h / rate``), with the amplitude ratio at least 1
#: (a saturation's falls). Development altitude sessions (seeds 410016-410928, identified models):
#: rate-limit singles 1.19-1.54 (one limit too weak to show, 1.04), every other session with an
#: amplitude ratio of 1 or more at most 1.04 (clean, lags, low-passes, dead zones). Not studied on
#: the attitude loops (None: not read there).
RL_PERIOD_RATIO: dict[str, float | None] = {"altitude": 1.12, "attitude": None}


def read_off_relays(session: Session, meas: list[dict | None],
                    sims: list[list[dict | None]], *, model: ModelSpec | None = None) -> list[EffectSpec]:
    """A saturation or a dead zone, where two relay runs show the loop's gain moving with amplitude;
    a rate limit, where they show its phase lag moving with amplitude.

    A relay's output is a square wave of amplitude ``h``; clipped at ``limit < h`` it is a
    square wave of amplitude ``limit``. A linear loop's relay cycle grows in proportion to ``h``
    (the base model, flown with the runs' own relays, says by how much under their noise
    settings). Of two runs of one ``beta`` with ``h_small < h_large``, let ``r`` be the larger
    run's cycle amplitude over the smaller's, measured over simulated. With a saturation
    between the two ``h``, the larger cycle grows only as far as the limit: ``limit = r *
    h_large``, read when ``r`` is at most :data:`SAT_AMP_RATIO`, the period ratio stays
    within :data:`SAT_PERIOD_BAND` and the relay's duty within :data:`SAT_DUTY_SHIFT` (a
    limit unequal both ways, which the vocabulary's saturation is not, biases the clipped wave).

    Through a dead zone of half-width ``width`` the square wave has amplitude ``h - width``,
    so the larger cycle grows more than ``h`` does: ``r = (h_large - width) h_small /
    ((h_small - width) h_large)``, read for ``width`` when ``r`` is at least
    :data:`DZ_AMP_RATIO` with the period ratio within :data:`DZ_PERIOD_BAND`, the duty within
    :data:`SAT_DUTY_SHIFT` (a bias moves it), and when the step runs settle as the base model's
    do (:data:`HUNT_SWING`): play in the loop passes the square wave alike, and keeps the steps'
    PD loop hunting.

    A slew-rate limit ramps each switch of the square wave over ``2 h / rate``: the wave's centre
    comes ``h / rate`` late, a delay that grows with ``h``, so the larger run's period grows
    beyond the model's. Read, with the base ``model`` given, where the period ratio is at least
    :data:`RL_PERIOD_RATIO` of the loop's family with ``r`` at least 1 (:func:`rate_from_periods`
    gives the rate).

    Parameters
    ----------
    session : Session
    meas : list of dict or None, length R
        The measured runs' features (:func:`uavsim.gap.features.run_features`).
    sims : list of list of dict or None
        Per noise seed, the base model's simulated runs' features, length R each.
    model : ModelSpec, optional
        The base model flown in ``sims``: without it no rate limit is read.

    Returns
    -------
    list of EffectSpec
        ``[saturation]``, ``[dead_zone]``, ``[rate_limit]`` or empty.
    """
    runs = [i for i, r in enumerate(session.runs) if r.spec.kind != STEP_RUN and r.spec.h
            and meas[i] is not None and all(f[i] is not None for f in sims)]  # fmt: skip
    specs = [r.spec for r in session.runs]
    pairs = [(specs[j].h / specs[i].h, i, j) for i in runs for j in runs
             if (specs[i].kind, specs[i].beta) == (specs[j].kind, specs[j].beta)
             and specs[j].h >= SAT_H_RATIO * specs[i].h]  # fmt: skip
    if not pairs or not sims:
        return []
    _, i, j = max(pairs, key=lambda p: p[0])  # the widest h ratio (the first of equals)

    def shift(feature: str) -> float:
        """Larger run's ``feature`` less the smaller's, measured less simulated (mean over seeds)."""
        return meas[j][feature] - meas[i][feature] - float(np.mean([f[j][feature] - f[i][feature] for f in sims]))

    r = math.exp(shift("amplitude"))  # amplitude and period features are logs
    h_s, h_l = float(specs[i].h), float(specs[j].h)
    period = abs(shift("period"))
    if abs(shift("duty")) > SAT_DUTY_SHIFT:
        return []
    if r <= SAT_AMP_RATIO and r * h_l > h_s and period <= math.log(SAT_PERIOD_BAND):
        return [EffectSpec("saturation", {"limit": r * h_l})]
    if r >= DZ_AMP_RATIO and period <= math.log(DZ_PERIOD_BAND) and step_hunting(session, meas, sims) <= HUNT_SWING:
        return [EffectSpec("dead_zone", {"width": h_l * h_s * (r - 1.0) / (r * h_l - h_s)})]
    if model is None or r < 1.0:
        return []
    limit = RL_PERIOD_RATIO.get(loop_family(session.loop))
    longer = math.exp(shift("period"))
    if limit is not None and longer >= limit:
        rate = rate_from_periods(model, session.loop, float(specs[i].beta), h_s, h_l, longer)
        if rate is not None:
            return [EffectSpec("rate_limit", {"rate": rate})]
    return []


def rate_from_periods(model: ModelSpec, loop: str, beta: float, h_small: float, h_large: float,
                      ratio: float) -> float | None:
    """The slew rate (command units per s) that lengthens ``model``'s relay cycle at ``h_large`` over its
    cycle at ``h_small`` by ``ratio`` (harmonic balance), or None where no rate in range does.

    The limit is taken as the delay of the ramped square wave's centre, ``h / rate``; the model's
    ``tau`` is taken to hold that delay at ``h_small`` already (an identified model put the smaller
    run's phase there), down to 0.
    """
    fam = loop_family(loop)
    p = {"K": model.K, "T_prop": model.T_prop, "T1": model.T1}
    w0, _ = mrft_prediction_batch(fam, beta, h_small, tau=np.array([float(model.tau)]), **p)
    if not np.isfinite(w0[0]):
        return None
    # the larger run's delay up to a quarter of the cycle: beyond it, its ramps fill the half period
    d_l = np.geomspace(1e-4, 0.5 * math.pi / float(w0[0]), 96)
    d_s = d_l * h_small / h_large
    tau0 = np.maximum(float(model.tau) - d_s, 0.0)
    w_s, _ = mrft_prediction_batch(fam, beta, h_small, tau=tau0 + d_s, **p)
    w_l, _ = mrft_prediction_batch(fam, beta, h_large, tau=tau0 + d_l, **p)
    got = w_s / w_l  # the period ratio, growing with the delay
    ok = np.isfinite(got) & (got >= np.fmax.accumulate(np.where(np.isfinite(got), got, 0.0)))
    if not ok.any() or not got[ok].min() <= ratio <= got[ok].max():
        return None
    d = float(np.exp(np.interp(math.log(ratio), np.log(got[ok]), np.log(d_l[ok]))))
    return h_large / d


def step_hunting(session: Session, meas: list[dict | None], sims: list[list[dict | None]]) -> float:
    """The step runs' largest tail swing measured beyond the simulated (mean over seeds), in steps; 0 without steps."""
    specs = [r.spec for r in session.runs]
    flown = [step_swings(specs, f) for f in sims]
    out = 0.0
    for k, w in step_swings(specs, meas).items():
        ws = [f[k] for f in flown if k in f]
        out = max(out, w - (float(np.mean(ws)) if ws else 0.0))
    return out


def _staircase(session: Session, rate_hz: float) -> tuple[dict[str, float], set[str]]:
    ys = [np.asarray(r.data.y, dtype=np.float64) for r in session.runs]
    ys = [y[np.isfinite(y)] for y in ys]
    ys = [y for y in ys if y.size > 1]
    if not ys:
        return {}, set()
    same = np.concatenate([y[1:] == y[:-1] for y in ys])
    if not same.mean() >= STAIR_REPEATS:
        return {}, set()
    hints: dict[str, float] = {}
    levels = np.unique(np.concatenate(ys))
    d = np.diff(levels)
    d = d[d > 1e-12 * max(1.0, float(np.max(np.abs(levels))))]
    lattice = False
    if d.size:
        q = float(d.min())
        k = d / q
        lattice = bool(np.mean(np.abs(k - np.round(k)) <= 0.05) >= STAIR_LATTICE)
        hints["quantization"] = q
    runs = np.concatenate([_equal_runs(y) for y in ys])
    held = bool(np.mean(runs >= 2) >= STAIR_HELD_SHARE)
    run_len = 1.0 / max(1.0 - same.mean(), 1e-9)
    if run_len >= 1.5:
        hints["sample_hold"] = rate_hz / run_len
    out: set[str] = set()
    if lattice and not held:
        out.add("sample_hold")
    if held and not lattice:
        out.add("quantization")
    return hints, out


def candidate_grid(name: str, sc: dict[str, float], noise_std: float, rate_hz: float, n: int = 8,
                   hint: float | None = None) -> np.ndarray:
    """Coarse grid of effect ``name``'s parameter for a session with scales ``sc`` (vocabulary units).

    ``hint`` (``data_hints``), when given, is added with its neighbours 15% either side.
    """
    grid = np.asarray(vocabulary.term(name).grid(sc, noise_std, rate_hz, n), dtype=np.float64)
    if hint is None or not math.isfinite(hint) or hint <= 0:
        return grid
    return np.unique(np.concatenate([grid, hint * np.array([0.85, 1.0, 1.15])]))


def base_effects(session: Session) -> dict[str, float]:
    """The session's ``[[effects]]`` as flown on every episode: name -> its first parameter.

    Raises
    ------
    SessionError
        When an effect is listed twice (the workflow needs one of each).
    """
    base: dict[str, float] = {}
    for e in session.effects:
        if e.name == "none":
            continue
        if e.name in base:
            raise SessionError(f"session.toml: effect {e.name!r} listed twice (the gap workflow needs one of each)")
        base[e.name] = float(e.params[EFFECT_PARAMS[e.name][0]])
    return base


class GapEvaluator:
    """Simulates a session's runs on candidate models and scores them against its measured features (the gap)."""

    def __init__(self, session: Session, model: ModelSpec, base: dict[str, float], seed: int, nthread: int,
                 dt: float, anchor_hz: float | None = None, anchor_h: float = 0.0):
        self.session, self.model, self.base, self.seed, self.nthread = session, model, base, seed, nthread
        self.dt, self.anchor_hz, self.anchor_h = dt, anchor_hz, anchor_h
        self.R = len(session.runs)
        self.meas = [run_features(r.spec, r.data.t, r.data.y, r.data.u) for r in session.runs]
        self.scales: list[dict[str, float]] | None = None
        self.offsets: list[dict[str, float]] | None = None
        self.calls = 0

    def sims(self, cands: list[tuple[str, float]], seeds: int = 1) -> list[list[SimRun]]:
        """Per (candidate, seed), the simulated runs."""
        plans = []
        for name, v in cands:
            shift, cut = self.anchored(name, float(v))
            plans += [Episode(i, name, float(v), s, shift, cut) for s in range(seeds) for i in range(self.R)]
        return self.fly(plans)

    def fly(self, plans: list[Episode]) -> list[list[SimRun]]:
        """Fly ``plans`` (every run of the session in order, for each point) in one batch: the runs of each point.

        Each call draws its noise from the next seed of the evaluator's sequence.
        """
        self.calls += 1
        out = simulate(self.session, self.model, plans, seed=self.seed * 1000 + self.calls,
                       nthread=self.nthread, base_effects=self.base, dt=self.dt)  # fmt: skip
        return [out[k * self.R:(k + 1) * self.R] for k in range(len(plans) // self.R)]

    def anchored(self, name: str, value: float) -> tuple[float, ModelSpec | None]:
        """What candidate ``name`` = ``value`` takes out of the model where it adds phase at the anchor:
        the part of ``tau`` (s) and, beyond what ``tau`` holds, the model with ``T_prop`` cut, ``K`` scaled to
        keep the model's gain there (None when ``tau`` holds it all, without an anchor, or on an outer loop).

        A network's class can carry the cycle's lag in ``T_prop`` with ``tau`` near 0 (a low-pass's
        phase read as a slower propulsion): without the cut such a candidate adds its phase twice and
        cannot fly the cycle it explains. ``T_prop`` keeps at least :data:`T_PROP_KEEP` of itself.
        """
        if not self.anchor_hz:
            return 0.0, None
        w = 2 * math.pi * self.anchor_hz
        phase = candidate_phase(name, value, self.anchor_hz, self.anchor_h, self.session.control_rate_hz)
        shift, cut = take_out_phase(self.model, phase, w, t_prop_min=T_PROP_KEEP * self.model.T_prop)
        # only the inner loops' T_prop is a first-order factor whose phase take_out_phase moves
        return shift, cut if self.session.loop in INNER_LOOPS else None

    def tau_shift(self, name: str, value: float) -> float:
        """What candidate ``name`` = ``value`` takes off the model's ``tau`` (0 without an anchor), s."""
        return self.anchored(name, value)[0]

    def trimmed(self, name: str, value: float) -> ModelSpec | None:
        """The model with ``T_prop`` cut beyond what ``tau`` holds (:meth:`anchored`), or None."""
        return self.anchored(name, value)[1]

    def calibrate(self, feats_by_seed: list[list[dict | None]], *, smoother: bool = True) -> None:
        """Set the noise scales (and, with ``smoother``, the sensor's smoothing offsets) from the
        model's own flights over several noise seeds (:func:`noise_scales`, :func:`noise_offsets`)."""
        self.scales = noise_scales(feats_by_seed)
        if smoother:
            self.offsets = noise_offsets(self.meas, feats_by_seed, self.scales)

    def features(self, sims: list[SimRun]) -> list[dict | None]:
        return [run_features(r.spec, s.t, s.y, s.u) for r, s in zip(self.session.runs, sims, strict=True)]

    def gap(self, feats: list[dict | None]) -> float:
        return gap_value(compare(self.meas, feats, self.scales, self.offsets))

    def seed_gap(self, sims_by_seed: list[list[SimRun]]) -> float:
        """Mean gap over noise seeds of one model, noise scales widened by that model's own seed spread."""
        fv = [self.features(s) for s in sims_by_seed]
        own = noise_scales(fv)
        sc = [{k: math.hypot(a.get(k, 0.0), b.get(k, 0.0)) for k in set(a) | set(b)}
              for a, b in zip(self.scales, own, strict=True)]  # fmt: skip
        return float(np.mean([gap_value(compare(self.meas, f, sc, self.offsets)) for f in fv]))


def _polish(ev: GapEvaluator, effect: str, value: float, rate_hz: float) -> tuple[float, float, list[SimRun]]:
    """The winner's value re-fitted on :data:`POLISH` x ``value`` with every point averaged over
    seeds (the grids above score one noise draw each), then re-simulated with fresh seeds.

    Returns the value, its fresh-seed gap and those runs (seed 0)."""
    vals = value * np.asarray(POLISH)
    cap = vocabulary.term(effect).cap
    if cap is not None:  # e.g. a frame rate above the control rate is no hold at all
        vals = np.minimum(vals, cap(rate_hz))
    vals = np.unique(vals)
    sims = ev.sims([(effect, float(v)) for v in vals], seeds=SEEDS)
    gaps = [ev.seed_gap(sims[k * SEEDS:(k + 1) * SEEDS]) for k in range(vals.size)]
    best = float(vals[int(np.argmin(gaps))])
    fresh = ev.sims([(effect, best)], seeds=SEEDS)
    return best, ev.seed_gap(fresh), fresh[0]


def _refine(values: np.ndarray, gaps: np.ndarray) -> float:
    """Best value, by a parabola through the best grid point and its neighbours (log of |value|)."""
    # duplicate grid values (fine grids include coarse points): keep the best score of each
    uniq = np.unique(values)
    gaps = np.array([gaps[values == v].min() for v in uniq])
    values = uniq
    k = int(np.argmin(gaps))
    if k == 0 or k == values.size - 1 or np.sign(values[k - 1]) != np.sign(values[k + 1]):
        return float(values[k])
    s = math.copysign(1.0, values[k])
    x = np.log(np.abs(values[k - 1:k + 2]))
    y = gaps[k - 1:k + 2]
    with np.errstate(all="ignore"):
        return _vertex(x, y, s, float(values[k]))


def _vertex(x: np.ndarray, y: np.ndarray, s: float, fallback: float) -> float:
    den = (x[0] - x[1]) * (x[0] - x[2]) * (x[1] - x[2])
    a = (x[2] * (y[1] - y[0]) + x[1] * (y[0] - y[2]) + x[0] * (y[2] - y[1])) / den
    b = (x[2] ** 2 * (y[0] - y[1]) + x[1] ** 2 * (y[2] - y[0]) + x[0] ** 2 * (y[1] - y[2])) / den
    if not (np.isfinite(a) and np.isfinite(b)) or a <= 0:
        return fallback
    xv = float(np.clip(-b / (2 * a), min(x[0], x[2]), max(x[0], x[2])))
    return s * math.exp(xv)


def _effect_params(name: str, value: float) -> dict[str, float]:
    return {EFFECT_PARAMS[name][0]: float(value)} if name != "none" else {}


def run_gap(
    session: Session,
    model: ModelSpec | None = None,
    seed: int = 0,
    nthread: int = 0,
    top: int = 3,
    coarse: int = 6,
    fine: int = 7,
    dt: float = 0.001,
    candidates: tuple[str, ...] = CANDIDATES,
    smoother_sensor: bool = True,
    name_ratio: float = NAME_RATIO,
    phase_anchor_hz: float | None = None,
    phase_anchor_h: float = 0.0,
    credit: dict[str, float] | None = None,
    read_staircase: bool = False,
    log=None,
) -> GapResult:
    """Run the whole gap workflow on a session.

    Parameters
    ----------
    session : Session
        Measured runs (np-mrft, mrft, step) of the altitude, roll or pitch loop.
    model : ModelSpec, optional
        Model to test instead of the session's ``[model]``.
    seed : int
        Seed of every simulated noise draw (recorded in the result).
    nthread : int
        MuJoCo threads (0: all CPUs).
    top : int
        Candidates that get the fine grid.
    coarse, fine : int
        Points of the coarse grid per candidate and of the fine grid.
    dt : float
        Physics step of the MuJoCo simulations, s (1 ms: the loops' dynamics
        are much slower; half the cost of the 0.5 ms default).
    candidates : tuple of str
        Vocabulary effects to try (default: all).
    smoother_sensor : bool
        Take a measured noise smoother than the model's white noise as the
        sensor's filtering, not as evidence
        (:func:`uavsim.gap.features.noise_offsets`).
    name_ratio : float
        The best candidate is named only when its gap is at most this share of
        the gap before (default :data:`NAME_RATIO`).
    phase_anchor_hz : float, optional
        Frequency at which the model's ``tau`` was fitted to a measured cycle
        (an identified model: the relay run's): candidates whose vocabulary term has a ``phase``
        (``lag``, ``lowpass``, ``rate_limit``, ``sample_hold``) take their phase there out of ``tau`` (down to 0),
        so that the model keeps the measured phase and only the candidate's shape is
        tested; a winner's result carries the model with the shorter ``tau``.
    phase_anchor_h : float
        That relay run's amplitude ``h`` (command units): a rate limit's phase grows with it.
    credit : dict of str to float, optional
        Per candidate, the squared gap it removes from a clean session of the loop
        (the base model's own misfit, which every session has): candidates are
        ranked, verified and named by :func:`credited_gap`, not by the raw gap
        they leave (``ranking`` keeps both; ``gap_after`` is the raw gap).
    read_staircase : bool
        Leave out the staircase cause the measured samples exclude (:func:`ruled_out`).
        Off for a session's own model: the hidden-effect suite's fits are measured
        without it (one of its sample-and-hold fits moved past its 1/3 gap ratio with it).
    log : callable(str), optional
        Progress messages.

    Returns
    -------
    GapResult
    """
    t_start = time.perf_counter()
    candidates = tuple(candidates)
    bad = [c for c in candidates if c not in CANDIDATES]
    if bad or not candidates:
        raise UserError(f"unknown candidate effect {bad[0] if bad else '(none given)'!r}")
    top = min(top, len(candidates))
    log = log or (lambda msg: None)
    model = model or session.model
    if model is None:
        raise UserError("the session has no [model] and no --model FILE was given: nothing to compare with")
    model_params(session, model)  # loop support and parameter checks
    ev = GapEvaluator(session, model, base_effects(session), seed, nthread, dt, phase_anchor_hz, phase_anchor_h)
    for i, (r, f) in enumerate(zip(session.runs, ev.meas, strict=True)):
        if f is None:
            what = "fewer than 3 full relay cycles after the first two" if r.spec.kind != STEP_RUN else "no usable step"
            raise UserError(f"run {i} ({r.spec.file}): the measured data holds {what}; the gap cannot be measured")
    rate = float(session.control_rate_hz)
    hints, shown_not = _staircase(session, rate)
    excluded = sorted(shown_not & set(candidates)) if read_staircase else []
    if excluded and len(excluded) < len(candidates):
        candidates = tuple(c for c in candidates if c not in excluded)
        top = min(top, len(candidates))
        log(f"not searched, the measured samples exclude them: {', '.join(excluded)}")
    else:
        excluded = []

    # 1. gap before, with several noise seeds (their spread is what noise explains)
    before = ev.sims([("none", 0.0)], seeds=SEEDS)
    fb = [ev.features(s) for s in before]
    for i, (r, f) in enumerate(zip(session.runs, fb[0], strict=True)):
        if f is None and r.spec.kind != STEP_RUN:
            raise UnflownRun(
                i, f"run {i} ({r.spec.file}): the model does not even reproduce the oscillation "
                f"(measured period {math.exp(ev.meas[i]['period']):.3g} s; the simulated run "
                "does not oscillate or diverges): check K, T_prop, T1, tau before looking for effects"
            )
        if f is None:
            raise UnflownRun(i, f"run {i} ({r.spec.file}): the model's step response diverges; check the model")
    ev.calibrate(fb, smoother=smoother_sensor)
    gaps_before = [ev.gap(f) for f in fb]
    gap_before = float(np.mean(gaps_before))
    z = compare(ev.meas, fb[0], ev.scales, ev.offsets)
    disagreements = []
    for (i, feat), zv in sorted(z.items(), key=lambda kv: -abs(kv[1]))[:8]:
        if abs(zv) < 2.0:
            break
        run = session.runs[i]
        f = ev.meas[i]
        width = math.exp(f["period"]) if "period" in f else 1.0
        w = worst_window(run.data.t, run.data.y, before[0][i].y, width)
        disagreements.append(Disagreement(f"{i}:{run.spec.file}", feat, float(zv), w))
    log(f"gap before {gap_before:.3f} ({time.perf_counter() - t_start:.1f} s)")

    # 2. coarse grids of every candidate in one batch
    sc = _session_scales(session, ev.meas)
    grids = {c: candidate_grid(c, sc, float(model.noise_std), rate, coarse, hints.get(c)) for c in candidates}
    cands = [(c, float(v)) for c in candidates for v in grids[c]]
    sims = ev.sims(cands)
    scores = np.array([ev.gap(ev.features(s)) for s in sims])
    per: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    k = 0
    for c in candidates:
        m = grids[c].size
        per[c] = (grids[c], scores[k:k + m])
        k += m
    log(f"coarse grids done ({time.perf_counter() - t_start:.1f} s)")

    # 3. fine grids around the best of the top candidates, then a zoom on the best two
    allv = {c: list(zip(per[c][0].tolist(), per[c][1].tolist(), strict=True)) for c in candidates}
    for stage, (ntop, npts) in enumerate(((top, fine), (2, 5))):
        order = sorted(candidates, key=lambda c: credited_gap(c, min(g for _, g in allv[c]), credit))
        fine_c: list[tuple[str, float]] = []
        for c in order[:ntop]:
            pts = sorted(allv[c])
            vals = np.array([v for v, _ in pts])
            j = int(np.argmin([g for _, g in pts]))
            lo, hi = vals[max(j - 1, 0)], vals[min(j + 1, vals.size - 1)]
            if np.sign(lo) != np.sign(vals[j]) or lo == 0:
                lo = vals[j] * 0.6
            if np.sign(hi) != np.sign(vals[j]) or hi == 0:
                hi = vals[j] / 0.6
            fine_c += [(c, float(v)) for v in np.sign(vals[j]) * np.geomspace(abs(lo), abs(hi), npts)]
        sims = ev.sims(fine_c)
        for (c, v), s in zip(fine_c, sims, strict=True):
            allv[c].append((v, ev.gap(ev.features(s))))
        log(f"fine grid {stage + 1} done ({time.perf_counter() - t_start:.1f} s)")
    best: dict[str, tuple[float, float]] = {}
    for c in candidates:
        pts = sorted(allv[c])
        vals = np.array([v for v, _ in pts])
        gs = np.array([g for _, g in pts])
        best[c] = (_refine(vals, gs), float(gs.min()))

    # 4. verify the refined value of the top candidates with fresh seeds, decide
    top_c = sorted(candidates, key=lambda c: credited_gap(c, best[c][1], credit))[:VERIFY]
    ver = ev.sims([(c, best[c][0]) for c in top_c], seeds=SEEDS) if top_c else []
    verified = {c: ev.seed_gap(ver[j * SEEDS:(j + 1) * SEEDS]) for j, c in enumerate(top_c)}
    while True:
        ranking = [{"effect": "none", "params": {}, "gap": gap_before, "credited": gap_before, "score": gap_before}]
        for c in candidates:
            g = verified.get(c, best[c][1])
            cg = credited_gap(c, g, credit)
            ranking.append({"effect": c, "params": _effect_params(c, best[c][0]), "gap": g, "credited": cg,
                            "score": cg + PENALTY})
        ranking.sort(key=lambda r: r["score"])
        winner = ranking[0]
        # name an effect only when it explains most of the gap: a gap within noise,
        # or one that no single effect closes, is answered ``none``
        named = not (gap_before <= NONE_GAP or winner["credited"] > name_ratio * gap_before)
        if winner["effect"] == "none" or winner["effect"] in verified or not named:
            break
        # fresh seeds raised the verified candidates above one scored on its grid's seed alone: it is
        # verified too before it can be named
        c = winner["effect"]
        ver += ev.sims([(c, best[c][0])], seeds=SEEDS)
        top_c.append(c)
        verified[c] = ev.seed_gap(ver[-SEEDS:])
    if not named:
        winner = ranking[[r["effect"] for r in ranking].index("none")]
    effect = winner["effect"]
    if effect == "none":
        gap_after, sims_after = gap_before, before[0]
        effects = list(session.effects)
    else:
        j = top_c.index(effect)
        gap_after, sims_after = verified[effect], ver[j * SEEDS]
        value, gap_p, sims_p = _polish(ev, effect, best[effect][0], rate)
        if gap_p < gap_after:
            gap_after, sims_after = gap_p, sims_p
            cg = credited_gap(effect, gap_p, credit)
            winner = {**winner, "params": _effect_params(effect, value), "gap": gap_p, "credited": cg,
                      "score": cg + PENALTY}
            ranking = sorted([winner] + [r for r in ranking if r["effect"] != effect], key=lambda r: r["score"])
        log(f"winner polished ({time.perf_counter() - t_start:.1f} s)")
        effects = [e for e in session.effects if e.name != effect]
        effects.append(EffectSpec(effect, dict(winner["params"])))
        shift, cut = ev.anchored(effect, float(next(iter(winner["params"].values()))))
        if shift:
            log(f"{effect} takes {shift * 1e3:.1f} ms of phase out of tau ({model.tau * 1e3:.1f} ms)")
            model = dataclasses.replace(model, tau=max(float(model.tau) - shift, 0.0))
        if cut is not None:
            log(f"{effect} takes the rest of its phase out of T_prop ({model.T_prop * 1e3:.1f} -> "
                f"{cut.T_prop * 1e3:.1f} ms, K {model.K:.4g} -> {cut.K:.4g})")
            model = dataclasses.replace(model, K=cut.K, T_prop=cut.T_prop)
    return GapResult(
        effect=effect,
        params=dict(winner["params"]),
        gap_before=gap_before,
        gap_after=gap_after,
        ranking=ranking,
        disagreements=disagreements,
        model=model,
        effects=effects,
        seed=seed,
        seconds=time.perf_counter() - t_start,
        sims_before=before[0],
        sims_after=sims_after,
        ruled_out=list(excluded),
    )


def updated_session(session: Session, result: GapResult) -> Session:
    """The session with the tested model and the winner added to its ``[[effects]]``."""
    return dataclasses.replace(session, model=result.model, effects=list(result.effects))


def format_table(result: GapResult) -> str:
    """Readable summary: the answer, the ranking, and where the model disagrees."""
    lines = [
        f"effect: {result.effect}  params: "
        + (", ".join(f"{k}={v:.4g}" for k, v in result.params.items()) or "-"),
        f"gap before: {result.gap_before:.3f}   gap after: {result.gap_after:.3f}"
        f"   ({result.seconds:.1f} s, seed {result.seed})",
        "",
        f"{'rank':<5}{'effect':<14}{'params':<26}{'gap':>9}{'score':>9}",
    ]
    for i, r in enumerate(result.ranking, 1):
        p = ", ".join(f"{k}={v:.4g}" for k, v in r["params"].items()) or "-"
        lines.append(f"{i:<5}{r['effect']:<14}{p:<26}{r['gap']:>9.3f}{r['score']:>9.3f}")
    if result.disagreements:
        lines += ["", "where the model disagrees (before):", f"{'run':<24}{'feature':<12}{'z':>8}   window (s)"]
        for d in result.disagreements:
            lines.append(f"{d.run:<24}{d.feature:<12}{d.z:>8.1f}   {d.window_s[0]:.2f}-{d.window_s[1]:.2f}")
    return "\n".join(lines)
