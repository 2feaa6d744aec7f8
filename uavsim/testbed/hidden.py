"""Hidden effects of the testbed: the session vocabulary's and effects of other shapes, written independently.

These are what the gap workflow must find, so none of them comes from
``uavsim.model.effects`` (the workflow's candidates): each is written here
for the testbed's physics-rate command path (1 kHz, between the controller's
held command and the autopilot's mixer) or its measurement path.

Command side, in this order: ``delay`` / ``varying_delay`` (the held command
read ``d`` seconds late; a step inside a physics step is averaged over it),
``gain``, ``lag`` (first order), ``resonance`` (second order, underdamped),
``rate_limit``, ``backlash`` (play of width ``width``), ``dead_zone``,
``saturation``, ``asym_saturation``, ``bias``. Measurement side: ``lowpass``
(2nd-order Butterworth at the physics rate) and ``sample_hold`` (frames at
``rate_hz`` with a random phase, on physics time) before the controller
samples, then ``quantization`` and ``noise`` (white Gaussian) on the sample.

Vocabulary effects (``session.md``): delay, lag, gain, saturation, dead_zone,
rate_limit, bias, quantization, sample_hold, lowpass, noise. Other shapes:
``asym_saturation`` (``upper``, ``lower``: clipped to ``[-lower, upper]``),
``backlash`` (``width``), ``varying_delay`` (``delay`` mean, ``amplitude``,
``period``: ``d(t) = delay + amplitude sin(2 pi t / period + phase)``) and
``resonance`` (``freq_hz``, ``zeta``).

    spec = draw_effect("lag", rng, Scales(period_s=0.5, h=1.0, amp=0.05))
    chain = CommandChain([spec], dt_s=0.001, rate_hz=200.0, rng=rng)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from uavsim.errors import UserError
from uavsim.testbed.filters import Biquad, SecondOrderLag

__all__ = ["VOCABULARY", "OUTSIDE", "COMMAND_ORDER", "MEASURE_ORDER", "HiddenEffect", "Scales", "draw_effect",
           "CommandChain", "MeasurementChain", "PARAMS"]

VOCABULARY = ("delay", "lag", "gain", "saturation", "dead_zone", "rate_limit", "bias",
              "quantization", "sample_hold", "lowpass", "noise")  # fmt: skip
OUTSIDE = ("asym_saturation", "backlash", "varying_delay", "resonance")
COMMAND_ORDER = ("delay", "varying_delay", "gain", "lag", "resonance", "rate_limit", "backlash", "dead_zone",
                 "saturation", "asym_saturation", "bias")  # fmt: skip
MEASURE_ORDER = ("lowpass", "sample_hold", "quantization", "noise")
#: parameter names of each effect
PARAMS: dict[str, tuple[str, ...]] = {
    "delay": ("delay",), "lag": ("T",), "gain": ("factor",), "saturation": ("limit",), "dead_zone": ("width",),
    "rate_limit": ("rate",), "bias": ("offset",), "quantization": ("step",), "sample_hold": ("rate_hz",),
    "lowpass": ("cutoff_hz",), "noise": ("std",), "asym_saturation": ("upper", "lower"), "backlash": ("width",),
    "varying_delay": ("delay", "amplitude", "period"), "resonance": ("freq_hz", "zeta"),
}  # fmt: skip


@dataclass
class HiddenEffect:
    """One hidden effect: its name and parameters (vocabulary units)."""

    name: str
    params: dict[str, float] = field(default_factory=dict)

    def check(self) -> HiddenEffect:
        if self.name not in PARAMS:
            raise UserError(f"testbed: unknown hidden effect {self.name!r}")
        if set(self.params) != set(PARAMS[self.name]):
            raise UserError(f"testbed: effect {self.name} needs {', '.join(PARAMS[self.name])}")
        return self


@dataclass(frozen=True)
class Scales:
    """The loop's own scales, for magnitudes that are visible but flyable.

    Attributes
    ----------
    period_s : float
        Expected MRFT period at beta -0.73, s.
    h : float
        Smallest relay amplitude of the session, command units.
    amp : float
        Expected oscillation amplitude at ``h``, output units.
    noise_std : float
        The vehicle's own measurement noise (high-passed std in a hover), output units;
        ``nan`` when not measured (only ``noise`` needs it).
    """

    period_s: float
    h: float
    amp: float
    noise_std: float = float("nan")


def draw_effect(name: str, rng: np.random.Generator, s: Scales) -> HiddenEffect:
    """A random magnitude of ``name`` for a loop with scales ``s``."""
    u = rng.uniform
    P, h, a = s.period_s, s.h, s.amp
    sign = float(rng.choice([-1.0, 1.0]))
    table = {
        "delay": lambda: {"delay": u(0.04, 0.12) * P},
        "lag": lambda: {"T": u(0.04, 0.12) * P},
        "gain": lambda: {"factor": math.exp(sign * u(math.log(1.3), math.log(2.0)))},
        "saturation": lambda: {"limit": u(1.2, 2.5) * h},  # the relay at 3 h and the large step clip
        "dead_zone": lambda: {"width": u(0.15, 0.4) * h},
        "rate_limit": lambda: {"rate": 2 * h / (u(0.05, 0.15) * P)},  # a 2 h swing takes 5-15% of the period
        "bias": lambda: {"offset": sign * u(0.15, 0.35) * h},
        "quantization": lambda: {"step": u(0.1, 0.3) * a},
        "sample_hold": lambda: {"rate_hz": math.exp(u(math.log(12.0), math.log(max(min(60.0, 1 / (0.03 * P)), 13.0))))},
        "lowpass": lambda: {"cutoff_hz": (1.0 / P) / u(0.12, 0.35)},
        # extra noise 1.5-4 times the vehicle's own (at least 0.5% of the amplitude)
        "noise": lambda: {"std": u(1.5, 4.0) * max(s.noise_std if math.isfinite(s.noise_std) else 0.0, 0.005 * a)},
        "asym_saturation": lambda: _asym(u(1.2, 2.5) * h, u(0.35, 0.7), sign),
        "backlash": lambda: {"width": u(0.2, 0.6) * h},
        "varying_delay": lambda: _varying(u(0.03, 0.08) * P, u(0.5, 0.9), u(1.5, 4.0) * P),
        "resonance": lambda: {"freq_hz": u(2.5, 5.0) / P, "zeta": u(0.12, 0.3)},
    }
    if name not in table:
        raise UserError(f"testbed: unknown hidden effect {name!r}")
    return HiddenEffect(name, {k: float(v) for k, v in table[name]().items()}).check()


def _asym(big: float, ratio: float, sign: float) -> dict[str, float]:
    return {"upper": big, "lower": big * ratio} if sign > 0 else {"upper": big * ratio, "lower": big}


def _varying(mean: float, rel: float, period: float) -> dict[str, float]:
    return {"delay": mean, "amplitude": rel * mean, "period": period}


class CommandChain:
    """The command-side hidden effects at the physics rate.

    Call :meth:`push` once per control sample with the controller's command
    and :meth:`__call__` once per physics step with the step's start time.
    """

    def __init__(self, effects: list[HiddenEffect], dt_s: float, rate_hz: float, rng: np.random.Generator):
        by = {e.name: e.params for e in effects if e.name in COMMAND_ORDER}
        self.fx = [(n, by[n]) for n in COMMAND_ORDER if n in by]
        self.dt, self.Ts = float(dt_s), 1.0 / float(rate_hz)
        self.u_hist: list[float] = []
        self.t0: float | None = None
        self.state: dict[str, object] = {}
        self.vd_phase = float(rng.uniform(0, 2 * math.pi))
        for n, p in self.fx:
            if n == "resonance":
                self.state[n] = SecondOrderLag(p["freq_hz"], p["zeta"], self.dt)
        max_d = max([p["delay"] + p.get("amplitude", 0.0) for n, p in self.fx if "delay" in p] + [0.0])
        self.keep = int(max_d / self.Ts) + 4

    def push(self, t: float, u: float) -> None:
        """The controller's command ``u`` from time ``t`` on (held until the next push)."""
        if self.t0 is None:
            self.t0 = t
            for n, _ in self.fx:
                if n == "resonance":
                    self.state[n].reset(u)
                elif n in ("lag", "rate_limit", "backlash"):
                    self.state[n] = u
        self.u_hist.append(float(u))
        if len(self.u_hist) > 4 * self.keep + 64:
            drop = len(self.u_hist) - self.keep - 1
            self.u_hist = self.u_hist[drop:]
            self.t0 += drop * self.Ts

    def _held(self, t: float) -> float:
        """The held command at time ``t`` (the first one before the record starts)."""
        j = int(math.floor((t - self.t0) / self.Ts + 1e-9))
        return self.u_hist[min(max(j, 0), len(self.u_hist) - 1)]

    def _delayed(self, t: float, d: float) -> float:
        """Mean of the held command over ``[t - d, t - d + dt]``."""
        a = t - d
        b = a + self.dt
        # edge of the staircase inside [a, b]
        j = math.floor((b - self.t0) / self.Ts + 1e-9)
        edge = self.t0 + j * self.Ts
        if a < edge < b:
            f = (edge - a) / self.dt
            return f * self._held(a) + (1 - f) * self._held(edge)
        return self._held(a)

    def __call__(self, t: float) -> float:
        """The command reaching the autopilot's mixer during the physics step starting at ``t``."""
        x = None
        for n, p in self.fx:
            if n == "delay":
                x = self._delayed(t, p["delay"])
            elif n == "varying_delay":
                d = p["delay"] + p["amplitude"] * math.sin(2 * math.pi * t / p["period"] + self.vd_phase)
                x = self._delayed(t, max(d, 0.0))
        if x is None:
            x = self._held(t)
        for n, p in self.fx:
            if n == "gain":
                x = x * p["factor"]
            elif n == "lag":
                self.state[n] += (x - self.state[n]) * (1.0 - math.exp(-self.dt / p["T"]))
                x = self.state[n]
            elif n == "resonance":
                x = self.state[n](x)
            elif n == "rate_limit":
                s = p["rate"] * self.dt
                self.state[n] += min(max(x - self.state[n], -s), s)
                x = self.state[n]
            elif n == "backlash":
                half = 0.5 * p["width"]
                self.state[n] = min(max(self.state[n], x - half), x + half)
                x = self.state[n]
            elif n == "dead_zone":
                x = math.copysign(max(abs(x) - p["width"], 0.0), x)
            elif n == "saturation":
                x = min(max(x, -p["limit"]), p["limit"])
            elif n == "asym_saturation":
                x = min(max(x, -p["lower"]), p["upper"])
            elif n == "bias":
                x = x + p["offset"]
        return x


