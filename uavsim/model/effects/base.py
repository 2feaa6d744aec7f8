"""The effect interface: named, parameterized, validated, seeded.

An effect is one physical imperfection of a loop. It acts in one of four
places, which is all the simulator needs to know about it:

- ``"model"``: it changes the MuJoCo model of each episode (extra delay, loop
  gain); the runner reads its parameters when it maps the batch.
- ``"command"``: it transforms the command between controller and actuator
  (saturation, dead zone, rate limit, bias, extra lag), once per control sample.
- ``"measurement"``: it transforms the measurement between the vehicle and the
  controller (noise, quantization, sample-and-hold, low-pass), once per
  control sample: the controller sees the measurement chain, never ground truth.
- ``"force"``: it adds an external force on the body (wind, pull), set once per
  control sample from the vehicle's state.

Every numeric parameter is either one scalar for the whole batch or an array
of shape ``(n,)``, one value per episode (broadcast over the batch, validated
element by element), so that one batch can hold many parameter values -- as
the gap workflow's fits do. Signal effects keep their state in arrays of
shape ``(n,)`` for ``n`` episodes, and draw every random number from the
generator given to ``reset``, so that an episode is reproducible from its seed.

    eff = Quantization(step=0.01)                      # or step=np.array([0.01, 0.02, ...])
    eff.reset(n=8, rate_hz=200.0, rng=np.random.default_rng(0))
    y_seen = eff(y_true, k)      # (8,) -> (8,)
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from uavsim.errors import UserError

#: a parameter: one value for every episode, or one per episode, shape (n,)
Param = float | np.ndarray

REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make an effect available by its ``name``."""
    REGISTRY[cls.name] = cls
    return cls


def require(cond: bool | np.ndarray, effect: str, message: str) -> None:
    """Raise a one-line ``UserError`` for an invalid effect parameter (``cond`` may be an array: all must hold)."""
    if not bool(np.all(cond)):
        raise UserError(f"effect {effect}: {message}")


def require_each(ok: bool | np.ndarray, effect: str, value: Param, message: Callable[[float], str]) -> None:
    """Check a parameter element by element; the error names the first bad value (and its episode).

    Parameters
    ----------
    ok : bool or (n,) bool
        Where the parameter is valid.
    effect : str
        The effect's name, for the message.
    value : float or (n,)
        The parameter.
    message : callable float -> str
        The message for a bad value, e.g. ``lambda v: f"width must be >= 0, got {v}"``.
    """
    ok = np.asarray(ok)
    if bool(np.all(ok)):
        return
    arr = np.asarray(value)
    if arr.ndim == 0:
        raise UserError(f"effect {effect}: {message(value)}")
    i = int(np.flatnonzero(~np.broadcast_to(ok, arr.shape))[0])
    raise UserError(f"effect {effect}: {message(float(arr[i]))} (episode {i})")


def _numbers(effect: str, allow_inf: bool, values: dict[str, Param]) -> None:
    what = "number (or inf)" if allow_inf else "finite number"
    for k, v in values.items():
        if isinstance(v, np.ndarray):
            if v.dtype.kind != "f" or v.ndim != 1:  # __post_init__ made numeric arrays float64
                raise UserError(f"effect {effect}: {k} must be a {what} or an (n,) array of them, got {v!r}")
            bad = np.isnan(v) if allow_inf else ~np.isfinite(v)
            require_each(~bad, effect, v, lambda x, k=k: f"{k} must be a {what}, got {x!r}")
        elif not isinstance(v, (int, float, np.integer, np.floating)) or isinstance(v, (bool, np.bool_)) or (
            math.isnan(v) or (not allow_inf and math.isinf(v))
        ):
            also = " or an (n,) array of them" if isinstance(v, (list, tuple)) else ""
            raise UserError(f"effect {effect}: {k} must be a {what}{also}, got {v!r}")


def finite(effect: str, **values: Param) -> None:
    """Raise ``UserError`` unless every value is a finite number (scalar or every element of an (n,) array)."""
    _numbers(effect, False, values)


def number(effect: str, **values: Param) -> None:
    """As :func:`finite`, but ``inf`` passes (a parameter whose infinity means "no effect": no limit, no filter)."""
    _numbers(effect, True, values)


def batched(value: Param, n: int, effect: str, name: str) -> Param:
    """A parameter checked against the batch: a scalar as is, an (n,) array as is; other lengths are an error."""
    if isinstance(value, np.ndarray) and value.shape != (n,):
        raise UserError(f"effect {effect}: {name} has {value.size} values, the batch has {n} episodes")
    return value


@dataclass(eq=False)  # parameters may be arrays: compare effects by identity
class Effect(ABC):
    """Base of every effect; subclasses are dataclasses of their parameters (scalars or (n,) arrays)."""

    name = "effect"
    #: "model", "command", "measurement" or "force"
    target = "measurement"

    def __post_init__(self) -> None:
        # per-episode parameters (numeric lists, tuples, arrays) become float64 arrays once, here;
        # other fields (a noise model's groups of effects) are left alone
        for f in fields(self):
            v = getattr(self, f.name)
            numeric_seq = isinstance(v, (list, tuple)) and len(v) > 0 and all(
                isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_)) for x in v
            )
            if numeric_seq or (isinstance(v, np.ndarray) and v.dtype.kind in "iuf"):
                arr = np.asarray(v, dtype=np.float64)
                setattr(self, f.name, float(arr) if arr.ndim == 0 else arr)
        self.validate()

    @abstractmethod
    def validate(self) -> None:
        """Raise ``UserError`` when a parameter is impossible (for an array: any element)."""

    def params(self) -> dict[str, Param]:
        """The parameters by name: floats, or (n,) arrays for per-episode values."""
        return {f.name: getattr(self, f.name) for f in fields(self) if not f.name.startswith("_")}

    def describe(self) -> str:
        def fmt(v):
            if isinstance(v, np.ndarray):
                return f"[{v.size} values]"
            return f"{v:g}" if isinstance(v, float) else f"{v}"

        return f"{self.name}({', '.join(f'{k}={fmt(v)}' for k, v in self.params().items())})"


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


def make_effect(name: str, **params: Param) -> Effect:
    """Build an effect from the session vocabulary, e.g. ``make_effect("delay", delay=0.02)``.

    Any numeric parameter may be an array (n,): one value per episode of the batch.
    """
    if name not in REGISTRY:
        raise UserError(f"unknown effect {name!r} (known: {', '.join(sorted(REGISTRY))})")
    cls = REGISTRY[name]
    try:
        return cls(**params)
    except TypeError as exc:
        raise UserError(f"effect {name}: {exc}") from None
