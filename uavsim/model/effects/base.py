"""The effect interface: named, parameterized, validated, seeded.

An effect is one physical imperfection of a loop. It acts in one of three
places, which is all the simulator needs to know about it:

- ``"model"``: it changes the MuJoCo model of each episode (extra delay, loop
  gain); ``apply_model(loop_model)`` edits the per-episode mapping before the
  batch is built.
- ``"command"``: it transforms the command between controller and actuator
  (saturation, dead zone, rate limit, bias, extra lag), once per control sample.
- ``"measurement"``: it transforms the measurement between the vehicle and the
  controller (noise, quantization, sample-and-hold, low-pass), once per
  control sample: the controller sees the measurement chain, never ground truth.
- ``"force"``: it adds an external force on the body (wind, pull), set once per
  control sample from the vehicle's state.

Signal effects keep their state in arrays of shape ``(n,)`` for ``n``
episodes, and draw every random number from the generator given to
``reset``, so that an episode is reproducible from its seed.

    eff = Quantization(step=0.01)
    eff.reset(n=8, rate_hz=200.0, rng=np.random.default_rng(0))
    y_seen = eff(y_true, k)      # (8,) -> (8,)
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass

import numpy as np

from uavsim.errors import UserError

REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make an effect available by its ``name``."""
    REGISTRY[cls.name] = cls
    return cls


def require(cond: bool, effect: str, message: str) -> None:
    """Raise a one-line ``UserError`` for an invalid effect parameter."""
    if not cond:
        raise UserError(f"effect {effect}: {message}")


def finite(effect: str, **values: float) -> None:
    for k, v in values.items():
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise UserError(f"effect {effect}: {k} must be a finite number, got {v!r}")


@dataclass
class Effect(ABC):
    """Base of every effect; subclasses are dataclasses of their parameters."""

    name = "effect"
    #: "model", "command", "measurement" or "force"
    target = "measurement"

    def __post_init__(self) -> None:
        self.validate()

    @abstractmethod
    def validate(self) -> None:
        """Raise ``UserError`` when a parameter is impossible."""

    def params(self) -> dict[str, float]:
        return {k: v for k, v in asdict(self).items() if not k.startswith("_")}

    def describe(self) -> str:
        inner = ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in self.params().items())
        return f"{self.name}({inner})"


class SignalEffect(Effect):
    """An effect on a sampled signal (command or measurement), one call per control sample."""

    def reset(self, n: int, rate_hz: float, rng: np.random.Generator) -> None:
        """Start ``n`` episodes at controller rate ``rate_hz`` drawing from ``rng``."""
        self.n = int(n)
        self.rate_hz = float(rate_hz)
        self.rng = rng

    @abstractmethod
    def __call__(self, x: np.ndarray, k: int) -> np.ndarray:
        """Transform sample ``k`` of the signal, ``x`` of shape (n,); return (n,)."""


def make_effect(name: str, **params: float) -> Effect:
    """Build an effect from the session vocabulary, e.g. ``make_effect("delay", delay=0.02)``."""
    if name not in REGISTRY:
        raise UserError(f"unknown effect {name!r} (known: {', '.join(sorted(REGISTRY))})")
    cls = REGISTRY[name]
    try:
        return cls(**params)
    except TypeError as exc:
        raise UserError(f"effect {name}: {exc}") from None
