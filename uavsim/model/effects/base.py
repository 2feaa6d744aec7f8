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

An effect of the flight session format's vocabulary also carries a
:class:`SessionTerm` (``session = SessionTerm(...)``): its one parameter, that
parameter's range, the value that leaves the loop unchanged, its place in the
format's table and in the simulated chain, the gap workflow's search grid and
the hidden-effect generator's draw. The session format, its schema, the gap
workflow and the hidden-effect sessions read the vocabulary from there
(:mod:`uavsim.model.effects.vocabulary`), so a new vocabulary effect is one
new file.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import ClassVar

import numpy as np

from uavsim.errors import UserError

#: a parameter: one value for every episode, or one per episode, shape (n,)
Param = float | np.ndarray

REGISTRY: dict[str, type[Effect]] = {}

#: a session parameter's allowed range: strictly positive, non-negative, any finite value
RANGES = (">0", ">=0", "any")


@dataclass(frozen=True)
class SessionTerm:
    """How a vocabulary effect appears in the session format, the gap workflow and the hidden-effect sessions.

    Attributes
    ----------
    param : str
        Its one parameter: the key in ``session.toml`` and the effect's field of that name
        (parameter names are unique across the vocabulary).
    range : str
        The parameter's allowed range in a session, one of :data:`RANGES`.
    identity : float
        The value that leaves the loop unchanged (``nan`` with ``identity_is_rate``).
    table : int
        Position in the format's effect table (``none`` is 0).
    chain : int
        Position in the simulated chain, as the session generator applies the effects:
        model effects first, then command effects, then measurement effects.
    grid : callable (scales, noise_std, rate_hz, n) -> ndarray
        The gap workflow's coarse search values for a session with ``scales`` (a mapping with
        ``period`` s, ``umax``, ``h_min``, ``h_max`` command units, ``amp`` output units),
        the model's noise std, the control rate (Hz) and grid size ``n``.
    draw : callable (rng, period, h, amp, noise_std, rate_hz) -> dict
        A random observable magnitude for a hidden-effect session: MRFT period (s), smallest
        relay amplitude, oscillation amplitude, noise std and control rate; returns ``{param: value}``.
    cap : callable rate_hz -> float, optional
        The largest value worth fitting at a control rate (values above it act as the cap).
    identity_is_rate : bool
        The identity value is the control rate (a frame rate equal to it holds nothing).
    phase : callable (value, freq_hz, h) -> float, optional
        For an effect whose phase a fitted delay can hold: the phase lag (rad) it adds to a
        relay cycle at ``freq_hz`` whose relay output swings +-``h`` (command units; a linear
        effect's own phase does not depend on it). Identification from that relay run puts
        it in the model's ``tau``; the gap workflow takes it out again.
    """

    param: str
    range: str
    identity: float
    table: int
    chain: int
    grid: Callable[[Mapping[str, float], float, float, int], np.ndarray]
    draw: Callable[[np.random.Generator, float, float, float, float, float], dict[str, float]]
    cap: Callable[[float], float] | None = None
    identity_is_rate: bool = False
    phase: Callable[[float, float, float], float] | None = None

    def __post_init__(self) -> None:
        if self.range not in RANGES:
            raise ValueError(f"session range {self.range!r} is not one of {RANGES}")


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
    #: the effect's entry in the session vocabulary; None: not a session effect (wind, pull)
    session: ClassVar[SessionTerm | None] = None

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

    def trace(self, m: int, T: int, rate_hz: float, rng: np.random.Generator) -> np.ndarray:
        """The signal an additive noise model adds to ``m`` episodes of ``T`` samples, shape (T, m), drawn at once.

        Vectorized over time (dataset generation precomputes whole episodes), with the same
        model, parameters and statistics as the per-sample ``__call__``, not the same draws.
        Only additive models have one; the others raise ``TypeError``.
        """
        raise TypeError(f"no precomputed trace for {type(self).__name__}")


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
