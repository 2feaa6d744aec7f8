"""Features of a run that separate the effects a model may lack, and the gap between two runs.

Relay runs (np-mrft, mrft), over the full cycles after the first two (rising
edges of the relay output ``u``, which is noise-free):

* ``period`` (log), ``amplitude`` (log), ``offset`` (mean of y / amplitude),
  ``duty`` (fraction of the cycle with the relay high: asymmetry),
* ``phase1`` (phase of y's fundamental against the relay's rising edge, rad),
  ``h2``, ``h3`` (2nd and 3rd harmonic over the fundamental),
* ``r3mag`` (log), ``r3arg`` (rad): the process's own 3rd-harmonic response
  relative to its fundamental, ``R3 = (Y3 / U3) / (Y1 / U1) = G(3 j w) / G(j w)``,
  from the harmonics of y and u on the samples of every cycle (independent of
  the relay's duty and of where the cycle sits in time; NaN when the relay's
  3rd harmonic is too weak to divide by, duty near 1/3 or 2/3),
* ``shape`` (RMS difference of the mean cycle waveform, normalized by amplitude:
  a distance, only defined between two runs),
* residual spectrum: ``resid`` (log of a robust std of the second difference
  of y minus its mean cycle, over the amplitude), ``ac1`` (lag-1
  autocorrelation of that second difference: low-pass and hold colour it), ``repeat`` (fraction of samples equal to the previous one:
  staircase levels of quantization and sample-and-hold).

Step runs, after ``step_time`` and normalized by the step size:
``overshoot``, ``onset`` (log time to 5% of the step), ``rise`` (log 10-90%
rise time), ``ise`` (log), ``settled`` (mean error over the last 30%),
``trace`` (RMS difference of the smoothed responses: a distance), and the
same residual features on the last 40%.

Delay against lag: both add phase at the cycle's frequency, so both can match
the period. At the cycle's frequency a pure delay ``tau`` turns ``R3`` by
``-2 w tau`` and keeps its magnitude; a lag ``T`` also shrinks it, by
``sqrt((1 + w^2 T^2) / (1 + 9 w^2 T^2))``. ``R3`` is a property of the
process, of magnitude ``|G(3 j w) / G(j w)|`` (about 0.03-0.3 for these
loops) whatever the relay did, so its log-magnitude and angle stay well
conditioned where the phase of y's small 3rd harmonic would not (a relay bias
shrinks that harmonic, not R3). On the step, a delay is dead time before the
response starts (``onset``), a lag a rounded start.

Dependence on amplitude and on frequency comes from comparing runs with
different ``h`` and ``beta``: each run's features are compared separately, so
an effect that acts at one h (saturation, dead zone) or one frequency shows in
that run only. :func:`compare` turns two sets of features into z-scores, one
per (run, feature), each divided by a scale that is what noise explains (a
floor, plus the spread across simulated noise seeds); the gap is the RMS of
the z-scores.

    fm = run_features(spec, t, y, u, rate_hz)      # measured
    fs = run_features(spec, t, ys, us, rate_hz)    # simulated
    z = compare([fm], [fs], scales)                # {(run, feature): z}
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from uavsim.formats.session import STEP_RUN, RunSpec
from uavsim.noise.analysis import cycle_harmonics, relay_phase
from uavsim.noise.estimate import robust_std

__all__ = ["FLOORS", "DISTANCES", "SMOOTHER", "run_features", "compare", "gap_value", "noise_offsets", "worst_window",
           "tail_swing", "step_swings"]

# Smallest scale of each feature (what a perfect model still misses: sampling
# of the switching at the control rate, finite record), in feature units.
FLOORS: dict[str, float] = {
    "period": 0.01, "amplitude": 0.02, "offset": 0.02, "duty": 0.01, "phase1": 0.03,
    "h2": 0.01, "h3": 0.01, "r3mag": 0.02, "r3arg": 0.02, "shape": 0.03, "resid": 0.08, "ac1": 0.05, "repeat": 0.02,
    "overshoot": 0.02, "onset": 0.02, "rise": 0.04, "ise": 0.05, "settled": 0.01, "trace": 0.03,
}  # fmt: skip
# Features that are distances between two runs (need both waveforms), not values.
DISTANCES = ("shape", "trace")
# Noise-level features whose deficit (measured smoother than the model's white noise of the same
# std) is the sensor's filtering (a DLPF, a Kalman filter), not an effect: see :func:`noise_offsets`.
SMOOTHER = ("resid",)
# Share of samples equal to the one before above which a measurement is a staircase (quantized or
# held): its second difference is small because it is mostly zero, not because a filter smoothed it.
STAIRCASE = 0.2
# Features that are angles, rad: differences are wrapped to [-pi, pi).
ANGLES = ("phase1", "r3arg")
# Below this |U3 / U1| the relay has too little 3rd harmonic for ``R3``
# (a square wave of duty 1/2 has 1/3).
_U3_MIN = 0.12
_NPHASE = 64


def _resid_features(x: np.ndarray, resid: np.ndarray, scale: float) -> dict[str, float]:
    """Residual-spectrum features of a stretch ``x`` (output units) and its residual ``resid``.

    The level is a robust std of the residual's second difference (MAD, so that
    the few samples around relay switches and hops between neighbouring
    quantized orbits do not count), divided by sqrt(6) as for white noise;
    ``ac1`` is the lag-1 autocorrelation of that second difference (-2/3 for
    white noise, other values for coloured or held noise).
    """
    d2 = np.diff(resid, 2)
    if d2.size < 4:
        return {"resid": 0.0, "ac1": 0.0, "repeat": 0.0}
    med = np.median(d2)
    mad = robust_std(d2, med)
    sd = mad / math.sqrt(6.0)
    # rounding of the mean cycle's interpolation leaves ~1e-17 where a staircase is flat
    moving = np.abs(d2) > 1e-9 * scale
    if 0 < moving.sum() < d2.size:
        # a staircase (quantized or held samples) has flat stretches, which noise never gives: once they
        # are half the samples the MAD drops to zero, a jump of ~15 in log that a few more repeated
        # samples make. The level of the moving samples, weighted by their share, is the same level
        # without zeros and falls smoothly as the stairs lengthen
        dm = d2[moving]
        share = float(moving.mean())
        sd = robust_std(dm) * math.sqrt(share) / math.sqrt(6.0)
    spread = sd * math.sqrt(6.0)  # the MAD, or the staircase's level of its moving samples
    c = np.clip(d2 - med, -5 * spread - 1e-300, 5 * spread + 1e-300)
    c = c - c.mean()
    ac1 = float(np.dot(c[1:], c[:-1]) / max(np.dot(c, c), 1e-300))
    rep = float(np.mean(x[1:] == x[:-1])) if x.size > 1 else 0.0
    return {"resid": math.log(max(sd / scale, 1e-9)), "ac1": ac1, "repeat": rep}


def cycle_edges(hi: np.ndarray) -> np.ndarray:
    """Sample indices of the relay's rising edges after the first two (the full cycles analysed), from
    ``hi``, where the relay output is high (``relay_phase(u)``)."""
    return (np.flatnonzero(hi[1:] & ~hi[:-1]) + 1)[2:]


def relay_features(t: np.ndarray, y: np.ndarray, u: np.ndarray) -> dict | None:
    """Features of a relay run; None when it holds fewer than 3 full cycles after the first two."""
    hi = relay_phase(u)
    edges = cycle_edges(hi)
    if edges.size < 4 or not np.isfinite(y).all():
        return None
    a, b = edges[0], edges[-1]
    nc = edges.size - 1
    period = float((t[b] - t[a]) / nc)
    amps = [0.5 * (y[i:j].max() - y[i:j].min()) for i, j in zip(edges[:-1], edges[1:], strict=True)]
    amp = float(np.mean(amps))
    if not amp > 0:
        return None
    mean = float(y[a:b].mean())
    duty = float(hi[a:b].mean())
    # mean cycle waveform on a phase grid (cycles of unequal length resampled)
    ph = np.linspace(0.0, 1.0, _NPHASE, endpoint=False)
    waves = []
    phase_all = np.empty(b - a)
    for i, j in zip(edges[:-1], edges[1:], strict=True):
        tp = (np.arange(i, j) - i) / (j - i)
        phase_all[i - a:j - a] = tp
        waves.append(np.interp(ph, tp, y[i:j], period=1.0))
    w = np.mean(waves, axis=0)
    wn = (w - mean) / amp
    c = np.fft.rfft(wn) / _NPHASE
    hy, hu = cycle_harmonics(y, edges, (1, 3)), cycle_harmonics(hi, edges, (1, 3))
    if abs(hu[1]) >= _U3_MIN * abs(hu[0]) > 0:
        r3 = (hy[1] / hu[1]) / (hy[0] / hu[0])
    else:
        r3 = complex(math.nan, math.nan)
    c1 = abs(c[1]) + 1e-12
    resid = y[a:b] - np.interp(phase_all, ph, w, period=1.0)
    f = {
        "period": math.log(period), "amplitude": math.log(amp), "offset": mean / amp, "duty": duty,
        "phase1": float(np.angle(c[1])), "h2": float(abs(c[2]) / c1), "h3": float(abs(c[3]) / c1),
        "r3mag": math.log(abs(r3)) if abs(r3) > 0 else math.nan, "r3arg": float(np.angle(r3)),
    }  # fmt: skip
    f.update(_resid_features(y[a:b], resid, amp))
    f["_wave"] = wn
    f["_cycles"] = nc
    return f


def _wrap(a: float | np.ndarray) -> float | np.ndarray:
    """Angle(s) wrapped to [-pi, pi), rad."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def _smooth(x: np.ndarray, n: int = 5) -> np.ndarray:
    k = np.ones(n) / n
    return np.convolve(np.pad(x, (n // 2, n - 1 - n // 2), mode="edge"), k, mode="valid")


def step_features(spec: RunSpec, t: np.ndarray, y: np.ndarray) -> dict | None:
    """Features of a step run; None when the record is not finite or ends before the step."""
    S = float(spec.step)
    k0 = int(np.searchsorted(t, float(spec.step_time) - 1e-9))
    if not np.isfinite(y).all() or k0 >= t.size - 10 or S == 0:
        return None
    ys = _smooth(y[k0:]) / S
    tt = t[k0:] - t[k0]
    e = 1.0 - ys

    def cross(level: float) -> float:
        i = np.flatnonzero(ys >= level)
        return float(tt[i[0]]) if i.size else float(tt[-1] * 2)

    rise = max(cross(0.9) - cross(0.1), 1.0 / max(len(tt), 1))
    # dead time: until the response has moved 5% of the step from where it stood at the step
    moved = np.flatnonzero(ys - ys[0] >= 0.05)
    onset = float(tt[moved[0]]) if moved.size else float(tt[-1] * 2)
    dt = float(t[1] - t[0])
    n = ys.size
    tail = slice(int(0.6 * n), n)
    f = {
        "overshoot": float(ys.max() - 1.0), "onset": math.log(max(onset, 1.0 / max(len(tt), 1))),
        "rise": math.log(rise), "ise": math.log(max(float(np.sum(e * e) * dt), 1e-12)),
        "settled": float(e[int(0.7 * n):].mean()),
    }  # fmt: skip
    yt = y[k0:][tail]
    f.update(_resid_features(yt, yt, abs(S)))
    f["_trace"] = ys
    return f


def tail_swing(trace: np.ndarray) -> float:
    """Swing of a step response's second half about its slow drift, in steps.

    ``trace`` is a step run's smoothed response over the step (the features' ``_trace``).
    Its second half less a quadratic fit (the drift of a slow settle or of a disturbance),
    as a sinusoid's peak-to-peak: ``2 sqrt(2)`` times the std of what is left. A stable
    linear loop settles and leaves its noise; a loop with play in it hunts, a limit cycle
    that keeps swinging.
    """
    x = np.asarray(trace, dtype=np.float64)
    x = x[x.size // 2:]
    if x.size < 4:
        return 0.0
    k = np.arange(x.size, dtype=np.float64)
    rest = x - np.polyval(np.polyfit(k, x, 2), k)
    return float(2.0 * math.sqrt(2.0) * np.std(rest))


def step_swings(specs: Sequence[RunSpec], feats: Sequence[dict | None]) -> dict[int, float]:
    """Per step run with features (index into ``specs``), its :func:`tail_swing`, in steps."""
    return {k: tail_swing(f["_trace"]) for k, (spec, f) in enumerate(zip(specs, feats, strict=True))
            if spec.kind == STEP_RUN and f is not None}  # fmt: skip


def run_features(spec: RunSpec, t: np.ndarray, y: np.ndarray, u: np.ndarray) -> dict | None:
    """Features of one run (see the module docstring); None when it cannot be analysed."""
    t, y, u = (np.asarray(v, dtype=np.float64) for v in (t, y, u))
    if spec.kind == STEP_RUN:
        return step_features(spec, t, y)
    return relay_features(t, y, u)


def _dist(fm: dict, fs: dict, name: str) -> float:
    if name == "shape":
        d = fm["_wave"] - fs["_wave"]
    else:
        a, b = fm["_trace"], fs["_trace"]
        m = min(a.size, b.size)
        d = a[:m] - b[:m]
    return float(np.sqrt(np.mean(d * d)))


def _names(f: dict) -> list[str]:
    names = [k for k in f if not k.startswith("_")]
    names += ["shape"] if "_wave" in f else ["trace"]
    return names


def compare(meas: Sequence[dict | None], sim: Sequence[dict | None],
            scales: Sequence[dict[str, float]] | None = None,
            offsets: Sequence[dict[str, float]] | None = None) -> dict[tuple[int, str], float]:
    """z-score of every (run, feature) between measured and simulated features.

    Parameters
    ----------
    meas, sim : sequences of feature dicts (or None), one per run
    scales : per run, feature -> extra scale from noise (added in quadrature to :data:`FLOORS`)
    offsets : per run, feature -> measured-minus-simulated difference that is not the model's
        (:func:`noise_offsets`), taken off before scaling

    Returns
    -------
    dict (run, feature) -> z
        Signed for value features, >= 0 for distances. A run that the
        simulation cannot analyse (no oscillation, diverged) while the
        measurement can scores 30 on its ``period``.
    """
    z: dict[tuple[int, str], float] = {}
    for i, (fm, fs) in enumerate(zip(meas, sim, strict=True)):
        if fm is None:
            continue
        if fs is None:
            z[(i, "period")] = 30.0
            continue
        sc = scales[i] if scales is not None and scales[i] is not None else {}
        off = offsets[i] if offsets is not None and offsets[i] is not None else {}
        for name in _names(fm):
            s = math.hypot(FLOORS[name], sc.get(name, 0.0))
            if name in DISTANCES:
                z[(i, name)] = _dist(fm, fs, name) / s
            else:
                d = fm[name] - fs[name]
                if math.isnan(d):  # R3 undefined on one side: the duty feature carries that difference
                    continue
                if name in ANGLES:
                    d = _wrap(d)
                z[(i, name)] = (d - off.get(name, 0.0)) / s
    return z


def noise_scales(sims_by_seed: Sequence[Sequence[dict | None]]) -> list[dict[str, float]]:
    """Per run, the spread of each feature across simulated noise seeds (distances: mean pairwise).

    Parameters
    ----------
    sims_by_seed : sequence over seeds of sequences over runs of feature dicts
    """
    nruns = len(sims_by_seed[0])
    out: list[dict[str, float]] = []
    for i in range(nruns):
        fs = [s[i] for s in sims_by_seed if s[i] is not None]
        sc: dict[str, float] = {}
        if len(fs) >= 2:
            for name in _names(fs[0]):
                if name in DISTANCES:
                    ds = [_dist(a, b, name) for j, a in enumerate(fs) for b in fs[j + 1:]]
                    sc[name] = float(np.mean(ds))
                    continue
                v = [f[name] for f in fs if not math.isnan(f[name])]
                if len(v) < 2:
                    continue
                if name in ANGLES:  # spread around the first angle, across the wrap
                    v = [_wrap(x - v[0]) for x in v]
                sc[name] = float(np.std(v, ddof=1))
        out.append(sc)
    return out


def noise_offsets(meas: Sequence[dict | None], sims_by_seed: Sequence[Sequence[dict | None]],
                  scales: Sequence[dict[str, float]]) -> list[dict[str, float]]:
    """Per run, the part of the :data:`SMOOTHER` features' difference that is the sensor's colour.

    The workflow simulates white measurement noise of the measured std. A real
    sensor's noise is filtered (a DLPF, a camera + IMU Kalman filter): at the
    same std its second difference is much smaller, so the base model's noise
    looks too rough in every run, which no effect but a low-pass explains. A
    measured level *below* the base model's (by more than noise and the floor)
    is taken as the sensor's and taken off every model's comparison; a level
    above it (extra noise, quantization hops) stays evidence, and so does a
    staircase (:data:`STAIRCASE`: quantization or a hold flattens the second
    difference without filtering).

    Parameters
    ----------
    meas : per run, the measured features (or None)
    sims_by_seed : over seeds, per run, the base model's simulated features
    scales : per run, :func:`noise_scales` of those simulations

    Returns
    -------
    list of dict
        Per run, feature -> offset (feature units, <= 0), to pass to :func:`compare`.
    """
    out: list[dict[str, float]] = []
    for i, fm in enumerate(meas):
        off: dict[str, float] = {}
        fs = [s[i] for s in sims_by_seed if s[i] is not None]
        if fm is not None and fs:
            if fm.get("repeat", 0.0) >= STAIRCASE:  # a staircase (quantization, a hold) is not a filter
                out.append(off)
                continue
            for name in SMOOTHER:
                if name not in fm:
                    continue
                d = fm[name] - float(np.mean([f[name] for f in fs]))
                if d < -math.hypot(FLOORS[name], scales[i].get(name, 0.0)):
                    off[name] = d
        out.append(off)
    return out


def gap_value(z: dict[tuple[int, str], float]) -> float:
    """The gap: RMS of the z-scores (about 1 when only noise separates the runs)."""
    if not z:
        return float("inf")
    v = np.array(list(z.values()), dtype=np.float64)
    return float(np.sqrt(np.mean(v * v)))


def worst_window(t: np.ndarray, y_meas: np.ndarray, y_sim: np.ndarray, width_s: float) -> tuple[float, float]:
    """Time window (start, end), s, of width ``width_s`` where the measured and simulated runs differ most."""
    d = np.abs(np.asarray(y_meas) - np.asarray(y_sim))
    d = np.where(np.isfinite(d), d, np.nanmax(np.where(np.isfinite(d), d, 0.0)) + 1.0)
    rate = 1.0 / float(t[1] - t[0])
    n = max(1, min(int(round(width_s * rate)), d.size))
    c = np.convolve(d, np.ones(n), mode="valid")
    k = int(np.argmax(c))
    return float(t[k]), float(t[min(k + n - 1, t.size - 1)])
