"""The session vocabulary, read from the registered effects' :class:`~uavsim.model.effects.base.SessionTerm`.

Every registered effect with a ``session`` term is a word of the flight session
format's effect vocabulary. The tables here are live views of the registry, so
an effect registered later (a plug-in, a test's toy effect) is in them at once:
the session reader and writer, the schema, the gap workflow's candidates and
the hidden-effect sessions all read these.

    from uavsim.model.effects.vocabulary import EFFECT_PARAMS, names, term
    EFFECT_PARAMS["lag"]          # ("T",)
    names()                       # ("delay", "lag", ..., "noise"), in the format's table order
    term("lag").grid(scales, noise_std, 200.0, 8)
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

from uavsim.errors import UserError
from uavsim.model.effects.base import REGISTRY, SessionTerm

__all__ = ["EFFECT_PARAMS", "PARAM_RANGES", "IDENTITY", "NAMES", "WITH_NONE", "names", "chain", "term", "identity"]


def names() -> tuple[str, ...]:
    """The vocabulary effects (``none`` excluded), in the format's table order."""
    return tuple(sorted((n for n, c in REGISTRY.items() if c.session is not None), key=lambda n: REGISTRY[n].session.table))


def chain() -> tuple[str, ...]:
    """The vocabulary effects in the order the simulated chain applies them."""
    return tuple(sorted(names(), key=lambda n: REGISTRY[n].session.chain))


def term(name: str) -> SessionTerm:
    """The session term of vocabulary effect ``name``; ``UserError`` for any other name."""
    cls = REGISTRY.get(name)
    if cls is None or cls.session is None:
        raise UserError(f"unknown vocabulary effect {name!r} (known: {', '.join(names())})")
    return cls.session


def identity(rate_hz: float) -> dict[str, float]:
    """Per vocabulary effect, the parameter value that leaves a loop at control rate ``rate_hz`` unchanged."""
    return {n: (float(rate_hz) if term(n).identity_is_rate else term(n).identity) for n in chain()}


class _Live(Mapping):
    """A read-only mapping recomputed from the registry on every access (cheap: a dozen entries)."""

    def __init__(self, build: Callable[[], dict[str, Any]]) -> None:
        self._build = build

    def __getitem__(self, key: str) -> Any:
        return self._build()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._build())

    def __len__(self) -> int:
        return len(self._build())

    def __repr__(self) -> str:
        return repr(self._build())


class _LiveNames(Sequence):
    """A read-only sequence of names recomputed from the registry on every access."""

    def __init__(self, build: Callable[[], tuple[str, ...]]) -> None:
        self._build = build

    def __getitem__(self, i):
        return self._build()[i]

    def __len__(self) -> int:
        return len(self._build())

    def __eq__(self, other: object) -> bool:
        return tuple(self) == (tuple(other) if isinstance(other, Sequence) else other)

    def __hash__(self) -> int:
        return hash(self._build())

    def __repr__(self) -> str:
        return repr(self._build())


#: the vocabulary effects in table order (:func:`names`), and the same after ``none``
NAMES: Sequence[str] = _LiveNames(names)
WITH_NONE: Sequence[str] = _LiveNames(lambda: ("none", *names()))
#: effect name -> its parameter names, ``none`` (no parameters) first, then the table order
EFFECT_PARAMS: Mapping[str, tuple[str, ...]] = _Live(lambda: {"none": (), **{n: (term(n).param,) for n in names()}})
#: parameter name -> its allowed range (">0", ">=0", "any"); parameter names are unique across effects
PARAM_RANGES: Mapping[str, str] = _Live(lambda: {term(n).param: term(n).range for n in names()})
#: effect name -> identity value, in chain order (``nan`` where it is the control rate: see :func:`identity`)
IDENTITY: Mapping[str, float] = _Live(lambda: {n: term(n).identity for n in chain()})