class MeasurementChain:
    """The measurement-side hidden effects: physics-rate filters, then control-rate ones."""

    def __init__(self, effects: list[HiddenEffect], dt_s: float, rng: np.random.Generator):
        by = {e.name: e.params for e in effects if e.name in MEASURE_ORDER}
        self.fx = [(n, by[n]) for n in MEASURE_ORDER if n in by]
        self.rng = rng
        self.dt = float(dt_s)
        self.lp = Biquad.butter_lowpass(by["lowpass"]["cutoff_hz"], 1.0 / dt_s) if "lowpass" in by else None
        self.sh_period = 1.0 / by["sample_hold"]["rate_hz"] if "sample_hold" in by else None
        self.sh_next = float(rng.uniform(0, self.sh_period)) if self.sh_period else 0.0
        self.sh_value: float | None = None
        self.primed = False

    def physics(self, t: float, s: float) -> float:
        """The sensor output ``s`` at physics time ``t`` after the low-pass and the frame hold."""
        if self.lp is not None:
            if not self.primed:
                self.lp.prime(s)
            s = float(self.lp(s))
        self.primed = True
        if self.sh_period is not None:
            if self.sh_value is None or t + 1e-12 >= self.sh_next:
                self.sh_value = s
                while self.sh_next <= t + 1e-12:
                    self.sh_next += self.sh_period
            s = self.sh_value
        return s

    def sample(self, y: float) -> float:
        """The controller's sample after quantization and extra noise."""
        for n, p in self.fx:
            if n == "quantization":
                y = round(y / p["step"]) * p["step"]
            elif n == "noise":
                y = y + p["std"] * float(self.rng.standard_normal())
        return y
