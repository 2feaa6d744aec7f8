"""THE preprocessing of relay oscillations into fixed-length network inputs.

Used both to build training sets (``uavsim.data.generate``) and to identify a
flight session, so that the network sees the same thing in both places. From a
relay test's measured output ``y`` and relay command ``u`` (as the controller
saw and computed them, bias included):

1. Resample to ``INPUT_RATE_HZ`` when the control rate differs (``y`` linearly,
   ``u`` by zero-order hold, as a relay command is held).
2. Find the rising edges of the relay, ``(u - bias) / h`` going from -1 to +1.
   The segment used is the last ``cycles`` full cycles, between rising edges;
   at least one earlier cycle must exist (it is the transient and is dropped).
3. Normalize: ``y`` centred on its mid-range and divided by half its
   peak-to-peak (so it spans [-1, 1]); ``u`` as ``(u - bias) / h`` (so +-1).
4. Right-align both channels in a zero-padded ``(C, L)`` float32 array.

The period (mean over the cycles used) and the amplitude (half peak-to-peak of
``y``) are returned alongside, and the loop's **fundamental response**: the
ratio of the first harmonics of ``y`` and of the command, ``Y1 / (h U1)``, over
the last ``RESPONSE_CYCLES`` steady cycles (``response_cycles``). For a linear process
that ratio is its frequency response ``G(j w)`` at the cycle's frequency ``w`` whatever the
relay did (bias, ``tau_obs``, ``a_n``, sampling), and zero-mean noise averages
out of it; the input is shape only, and the gain comes back from the response
and the identified class's own ``|G(j w)|`` (``uavsim.ident``).

Departures from the authors' scheme (NOTES.md section 2), and why:

* Inputs are built at 200 Hz instead of 1 kHz. The controller only ever sees
  and commands control-rate samples, so the 1 kHz vector carries the same
  information, interpolated, in a vector five times longer (a 5x larger first
  layer and dataset). Sessions recorded at another rate are resampled.
* The length ``L`` has a 25% margin over the grid's longest period (rounded up
  to a multiple of 8 samples) instead of ``ceil`` to whole seconds: noise and
  the NP-MRFT correction lengthen cycles a little, and the margin is what keeps
  those cycles from being rejected without padding most inputs with zeros.
* Garbage is rejected (``NoOscillation``) instead of fed to the network: a
  relay command that is not +-h, a flat or non-finite output, a duty cycle
  outside [5%, 95%], a cycle shorter than 8 samples (the relay chatters on
  noise: a fast class whose ``tau_obs`` is capped to 0), or a last cycle whose period differs by more than 25% from
  the cycle before it (no steady state).

    from uavsim.data.preprocess import features, input_length
    f = features(y, u, rate_hz=200.0, h=1.0, bias=0.0, L=input_length(grid))
    f.x.shape, f.period, f.amplitude     # (2, L), s, output units
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uavsim.errors import NoOscillation, UserError
from uavsim.noise.analysis import cycle_harmonic_terms, mean_over_cycles

INPUT_RATE_HZ = 200.0  # inputs are built from control-rate samples
#: channel names of an input, in order
CHANNELS = ("y", "u")
#: margin of the input length over the longest class period
LENGTH_MARGIN = 1.25
_MIN_DUTY, _MAX_DUTY = 0.05, 0.95
#: the training preprocessing's steady state: the last two cycles' lengths differ by at most this fraction
STEADY_TOL = 0.25
#: shortest usable cycle, samples at INPUT_RATE_HZ: fewer than 4 samples a half-cycle is chattering, not a shape
MIN_CYCLE_SAMPLES = 8
#: most cycles the fundamental response is averaged over by default (the last ones, the first is never used)
RESPONSE_CYCLES = 4
#: what of a run the network input holds: the last cycles (training), the mean of the response cycles,
#: each response cycle as its own input (``features``; identification's choice: ``uavsim.ident.cycle``)
INPUTS = ("last", "mean", "each")
#: harmonics of the cycle's waveform measured over the same cycles (1 = the fundamental)
HARMONICS = 7
#: harmonics are measured (and scored) strictly below this fraction of the Nyquist frequency
HARMONIC_NYQUIST_FRACTION = 0.8


@dataclass
class CycleFeatures:
    """A network input and what was measured on the cycles it was built from.

    Attributes
    ----------
    x : (C, L) float32
        Network input, channels ``CHANNELS``, right-aligned, zero-padded.
    period : float
        Mean period of the cycles used, s.
    amplitude : float
        Half the peak-to-peak of ``y`` over the cycles used, output units.
    n_cycles : int
        Cycles used.
    start, stop : int
        Sample indices (of the given ``y``, ``u``) of the segment used, ``[start, stop)``.
    response : complex
        ``Y1 / (h U1)``: first harmonic of ``y`` over that of the command, output units per
        command unit, over the last ``response_cycles`` cycles (see module docstring).
    response_period : float
        Mean period of those cycles, s (the frequency of ``response`` is ``2 pi / response_period``).
    response_cycles : int
    harmonics_y, harmonics_u : (HARMONICS,) complex
        Harmonics 1..HARMONICS of ``y`` (output units) and of the normalized command
        ``(u - bias) / h`` over the same cycles (``waveform_harmonics``). A relay's square
        command excites the loop at ``k w`` too, so the response at several frequencies comes
        for free: it tells delay (phase growing with frequency) from lag (phase levelling off),
        which the cycle's shape alone barely does (``uavsim.ident``).
    response_spread : (float, float)
        How much the response cycles disagree: the standard deviations over them of each
        cycle's own ``log |Y1 / (h U1)|`` and of its phase about ``response``'s (rad). Noise
        that corrupts the measured point shows here (``uavsim.ident.select.decide_stable``).
    looks : (m, C, L) float32 or None
        With ``features(..., inputs="each")``: each of the ``response_cycles`` cycles (those that
        fit ``L``) as its own one-cycle input, oldest first (the last is ``x``); else None.
    inputs : str
        What ``x`` (and ``looks``) hold: ``features``'s ``inputs``.
    input_cycles : int
        Cycles the network's input(s) were built from (``"last"``: ``n_cycles``).
    """

    x: np.ndarray
    period: float
    amplitude: float
    n_cycles: int
    start: int
    stop: int
    response: complex = complex("nan")
    response_period: float = float("nan")
    response_cycles: int = 0
    harmonics_y: np.ndarray | None = None
    harmonics_u: np.ndarray | None = None
    response_spread: tuple[float, float] = (0.0, 0.0)
    looks: np.ndarray | None = None
    inputs: str = "last"
    input_cycles: int = 1


def held_response(G, omega, rate_hz: float) -> np.ndarray:
    """What a controller at ``rate_hz`` measures of a process response ``G(j w)``: its command is held.

    A held command's fundamental is its samples' times ``sinc(w Ts / 2) e^{-j w Ts / 2}``, so the
    sampled output over the command's samples is ``G(j w)`` times that (aliases neglected: the
    cycles here are 28 samples or longer). Shapes broadcast.
    """
    x = np.asarray(omega, dtype=np.float64) / (2.0 * rate_hz)
    return np.asarray(G) * np.sinc(x / np.pi) * np.exp(-1j * x)


def process_response(response, response_period, *, rate_hz: float = INPUT_RATE_HZ) -> np.ndarray:
    """``G(j w)`` from a measured ``CycleFeatures.response`` at ``w = 2 pi / response_period``: the hold removed."""
    w = 2.0 * np.pi / np.asarray(response_period, dtype=np.float64)
    return np.asarray(response) / held_response(1.0, w, rate_hz)


def input_length(grid, margin: float = LENGTH_MARGIN) -> int:
    """Input length ``L`` in samples at ``INPUT_RATE_HZ`` for a grid.

    Parameters
    ----------
    grid : uavsim.tuning.grid.Grid
        The class grid (a lateral grid: all its sub-grids).
    margin : float
        Factor over the longest class period (K does not change the period).

    Returns
    -------
    int
        ``ceil(margin * max period * INPUT_RATE_HZ)`` rounded up to a multiple of 8.
    """
    periods = [g.period for g in grid.sub] if getattr(grid, "sub", None) else [grid.period]
    tmax = float(max(np.max(p) for p in periods))
    n = math.ceil(margin * tmax * INPUT_RATE_HZ)
    return int(8 * math.ceil(n / 8))


def _resample(y: np.ndarray, u: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    T = len(y)
    t_in = np.arange(T) / rate_hz
    t_out = np.arange(int(math.floor((T - 1) / rate_hz * INPUT_RATE_HZ + 1e-9)) + 1) / INPUT_RATE_HZ
    yr = np.interp(t_out, t_in, y)
    # zero-order hold: the command in force at t_out is the last one computed at or before it
    idx = np.clip(np.floor(t_out * rate_hz + 1e-9).astype(np.int64), 0, T - 1)
    return yr, u[idx]


def waveform_harmonics(x: np.ndarray, start: int, stop: int, period: float,
                       orders: int = HARMONICS) -> tuple[np.ndarray, ...]:
    """Harmonics 1..``orders`` of signals over ``[start, stop)`` at one common (non-integer) period.

    A least-squares fit of ``c0 + c1 t + sum_k (a_k cos(k w n) + b_k sin(k w n))``,
    ``w = 2 pi / period``; the harmonic is ``X_k = (a_k - j b_k) / 2`` (the DFT convention of
    ``cycle_harmonics``). Why not ``cycle_harmonics``: a cycle of a sampled loop lasts a
    non-integer number of samples, and a DFT over each cycle's whole samples leaks about
    ``1 / N`` of the fundamental into every other bin, as much as a well-damped third
    harmonic holds; the trend term takes up what is left of the transient's drift.

    Parameters
    ----------
    x : (S, T) signals (or (T,))
    start, stop : sample indices of whole cycles
    period : float, samples per cycle (mean over the cycles)
    orders : highest harmonic

    Returns
    -------
    One (orders,) complex array per signal; NaN for the orders at or above
    ``HARMONIC_NYQUIST_FRACTION`` of Nyquist (``k >= 0.4 period``), which are not fitted.
    """
    x = np.atleast_2d(np.asarray(x, dtype=np.float64))
    out = np.full((x.shape[0], orders), complex("nan"))
    # harmonics near Nyquist are aliases (and exactly at it, a zero column): fit those below
    # HARMONIC_NYQUIST_FRACTION of it only
    H = min(orders, int(np.ceil(HARMONIC_NYQUIST_FRACTION * period / 2.0)) - 1)
    n = np.arange(start, stop, dtype=np.float64)
    if H < 1 or len(n) < 2 * H + 4:
        return tuple(out)
    t = (n - n.mean()) / len(n)
    z = np.cumprod(np.broadcast_to(np.exp(1j * (2.0 * np.pi / period) * n)[:, None], (len(n), H)), axis=1)
    A = np.column_stack([np.ones_like(n), t, z.real, z.imag])  # z[:, k-1] = exp(j k w n)
    # normal equations: the columns are near-orthogonal over whole cycles, and a (2H+2)^2 solve
    # is several times faster than an SVD of the (samples, 2H+2) matrix (identification latency)
    try:
        c = np.linalg.solve(A.T @ A, A.T @ x[:, start:stop].T)
    except np.linalg.LinAlgError:
        c = np.linalg.lstsq(A, x[:, start:stop].T, rcond=None)[0]
    out[:, :H] = (0.5 * (c[2 : 2 + H] - 1j * c[2 + H :])).T
    return tuple(out)


def features(y: np.ndarray, u: np.ndarray, rate_hz: float, h: float, bias: float, L: int, *,
             cycles: int = 1, steady_tol: float | None = None, inputs: str = "last",
             harmonics: bool = True, response_cycles: int = RESPONSE_CYCLES) -> CycleFeatures:
    """Network input from one relay test.

    Parameters
    ----------
    y : (T,) measured output, output units
    u : (T,) relay command as computed, bias included, command units
    rate_hz : float
        Sample rate of ``y`` and ``u``, Hz.
    h : float
        Relay amplitude, command units, > 0.
    bias : float
        Constant added to the relay output, command units.
    L : int
        Input length, samples at ``INPUT_RATE_HZ``.
    cycles : int
        Cycles to use (the last ones).
    steady_tol : float, optional
        Largest relative difference of the last two cycles' lengths (and of the response
        cycles'); None: the 25 % of the module docstring, which the training sets always use.
        Identification may pass a looser one (``uavsim.ident.cycle.IDENT_STEADY_TOL``).
    inputs : ``"last"``, ``"mean"`` or ``"each"``
        What the network is to see of the run (``INPUTS``): ``"last"`` the last ``cycles`` cycles
        (the training sets' input, always); ``"mean"`` (``cycles`` 1 only) ``x`` is the mean of the
        response cycles instead (``mean_cycle``), laid out like one cycle; ``"each"`` (``cycles`` 1
        only) ``x`` stays the last cycle and ``looks`` holds every response cycle as its own
        one-cycle input (the last one is ``x``). Both take the response cycles after the last
        one longer than ``L``, if any (the last cycle always fits).
    harmonics : bool
        Measure ``harmonics_y`` and ``harmonics_u`` (None without: identification does not use them).
    response_cycles : int
        Most steady cycles the fundamental response is averaged over, where the run has them
        (``RESPONSE_CYCLES``; identification's per loop: ``uavsim.ident.cycle.IDENT_RESPONSE_CYCLES``).

    Raises
    ------
    NoOscillation
        When the traces hold no usable steady oscillation (see module docstring).
    """
    y = np.asarray(y, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    if y.ndim != 1 or y.shape != u.shape:
        raise NoOscillation(f"y and u must be 1-D of the same length, got {y.shape} and {u.shape}")
    if not (math.isfinite(h) and h > 0 and math.isfinite(bias) and math.isfinite(rate_hz) and rate_hz > 0):
        raise UserError(f"preprocess needs h > 0, a finite bias and rate > 0 (got h={h}, bias={bias}, rate={rate_hz})")
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(u))):
        raise NoOscillation("the traces contain NaN or inf")
    tol = STEADY_TOL if steady_tol is None else float(steady_tol)
    if int(response_cycles) < 1:
        raise UserError(f"response_cycles must be >= 1, got {response_cycles}")
    if inputs not in INPUTS or (inputs != "last" and cycles != 1):
        raise UserError(f"inputs must be one of {', '.join(INPUTS)} ('last' with cycles > 1), got {inputs!r}")
    scale = 1.0
    precise_period = None
    if abs(rate_hz - INPUT_RATE_HZ) > 1e-9:
        # the period is timed on the original samples (a faster rate times it better)
        pos0 = (u - bias) > 0
        e0 = np.flatnonzero(pos0[1:] & ~pos0[:-1]) + 1
        if len(e0) >= cycles + 1:
            precise_period = (e0[-1] - e0[-1 - cycles]) / cycles / rate_hz
        scale = rate_hz / INPUT_RATE_HZ
        y, u = _resample(y, u, rate_hz)
    s = (u - bias) / h
    if np.max(np.abs(np.abs(s) - 1.0)) > 1e-2:
        raise NoOscillation("u is not a relay command of amplitude h around the bias")
    pos = s > 0
    edges = np.flatnonzero(pos[1:] & ~pos[:-1]) + 1
    if len(edges) < cycles + 2:
        raise NoOscillation(f"{max(len(edges) - 1, 0)} full relay cycles, need {cycles + 1} "
                            f"(one transient, {cycles} used): episode too short or no switching")
    start, stop = int(edges[-1 - cycles]), int(edges[-1])
    n = stop - start
    if n > L:
        raise NoOscillation(f"{cycles} cycle(s) of {n} samples do not fit the input length {L}")
    if np.min(np.diff(edges[-2 - cycles:])) < MIN_CYCLE_SAMPLES:
        raise NoOscillation(f"cycles shorter than {MIN_CYCLE_SAMPLES} samples: the relay chatters")
    last = edges[-1] - edges[-2]
    before = edges[-2] - edges[-3]
    if abs(last - before) > tol * max(last, before):
        raise NoOscillation(f"no steady state: last cycles of {before} and {last} samples")
    seg_y = y[start:stop]
    hi, lo = float(seg_y.max()), float(seg_y.min())
    amp = 0.5 * (hi - lo)
    if not amp > 0:
        raise NoOscillation("flat output over the cycle")
    seg_u = s[start:stop]
    duty = float(np.mean(seg_u > 0))
    if not _MIN_DUTY <= duty <= _MAX_DUTY:
        raise NoOscillation(f"unsymmetric cycle: relay up {100 * duty:.0f}% of the time")
    x = _layout(seg_y, seg_u, L)
    period = precise_period if precise_period is not None else n / cycles / INPUT_RATE_HZ
    # the fundamental response over the last steady cycles (never the first, transient one)
    m = min(int(response_cycles), len(edges) - 2)
    lens = np.diff(edges[-1 - m:])
    while m > cycles and abs(lens[0] - lens[-1]) > tol * max(lens[0], lens[-1]):
        m -= 1
        lens = lens[1:]
    re = edges[-1 - m:]
    ty, tu = cycle_harmonic_terms(y, re), cycle_harmonic_terms(s, re)  # each cycle's own fundamental
    yh, uh = mean_over_cycles(ty)[0], mean_over_cycles(tu)[0]
    hy, hu = (waveform_harmonics(np.stack([y, s]), int(re[0]), int(re[-1]), (re[-1] - re[0]) / m) if harmonics
              else (None, None))
    response = complex(yh / (h * uh))
    each = ty[:, 0] / (h * tu[:, 0])
    with np.errstate(all="ignore"):
        spread = (float(np.std(np.log(np.abs(each)))), float(np.std(np.angle(each / response))))
    looks, n_in = None, cycles
    if inputs != "last":
        # the response cycles back to the first one longer than the input (the last one fits: checked above)
        long = np.flatnonzero(np.diff(re) > L)
        le = re[long[-1] + 1:] if long.size else re
        n_in = le.size - 1
        if inputs == "mean":
            x = _layout(*mean_cycle(y, s, le), L)
        else:
            looks = np.stack([_layout(y[a:b], s[a:b], L) for a, b in zip(le[:-1], le[1:], strict=True)])
    return CycleFeatures(x=x, period=period, amplitude=amp, n_cycles=cycles,
                         start=int(round(start * scale)), stop=int(round(stop * scale)),
                         response=response, response_period=float(np.mean(lens)) / INPUT_RATE_HZ,
                         response_cycles=int(m), harmonics_y=hy, harmonics_u=hu, response_spread=spread,
                         looks=looks, inputs=inputs, input_cycles=int(n_in))


def _layout(seg_y: np.ndarray, seg_u: np.ndarray, L: int) -> np.ndarray:
    """One cycle's ``y`` and normalized command as a (C, L) input: ``y`` centred on its mid-range over half its
    peak-to-peak, both right-aligned, zero-padded (module docstring, steps 3-4)."""
    n = seg_y.size
    hi, lo = float(seg_y.max()), float(seg_y.min())
    x = np.zeros((len(CHANNELS), L), dtype=np.float32)
    x[0, L - n:] = (seg_y - 0.5 * (hi + lo)) / (0.5 * (hi - lo))
    x[1, L - n:] = seg_u
    return x


def mean_cycle(y: np.ndarray, s: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mean of the cycles between consecutive rising ``edges``, each resampled to their mean length.

    Each cycle ``[e_i, e_{i+1})`` is read at ``N = round(mean length)`` points equally spaced from its
    rising edge (``y`` linearly interpolated, the command ``s`` held), so the cycles line up at their
    rising edges and at their ends; ``y`` is averaged and the command is the sign of the averaged
    command (a relay command is +-1; where the cycles' falling edges differ it switches where most do).
    Zero-mean noise falls by about the square root of the cycles' count; cycles of one length give
    their own samples' mean.

    Parameters
    ----------
    y : (T,) output
    s : (T,) normalized command ``(u - bias) / h``
    edges : (m + 1,) sample indices of rising edges, m >= 1

    Returns
    -------
    (N,) float64 mean output, (N,) float64 command in {-1, +1}
    """
    edges = np.asarray(edges, dtype=np.int64)
    lens = np.diff(edges)
    N = int(round(float(lens.mean())))
    k = np.arange(N, dtype=np.float64) / N
    ym = np.zeros(N)
    sm = np.zeros(N)
    for e0, n in zip(edges[:-1], lens, strict=True):
        pos = k * n
        ym += np.interp(pos, np.arange(n + 1, dtype=np.float64), y[e0 : e0 + n + 1])
        sm += s[e0 + np.floor(pos + 1e-9).astype(np.int64)]
    return ym / lens.size, np.where(sm >= 0.0, 1.0, -1.0)


def features_batch(Y: np.ndarray, U: np.ndarray, rate_hz: float, h: np.ndarray, bias: np.ndarray, L: int, *,
                   cycles: int = 1, response: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``features`` on each row; rows without a usable oscillation get ``ok = False``.

    Parameters
    ----------
    Y, U : (n, T)
    rate_hz : float
    h, bias : (n,) or scalars
    L : int
    cycles : int
    response : dict, optional
        When given, filled with ``response`` (n,) complex, ``response_period`` (n,) s and
        ``harmonics_y``, ``harmonics_u`` (n, HARMONICS) complex (``CycleFeatures``; NaN where not ok).

    Returns
    -------
    X : (n, C, L) float32 (zeros where not ok)
    period : (n,) s (NaN where not ok)
    amplitude : (n,) output units (NaN where not ok)
    ok : (n,) bool
    """
    Y = np.asarray(Y, dtype=np.float64)
    U = np.asarray(U, dtype=np.float64)
    n = Y.shape[0]
    h = np.broadcast_to(np.asarray(h, dtype=np.float64), (n,))
    bias = np.broadcast_to(np.asarray(bias, dtype=np.float64), (n,))
    X = np.zeros((n, len(CHANNELS), L), dtype=np.float32)
    period = np.full(n, np.nan)
    amplitude = np.full(n, np.nan)
    ok = np.zeros(n, dtype=bool)
    resp = np.full(n, complex("nan"))
    resp_period = np.full(n, np.nan)
    hy = np.full((n, HARMONICS), complex("nan"))
    hu = np.full((n, HARMONICS), complex("nan"))
    for i in range(n):
        try:
            f = features(Y[i], U[i], rate_hz, float(h[i]), float(bias[i]), L, cycles=cycles)
        except NoOscillation:
            continue
        X[i], period[i], amplitude[i], ok[i] = f.x, f.period, f.amplitude, True
        resp[i], resp_period[i], hy[i], hu[i] = f.response, f.response_period, f.harmonics_y, f.harmonics_u
    if response is not None:
        response.update(response=resp, response_period=resp_period, harmonics_y=hy, harmonics_u=hu)
    return X, period, amplitude, ok
