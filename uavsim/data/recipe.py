"""Dataset recipes: strict TOML files that say exactly how a training set is made.

A recipe names the grid (loop family and optional class subset), the relay test
(beta, h, tau_obs, a_n), the episodes (per class, length, physics timestep,
control rate), the randomization (gain, relay bias, noise kinds and levels,
initial output, optional effects), the preprocessing and the seed. Everything
random in a dataset is drawn from the recipe's seed, so that the same recipe
text gives the same file. Unknown keys are errors naming the key and the file:
a typo must not silently give a different dataset.

    from uavsim.data.recipe import load_recipe
    r = load_recipe("datasets/small.toml")
    r.loop, r.episodes.per_class, r.noise.kinds

Recipe reference (every key optional unless marked)::

    loop = "altitude"            # required: altitude | attitude | lateral
    seed = 1                     # required: int >= 0
    classes = [0, 10, 20]        # optional subset of grid classes (default: all)
    att_classes = [0, 1]         # lateral only: attitude classes (default: all), one file each

    [test]
    beta = -0.73                 # default: the grid's beta (the classes' oscillation is for it)
    h = 1.0                      # relay amplitude, command units
    settings = "recommended"     # NP-MRFT tau_obs and a_n as a user gets them (default), or "fixed"
    refinements = 2              # recommended: relay runs refined from the previous one, in the episode
    refine_cycles = 4            # recommended: length of each refined run, in cycles (as episodes.cycles)
    # tau_obs = 0.03             # fixed only: s, capped per class so beta_min <= beta
    # a_n = 1.0                  # fixed only: a multiple of the episode's noise amplitude
    bias_trim = "off"            # "duty": the relay trims its bias from each cycle's duty (see below)

With ``settings = "recommended"`` every episode gets the NP-MRFT settings of
the user's procedure (``uavsim.noise.estimate``): a hover segment of the
episode's own noise gives the first run's settings (``recommend``), and the
episode then runs ``refinements`` times ``refine_cycles`` cycles (or
``duration_s``) with settings refined from the run before (``refine``)
before the episode proper (``cycles`` or ``duration_s``) with the last ones.
A recipe that gives ``tau_obs`` or ``a_n`` and no ``settings`` is read as
``settings = "fixed"`` (how recipes were written before).

With ``bias_trim = "duty"`` the relay starts at its drawn bias and trims it from
each cycle's duty (``uavsim.control.relay``: on these integrating loops the cycle
then becomes the bias-free one), as a user's relay trims the error of its hover
command; the features are read from the relay's states.

    [episodes]
    per_class = 80               # required
    cycles = 8                   # episode length in cycles of the slowest class of its chunk ...
    duration_s = 10.0            # ... or a fixed length in s (exactly one of the two)
    dt = 0.001                   # physics timestep, s
    rate_hz = 200.0              # control rate, Hz
    chunk = 256                  # episodes per batch (one task); part of the recipe: it fixes the seeds

    [randomize]
    K = [0.5, 2.0]               # gain factor range (log-uniform) times the class gain (1)
    bias = 0.5                   # relay bias uniform in [-bias, bias] * h (<= 0.5)
    y0 = 0.5                     # initial output uniform in [-y0, y0] * a0 (a0: the episode's amplitude)
    offgrid = 0.0                # share of each class's episodes drawn off the class centre, in its cell
                                 # (uavsim.data.plan); > 0 also stores each sample's cost vector

    [noise]
    kinds = ["none", "white", "paper", "coloured", "quantization", "outliers"]
    weights = [1, 1, 1, 1, 1, 1] # relative frequency of each kind (default: equal)
    level = [0.0, 0.2]           # noise amplitude / a0, uniform (<= 0.2)

    [preprocess]
    cycles = 1                   # cycles per network input
    keep_raw = false             # also store the raw y, u traces

    [[effects]]                  # optional, any number: an effect of the session vocabulary
    name = "delay"               # parameters: a number, or [lo, hi] for a uniform draw per episode
    delay = [0.0, 0.005]
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uavsim.errors import UserError
from uavsim.noise.models import NOISE_KINDS

LOOP_FAMILIES = ("altitude", "attitude", "lateral")
#: how episodes get their NP-MRFT tau_obs and a_n
SETTINGS = ("recommended", "fixed")
#: noise kinds a recipe may name: "none" plus the study models
RECIPE_NOISE_KINDS = ("none",) + tuple(NOISE_KINDS)


@dataclass(frozen=True)
class TestSpec:
    """Relay test of every episode.

    Attributes
    ----------
    beta : float or None
        MRFT parameter in (-1, 1); None: the grid's beta.
    h : float
        Relay amplitude, command units, > 0.
    settings : str
        ``"recommended"`` (the user's procedure) or ``"fixed"`` (``tau_obs``, ``a_n``).
    refinements : int
        Recommended settings: refined runs before the episode proper.
    refine_cycles : float
        Recommended settings: length of each refined run, cycles of the chunk's slowest class.
    tau_obs : float
        Fixed settings: NP-MRFT observation time, s, >= 0 (capped per class, see module docstring).
    a_n : float
        Fixed settings: NP-MRFT ``a_n`` relative to the episode's noise amplitude, >= 0.
    bias_trim : str
        ``"off"`` or ``"duty"`` (``uavsim.formats.session.RELAY_BIAS_TRIMS``).
    """

    beta: float | None = None
    h: float = 1.0
    settings: str = "recommended"
    refinements: int = 2
    refine_cycles: float = 4.0
    tau_obs: float = 0.03
    a_n: float = 1.0
    bias_trim: str = "off"


@dataclass(frozen=True)
class EpisodeSpec:
    """Episodes: count, length, timestep, rate and chunking (see module docstring)."""

    per_class: int = 0
    cycles: float | None = None
    duration_s: float | None = None
    dt: float = 0.001
    rate_hz: float = 200.0
    chunk: int = 256


@dataclass(frozen=True)
class RandomizeSpec:
    """Per-episode randomization ranges (gain factor log-uniform, bias and y0 relative)."""

    K: tuple[float, float] = (0.5, 2.0)
    bias: float = 0.5
    y0: float = 0.5
    offgrid: float = 0.0


@dataclass(frozen=True)
class NoiseSpec:
    """Noise kinds (with weights) and level range (noise amplitude / a0)."""

    kinds: tuple[str, ...] = ("none",)
    weights: tuple[float, ...] = (1.0,)
    level: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class PreprocessSpec:
    """Cycles per input and whether to keep the raw traces."""

    cycles: int = 1
    keep_raw: bool = False


@dataclass(frozen=True)
class EffectSpec:
    """One effect: its name and parameters (a float, or a (lo, hi) uniform range)."""

    name: str
    params: dict[str, float | tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class Recipe:
    """A parsed recipe; ``text`` is the exact TOML it came from (stored in datasets)."""

    loop: str
    seed: int
    test: TestSpec
    episodes: EpisodeSpec
    randomize: RandomizeSpec
    noise: NoiseSpec
    preprocess: PreprocessSpec
    effects: tuple[EffectSpec, ...] = ()
    classes: tuple[int, ...] | None = None
    att_classes: tuple[int, ...] | None = None
    text: str = ""
    source: str = "<recipe>"
    name: str = "recipe"

    @property
    def hash(self) -> str:
        """sha256 of the recipe text (identifies resume state)."""
        return hashlib.sha256(self.text.encode()).hexdigest()


_SECTIONS = {
    "test": ("beta", "h", "settings", "refinements", "refine_cycles", "tau_obs", "a_n", "bias_trim"),
    "episodes": ("per_class", "cycles", "duration_s", "dt", "rate_hz", "chunk"),
    "randomize": ("K", "bias", "y0", "offgrid"),
    "noise": ("kinds", "weights", "level"),
    "preprocess": ("cycles", "keep_raw"),
}
_TOP = ("loop", "seed", "classes", "att_classes", "effects", *_SECTIONS)


def _num(src: str, key: str, v: Any, lo: float | None = None, hi: float | None = None, *,
         strict_lo: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise UserError(f"{src}: {key} must be a finite number, got {v!r}")
    v = float(v)
    if lo is not None and (v < lo or (strict_lo and v == lo)):
        raise UserError(f"{src}: {key} must be {'>' if strict_lo else '>='} {lo}, got {v}")
    if hi is not None and v > hi:
        raise UserError(f"{src}: {key} must be <= {hi}, got {v}")
    return v


def _int(src: str, key: str, v: Any, lo: int = 0) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise UserError(f"{src}: {key} must be an integer >= {lo}, got {v!r}")
    return int(v)


def _pair(src: str, key: str, v: Any, lo: float, hi: float | None = None) -> tuple[float, float]:
    if not isinstance(v, list) or len(v) != 2:
        raise UserError(f"{src}: {key} must be a [lo, hi] pair, got {v!r}")
    a, b = (_num(src, key, x, lo, hi) for x in v)
    if b < a:
        raise UserError(f"{src}: {key} range [{a}, {b}] is reversed")
    return a, b


def _section(src: str, doc: dict, name: str) -> dict:
    sec = doc.get(name, {})
    if not isinstance(sec, dict):
        raise UserError(f"{src}: [{name}] must be a table")
    for k in sec:
        if k not in _SECTIONS[name]:
            raise UserError(f"{src}: unknown key {name}.{k} (known: {', '.join(_SECTIONS[name])})")
    return sec


def _classes(src: str, key: str, v: Any) -> tuple[int, ...] | None:
    if v is None:
        return None
    if not isinstance(v, list) or not v:
        raise UserError(f"{src}: {key} must be a non-empty list of class indices")
    out = tuple(_int(src, key, x) for x in v)
    if len(set(out)) != len(out):
        raise UserError(f"{src}: {key} has repeated classes")
    return out


def parse_recipe(text: str, source: str = "<recipe>", name: str = "recipe") -> Recipe:
    """Parse and validate recipe TOML ``text``; ``source`` names it in error messages."""
    src = source
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{src}: not valid TOML: {exc}") from None
    from uavsim.schema import validate

    validate("dataset", doc, src)  # keys, types, ranges and each effect's parameters (uavsim.schema.dataset)
    for k in doc:
        if k not in _TOP:
            raise UserError(f"{src}: unknown key {k!r} (known: {', '.join(_TOP)})")
    loop = doc.get("loop")
    if loop not in LOOP_FAMILIES:
        raise UserError(f"{src}: loop must be one of {', '.join(LOOP_FAMILIES)}, got {loop!r}")
    if "seed" not in doc:
        raise UserError(f"{src}: seed is required")
    seed = _int(src, "seed", doc["seed"])

    t = _section(src, doc, "test")
    beta = None if "beta" not in t else _num(src, "test.beta", t["beta"], -1, 1)
    if beta is not None and not -1 < beta < 1:
        raise UserError(f"{src}: test.beta must lie in (-1, 1), got {beta}")
    fixed_keys = [k for k in ("tau_obs", "a_n") if k in t]
    settings = t.get("settings", "fixed" if fixed_keys else "recommended")
    if settings not in SETTINGS:
        raise UserError(f"{src}: test.settings must be one of {', '.join(SETTINGS)}, got {settings!r}")
    if settings == "recommended" and fixed_keys:
        raise UserError(f"{src}: test.{fixed_keys[0]} only goes with settings = \"fixed\" (recommended settings come "
                        f"from each episode's hover and relay runs)")
    refine_keys = [k for k in ("refinements", "refine_cycles") if k in t]
    if settings == "fixed" and refine_keys:
        raise UserError(f"{src}: test.{refine_keys[0]} only goes with settings = \"recommended\"")
    refinements = _int(src, "test.refinements", t.get("refinements", 2), 0)
    if refinements > 5:
        raise UserError(f"{src}: test.refinements must be <= 5, got {refinements}")
    test = TestSpec(beta=beta, h=_num(src, "test.h", t.get("h", 1.0), 0, strict_lo=True), settings=settings,
                    refinements=refinements,
                    refine_cycles=_num(src, "test.refine_cycles", t.get("refine_cycles", 4.0), 2, strict_lo=True),
                    tau_obs=_num(src, "test.tau_obs", t.get("tau_obs", 0.03), 0),
                    a_n=_num(src, "test.a_n", t.get("a_n", 1.0), 0), bias_trim=t.get("bias_trim", "off"))

    e = _section(src, doc, "episodes")
    if "per_class" not in e:
        raise UserError(f"{src}: episodes.per_class is required")
    if ("cycles" in e) == ("duration_s" in e):
        raise UserError(f"{src}: give exactly one of episodes.cycles and episodes.duration_s")
    eps = EpisodeSpec(
        per_class=_int(src, "episodes.per_class", e["per_class"], 1),
        cycles=None if "cycles" not in e else _num(src, "episodes.cycles", e["cycles"], 2, strict_lo=True),
        duration_s=None if "duration_s" not in e else _num(src, "episodes.duration_s", e["duration_s"], 0,
                                                           strict_lo=True),
        dt=_num(src, "episodes.dt", e.get("dt", 0.001), 0, 0.01, strict_lo=True),
        rate_hz=_num(src, "episodes.rate_hz", e.get("rate_hz", 200.0), 0, strict_lo=True),
        chunk=_int(src, "episodes.chunk", e.get("chunk", 256), 1),
    )
    steps = 1.0 / (eps.rate_hz * eps.dt)
    if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
        raise UserError(f"{src}: control period 1/{eps.rate_hz} Hz is not a whole number of {eps.dt} s steps")

    r = _section(src, doc, "randomize")
    K = _pair(src, "randomize.K", r.get("K", [0.5, 2.0]), 1e-6)
    if K[0] <= 0:
        raise UserError(f"{src}: randomize.K must be > 0")
    rnd = RandomizeSpec(K=K, bias=_num(src, "randomize.bias", r.get("bias", 0.5), 0, 0.5),
                        y0=_num(src, "randomize.y0", r.get("y0", 0.5), 0, 10),
                        offgrid=_num(src, "randomize.offgrid", r.get("offgrid", 0.0), 0, 1))
    if rnd.offgrid > 0 and loop == "lateral":
        raise UserError(f"{src}: randomize.offgrid is for the inner loops (altitude, attitude), not lateral")

    n = _section(src, doc, "noise")
    kinds = n.get("kinds", ["none"])
    if not isinstance(kinds, list) or not kinds or any(k not in RECIPE_NOISE_KINDS for k in kinds):
        raise UserError(f"{src}: noise.kinds must be a non-empty list of {', '.join(RECIPE_NOISE_KINDS)}, "
                        f"got {kinds!r}")
    if len(set(kinds)) != len(kinds):
        raise UserError(f"{src}: noise.kinds has repeated kinds")
    weights = n.get("weights", [1.0] * len(kinds))
    if not isinstance(weights, list) or len(weights) != len(kinds):
        raise UserError(f"{src}: noise.weights must have one weight per kind ({len(kinds)})")
    weights = tuple(_num(src, "noise.weights", w, 0) for w in weights)
    if sum(weights) <= 0:
        raise UserError(f"{src}: noise.weights must not all be 0")
    noise = NoiseSpec(kinds=tuple(kinds), weights=weights,
                      level=_pair(src, "noise.level", n.get("level", [0.0, 0.0]), 0, 0.2))

    p = _section(src, doc, "preprocess")
    keep_raw = p.get("keep_raw", False)
    if not isinstance(keep_raw, bool):
        raise UserError(f"{src}: preprocess.keep_raw must be true or false")
    pre = PreprocessSpec(cycles=_int(src, "preprocess.cycles", p.get("cycles", 1), 1), keep_raw=keep_raw)
    if eps.cycles is not None and eps.cycles < pre.cycles + 2:
        raise UserError(f"{src}: episodes.cycles must be >= preprocess.cycles + 2 (transient + used cycles)")

    effects = []
    raw_fx = doc.get("effects", [])
    if not isinstance(raw_fx, list):
        raise UserError(f"{src}: effects must be [[effects]] tables")
    from uavsim.model.effects import REGISTRY

    for i, fx in enumerate(raw_fx):
        if not isinstance(fx, dict) or "name" not in fx:
            raise UserError(f"{src}: effects[{i}] needs a name")
        if fx["name"] not in REGISTRY:
            raise UserError(f"{src}: effects[{i}]: unknown effect {fx['name']!r} (known: {', '.join(sorted(REGISTRY))})")
        params: dict[str, float | tuple[float, float]] = {}
        for k, v in fx.items():
            if k == "name":
                continue
            key = f"effects[{i}].{k}"
            params[k] = _pair(src, key, v, -math.inf) if isinstance(v, list) else _num(src, key, v)
        effects.append(EffectSpec(fx["name"], params))

    return Recipe(loop=loop, seed=seed, test=test, episodes=eps, randomize=rnd, noise=noise, preprocess=pre,
                  effects=tuple(effects), classes=_classes(src, "classes", doc.get("classes")),
                  att_classes=_classes(src, "att_classes", doc.get("att_classes")), text=text, source=src,
                  name=name)


def load_recipe(path: str | Path) -> Recipe:
    """Read and validate the recipe at ``path`` (UserError naming the file and key on any problem)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise UserError(f"cannot read recipe {path}: {exc.strerror}") from None
    return parse_recipe(text, str(path), path.stem)
